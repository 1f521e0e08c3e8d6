"""The walker as an ``rba.domains`` domain: its attributes, parameters, rollout, rendering and raw view.

The parts are the package's other modules (see ``rba.domains.walker``): the rollout is ``run_skill`` of a
:class:`~rba.domains.walker.sim.WalkerSim` and a :class:`~rba.domains.walker.sim.GaitPolicy` reading the sim's own
physics, measured by :func:`~rba.domains.walker.measure.measure`.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from types import MappingProxyType

import numpy as np

from rba.domains.base import (
    ALL_FRAMES,
    AttributeSpec,
    Domain,
    FeedbackPhrases,
    Overlay,
    Reading,
    Rollout,
    SkillPolicy,
    SkillSim,
    run_skill,
    stack_samples,
)
from rba.domains.mujoco_render import Camera, MujocoView, Sky, ThreadRenderers
from rba.domains.walker.gait import PARAM_RANGES, GaitPlan
from rba.domains.walker.measure import (
    FRAME_RATE,
    RAW_EVERY,
    STATE_EVERY,
    STATE_FEATURES,
    measure,
    observed_touchdowns,
    touchdown_proxies,
    walker_overlays,
)
from rba.domains.walker.physics import WalkerPhysics
from rba.domains.walker.sim import GaitPolicy, WalkerSim, WalkerSkillPolicy

# free-text feedback's anchors (rba.interact.free_text): both sides written with the same nouns
FEEDBACK_PHRASES = MappingProxyType({
    "step_size": FeedbackPhrases(
        more=("longer steps", "big strides", "take long strides", "lengthen the stride", "stretch the legs out far",
              "wide steps", "large steps", "cover ground with each step"),
        less=("shorter steps", "small strides", "take short strides", "shorten the stride", "tiny steps",
              "little steps", "keep the legs close together", "shuffle"),
        names=("stride length", "step length")),
    "softness": FeedbackPhrases(
        more=("soft landings", "land gently", "gentle steps", "light footsteps", "tread lightly", "quiet feet",
              "tiptoe", "land softly", "cushion the landing", "delicate steps", "careful footfalls"),
        less=("stomp", "stomping", "hard landings", "land heavily", "heavy steps", "loud footsteps",
              "slam the feet down", "pound the ground", "thud", "forceful landings", "harsh impact"),
        names=("landing softness",)),
})


class Walker(Domain):
    """dm_control walker taking three scripted, assisted steps (the skill: ``rba.domains.walker.gait``)."""

    name = "walker"
    description = "A two-legged robot walks three steps; tune how long and how softly it steps."
    attributes = (
        AttributeSpec(
            name="step_size",
            description="How long the walker's steps are: the distance between its feet when a foot lands.",
            unit="m",
        ),
        AttributeSpec(
            name="softness",
            description="How softly the walker puts its feet down: gentle, slow landings are soft, stomping is not.",
            unit="m/s",
            reading=Reading("landing speed", -1, "lower is softer"),
        ),
    )
    state_dim = len(STATE_FEATURES)
    param_names = tuple(PARAM_RANGES)
    param_ranges = PARAM_RANGES
    frame_rate = FRAME_RATE
    feedback_phrases = FEEDBACK_PHRASES
    zeta_surface = 96  # the generating agent reads clips on ζσ over the parameters: decision 0008
    export_refit = False  # decision 0012
    generate_spread = 0.5  # with the surface: decisions 0003 and 0008
    zeta_noise = 0.04  # its soft step, chosen with the surface: val AF lowest with SR held (same report)
    generate_seconds = 1.0  # decision 0005

    def __init__(self) -> None:
        self._physics: WalkerPhysics | None = None
        # the camera only slides along x, and three quarters of each frame are sky: drawn once a clip
        self._renderers = ThreadRenderers(sky=Sky.ONCE)

    def physics(self) -> WalkerPhysics:
        """The walker's physics, made on first use."""
        if self._physics is None:
            self._physics = WalkerPhysics.from_suite()
        return self._physics

    # ------------------------------------------------------------------ skill
    def rollout(self, params: dict[str, float], seed: int) -> Rollout:
        physics = self.physics()
        sim, policy = WalkerSim(physics), GaitPolicy(GaitPlan.from_params(params, physics.geometry), physics)
        states = run_skill(sim, policy, params, seed)
        recording = sim.recording
        m = measure(recording, policy.controller.touchdowns, policy.plan, physics.body_weight(), physics.timestep())
        states = (stack_samples(recording.raw, STATE_EVERY // RAW_EVERY) if self.raw_states
                  else np.asarray(states, dtype=np.float32))
        return Rollout(id="", domain=self.name, params={k: float(params[k]) for k in self.param_names},
                       seed=int(seed), states=states,
                       replay=np.asarray(recording.frames, dtype=np.float64), proxies=m.proxies,
                       success=m.success, info=m.info)

    # ------------------------------------------------------------------ rendering
    def clip_view(self, rollout: Rollout | None = None) -> MujocoView:
        camera = Camera(CAMERA_DISTANCE, CAMERA_ELEVATION,  # follows the torso along x
                        aim=lambda data: (float(data.xpos[1, 0]), 0.0, CAMERA_LOOKAT_Z))
        return MujocoView(self.physics().model, camera, self._renderers)

    def render(self, rollout: Rollout, width: int, height: int, frames: slice = ALL_FRAMES) -> Iterator[np.ndarray]:
        return self.clip_view(rollout).replay(rollout.replay[frames], width, height)

    def clip_overlays(self, rollout: Rollout, track: Mapping[str, np.ndarray]) -> list[Overlay]:
        return walker_overlays(track["right_foot"], track["left_foot"], self.frame_rate)

    # ------------------------------------------------------------------ stepping (rba.gym)
    def simulator(self) -> SkillSim:
        return WalkerSim(WalkerPhysics.from_suite())

    def skill_policy(self, params: dict[str, float], seed: int) -> SkillPolicy:
        return WalkerSkillPolicy(params)

    def observed_proxies(self, observations: np.ndarray) -> dict[str, float]:
        """The touchdowns' proxies (``touchdown_proxies``) of the touchdowns seen in the observations."""
        return touchdown_proxies(observed_touchdowns(observations, self.physics().timestep()))


class WalkerRaw(Walker):
    """The walker's raw view (``--states raw``): each 10 Hz state is the MuJoCo ``qpos`` and ``qvel`` (9 + 9: root
    z, x, pitch and the six leg joints) at four 40 Hz samples, nothing computed from them.

    ``softness`` is the harder attribute here: it is the foot's peak speed in the 50 ms before touchdown, and a
    40 Hz sample falls in that window once or twice per landing, where the foot's speed is a function of the
    whole leg's angles and rates (its Jacobian) for the models to learn; the feature view hands it over as
    the peak foot speed. ``step_size`` is in the positions (root x and the leg angles at touchdown).
    """

    name = "walker_raw"
    raw_states = True
    state_dim = (STATE_EVERY // RAW_EVERY) * 2 * 9
    generate_seconds = Domain.generate_seconds  # decision 0005 measured the feature view; this one keeps the default
    # no rba.gym env: the gait's policy reads the feature view's observations (foot positions and speeds)
    simulator, skill_policy, observed_proxies = Domain.simulator, Domain.skill_policy, Domain.observed_proxies


CAMERA_DISTANCE = 3.3  # m from the torso, side view
CAMERA_ELEVATION = -8.0  # degrees
CAMERA_LOOKAT_Z = 0.75  # m

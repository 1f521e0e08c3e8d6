"""HalfCheetah from ``gymnasium[mujoco]`` as an RBA domain: tune how fast it runs and how much its body bounces.

The skill is an open-loop gait: each of the six joints follows ``amplitude * sin(2π frequency t + phase)``
with fixed phases (found by a small random search for a gait that runs forward without flipping), for 4 s
(80 env steps of 0.05 s). Two parameters, ``frequency`` (Hz) and ``amplitude`` (of the motor command, which
the env bounds to [-1, 1]), and the reset's noise (``reset_noise_scale`` = 0.1, drawn from the seed), make
clips that differ in two things a person sees:

* ``speed``: the torso's mean forward velocity (m/s) after the first 0.5 s (the start from rest);
* ``bounce``: how far the torso moves up and down after the first 0.5 s: the 5th to 95th percentile
  range of its height (m).

Both are read from the env's own observations (``obs[0]`` the torso's height, ``obs[8]`` its forward
velocity), which are also the states the models see. A clip where the cheetah tips over (its pitch passes
1 rad) is a failure: the libraries keep the others.
"""

from __future__ import annotations

from types import MappingProxyType

import numpy as np

from rba.domains.base import AttributeSpec, FeedbackPhrases
from rba.domains.gym_mujoco import Act, GymMujocoDomain
from rba.domains.mujoco_render import Camera

DT = 0.05  # s per env step: HalfCheetah-v5's 5 physics steps of 0.01 s
SETTLE = 10  # steps (0.5 s) from rest the measurements leave out
HEIGHT, PITCH, FORWARD_VELOCITY = 0, 1, 8  # indices of HalfCheetah-v5's observation
MAX_PITCH = 1.0  # rad: beyond it the cheetah is tipping over
# the joints' phases (bthigh, bshin, bfoot, fthigh, fshin, ffoot), in units of π
PHASES = np.pi * np.array([0.22, 0.84, 0.79, 1.0, 0.5, 0.65])
PARAM_RANGES = MappingProxyType({
    "frequency": (1.5, 4.0),  # Hz of the gait
    "amplitude": (0.2, 0.7),  # of the motor commands; wider swings tip the cheetah over
})

FEEDBACK_PHRASES = MappingProxyType({
    "speed": FeedbackPhrases(
        more=("run fast", "sprint", "hurry", "quick run", "rapid pace", "dash forward"),
        less=("run slowly", "stroll", "take your time", "slow run", "gentle pace", "dawdle"),
        names=("running speed", "pace")),
    "bounce": FeedbackPhrases(
        more=("bouncy body", "hop up and down", "springy", "bob a lot", "jumpy stride", "bumpy ride"),
        less=("level body", "stay flat", "smooth ride", "bob little", "glide", "steady body"),
        names=("bounciness", "bobbing", "how much it bobs")),
})


def side_view(data) -> tuple[float, float, float]:
    """Look at the torso from the side, at a fixed height (only the lookat's x moves)."""
    return float(data.qpos[0]), 0.0, 0.3


class HalfCheetah(GymMujocoDomain):
    name = "halfcheetah"
    description = "A planar cheetah runs on a sinusoidal gait; tune how fast it goes and how much it bounces."
    attributes = (
        AttributeSpec("speed", "How fast the cheetah runs forward.", "m/s"),
        AttributeSpec("bounce", "How much the cheetah's body bobs up and down as it runs.", "m"),
    )
    env_id = "HalfCheetah-v5"
    episode_steps = 80
    state_dim = 17  # HalfCheetah-v5's observation: joint angles (x left out) and velocities
    param_names = tuple(PARAM_RANGES)
    param_ranges = PARAM_RANGES
    frame_rate = 1.0 / DT
    camera = Camera(distance=3.0, elevation=-10.0, aim=side_view)
    feedback_phrases = FEEDBACK_PHRASES
    noisy_skill = True  # the reset's noise, drawn from the seed, changes the gait's outcome

    def skill(self, params: dict[str, float], seed: int) -> Act:
        frequency, amplitude = params["frequency"], params["amplitude"]

        def act(obs: np.ndarray, step: int) -> np.ndarray:
            return np.clip(amplitude * np.sin(2 * np.pi * frequency * step * DT + PHASES), -1.0, 1.0)

        return act

    def observed_proxies(self, observations: np.ndarray) -> dict[str, float]:
        moving = observations[SETTLE:]
        low, high = np.percentile(moving[:, HEIGHT], [5.0, 95.0])
        return {"speed": float(moving[:, FORWARD_VELOCITY].mean()), "bounce": float(high - low)}

    def succeeded(self, observations: np.ndarray) -> bool:
        return super().succeeded(observations) and bool(np.abs(observations[:, PITCH]).max() < MAX_PITCH)

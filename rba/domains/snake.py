"""Snake: concertina locomotion of a 14-link MuJoCo snake of our own (``assets/snake.xml``).

Two-anchor concertina, one cycle per ``period``: in the first half the two head links are
anchored (high friction) and the middle of the body folds into a windowed sine wave, pulling
the tail forward; in the second half the two tail links are anchored and the body straightens,
pushing the head forward. "Anchored" is friction: a link's geom friction switches between 1.5
and 0.03 (the floor's is 0.03, and MuJoCo uses the larger of the two). Joints are position
servos (kp 6) following smooth target changes; physics at 2 ms, control at 100 Hz.

Parameters: ``amplitude`` (rad, the fold's joint-angle amplitude), ``wavelength`` (links per
sine period), ``period`` (s per cycle). Attributes: ``bend_width`` = 95th percentile over time
of the body's lateral extent in its principal-axis frame (m); ``compression`` = 95th
percentile of 1 − head-tail distance / body length; ``speed`` = centre-of-mass speed (m/s).

States (10 Hz): the 13 joint angles, the centre-of-mass velocity in the start heading's frame,
the head-tail distance over the body length, the body's width now, and which end is anchored.

Stepping (``rba.gym``): :class:`SnakeSim` is the snake under per-control-step actions, the 13 joint
targets and each link's friction (anchored or sliding); :class:`ConcertinaPolicy` is the skill, open loop,
reading the shape and the centre of mass's motion off the observations for ``measured()``. The observation
at each control step is the state vector then (the velocity is the mean since the last recorded state);
every 10th is one the rollout records. ``rollout`` is ``run_skill`` of the two: one code path. The raw view
gets no env: its ``qpos`` has no link positions (MuJoCo's, read after its step, lag ``qpos`` by a physics
step), so a policy on them could not measure the shape proxies.
"""

from __future__ import annotations

import copy
import functools
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType

import mujoco
import numpy as np

from rba.domains.base import (
    ALL_FRAMES,
    AttributeSpec,
    Domain,
    FeedbackPhrases,
    Marker,
    Overlay,
    ParamSpace,
    Rollout,
    SkillPolicy,
    SkillSim,
    run_skill,
    stack_samples,
)
from rba.domains.mujoco_render import Camera, MujocoView, Sky, ThreadRenderers

XML = Path(__file__).resolve().parent / "assets" / "snake.xml"
LINKS = 14
LINK_LENGTH = 0.07  # m
BODY_LENGTH = LINKS * LINK_LENGTH  # 0.98 m
ANCHOR_LINKS = 2  # links per anchored end
ANCHORED, SLIDING = 1.5, 0.03  # link friction (the floor's is 0.03)
TIMESTEP = 0.002  # s, the MJCF's physics step
CONTROL_EVERY = 5  # physics steps (2 ms) per control step: 100 Hz
CONTROL_DT = TIMESTEP * CONTROL_EVERY  # s per control step
STATE_EVERY = 10  # control steps per state: 10 Hz
FRAME_EVERY = 4  # control steps per rendered frame: 25 fps (the snake is slow)
CYCLES = 2  # concertina cycles per clip
SETTLE = 0.3  # s straight and still before the first cycle
MAX_HEADING_DRIFT = np.deg2rad(30)  # success: the snake keeps roughly its heading
MIN_ADVANCE = 0.03  # m the centre of mass must move forward

PARAM_RANGES = {
    "amplitude": (0.2, 1.4),  # rad
    "wavelength": (3.0, 14.0),  # links per sine period of the fold
    "span": (5.0, 9.0),  # joints that fold
    "period": (1.2, 5.0),  # s per cycle
}
GRID_AMPLITUDES, GRID_WAVELENGTHS = 31, 23  # the fold-shape lookup grid
AMPLITUDE_STEP = (PARAM_RANGES["amplitude"][1] - PARAM_RANGES["amplitude"][0]) / (GRID_AMPLITUDES - 1)
WAVELENGTH_STEP = (PARAM_RANGES["wavelength"][1] - PARAM_RANGES["wavelength"][0]) / (GRID_WAVELENGTHS - 1)
SPEED_RANGE = (0.008, 0.05)  # m/s: the speed sample_params aims for
ADVANCE_PER_CYCLE = 0.9  # advance per cycle / (compression × body length), measured
FOLD_CENTRE = 7  # the fold is centred on joint 7; joints 1-2 and 12-13 (the anchored ends) stay straight
TARGET_WIDTH = (0.06, 0.15)  # m: the (bend_width, compression) box sample_params draws targets from,
TARGET_COMPRESSION = (0.03, 0.09)  # inside what the fold shapes reach, so the two vary independently
# the state vector: joint angles, centre-of-mass velocity, head-tail distance / length, width now, anchor phase
OBS_VELOCITY = slice(LINKS - 1, LINKS + 1)
OBS_HEAD_TAIL, OBS_WIDTH, OBS_ANCHOR = LINKS + 1, LINKS + 2, LINKS + 3


def fold_shape(amplitude: float, wavelength: float, span: float) -> np.ndarray:
    """Target angles of joints 1..13 at full fold: a sine under a Hann window over ``span`` middle joints."""
    angles = np.zeros(LINKS - 1)
    n = round(span)
    k = np.arange(n)
    joints = np.round(FOLD_CENTRE - (n - 1) / 2 + k).astype(int)
    window = np.sin(np.pi * (k + 1) / (n + 1)) ** 2
    angles[joints - 1] = amplitude * window * np.sin(2 * np.pi * k / wavelength)
    return angles


def fold_geometry(angles: np.ndarray) -> tuple[float, float]:
    """(lateral extent, compression) of the chain bent by ``angles``, kinematically (no physics)."""
    heading = np.concatenate([[0.0], -np.cumsum(angles)])  # link i's direction; joint i turns link i vs i-1
    steps = LINK_LENGTH * np.stack([np.cos(heading), np.sin(heading)], 1)
    points = np.concatenate([[np.zeros(2)], -np.cumsum(steps, 0)])[:-1] - 0.5 * steps
    return body_metrics(points)


def clip_steps(period: float) -> int:
    """Control steps of a clip of ``CYCLES`` cycles of ``period`` s, the settling included."""
    return round((SETTLE + CYCLES * period) / CONTROL_DT)


def smoothstep(s: float) -> float:
    s = min(max(s, 0.0), 1.0)
    return s * s * (3 - 2 * s)


def body_metrics(points: np.ndarray) -> tuple[float, float]:
    """(lateral extent in the principal-axis frame, 1 − head-tail distance / length) of link centres [n, 2]."""
    centred = points - points.mean(0)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    lateral = centred @ vt[1]
    compression = 1.0 - np.linalg.norm(points[0] - points[-1]) / ((LINKS - 1) * LINK_LENGTH)
    return float(lateral.max() - lateral.min()), float(compression)


class ConcertinaController:
    """Two-anchor concertina: the head anchored while the body folds, then the tail while it straightens."""

    def __init__(self, fold: np.ndarray, period: float) -> None:
        self.fold, self.period = fold, period

    def control(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Joint targets and which links are anchored at time ``t`` (negative while settling: all)."""
        period = self.period
        phase = (t % period) / period if t >= 0 else -1.0
        head_anchor = 0 <= phase < 0.5
        tail_anchor = phase >= 0.5
        if t < 0:
            target, anchors = np.zeros(LINKS - 1), np.ones(LINKS, dtype=bool)
        else:
            s = smoothstep(phase / 0.5) if head_anchor else 1.0 - smoothstep((phase - 0.5) / 0.5)
            mirror = -1.0 if int(t // period) % 2 else 1.0  # alternate folds: their steering cancels
            target = mirror * s * self.fold
            anchors = np.zeros(LINKS, dtype=bool)
            anchors[:ANCHOR_LINKS] = head_anchor
            anchors[-ANCHOR_LINKS:] = tail_anchor
        return target, anchors


def anchor_phase(friction: np.ndarray) -> float:
    """1 while only the head is anchored, -1 while only the tail is, 0 otherwise (settling: both)."""
    head, tail = friction[0] > SLIDING, friction[-1] > SLIDING
    return 1.0 if head and not tail else -1.0 if tail and not head else 0.0


class ConcertinaPolicy:
    """The concertina as ``policy(obs) -> action`` (``SkillPolicy``): open loop, the joint targets then each
    link's friction; the shape after settling and the centre of mass's path are read off the observations."""

    def __init__(self, params: dict[str, float]) -> None:
        self.controller = ConcertinaController(
            fold_shape(float(params["amplitude"]), float(params["wavelength"]), float(params["span"])),
            float(params["period"]))
        self._n = clip_steps(self.controller.period)
        self._k = 0
        self._widths: list[float] = []
        self._compressions: list[float] = []
        self._com = np.zeros(2)  # m, from the first state's, at the last recorded state
        self._com_settled = np.zeros(2)  # ... after settling
        self._com_now = np.zeros(2)
        self.done = False

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        k = self._k
        if k:
            self._observe(k - 1, np.asarray(obs, dtype=np.float64))
        if k == self._n:
            self.done = True
            return np.zeros((LINKS - 1) + LINKS)
        target, anchors = self.controller.control(k * CONTROL_DT - SETTLE)
        self._k += 1
        return np.concatenate([target, np.where(anchors, ANCHORED, SLIDING)])

    def _observe(self, step: int, obs: np.ndarray) -> None:
        """Take in the observation after control step ``step``."""
        if step * CONTROL_DT - SETTLE >= 0:
            self._widths.append(obs[OBS_WIDTH])
            self._compressions.append(1.0 - obs[OBS_HEAD_TAIL] * BODY_LENGTH / ((LINKS - 1) * LINK_LENGTH))
        since = step % STATE_EVERY or STATE_EVERY  # control steps the velocity is the mean over
        self._com_now = self._com + obs[OBS_VELOCITY] * (since * CONTROL_DT) if step else np.zeros(2)
        if step % STATE_EVERY == 0:
            self._com = self._com_now
        if step == settled_step():
            self._com_settled = self._com_now

    def measured(self) -> dict[str, float]:
        return snake_proxies(self._widths, self._compressions, self._com_now - self._com_settled,
                             self.controller.period)


def settled_step() -> int:
    """The control step after which the clip's advance is counted (the end of settling)."""
    return int(SETTLE / CONTROL_DT)


def snake_proxies(widths: list[float], compressions: list[float], advance: np.ndarray,
                  period: float) -> dict[str, float]:
    """The attributes' proxies: 95th percentiles of the shape after settling, the mean speed (m/s)."""
    return {"bend_width": float(np.percentile(widths, 95)), "compression": float(np.percentile(compressions, 95)),
            "speed": float(np.linalg.norm(advance) / (CYCLES * period))}


@dataclass
class SnakeRecording:
    """What a rollout keeps besides its states: replay (qpos), body shape after settling, centre of mass."""

    raw: list[np.ndarray] = field(default_factory=list)  # qpos + qvel per state (10 Hz): the raw view
    replay: list[np.ndarray] = field(default_factory=list)
    widths: list[float] = field(default_factory=list)
    compressions: list[float] = field(default_factory=list)
    coms: list[np.ndarray] = field(default_factory=list)  # per control step


class SnakeSim:
    """The snake under per-control-step joint targets and link frictions (``SkillSim``)."""

    max_steps = clip_steps(PARAM_RANGES["period"][1])  # the longest clip

    def __init__(self, model: mujoco.MjModel) -> None:
        self._model = model
        self.action_low = np.concatenate([model.actuator_ctrlrange[:, 0], np.full(LINKS, SLIDING)])
        self.action_high = np.concatenate([model.actuator_ctrlrange[:, 1], np.full(LINKS, ANCHORED)])
        self._geoms = np.array([mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, f"link{i}") for i in range(LINKS)])
        self.bodies = np.array([mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, f"link{i}")
                                 for i in range(LINKS)])

    def reset(self, params: dict[str, float], seed: int) -> tuple[np.ndarray, bool]:
        self.model = copy.copy(self._model)  # friction is switched per episode: never on the shared model
        self.data = data = mujoco.MjData(self.model)
        rng = np.random.default_rng(seed)
        data.qpos[7:] = 0.01 * rng.standard_normal(LINKS - 1)  # a barely bent start: seeds differ slightly
        mujoco.mj_forward(self.model, data)
        self.recording = SnakeRecording()
        self._k, self._state_com = 0, self._com()
        return self._observe(0.0, 0, self._state_com)[0], False

    def step(self, action: np.ndarray) -> tuple[np.ndarray, bool]:
        a = np.asarray(action, dtype=np.float64)
        friction = a[LINKS - 1:]
        self.model.geom_friction[self._geoms, 0] = friction
        self.data.ctrl[:] = a[:LINKS - 1]
        mujoco.mj_step(self.model, self.data, nstep=CONTROL_EVERY)
        k, self._k = self._k, self._k + 1
        com = self._com()
        obs, (width, compression) = self._observe(anchor_phase(friction), k, com)
        rec, data = self.recording, self.data
        if k * CONTROL_DT - SETTLE >= 0:
            rec.widths.append(width)
            rec.compressions.append(compression)
        if k % FRAME_EVERY == 0:
            rec.replay.append(data.qpos.copy())
        recorded = k % STATE_EVERY == 0
        if recorded:
            self._state_com = com
            rec.raw.append(np.concatenate([data.qpos, data.qvel]))
        rec.coms.append(com)
        return obs, recorded

    def _com(self) -> np.ndarray:
        return self.data.subtree_com[self.bodies[0]][:2].copy()

    def _observe(self, anchor: float, step: int, com: np.ndarray) -> tuple[np.ndarray, tuple[float, float]]:
        """The state vector after control step ``step`` with the centre of mass at ``com`` (the velocity: the
        mean since the last recorded state, 0 at the first) and the body's (width, compression)."""
        data, bodies = self.data, self.bodies
        points = data.xpos[bodies][:, :2] + 0.5 * LINK_LENGTH * -_forward(data.xmat[bodies])
        since = step % STATE_EVERY or STATE_EVERY
        vel = (com - self._state_com) / (since * CONTROL_DT) if step else np.zeros(2)
        head_tail = np.linalg.norm(points[0] - points[-1]) / BODY_LENGTH
        shape = body_metrics(points)
        return np.array([*data.qpos[7:], *vel, head_tail, shape[0], anchor]), shape


def snake_overlays(links: np.ndarray, proxies: dict[str, float]) -> list[Overlay]:
    """The page's overlays from the links' centres per frame, float[F, LINKS, 3]: the two links farthest apart
    sideways when the body is widest, head and tail when it is most bunched, and the centre's path."""
    points = links[:, :, :2]
    widths = np.array([body_metrics(p)[0] for p in points])
    spans = np.linalg.norm(points[:, 0] - points[:, -1], axis=1)
    wide, bunched = int(np.argmax(widths)), int(np.argmin(spans))
    centred = points[wide] - points[wide].mean(0)
    axis = np.linalg.svd(centred, full_matrices=False)[2][1]  # the body's sideways principal axis
    side = centred @ axis
    def at(k: int, link: int) -> tuple[float, float, float]:
        return tuple(map(float, links[k, link]))
    centre = links.mean(1)
    return [Overlay("bend_width", "The widest bend: the two links farthest apart sideways",
                    (Marker(wide, at(wide, int(np.argmin(side))), ""),
                     Marker(wide, at(wide, int(np.argmax(side))), f"{widths[wide]:.2f} m wide"))),
            Overlay("compression", "Head and tail when the body is bunched most",
                    (Marker(bunched, at(bunched, 0), "head"),
                     Marker(bunched, at(bunched, LINKS - 1), f"{spans[bunched]:.2f} m apart"))),
            Overlay("speed", "The body's centre: its path",
                    (Marker(len(links) - 1, tuple(map(float, centre[-1])), f"{proxies['speed']:.3f} m/s"),),
                    tuple(tuple(map(float, p)) for p in centre))]


def measure(rec: SnakeRecording, period: float, data: mujoco.MjData,
            bodies: np.ndarray) -> tuple[dict[str, float], bool, dict[str, float]]:
    """Proxies, success and diagnostics of a finished clip."""
    heading = _heading(data.xmat[bodies[0]])
    coms_arr = np.asarray(rec.coms)
    advance = coms_arr[-1] - coms_arr[settled_step()]
    forward = float(advance[0])
    success = forward > MIN_ADVANCE and abs(heading) < MAX_HEADING_DRIFT and np.isfinite(data.qpos).all()
    proxies = snake_proxies(rec.widths, rec.compressions, advance, period)
    return proxies, bool(success), {"forward_m": forward, "heading_rad": float(heading)}


# free-text feedback's anchors (rba.interact.free_text): both sides written with the same nouns
FEEDBACK_PHRASES = MappingProxyType({
    "bend_width": FeedbackPhrases(
        more=("wide bends", "big sideways curves", "swing the body out wide", "broad waves", "large wiggles",
              "sweeping curves", "deep zigzag", "wide body"),
        less=("narrow bends", "small sideways curves", "keep the body straight", "slight wiggles",
              "shallow waves", "flat zigzag", "stay in line", "narrow body"),
        names=("bend width", "width of the bends", "sideways bend")),
    "compression": FeedbackPhrases(
        more=("bunch up tightly", "scrunch together", "compress the body", "coil up", "squeeze together",
              "fold up close", "contract"),
        less=("stretch out", "stay extended", "keep the body long", "elongate", "spread out", "uncoil",
              "loose body"),
        names=("compression", "bunching")),
    "speed": FeedbackPhrases(
        more=("fast", "move quickly", "slither rapidly", "hurry forward", "zoom", "speedy", "quick"),
        less=("slow", "move slowly", "crawl", "creep along", "leisurely pace", "unhurried", "sluggish"),
        names=("forward speed", "speed of travel")),
})


class Snake(Domain):
    name = "snake"
    description = "A robot snake crawls forward by folding and stretching its body; tune its bends and its speed."
    attributes = (
        AttributeSpec("bend_width", "How wide the snake's body bends sideways as it folds.", "m"),
        AttributeSpec("compression", "How tightly the snake bunches its body together before stretching out.",
                      "fraction of body length"),
        AttributeSpec("speed", "How fast the snake moves forward.", "m/s"),
    )
    # joint angles, centre-of-mass velocity (m/s), head-tail distance / length, body width now (m), anchor phase;
    # the width (with 800 ζσ steps) lifted bend_width's ζσ held-out accuracy from 0.92 to 0.96: a sum over
    # states cannot easily rebuild a shape measure from 13 angles
    state_dim = (LINKS - 1) + 2 + 1 + 1 + 1
    param_names = tuple(PARAM_RANGES)
    frame_rate = 1.0 / (FRAME_EVERY * CONTROL_EVERY * TIMESTEP)
    feedback_phrases = FEEDBACK_PHRASES
    zeta_noise = 0.03  # decision 0006
    # ζσ re-fitted on the session's answers (``rba.interact.refit``, from its ``REFIT_AFTER``-th): decision 0011
    session_refit = True
    generate_seconds = 1.25  # decision 0005

    def __init__(self) -> None:
        self._model: mujoco.MjModel | None = None
        # no floor reflection: the snake lies flat on the floor, so it would be a hairline under the
        # body, and drawing it costs ~2 ms of a ~5 ms frame; the camera looks down at the floor, never
        # at the sky (benchmarks/clip_cost.py)
        self._renderers = ThreadRenderers(reflection=False, sky=Sky.HIDDEN)

    def _physics(self) -> mujoco.MjModel:
        if self._model is None:
            self._model = mujoco.MjModel.from_xml_path(str(XML))
            assert self._model.opt.timestep == TIMESTEP  # the policy's clock counts TIMESTEP's
        return self._model

    def sample_params(self, rng: np.random.Generator) -> dict[str, float]:
        """Targets drawn independently, then the fold shape that reaches them (a kinematic lookup) and
        the period that gives the speed (a cycle advances ≈ compression × body length)."""
        width, compression = rng.uniform(*TARGET_WIDTH), rng.uniform(*TARGET_COMPRESSION)
        shapes, reached = _shape_table()
        best = int(np.argmin(((reached - (width, compression)) / (0.1, 0.05)) ** 2 @ np.ones(2)))
        amplitude, wavelength, span = shapes[best]
        amplitude += rng.uniform(-0.5, 0.5) * AMPLITUDE_STEP  # continuous within the grid cell: no two
        wavelength += rng.uniform(-0.5, 0.5) * WAVELENGTH_STEP  # rollouts share parameters by accident
        speed = rng.uniform(*SPEED_RANGE)
        period = ADVANCE_PER_CYCLE * reached[best, 1] * BODY_LENGTH / speed
        return {"amplitude": float(amplitude), "wavelength": float(wavelength), "span": float(span),
                "period": float(np.clip(period, *PARAM_RANGES["period"]))}

    def param_space(self) -> ParamSpace:
        """``sample_params`` jitters the fold shape half a grid cell beyond the grid's ends; ``span`` (whole
        joints) is fixed: a continuous search would only round it."""
        lo = {k: low for k, (low, _) in PARAM_RANGES.items()}
        hi = {k: high for k, (_, high) in PARAM_RANGES.items()}
        for name, step in (("amplitude", AMPLITUDE_STEP), ("wavelength", WAVELENGTH_STEP)):
            lo[name] -= step / 2
            hi[name] += step / 2
        return ParamSpace(lo, hi, frozenset({"span"}))

    def rollout(self, params: dict[str, float], seed: int) -> Rollout:
        sim = SnakeSim(self._physics())
        policy = ConcertinaPolicy(params)
        states = run_skill(sim, policy, params, seed)
        rec = sim.recording
        proxies, success, info = measure(rec, policy.controller.period, sim.data, sim.bodies)
        states = stack_samples(rec.raw, 1) if self.raw_states else np.asarray(states, dtype=np.float32)
        return Rollout("", self.name, dict(params), seed, states,
                       np.asarray(rec.replay, dtype=np.float32),  # qpos for rendering: float32 halves the library
                       proxies, success, info)

    def clip_view(self, rollout: Rollout | None = None) -> MujocoView:
        y0 = 0.0 if rollout is None else float(rollout.replay[0][1])  # the first row's, in every part of the clip
        camera = Camera(CAMERA_DISTANCE, CAMERA_ELEVATION,  # follows the centre of mass forward
                        aim=lambda data: (float(data.subtree_com[1][0]) - 0.1, y0, 0.0))
        return MujocoView(self._physics(), camera, self._renderers)

    def render(self, rollout: Rollout, width: int, height: int, frames: slice = ALL_FRAMES) -> Iterator[np.ndarray]:
        return self.clip_view(rollout).replay(rollout.replay[frames], width, height)

    def clip_overlays(self, rollout: Rollout, track: Mapping[str, np.ndarray]) -> list[Overlay]:
        return snake_overlays(np.stack([track[f"link{i}"] for i in range(LINKS)], 1), rollout.proxies)

    def simulator(self) -> SkillSim:
        return SnakeSim(self._physics())

    def skill_policy(self, params: dict[str, float], seed: int) -> SkillPolicy:
        return ConcertinaPolicy(params)


class SnakeRaw(Snake):
    """The snake's raw view (``--states raw``): each 10 Hz state is MuJoCo's ``qpos`` and ``qvel`` (20 + 19: the
    head link's free joint, position and quaternion, and the 13 hinge angles; their rates), nothing else.

    No width, no head-tail distance, no anchor phase: ``bend_width`` and ``compression`` are shape measures
    (an extent in the body's principal frame, a head-tail distance) the models must rebuild from 13 angles;
    with the width among the features ζσ's held-out accuracy on ``bend_width`` rose from 0.92 to 0.96.
    """

    name = "snake_raw"
    raw_states = True
    state_dim = 20 + 19
    generate_seconds = Domain.generate_seconds  # decision 0005 measured the feature view; this one keeps the default
    simulator, skill_policy = Domain.simulator, Domain.skill_policy  # no env: see the module docstring


CAMERA_DISTANCE = 1.4  # m
CAMERA_ELEVATION = -60.0  # degrees: from above and behind the side


@functools.cache
def _shape_table() -> tuple[np.ndarray, np.ndarray]:
    """Fold parameters on a grid [n, 3] and the (width, compression) each reaches kinematically [n, 2]."""
    grid = np.array([(a, w, n) for a in np.linspace(*PARAM_RANGES["amplitude"], GRID_AMPLITUDES)
                     for w in np.linspace(*PARAM_RANGES["wavelength"], GRID_WAVELENGTHS)
                     for n in range(int(PARAM_RANGES["span"][0]), int(PARAM_RANGES["span"][1]) + 1)])
    return grid, np.array([fold_geometry(fold_shape(*row)) for row in grid])


def _forward(xmat: np.ndarray) -> np.ndarray:
    """Each link's forward (local +x) direction in the plane, [n, 2]."""
    return xmat.reshape(-1, 3, 3)[:, :2, 0]


def _heading(xmat: np.ndarray) -> float:
    r = xmat.reshape(3, 3)
    return float(np.arctan2(r[1, 0], r[0, 0]))

"""Behaviours beyond the serve library: a CMA-ES search over a domain's skill parameters.

The serve library caps what an agent can show. When no clip is close to the agent's current target,
``search`` makes new ones: CMA-ES (the ``cma`` package) over the free parameters of
``Domain.param_space()``, scaled to [0, 1], starting from the parameters of the library clips that score
best, each generation's candidates simulated through the compute layer (``Compute.simulate``, or
``in_process`` here) and scored by an objective that sees only what the agent's models see (states,
never proxies): ``ZetaDistance`` (ζσ distance to the target vector) or ``RewardObjective`` (−Σ rθ(s | v_t)).

A generated rollout is a first-class ``Rollout`` whose id ``gen-<hash>`` is a hash of (domain, params,
seed): equal ids re-simulate to equal states (``replay``). Seeds are fixed (CMA-ES draws from its own
generator; candidates are simulated with ``SearchConfig.sim_seed``, or with seeds counted from it where the
domain's skill is noisy), so a search gives the same rollout every time.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import logging
import math
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
import torch

from rba.compute import SimJob
from rba.domains import ParamSpace, Rollout, domain_target, load_domain
from rba.generate.surface import ZetaSurface
from rba.learn.common import Ragged
from rba.learn.global_reward import GlobalReward, LibraryScorer
from rba.learn.ranker import AttributeRanker

if TYPE_CHECKING:
    import cma

log = logging.getLogger(__name__)

ID_PREFIX = "gen-"
FAILED = 1e6  # the objective of a rollout the skill failed (fell, stalled): worse than any finished one
Simulate = Callable[[list[SimJob]], Iterable[Rollout]]  # Compute.simulate, or in_process
Objective = Callable[[list[Rollout]], np.ndarray]  # one value per rollout, lower is better
Progress = Callable[[int, int], None]  # (generations done k, of at most K)
# surface_search: CMA-ES on ζ̃, where a candidate costs microseconds, not a simulation
SURFACE_GENERATIONS = 40
SURFACE_POPSIZE = 12
SURFACE_PULL = 0.01  # per unit of distance from the start in the unit box, against the ζσ distance (a range is 1)


def generated_id(domain: str, params: dict[str, float], seed: int) -> str:
    """``gen-<hash>`` of what a rollout is made from: the same id always names the same behaviour."""
    key = json.dumps({"domain": domain, "params": {k: float(v) for k, v in sorted(params.items())},
                      "seed": int(seed)}, sort_keys=True)
    return ID_PREFIX + hashlib.sha256(key.encode()).hexdigest()[:16]


def is_generated(rollout_id: str) -> bool:
    return rollout_id.startswith(ID_PREFIX)


def in_process(jobs: Iterable[SimJob]) -> Iterator[Rollout]:
    """Simulate in this process (tests, and one-core machines): the same rollouts as any backend."""
    return (load_domain(j.target).rollout(j.params, j.seed) for j in jobs)


def replay(domain: str, params: dict[str, float], seed: int, simulate: Simulate = in_process) -> Rollout:
    """The generated rollout of (domain, params, seed), simulated again; its id as ``search`` gave it."""
    (rollout,) = simulate([SimJob(domain_target(domain), dict(params), int(seed))])
    rollout.id = generated_id(domain, params, seed)
    return rollout


@dataclass(frozen=True)
class SearchConfig:
    """How hard to search: ``budget`` simulations in generations of ``popsize``; seeded.

    ``seconds`` bounds a search in time as well (the app: someone waits for the clip): no generation starts
    that the mean of those before it says would end later than that after the search began, and one running
    past it ends with the candidates simulated by then (once one of them succeeded; the others are not waited
    for). A search so bounded depends on the machine's speed; ``rba eval`` leaves it off unless asked.
    """

    budget: int = 48
    popsize: int = 8
    sigma: tuple[float, float] = (0.05, 0.25)  # CMA-ES's first step (share of each range): the starts' spread, clipped
    seed: int = 0  # CMA-ES's own draws
    sim_seed: int = 0  # every candidate is simulated with this seed: candidates differ in parameters only ...
    # ... unless each candidate gets a seed of its own, sim_seed + its number in the search (None: where the domain's
    # skill is noisy, ``Domain.noisy_skill``): there a target may lie where only some of the skill's draws reach
    vary_seed: bool | None = None
    good_enough: float | None = None  # stop early once the best objective is at most this
    seconds: float | None = None  # stop before a generation predicted to end later than this (None: budget only)

    def __post_init__(self) -> None:
        if self.seconds is not None and not 0.0 < self.seconds < math.inf:
            raise ValueError(f"a search's time bound must be a number of seconds > 0, got {self.seconds}")

    @property
    def generations(self) -> int:
        return max(self.budget // self.popsize, 1)


@dataclass
class Generation:
    """What a search found: the best candidate (None if every one failed), what it cost, and the other finished
    candidates, best first (a generating agent keeps the first few: clips it may show later without a search)."""

    rollout: Rollout | None
    objective: float
    simulations: int
    generations: int
    seconds: float
    runners_up: list[Rollout] = field(default_factory=list)


def _first_step(space: ParamSpace, starts: list[dict[str, float]], config: SearchConfig) -> tuple[np.ndarray, float]:
    """CMA-ES's start: the best start's free parameters, and a step as wide as the starts are spread."""
    units = np.array([space.to_unit(p) for p in starts])
    spread = float(units.std(0).mean()) if len(units) > 1 else config.sigma[1]
    return np.clip(units[0], 0.0, 1.0), float(np.clip(spread, *config.sigma))


def _cma(x0: np.ndarray, sigma0: float, popsize: int, seed: int) -> cma.CMAEvolutionStrategy:
    """CMA-ES in the unit box, drawing from its own seeded generator (numpy's global one is left alone).
    ``cma`` is imported here, not with the module: with ``scipy.stats`` it takes seconds, and a server that
    imports this module for ``SearchConfig`` should answer before its first search."""
    import cma

    rng = np.random.default_rng(seed)
    return cma.CMAEvolutionStrategy(x0, sigma0, {
        "bounds": [0.0, 1.0], "popsize": popsize, "seed": math.nan,  # nan: leave numpy's global seed alone
        "randn": lambda *shape: rng.standard_normal(shape), "verbose": -9, "verb_log": 0, "verb_disp": 0})


def _out_of_time(elapsed: float, generations: int, seconds: float | None) -> bool:
    """Whether another generation, as long as the mean of the ``generations`` run so far, would end after
    ``seconds``."""
    return seconds is not None and elapsed * (generations + 1) / generations > seconds


def _simulate_until(simulate: Simulate, jobs: list[SimJob], deadline: float, took: list[float]) -> list[Rollout]:
    """The jobs' rollouts in order, or those before the first to arrive after ``deadline`` (``perf_counter``)
    once one succeeded: closing the stream cancels the jobs not started (a slow candidate, e.g. a snake
    that swims its whole horizon, must not hold the clip a person waits for).

    The jobs are handed over one at a time and, once one succeeded, none that would end after the deadline if it
    took as long as the search's jobs so far (``took``: seconds from hand-over to arrival, appended to). Why: a
    backend that takes jobs as its workers free up (``LocalCompute``) runs what it took to the end, and the clip
    the search made is rendered next on the same workers, and would wait for them (decision 0005)."""
    rollouts: list[Rollout] = []
    handed: list[float] = []

    def in_time(_: SimJob) -> bool:
        now = time.perf_counter()
        if any(r.success for r in rollouts) and now + (sum(took) / len(took) if took else 0.0) > deadline:
            return False
        handed.append(now)
        return True

    stream = iter(simulate(itertools.takewhile(in_time, jobs)))
    try:
        for rollout in stream:
            took.append(time.perf_counter() - handed[len(rollouts)])
            rollouts.append(rollout)
            if time.perf_counter() > deadline and any(r.success for r in rollouts):
                break
    finally:
        close = getattr(stream, "close", None)
        if close is not None:
            close()
    return rollouts


def search(domain: str, starts: list[dict[str, float]], objective: Objective, simulate: Simulate = in_process,
           config: SearchConfig = SearchConfig(), on_progress: Progress | None = None) -> Generation:
    """CMA-ES from ``starts`` (best first: library clips' parameters) to the candidate minimising ``objective``.

    Fixed parameters keep the best start's values. Each generation's candidates are simulated together
    (``simulate`` may run them in parallel); ``on_progress(k, K)`` after each generation.
    """
    if not starts:
        raise ValueError("a search starts from at least one library clip's parameters")
    skill, target = load_domain(domain_target(domain)), domain_target(domain)
    space, vary = skill.param_space(), skill.noisy_skill if config.vary_seed is None else config.vary_seed
    x0, sigma0 = _first_step(space, starts, config)
    es = _cma(x0, sigma0, config.popsize, config.seed)
    finished: list[tuple[float, int, Rollout]] = []  # (objective, order simulated, rollout) of finished candidates
    done, clock, took = 0, time.perf_counter(), []
    deadline = clock + (config.seconds if config.seconds is not None else math.inf)
    for k in range(config.generations):
        units = es.ask()
        params = [space.from_unit(u, starts[0]) for u in units]
        seeds = [config.sim_seed + (done + j if vary else 0) for j in range(len(params))]
        rollouts = _simulate_until(simulate, [SimJob(target, p, s) for p, s in zip(params, seeds, strict=True)],
                                   deadline, took)
        scores = np.asarray(objective(rollouts), dtype=np.float64)
        ok = np.array([r.success for r in rollouts], dtype=bool) & np.isfinite(scores)  # NaN would break the ranking
        f = np.where(ok, scores, FAILED)
        cut = len(rollouts) < len(units)  # out of time within the generation: CMA-ES is told nothing more
        if not cut:
            es.tell(units, f.tolist())
        finished += [(float(f[j]), done + j, r) for j, r in enumerate(rollouts) if ok[j]]
        done += len(rollouts)
        best_f = min((x[0] for x in finished), default=math.inf)
        if on_progress:
            on_progress(k + 1, config.generations)
        if config.good_enough is not None and best_f <= config.good_enough:
            break
        if cut or _out_of_time(time.perf_counter() - clock, k + 1, config.seconds):
            break
    seconds = time.perf_counter() - clock
    ranked = [r for _, _, r in sorted(finished, key=lambda x: x[:2])]  # ties: the one simulated first
    for r in ranked:
        r.id = generated_id(domain, r.params, r.seed)
    best = ranked[0] if ranked else None
    log.info("%s: generated %s (objective %.4f) from %d simulations in %.2f s", domain,
             best.id if best else "nothing", best_f, done, seconds)
    return Generation(best, best_f, done, k + 1, seconds, ranked[1:])


def surface_search(domain: str, starts: list[dict[str, float]], surface: ZetaSurface, distance: ZetaDistance,
                   simulate: Simulate = in_process, config: SearchConfig = SearchConfig(),
                   on_progress: Progress | None = None) -> Generation:
    """The clip at the parameters whose ζ̃ (``surface``) is nearest ``distance``'s target, simulated once.

    CMA-ES runs on the surface, which costs no simulation, from the first start (the generating agent's: the clip
    it made last, else the nearest); among parameters that reach the target it keeps those nearest that start
    (``SURFACE_PULL``), where the surface was fitted on the clips around it. The result's ``objective`` is that
    distance (pull included); a skill that fails there gives no clip.
    """
    if not starts:
        raise ValueError("a search starts from at least one library clip's parameters")
    space, clock = load_domain(domain_target(domain)).param_space(), time.perf_counter()
    x0 = np.clip(space.to_unit(starts[0]), 0.0, 1.0)
    es = _cma(x0, config.sigma[0], SURFACE_POPSIZE, config.seed)
    best, best_f = x0, math.inf
    for _ in range(SURFACE_GENERATIONS):
        units = np.array(es.ask())
        f = distance.distances(surface(units)) + SURFACE_PULL * np.linalg.norm(units - x0, axis=1)
        es.tell(list(units), f.tolist())
        if f.min() < best_f:
            best, best_f = units[int(np.argmin(f))], float(f.min())
    made = replay(domain, space.from_unit(best, starts[0]), config.sim_seed, simulate)
    if on_progress:
        on_progress(1, 1)
    seconds = time.perf_counter() - clock
    log.info("%s: made %s on the ζσ surface (distance %.4f) in %.2f s", domain, made.id, best_f, seconds)
    return Generation(made if made.success else None, best_f, 1, 1, seconds)


def rollout_data(rollouts: list[Rollout]) -> Ragged:
    """The states of ``rollouts`` as one ``Ragged`` (what the models score)."""
    offsets = np.concatenate([[0], np.cumsum([len(r.states) for r in rollouts])])
    return Ragged.from_numpy(np.concatenate([r.states for r in rollouts]), offsets)


def ranker_zeta(ranker: AttributeRanker, rollouts: list[Rollout]) -> np.ndarray:
    """ζσ of each rollout's states, float[len(rollouts), k]."""
    return ranker.score(rollout_data(rollouts))


@dataclass
class ZetaDistance:
    """The largest per-attribute ζσ distance to ``target``, each attribute's train range scaled to 1.

    The max, not the sum: success is every attribute within ε, and a box is what the max measures.
    """

    ranker: AttributeRanker
    target: np.ndarray  # float64[k]: the agent's ζσ target vector v_t
    scale: np.ndarray  # float64[k]: each attribute's ζσ range over train

    def distances(self, zeta: np.ndarray) -> np.ndarray:
        return np.max(np.abs(np.atleast_2d(zeta) - self.target) / self.scale, axis=1)

    def zeta(self, rollouts: list[Rollout]) -> np.ndarray:
        return ranker_zeta(self.ranker, rollouts)

    def __call__(self, rollouts: list[Rollout]) -> np.ndarray:
        return self.distances(self.zeta(rollouts))


@dataclass
class RewardObjective:
    """−Σ_t rθ(s_t | v_t): the learned reward's own ranking of the candidates (the paper's objective)."""

    reward: GlobalReward
    target: np.ndarray

    def __call__(self, rollouts: list[Rollout]) -> np.ndarray:
        with torch.no_grad():
            return -LibraryScorer(self.reward, rollout_data(rollouts)).returns(self.target)

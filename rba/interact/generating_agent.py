"""RBA-Global that makes a clip when the serve library has none close to its target (``rba.generate.cma``).

``GeneratingGlobalAgent`` wraps a ``GlobalAgent``: the inner agent keeps the belief and picks a library
clip as always; when that clip's ζσ (the agent's own models, never proxies) is farther than ``threshold``
from the target v_t in some attribute (ζσ ranges scaled to 1), and farther than the belief is sure of the
target there (``spread``: early on, a library clip near a wide belief's median asks as well as a made one),
a CMA-ES search makes a clip for v_t,
starting from the nearest library and session clips, and shows it instead if it is nearer and moves the
asked attributes the asked way. Feedback about a generated clip updates the belief at that clip's ζσ. The belief
takes every answer as a soft step of the domain's ``zeta_noise`` (``rba.interact.bisection``): made clips land where
ζσ puts the target, where it orders clips a few high-precision ε apart only by chance, so answers there contradict
each other in ζσ.
Where the proxies move smoothly with the skill's parameters (``Domain.zeta_surface``, the walker) the agent reads
every clip on ζ̃, a fit of the serve library's ζσ over the parameters (``rba.generate.surface``), not on ζσ of the
clip's own states, and makes a clip by solving ζ̃ for its target (``rba.generate.cma.surface_search``: one
simulation), starting from the clip it made last, so its clips stay in one region of the parameters; a clip it
would make again (within ``REPEAT`` of one the user judged) is made by the ζσ search instead, in what is left of the
time bound.
A search whose best clip stayed farther than ``threshold`` from its target is not run again for a target
within ``threshold`` of that one for ``RETRY_AFTER`` rounds: the same starts and budget would fail again;
later it may, with the session's new clips as starts and another seed.
A search simulates dozens of candidates and shows one; the session keeps the best ``POOL_KEEP`` others by the
search's objective (the ζσ search's: the nearest the target), the *pool* (params, seed and ζ each). A pooled clip
within ``threshold`` of a later target is shown without a search, and in the rounds a search fell short or may not
run again, the pooled clip nearest the target is shown when it is nearer than the library's: there the library's
clips are far (a target no serve clip is near is why the agent searched), and each clip a user judges near the
target is another draw at it.

With ``GenerationContext.refit`` (``Domain.session_refit``; the snake's) the agent fits ζσ's last layers
again after each answer, from the ``refit_after``-th on, on the pairs its answers order (``rba.interact.refit``),
and reads everything above under them: the library, its made and pooled clips, where its earlier answers were
given, its searches' objective.

State: the agent's JSON keeps, per generated clip, its params, seed and ζσ (a few numbers), not its
states: the id is content-addressed (``gen-<hash of domain, params, seed>``), so anything that needs the
clip itself (the simulated user, a render) asks ``GenerationContext.rollout``, which keeps recent ones in
memory and re-simulates the rest, bit for bit. A restored agent never simulates to continue: ζσ is stored.
"""

from __future__ import annotations

import copy
import threading
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Generic, TypeVar

import numpy as np

from rba.core.artifacts import load_model
from rba.core.methods import Method, get_method
from rba.data.library import SkillLibrary
from rba.domains import Rollout, get_domain
from rba.generate.cma import (
    Generation,
    Progress,
    RewardObjective,
    SearchConfig,
    Simulate,
    ZetaDistance,
    in_process,
    ranker_zeta,
    replay,
    rollout_data,
    search,
    surface_search,
)
from rba.generate.surface import ZetaSurface
from rba.interact.base import SATISFIED, Agent, Feedback, validate_feedback
from rba.interact.global_agent import METHOD as GLOBAL
from rba.interact.global_agent import GlobalAgent, GlobalContext
from rba.interact.refit import REFIT_AFTER, Answered, refit_heads
from rba.learn.common import Ragged
from rba.learn.ranker import AttributeRanker

# ζσ distance (max over attributes, train range = 1) above which the agent generates: about the high-precision ε
# (1/42 of a range); so far checked on walker val targets only
THRESHOLD = 0.02
# ... and by more than ``GenerationContext.spread`` (the domain's ``Domain.generate_spread``) × the belief's half
# interquartile range there
STARTS = 4  # nearest clips whose parameters start (and spread) the search
RETRY_AFTER = 10  # rounds after which a search that fell short may run again near its own target
STORE_SIZE = 256  # generated rollouts kept in memory per context; older ones are re-simulated when asked for
OBJECTIVES = ("zeta", "reward")
REPEAT = 0.01  # a made clip this near one judged before (unit box, per parameter) is made again by the ζσ search
POOL_KEEP = 8  # a search's runners-up the session keeps (the best by the search's objective) ...
POOL_SIZE = 64  # ... up to this many in all, the oldest dropped first
MIN_SECONDS = 0.05  # the least time bound a ζσ search after the surface's set-aside clip gets (it makes one clip)
FEATURES_SIZE = 2048  # made clips whose summed features (``rba.interact.refit``) a context keeps
Made = tuple[Rollout, np.ndarray]  # a made clip and its ζ as the agent reads it


K = TypeVar("K")
V = TypeVar("V")


class Recent(Generic[K, V]):
    """The ``size`` most recently used values by key (thread-safe): the caches below, each of something that can
    be made again."""

    def __init__(self, size: int) -> None:
        self.size = size
        self._items: OrderedDict[K, V] = OrderedDict()
        self._lock = threading.Lock()

    def get(self, key: K) -> V | None:
        with self._lock:
            found = self._items.get(key)
            if found is not None:
                self._items.move_to_end(key)
            return found

    def put(self, key: K, value: V) -> None:
        with self._lock:
            self._items[key] = value
            self._items.move_to_end(key)
            while len(self._items) > self.size:
                self._items.popitem(last=False)

    def get_or_make(self, key: K, make: Callable[[], V]) -> V:
        """The value kept for ``key``, else ``make()`` (outside the lock: it may take long), kept."""
        found = self.get(key)
        if found is None:
            found = make()
            self.put(key, found)
        return found


class GeneratedStore:
    """Recent generated rollouts by id: a cache, since (params, seed) remake any of them."""

    def __init__(self, size: int = STORE_SIZE) -> None:
        self._recent: Recent[str, Rollout] = Recent(size)

    def put(self, rollout: Rollout) -> None:
        self._recent.put(rollout.id, rollout)

    def get(self, rollout_id: str) -> Rollout | None:
        return self._recent.get(rollout_id)

    def rollout(self, domain: str, rollout_id: str, params: dict[str, float], seed: int,
                simulate: Simulate = in_process) -> Rollout:
        """A generated rollout: from here, else simulated again from its params and seed (and kept)."""
        return self._recent.get_or_make(rollout_id, lambda: _remade(domain, rollout_id, params, seed, simulate))


def _remade(domain: str, rollout_id: str, params: dict[str, float], seed: int, simulate: Simulate) -> Rollout:
    found = replay(domain, params, seed, simulate)
    if found.id != rollout_id:
        raise ValueError(f"params and seed make {found.id}, not {rollout_id}")
    return found


Features = tuple[np.ndarray, float]  # a clip's summed features float[k, H] and its length


class FeatureCache:
    """ζσ's summed features (``AttributeRanker.summed_features``) of the serve library (computed once, when first
    asked for) and of recent made clips by id, and the last layers fitted per session's answers: what re-fitting
    ζσ's last layers on a session reads (``rba.interact.refit``)."""

    def __init__(self, size: int = FEATURES_SIZE) -> None:
        self._serve: dict[str, tuple[np.ndarray, np.ndarray]] = {}  # by the library's version
        self._serve_lock = threading.Lock()
        self._made: Recent[str, Features] = Recent(size)
        # by the answers they were fitted on: a restored session (the app restores one every step) reads them
        self._heads: Recent[tuple, tuple[np.ndarray, np.ndarray]] = Recent(size)

    def serve(self, ranker: AttributeRanker, serve: SkillLibrary) -> tuple[np.ndarray, np.ndarray]:
        """float[k, N, H] features and float[N] lengths of the serve library's clips."""
        with self._serve_lock:
            if serve.version not in self._serve:
                data = Ragged.from_numpy(serve.states, serve.state_offsets)
                self._serve[serve.version] = ranker.summed_features(data)
            return self._serve[serve.version]

    def made(self, ranker: AttributeRanker, rollout_id: str, rollout: Callable[[], Rollout]) -> Features:
        """A made clip's features: kept, else computed from ``rollout()`` (only then asked for). One clip at a time:
        the same clip's features are then the same bits whichever clips it was made with (a restored session)."""
        def compute() -> Features:
            phi, lengths = ranker.summed_features(rollout_data([rollout()]))
            return phi[:, 0], float(lengths[0])

        return self._made.get_or_make(rollout_id, compute)

    def heads(self, answered: Answered, fit: Callable[[], tuple[np.ndarray, np.ndarray]]
              ) -> tuple[np.ndarray, np.ndarray]:
        """The last layers ``fit`` gives for ``answered``: kept from an earlier fit on the same answers, else fitted."""
        return self._heads.get_or_make(tuple((rid, tuple(map(tuple, asked))) for rid, asked in answered), fit)


@dataclass
class GenerationContext:
    """A ``GlobalContext`` plus what generating needs: the ζσ ranker for new clips, a simulator, a store."""

    base: GlobalContext
    ranker: AttributeRanker
    simulate: Simulate = in_process  # Compute.simulate on the local pools or Ray
    # makes a clip already made again (its features, after a restart): not a search (None: ``simulate``)
    remake: Simulate | None = None
    config: SearchConfig = field(default_factory=SearchConfig)
    threshold: float = THRESHOLD
    spread: float | None = None  # see THRESHOLD (None: the domain's ``Domain.generate_spread``)
    objective: str = "zeta"
    on_progress: Progress | None = None  # (generation k, of K) of the running search
    # told, just before a search starts, the serve clip shown if it falls short (the app renders that one meanwhile)
    on_search: Callable[[str], None] | None = None
    store: GeneratedStore = field(default_factory=GeneratedStore)
    first_from_library: bool = False  # the first clip is the library's (the app: one first clip for every session)
    zeta_noise: float | None = None  # the belief's soft step (None: the domain's ``Domain.zeta_noise``)
    # where the belief starts (``GlobalContext.prior_width``; None: the domain's ``Domain.belief_prior``; 0: uniform)
    prior_width: float | None = None
    surface: int | None = None  # neighbours of the ζσ surface clips are read on (None: the domain's; 0: none)
    # fitted on construction from ``surface`` (then ``base`` reads the library on it); passed on by
    # ``dataclasses.replace`` (the app's per-step contexts), so a copy neither fits again nor smooths twice
    zeta_surface: ZetaSurface | None = None
    # re-fit ζσ's last layers on the session's answers (``rba.interact.refit``; None: the domain's
    # ``Domain.session_refit``); its features are shared by the copies ``with_heads`` makes
    refit: bool | None = None
    refit_after: int | None = None  # answers before the first re-fit (None: ``rba.interact.refit.REFIT_AFTER``)
    features: FeatureCache = field(default_factory=FeatureCache)

    def __post_init__(self) -> None:
        if self.objective not in OBJECTIVES:
            raise ValueError(f"unknown objective {self.objective!r}; valid: {', '.join(OBJECTIVES)}")
        domain = get_domain(self.base.domain)
        if self.zeta_noise is None:
            self.zeta_noise = domain.zeta_noise
        if self.spread is None:
            self.spread = domain.generate_spread
        if not self.spread >= 0.0:
            raise ValueError(f"spread is a share of the belief's half interquartile range (≥ 0), got {self.spread}")
        if not 0.0 <= self.zeta_noise < 1.0:
            raise ValueError(f"zeta_noise is a share of ζσ's range in [0, 1), got {self.zeta_noise}")
        if self.prior_width is None:
            self.prior_width = domain.belief_prior
        if not 0.0 <= self.prior_width < 1.0:
            raise ValueError(f"prior_width is a share of ζσ's range in [0, 1), got {self.prior_width}")
        if self.prior_width != self.base.prior_width:
            self.base = replace(self.base, prior_width=self.prior_width)
        if self.surface is None:
            self.surface = domain.zeta_surface
        if self.surface == 1 or self.surface < 0:
            raise ValueError(f"a ζσ surface fits a plane through 2 or more clips (0: none), got {self.surface}")
        if self.refit is None:
            self.refit = domain.session_refit
        if self.refit_after is None:
            self.refit_after = REFIT_AFTER
        if self.refit_after < 1:
            raise ValueError(f"refit_after counts the answers before the first re-fit (≥ 1), got {self.refit_after}")
        if self.refit and self.surface:
            raise ValueError("a session's re-fit reads ζσ of each clip's states, the surface ζ̃ over the parameters: "
                             "use one (surface=0 or refit=False)")
        self._space = domain.param_space()
        if self.surface and self.zeta_surface is None:
            self.zeta_surface = self._fit_surface()
        elif not self.surface:
            self.zeta_surface = None

    def _fit_surface(self) -> ZetaSurface:
        """ζ̃ over the serve library's parameters; the base context then reads the library's clips on it too."""
        surface = ZetaSurface.of_library(self.base.serve, self.base.serve_zeta, self._space, self.surface)
        self.base = replace(self.base, serve_zeta=surface(surface.units))
        return surface

    @property
    def domain(self) -> str:
        return self.base.domain

    @property
    def rep(self) -> str:
        return self.base.rep

    @property
    def model_version(self) -> str:
        return self.base.model_version

    @property
    def attribute_names(self) -> tuple[str, ...]:
        return self.base.attribute_names

    @property
    def generations(self) -> int:
        """Generations a search reports at most: one on the surface (one simulation; a search that falls back to
        the ζσ search reports that one's), else CMA-ES's."""
        return 1 if self.zeta_surface is not None and self.objective == "zeta" else self.config.generations

    @classmethod
    def load(cls, base: GlobalContext, models_root=None, **options) -> GenerationContext:
        return cls(base, load_model(base.domain, "ranker", base.rep, models_root).model, **options)

    def distance(self, target: np.ndarray) -> ZetaDistance:
        return ZetaDistance(self.ranker, np.asarray(target, np.float64),
                            np.maximum(self.base.bounds[1] - self.base.bounds[0], 1e-9))

    def generate(self, target: np.ndarray, starts: list[dict[str, float]], seed: int,
                 judged: list[dict[str, float]] = ()) -> tuple[Generation, np.ndarray, list[Made]]:
        """The best clip a search finds for ``target``, its ζ as the agent reads it, and the search's first
        ``POOL_KEEP`` runners-up with theirs (every one of them is in the store).

        On the surface, a clip within ``REPEAT`` of one already ``judged`` (the parameters of made clips the user
        did not accept) is made again by the ζσ search: where the surface errs it makes the same clip again."""
        dist = self.distance(target)
        config = replace(self.config, seed=self.config.seed + seed)
        found = spent = None
        if self.zeta_surface is not None and self.objective == "zeta":
            found = surface_search(self.base.domain, starts, self.zeta_surface, dist, self.simulate, config,
                                   self.on_progress)
            if found.rollout is not None and self._repeats(found.rollout.params, judged):
                found, spent = None, found
        if found is None:
            objective = dist if self.objective == "zeta" else RewardObjective(self.base.scorer.model, dist.target)
            good = self.threshold if self.objective == "zeta" else None
            found = search(self.base.domain, starts, objective, self.simulate,
                           replace(config, good_enough=good, seconds=_left(config.seconds, spent)), self.on_progress)
        if spent is not None:  # the surface's clip, simulated and set aside, is part of what this search cost
            found = replace(found, simulations=found.simulations + spent.simulations,
                            seconds=found.seconds + spent.seconds)
        if found.rollout is None:
            return found, np.full(len(dist.target), np.nan), []
        others = found.runners_up[:POOL_KEEP]
        for r in [found.rollout, *others]:
            self.store.put(r)
        zetas = self.zetas([found.rollout, *others])
        return found, zetas[0], list(zip(others, zetas[1:], strict=True))

    def _repeats(self, params: dict[str, float], judged: list[dict[str, float]]) -> bool:
        unit = self._space.to_unit(params)
        return any(np.max(np.abs(self._space.to_unit(p) - unit)) < REPEAT for p in judged)

    def zetas(self, rollouts: list[Rollout]) -> np.ndarray:
        """Made clips' ζ as the belief takes it: ζ̃ at their parameters on the surface, else ζσ of their states."""
        if self.zeta_surface is not None:
            return np.array([self.zeta_surface.at(self._space, r.params) for r in rollouts])
        if self.ranker.heads is not None:  # re-fitted: the features are kept for the next fit
            made = [self.features.made(self.ranker, r.id, lambda r=r: r) for r in rollouts]
            phi, lengths = zip(*made, strict=True)
            return self.ranker.zeta_of(np.stack(phi, 1), np.array(lengths), *self.ranker.head())
        return ranker_zeta(self.ranker, rollouts)

    def rollout(self, rollout_id: str, params: dict[str, float], seed: int) -> Rollout:
        """A generated rollout: from the store, else simulated again from its params and seed."""
        return self.store.rollout(self.base.domain, rollout_id, params, seed, self.remake or self.simulate)

    def with_heads(self, weight: np.ndarray, bias: np.ndarray) -> GenerationContext:
        """This context with ζσ's last layers (weight, bias) per attribute: its ranker, and the serve library read
        under them (``rba.interact.refit``)."""
        phi, lengths = self.features.serve(self.ranker, self.base.serve)
        base = replace(self.base, serve_zeta=self.ranker.zeta_of(phi, lengths, weight, bias))
        return replace(self, base=base, ranker=self.ranker.with_heads(weight, bias))

    def clip_features(self, rollout_id: str, made: dict | None) -> Features:
        """A clip's summed features and length: a serve clip's (``made`` None), or a made one's (its params, seed)."""
        if made is None:
            phi, lengths = self.features.serve(self.ranker, self.base.serve)
            i = self.base.serve.index_of(rollout_id)
            return phi[:, i], float(lengths[i])
        return self.features.made(self.ranker, rollout_id,
                                  lambda: self.rollout(rollout_id, made["params"], made["seed"]))


class GeneratingGlobalAgent(Agent):
    """RBA-Global over the serve library and the clips it generates when none is close (module docstring)."""

    method = "global"
    feedback_kind = "attribute"

    def __init__(self, ctx: GenerationContext, inner: GlobalAgent | None = None,
                 generated: dict[str, dict] | None = None, showing: str | None = None,
                 searches: list[dict] | None = None, pool: dict[str, dict] | None = None,
                 answered: Answered | None = None) -> None:
        self.ctx = ctx
        self.inner = inner or GlobalAgent(ctx.base, zeta_noise=ctx.zeta_noise)
        # id -> {"params", "seed", "zeta", "round" it was shown at, "pooled" if a runner-up shown without a search};
        # copied deep: a re-fit re-reads each clip's ζ in place, and the state given (a stored one) must not move
        self.generated = copy.deepcopy(generated or {})
        self.pool = copy.deepcopy(pool or {})  # id -> {"params", "seed", "zeta"}: searches' runners-up, not shown yet
        self.showing = showing  # the generated clip shown now (None: the inner agent's library clip)
        self.searches = list(searches or [])  # per search: simulations, whether its clip was shown
        # with ``ctx.refit``: per answer, the clip's id and the (attribute, ±1) said; ζσ's last layers are fitted on
        # them (``rba.interact.refit``), and ``ctx`` is then a copy with those, read by everything below
        self.answered: Answered = [(rid, [tuple(x) for x in asked]) for rid, asked in answered or []]
        if self._fitted():
            self._refit()
        # wall-clock seconds of this object's searches: kept out of the state, which must be a function of the
        # answers alone (equal states share the server's memo of steps)
        self.seconds: list[float] = []

    @property
    def shown(self) -> int | None:
        return self.inner.shown

    def _zeta_shown(self) -> np.ndarray:
        if self.showing is not None:
            return np.array(self.generated[self.showing]["zeta"])
        return self.ctx.base.serve_zeta[self.inner.shown]

    def first_query(self) -> str:
        self.inner.first_query()
        return self._choose(None, [])

    def update(self, feedback: Feedback) -> str:
        names = self.ctx.base.attribute_names
        if self.ctx.refit and feedback != SATISFIED and self.shown is not None:
            validate_feedback(feedback, self.feedback_kind, names)  # before it joins what the heads are fitted on
            shown = self.showing or self.ctx.base.serve.ids[self.inner.shown]
            self.answered.append((shown, [(names.index(fb.attribute), fb.direction) for fb in feedback]))
            if self._fitted():
                self._refit()
                self._read_again()
        before = self._zeta_shown()
        self.inner.shown_zeta = before if self.showing is not None else None
        try:
            library = self.inner.update(feedback)
        finally:
            self.inner.shown_zeta = None
        if feedback == SATISFIED:
            return self.showing or library
        return self._choose(before, [(names.index(fb.attribute), fb.direction) for fb in feedback])

    def _fitted(self) -> bool:
        """Whether enough answers were given for ζσ's last layers to be re-fitted on them (``refit_after``)."""
        return len(self.answered) >= self.ctx.refit_after

    def _refit(self) -> None:
        """ζσ's last layers fitted on the answers so far: ``ctx`` becomes a copy that reads clips with them."""
        heads = self.ctx.features.heads(self.answered,
                                        lambda: refit_heads(self.ctx.ranker, self.answered, self._features))
        self.ctx = self.ctx.with_heads(*heads)
        self.inner.use_context(self.ctx.base)

    def _features(self, rollout_id: str) -> Features:
        made = self.generated.get(rollout_id) or self.pool.get(rollout_id)
        return self.ctx.clip_features(rollout_id, made)

    def _read_again(self) -> None:
        """Made clips' ζ, and where each earlier answer was given, read under the re-fitted ζσ (the answer just
        given is placed by ``update``, at the shown clip's ζ)."""
        for rollout_id, made in (*self.generated.items(), *self.pool.items()):
            made["zeta"] = [float(v) for v in self._zeta_of(rollout_id)]
        placed = [(self._zeta_of(rid), asked) for rid, asked in self.answered[:-1]]
        self.inner.reread([(a, float(z[a]), h) for z, asked in placed for a, h in asked])

    def _zeta_of(self, rollout_id: str) -> np.ndarray:
        phi, length = self._features(rollout_id)
        return self.ctx.ranker.zeta_of(phi[:, None], np.array([length]), *self.ctx.ranker.head())[0]

    def _starts(self, dist: ZetaDistance) -> list[dict[str, float]]:
        """Parameters of the ``STARTS`` clips nearest the target, library and this session's generated ones; on the
        surface, the clip made last first.

        Why: the surface search stays near its first start, so made clips then stay in one region of the
        parameters, where ζ̃ and the proxies move together (locally affine: 0.14 / 0.27 high ε off). Started from the
        nearest clip instead, consecutive clips came from regions whose ζ̃ agree but whose proxies differ by
        several ε, and the agent alternated between them (decision 0008)."""
        base = self.ctx.base
        lib = dist.distances(base.serve_zeta)
        order = np.argsort(lib, kind="stable")[:STARTS]
        pool = [(float(lib[i]), dict(zip(base.serve.param_names, map(float, base.serve.params[i]), strict=True)))
                for i in order]
        pool += [(float(dist.distances(np.array(g["zeta"]))[0]), g["params"]) for g in self.generated.values()]
        nearest = [p for _, p in sorted(pool, key=lambda x: x[0])[:STARTS]]
        if self.ctx.zeta_surface is None or not self.generated:
            return nearest
        last = self._made_last()["params"]
        return [last, *[p for p in nearest if p is not last][:STARTS - 1]]

    def _made_last(self) -> dict:
        """The generated clip shown most recently (states from before ``round`` was kept: the last stored)."""
        made = list(self.generated.values())
        return max(enumerate(made), key=lambda ig: (ig[1].get("round", -1), ig[0]))[1]

    def _failed_near(self, dist: ZetaDistance) -> bool:
        """Whether a search in the last ``RETRY_AFTER`` rounds, for a target within the threshold of this one,
        ended farther than it. Later, a search there may run again: its seed and starts (the session's clips
        nearest the target) have changed, and a belief that stopped moving has no other way to the target."""
        now = len(self.inner.rejected)
        failed = [s["target"] for s in self.searches
                  if "target" in s and (s["reached"] is None or s["reached"] > self.ctx.threshold)
                  and now - s.get("round", 0) < RETRY_AFTER]
        return bool(failed) and float(dist.distances(np.array(failed)).min()) <= self.ctx.threshold

    def _off_target(self, off: np.ndarray, scale: np.ndarray) -> bool:
        """Whether a clip ``off`` the target by this much per attribute (ranges scaled to 1) misses it, on some
        attribute, by more than the threshold and more than ``spread`` × half the belief's interquartile range."""
        unsure = self.ctx.spread * self.inner.widths() / 2 / scale
        return bool(np.any(off > np.maximum(self.ctx.threshold, unsure)))

    def _choose(self, before: np.ndarray | None, asked: list[tuple[int, int]]) -> str:
        """The inner agent's library clip, or a made one when that is too far from the target: a pooled runner-up
        that is near enough (no search), else a search's best, else (the search fell short, or one near this
        target did a few rounds ago) the nearest pooled clip if it is nearer than the library's."""
        base, self.showing = self.ctx.base, None
        library = base.serve.ids[self.inner.shown]
        dist = self.ctx.distance(self.inner.target)
        off = np.abs(base.serve_zeta[self.inner.shown] - dist.target) / dist.scale
        near = float(off.max())  # = dist.distances of that clip
        if not self._off_target(off, dist.scale) or (before is None and self.ctx.first_from_library):
            return library
        pooled, pooled_at = self._pooled(dist, before, asked)
        if pooled is not None and pooled_at <= self.ctx.threshold:
            return self._show_pooled(pooled)
        if not self._failed_near(dist):
            made = self._search(dist, near, before, asked, library)
            if made is not None:
                return made
            pooled, pooled_at = self._pooled(dist, before, asked)
        return self._show_pooled(pooled) if pooled is not None and pooled_at < near else library

    def _search(self, dist: ZetaDistance, near: float, before: np.ndarray | None, asked: list[tuple[int, int]],
                library: str) -> str | None:
        """Search for the target; show its best clip if it is nearer than the library's and moves the asked
        attributes the asked way (else None). Its runners-up (and a best not shown) join the pool."""
        if self.ctx.on_search is not None:
            self.ctx.on_search(library)
        found, zeta, others = self.ctx.generate(self.inner.target, self._starts(dist), len(self.searches),
                                                [g["params"] for g in self.generated.values()])
        reached = float(dist.distances(zeta)[0]) if found.rollout is not None else None
        shown = reached is not None and reached < near and _moves(zeta, before, asked)
        self.searches.append({"simulations": found.simulations, "shown": shown, "round": len(self.inner.rejected),
                              "target": [float(v) for v in dist.target], "reached": reached})
        self.seconds.append(found.seconds)
        kept = others if shown or found.rollout is None else [(found.rollout, zeta), *others]
        for r, z in kept:
            self.pool[r.id] = _made(r, z)
        while len(self.pool) > POOL_SIZE:
            self.pool.pop(next(iter(self.pool)))
        return self._show(found.rollout.id, _made(found.rollout, zeta)) if shown else None

    def _pooled(self, dist: ZetaDistance, before: np.ndarray | None, asked: list[tuple[int, int]]
                ) -> tuple[str | None, float]:
        """The pooled clip nearest the target that moves the asked attributes the asked way, and its distance."""
        ids = [i for i, g in self.pool.items() if _moves(g["zeta"], before, asked)]
        if not ids:
            return None, np.inf
        d = dist.distances(np.array([self.pool[i]["zeta"] for i in ids]))
        return ids[int(np.argmin(d))], float(d.min())

    def _show_pooled(self, rollout_id: str) -> str:
        return self._show(rollout_id, {**self.pool.pop(rollout_id), "pooled": True})

    def _show(self, rollout_id: str, made: dict) -> str:
        self.generated[rollout_id] = {**made, "round": len(self.inner.rejected)}
        self.showing = rollout_id
        return rollout_id

    def rollout(self, rollout_id: str) -> Rollout:
        """A clip this agent generated (its true proxies are the simulation's: what the evaluation's user sees)."""
        g = self.generated[rollout_id]
        return self.ctx.rollout(rollout_id, g["params"], g["seed"])

    def target_ranks(self, mass: float = 0.5) -> dict[str, tuple[float, float]]:
        return self.inner.target_ranks(mass)

    def state_dict(self) -> dict:
        return {**self.inner.state_dict(), "generation": {
            "generated": self.generated, "showing": self.showing, "searches": self.searches, "pool": self.pool,
            "answered": [[rid, [list(x) for x in asked]] for rid, asked in self.answered]}}

    @classmethod
    def from_state(cls, state: dict, context: GenerationContext) -> GeneratingGlobalAgent:
        inner = {k: v for k, v in state.items() if k != "generation"}
        gen = state.get("generation", {})
        return cls(context, GlobalAgent.from_state(inner, context.base), gen.get("generated"), gen.get("showing"),
                   gen.get("searches"), gen.get("pool"), gen.get("answered"))


def _left(seconds: float | None, spent: Generation | None) -> float | None:
    """A search's time bound less what the surface's clip set aside took: the person waits for both (at least
    ``MIN_SECONDS``, in which the search still makes one clip)."""
    if seconds is None or spent is None:
        return seconds
    return max(seconds - spent.seconds, MIN_SECONDS)


def _moves(zeta: np.ndarray | list[float], before: np.ndarray | None, asked: list[tuple[int, int]]) -> bool:
    """Whether a clip at ``zeta`` moves each asked attribute the asked way from the clip answered about
    (``before``; None: the first clip, which answers nothing)."""
    return before is None or all(h * (zeta[a] - before[a]) > 0 for a, h in asked)


def _made(rollout: Rollout, zeta: np.ndarray) -> dict:
    """What the agent's state keeps of a made clip: (params, seed) remake it; ζ as the agent read it."""
    return {"params": dict(rollout.params), "seed": int(rollout.seed), "zeta": [float(v) for v in zeta]}


def made_clip(state: dict, rollout_id: str) -> dict | None:
    """What the agent whose ``state_dict()`` this is keeps of ``rollout_id`` if it made that clip (params, seed,
    ζ): None for a serve clip, or a state without generation."""
    return state.get("generation", {}).get("generated", {}).get(rollout_id)


def _extend(base: GlobalContext, models_root=None, **options) -> GenerationContext:
    return GenerationContext.load(base, models_root, **options)


def _load_context(domain: str, rep: str, data_root=None, models_root=None, **options) -> GenerationContext:
    return _extend(GlobalContext.load(domain, rep, data_root, models_root), models_root, **options)


# RBA-Global's generating form (``Method.generating`` of ``rba.interact.global_agent.METHOD``): its name, models
# and representations are RBA-Global's, and its agent's state is a global agent's plus what it made
METHOD = Method(agent=GeneratingGlobalAgent, label=GLOBAL.label, load_context=_load_context,
                model_kinds=GLOBAL.model_kinds, trainer=None, presets=(), reps=GLOBAL.reps,
                extends=_extend)


def generating_agents(method: str, context, models_root=None, **options) -> Callable[[], Agent]:
    """New generating agents of ``method`` over ``context`` (one generating context for all of them);
    ValueError naming the methods that can generate."""
    form = get_method(method).form(True)
    gctx = form.extends(context, models_root, **options)
    return lambda: form.agent(gctx)

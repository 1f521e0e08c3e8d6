"""The paper's protocol (docs/architecture.md §5): simulated users chase held-out targets; SR and AF.

ε comes from the serve library's robust proxy range (``Domain.epsilons``); the user is any teacher kind of
``rba.interact.users`` (``user="KIND[:param]"``). A trial ends when the user says it is satisfied and succeeds
if the clip's true proxies are then within ε of the user's target, so a user who misjudges can end on a miss.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from rba.data.library import HELD_OUT, SkillLibrary
from rba.domains import domain_target, get_domain, load_domain
from rba.interact import SATISFIED, Agent, FeedbackKind, Preference, load_context, new_agent
from rba.interact.users import SKIP, USER_KINDS, PreferenceTeacher, SimulatedUser, UserSpec, parse_user

if TYPE_CHECKING:
    from rba.generate.cma import Simulate
    from rba.generate.config import GenerationConfig

log = logging.getLogger(__name__)

MAX_FEEDBACK = 500  # attribute-level feedbacks before a trial is a failure (the paper's budget)
MAX_ROUNDS = 1000  # rounds (answers, skips included) before a trial is a failure: a user who always skips
BEYOND_CODE = 4  # seeds the beyond-range targets' stream: no split uses it (library.SPLIT_CODES)
BEYOND_TRIES = 12  # rollouts simulated per wanted beyond-range target, at most
BEYOND_STARTS = 16  # the serve clips most extreme on a side whose parameters are perturbed
BEYOND_SPREAD = 0.15  # the perturbation's σ, a share of each parameter's range


@dataclass
class Trial:
    target: dict[str, float]
    success: bool
    feedback_count: int
    rounds: int = 0  # clips judged (a skipped round shows the same clip again)
    shown: list[dict[str, float]] = field(default_factory=list)  # proxies of each shown rollout
    shown_ids: list[str] = field(default_factory=list)


@dataclass
class EvalResult:
    domain: str
    method: str
    rep: str
    precision: str
    user: str  # the simulated user's spec, e.g. "paper", "mistake:0.1"
    seed: int
    success_rate: float
    avg_feedback: float | None  # over successful trials
    std_feedback: float | None
    seconds: float
    trials: list[Trial]
    split: str = "test"  # where the targets came from: "val" while tuning, "test" for reports
    beyond: float | None = None  # targets from beyond the serve range by up to this share of it (not a split)
    serve_size: int | None = None  # serve rollouts the agent chose from
    generate: bool = False  # the agent made clips beyond the serve library (rba.interact.generating_agent)
    generation: dict | None = None  # what generating cost and gave (``generation_summary``)

    def to_json(self) -> dict:
        return asdict(self)


def _new_trial(serve: SkillLibrary, target) -> Trial:
    return Trial(target=dict(zip(serve.attribute_names, map(float, target), strict=True)),
                 success=False, feedback_count=0)


def _record_shown(trial: Trial, serve: SkillLibrary, rollout_id: str, agent: Agent | None = None,
                  user: SimulatedUser | None = None) -> int:
    """Log what the user is shown (id and true proxies); return its index among the clips the user judges.

    A clip the agent generated (not in ``serve``) is measured by its own simulation (``agent.rollout``).
    """
    made = getattr(agent, "rollout", None)
    if rollout_id in serve or made is None or user is None:
        i = serve.index_of(rollout_id)
        proxies = serve.proxies_of(i)
    else:
        proxies = dict(made(rollout_id).proxies)
        i = user.add_clip(np.array([proxies[a] for a in serve.attribute_names]))
    trial.shown_ids.append(rollout_id)
    trial.shown.append(proxies)
    return i


def run_trial(agent: Agent, user: SimulatedUser, serve: SkillLibrary, max_feedback: int = MAX_FEEDBACK) -> Trial:
    """Show, listen, update until the user is satisfied or the feedback budget is spent."""
    trial = _new_trial(serve, user.target)
    rid = agent.first_query()
    while trial.rounds < MAX_ROUNDS:
        i = _record_shown(trial, serve, rid, agent, user)
        trial.rounds += 1
        answer = user.respond(i)
        if answer == SATISFIED:
            trial.success = user.succeeded(i)
            return trial
        if answer == SKIP:  # no answer: nothing to update on; the same clip is shown again
            continue
        trial.feedback_count += len(answer)
        if trial.feedback_count >= max_feedback:
            return trial
        rid = agent.update(answer)
    return trial


def run_preference_trial(agent, teacher: PreferenceTeacher, serve: SkillLibrary,
                         max_feedback: int = MAX_FEEDBACK) -> Trial:
    """The preference loop (PbRL): show the argmax; if it is not the target, ask one A/B question and update.

    ``agent`` takes ``Preference`` feedback and says what to ask with ``query_pair()``.

    ``feedback_count`` counts binary labels; success is judged on the shown rollout.
    """
    trial = _new_trial(serve, teacher.target)
    rid = agent.first_query()
    while True:
        i = _record_shown(trial, serve, rid)
        trial.rounds += 1
        if teacher.satisfied_with(i):
            trial.success = True
            return trial
        if trial.feedback_count >= max_feedback:
            return trial
        a, b = agent.query_pair()
        label = teacher.prefer(serve.index_of(a), serve.index_of(b))
        trial.feedback_count += 1
        rid = agent.update(Preference(a if label == 1.0 else b if label == 0.0 else None))


@dataclass(frozen=True)
class TrialLoop:
    """How a trial runs for one kind of feedback: who answers, and the show/answer/update loop."""

    user: type[SimulatedUser]  # the answers' kind; which teacher of that kind: ``make``
    make: Callable[[UserSpec, np.ndarray, np.ndarray, SkillLibrary, int], SimulatedUser]
    run: Callable[..., Trial]  # (agent, user, serve, max_feedback) -> Trial


TRIAL_LOOPS: dict[FeedbackKind, TrialLoop] = {
    "attribute": TrialLoop(SimulatedUser, UserSpec.build, run_trial),
    "preference": TrialLoop(PreferenceTeacher, PreferenceTeacher.for_spec, run_preference_trial),
}


def simulate(agent: Agent, target: np.ndarray, epsilon: np.ndarray, serve: SkillLibrary,
             user: str | UserSpec = "paper", seed: int = 0, max_feedback: int = MAX_FEEDBACK) -> Trial:
    """One trial of ``agent`` chasing ``target``, with the simulated ``user`` (``KIND[:param]``) it answers to."""
    loop = TRIAL_LOOPS[agent.feedback_kind]
    return loop.run(agent, loop.make(parse_user(user), target, epsilon, serve, seed), serve, max_feedback)


def success_summary(outcomes: list[tuple[bool, int]]) -> dict[str, float | None]:
    """SR and the mean and std of AF over the successful trials (None: none succeeded), from (success, feedbacks)."""
    fb = np.array([n for ok, n in outcomes if ok], dtype=float)
    return {"success_rate": float(np.mean([ok for ok, _ in outcomes])),
            "avg_feedback": float(fb.mean()) if len(fb) else None, "std_feedback": float(fb.std()) if len(fb) else None}


def held_out_targets(held_out: SkillLibrary, count: int, seed: int) -> np.ndarray:
    """float64[n, k]: the proxies of ``count`` rollouts of a held-out split drawn without replacement (seeded),
    every agent's targets for that split and seed."""
    pick = np.random.default_rng(seed).choice(len(held_out), size=min(count, len(held_out)), replace=False)
    return held_out.proxies[pick]


def beyond_targets(serve: SkillLibrary, share: float, count: int, seed: int = 0) -> np.ndarray:
    """Up to ``count`` targets outside the serve library's proxy range by at most ``share`` of it, each the
    proxies of a rollout the skill made (so the skill can produce it), float64[n, k].

    Candidates perturb the parameters of the serve clips most extreme on a random attribute and side (σ
    ``BEYOND_SPREAD`` of each range, inside the domain's parameter space), simulated with seeds of their own
    stream; a candidate is kept if it succeeded, leaves the range on some attribute and stays within
    ``share`` beyond it on every one. Seeded: the same serve library and seed give the same targets.
    """
    if not 0.0 < share <= 0.5:
        raise ValueError(f"share beyond the serve range must be in (0, 0.5]; got {share}")
    domain = load_domain(domain_target(serve.domain))
    space = domain.param_space()
    low, high = serve.proxies.min(axis=0), serve.proxies.max(axis=0)
    band = share * (high - low)
    rng = np.random.default_rng([seed, BEYOND_CODE])
    kept: list[np.ndarray] = []
    for k in range(count * BEYOND_TRIES):
        r = domain.rollout(_beyond_params(serve, space, rng), seed * 10_000_000 + BEYOND_CODE * 1_000_000 + k)
        x = np.array([r.proxies[a] for a in serve.attribute_names])
        if r.success and ((x < low) | (x > high)).any() and np.all((x >= low - band) & (x <= high + band)):
            kept.append(x)
            if len(kept) == count:
                break
    log.info("%s: %d targets up to %.0f%% beyond the serve range", serve.domain, len(kept), 100 * share)
    return np.array(kept, dtype=np.float64).reshape(-1, len(serve.attribute_names))


def _beyond_params(serve: SkillLibrary, space, rng: np.random.Generator) -> dict[str, float]:
    """Perturbed parameters of one of the serve clips most extreme on a random attribute and side."""
    column = serve.proxies[:, rng.integers(serve.proxies.shape[1])]
    order = np.argsort(column)
    starts = order[:BEYOND_STARTS] if rng.random() < 0.5 else order[-BEYOND_STARTS:]
    params = dict(zip(serve.param_names, map(float, serve.params[rng.choice(starts)]), strict=True))
    return space.from_unit(space.to_unit(params) + rng.normal(0.0, BEYOND_SPREAD, len(space.free)), params)


def evaluate(domain_name: str, method: str, rep: str = "onehot", targets: int = 20, seed: int = 0,
             precision: str = "normal", user: str | UserSpec = "paper", data_root=None, models_root=None,
             context=None, split: str = "test", generate: bool = False,
             gen_config: GenerationConfig | None = None, beyond: float | None = None,
             serve_size: int | None = None, simulator: Simulate | None = None) -> EvalResult:
    """SR / AF over ``targets`` targets drawn from ``split``: ``val`` for tuning and model selection,
    ``test`` (the default) only for reported numbers; with ``beyond``, instead from beyond the serve range
    (``beyond_targets``). ``generate``: the agent may make clips beyond the serve library
    (``rba.interact.generating_agent``), tuned by ``gen_config`` (None: every default), its candidates simulated
    by ``simulator`` (``Compute.simulate``; None: in this process). ``serve_size``: the agent sees only the serve
    library's first rollouts (contexts with ``first``: RBA-Global)."""
    if split not in HELD_OUT:
        raise ValueError(f"targets come from a held-out split; got {split!r}, valid: {', '.join(HELD_OUT)}")
    spec = parse_user(user)
    domain = get_domain(domain_name)
    context = context or load_context(domain_name, method, rep, data_root, models_root)
    eps = domain.epsilons(context.serve.proxies, precision)  # the whole library's: the task, whatever the agent sees
    if serve_size is not None:
        if not hasattr(context, "first"):
            raise ValueError(f"a smaller serve library works with method global only, not {method!r}")
        context = context.first(serve_size)
    serve = context.serve
    make = _agents(method, context, spec, models_root, generate, gen_config, simulator)
    if beyond is None:
        chosen = held_out_targets(SkillLibrary.load(domain_name, split, data_root), targets, seed)
    else:
        chosen = beyond_targets(serve, beyond, targets, seed)
        if not len(chosen):
            raise ValueError(f"the {domain_name} skill made no rollout beyond its serve range within {beyond:.0%}")
    start = time.perf_counter()
    agents = [make() for _ in chosen]
    trials = []
    for n, (agent, t) in enumerate(zip(agents, chosen, strict=True)):
        trials.append(simulate(agent, t, eps, serve, spec, seed * 1000 + n))
        log.info("%s %s: trial %d of %d %s after %d feedbacks", domain_name, method, n + 1, len(chosen),
                 "succeeded" if trials[-1].success else "failed", trials[-1].feedback_count)
    return EvalResult(domain_name, method, rep, precision, str(spec), seed,
                      **success_summary([(t.success, t.feedback_count) for t in trials]),
                      seconds=round(time.perf_counter() - start, 2), trials=trials,
                      split=split if beyond is None else "beyond",
                      generate=generate, generation=generation_summary(agents) if generate else None,
                      beyond=beyond, serve_size=len(serve))


def _judges_generated(spec: UserSpec) -> bool:
    return USER_KINDS[spec.kind].cls.judges_generated


def can_generate(method: str, user: str | UserSpec) -> bool:
    """Whether ``evaluate(..., generate=True)`` works: the method has a generating agent and the user can judge
    new clips (``rba eval``'s default for ``--generate``)."""
    from rba.core.methods import generating_methods

    return method in generating_methods() and _judges_generated(parse_user(user))


def _agents(method: str, context, spec: UserSpec, models_root, generate: bool, gen_config: GenerationConfig | None,
            simulator: Simulate | None) -> Callable[[], Agent]:
    """A maker of fresh agents for the trials: generating ones if asked (and the user can judge their clips)."""
    if not generate:
        if gen_config is not None:
            raise ValueError("a generation config tunes how the agent makes clips: it needs generation on")
        return lambda: new_agent(method, context)
    from rba.generate.config import GenerationConfig
    from rba.interact.generating_agent import generating_agents

    if not _judges_generated(spec):
        able = [k for k, kind in USER_KINDS.items() if kind.cls.judges_generated]
        raise ValueError(f"a {spec.kind} user cannot judge generated clips; with generation use: {', '.join(able)}")
    options = (gen_config or GenerationConfig()).context_options(get_domain(context.serve.domain), simulator)
    return generating_agents(method, context, models_root, **options)


def generation_summary(agents: list) -> dict:
    """Searches run, their clips shown, searches' runners-up shown later (no search), and seconds per search
    (mean, p95) over every trial's agent."""
    runs = [s for a in agents for s in a.searches]
    seconds = np.array([t for a in agents for t in a.seconds], dtype=float)
    pooled = sum(bool(g.get("pooled")) for a in agents for g in a.generated.values())
    return {"searches": len(runs), "shown": sum(s["shown"] for s in runs), "pooled": pooled,
            "simulations": int(sum(s["simulations"] for s in runs)),
            "seconds_mean": round(float(seconds.mean()), 3) if len(runs) else None,
            "seconds_p95": round(float(np.percentile(seconds, 95)), 3) if len(runs) else None}


def af_cell(avg_feedback: float | None, std_feedback: float | None) -> str:
    """AF (std) as the reports write it; – where no trial succeeded."""
    return "–" if avg_feedback is None else f"{avg_feedback:.2f} ({std_feedback:.2f})"


def searches_cell(generation: dict | None) -> str:
    """A ``generation_summary``'s searches (clips of theirs shown) as the reports write it; – without generation."""
    return f"{generation['searches']} ({generation['shown']})" if generation else "–"


def format_table(results: list[EvalResult]) -> str:
    """A Markdown table of SR / AF (std), one row per result."""
    rows = ["| domain | method | rep | precision | user | SR | AF (std) |", "|---|---|---|---|---|---|---|"]
    for r in results:
        cells = (r.domain, r.method, r.rep, r.precision, r.user, f"{r.success_rate:.2f}",
                 af_cell(r.avg_feedback, r.std_feedback))
        rows.append("| " + " | ".join(cells) + " |")
    return "\n".join(rows)

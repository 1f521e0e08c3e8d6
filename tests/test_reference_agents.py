"""The tables' reference rows (random floor, oracle ceiling) and the evaluation loop with teacher kinds."""

import json

import numpy as np
import pytest

from rba.core.methods import get_method, methods
from rba.data.library import SkillLibrary
from rba.domains import get_domain
from rba.interact import AttributeFeedback, new_agent, restore_agent
from rba.interact.base import REJECT_MEMORY
from rba.interact.evaluate import MAX_ROUNDS, run_trial, simulate
from rba.interact.reference import OracleAgent, RandomAgent, ReferenceContext
from rba.interact.users import SKIP, MyopicUser, SimulatedUser
from tests.benchmark_scripts import load_benchmark
from tests.toy import Toy


@pytest.fixture(scope="module")
def serve() -> SkillLibrary:
    """A hand-made toy serve library: a 20 × 20 grid of amplitudes and paces."""
    toy = Toy()
    rollouts = []
    for i, (a, f) in enumerate((a, f) for a in np.linspace(0.2, 2.0, 20) for f in np.linspace(0.5, 3.0, 20)):
        r = toy.rollout({"amplitude": float(a), "pace": float(f)}, seed=i)
        r.id = f"serve-{i:05d}"
        rollouts.append(r)
    return SkillLibrary.from_rollouts(rollouts, "serve", toy.param_names, toy.attribute_names)


@pytest.fixture(scope="module")
def ctx(serve) -> ReferenceContext:
    return ReferenceContext.from_library(serve)


def _run(ctx, method: str, precision: str, user: str = "paper", n: int = 12):
    """Trials towards targets a library clip satisfies even at high precision (the grid is coarse)."""
    eps = get_domain("toy").epsilons(ctx.serve.proxies, precision)
    rng = np.random.default_rng(0)
    targets = ctx.serve.proxies[rng.choice(len(ctx.serve), n, replace=False)] + rng.uniform(-0.5, 0.5, (n, 2)) * eps
    return [simulate(new_agent(method, ctx), t, eps, ctx.serve, user, seed=k) for k, t in enumerate(targets)]


def test_oracle_reaches_every_target_within_few_feedbacks(ctx):
    normal, high = _run(ctx, "oracle", "normal"), _run(ctx, "oracle", "high")
    assert all(t.success for t in normal) and np.mean([t.feedback_count for t in normal]) <= 4
    assert all(t.success for t in high) and np.mean([t.feedback_count for t in high]) <= 12
    assert all(t.success for t in _run(ctx, "oracle", "normal", "mistake:0.2"))  # wrong answers are outvoted


def test_random_ignores_feedback_so_it_needs_many_more(ctx):
    rand, oracle = _run(ctx, "random", "normal"), _run(ctx, "oracle", "normal")
    assert np.mean([t.success for t in rand]) >= 0.9  # 400 clips, ε a seventh of the range: hits come by chance
    assert np.mean([t.feedback_count for t in rand]) > 3 * np.mean([t.feedback_count for t in oracle])


def test_random_never_reshows_a_recently_rejected_clip_and_is_deterministic(ctx):
    agent, twin = RandomAgent(ctx), RandomAgent(ctx)
    shown = [agent.first_query()]
    assert twin.first_query() == shown[0]
    for k in range(REJECT_MEMORY):
        fb = [AttributeFeedback("pace", 1 if k % 2 else -1)]
        shown.append(agent.update(fb))
        assert twin.update(fb) == shown[-1]
    assert len(set(shown)) == len(shown)
    clone = restore_agent(json.loads(json.dumps(agent.state_dict())), ctx)
    assert clone.update([AttributeFeedback("amplitude", 1)]) == agent.update([AttributeFeedback("amplitude", 1)])


def test_oracle_bisects_on_the_true_proxies_and_keeps_silent_attributes(ctx):
    agent = OracleAgent(ctx)
    first = ctx.serve.index_of(agent.first_query())
    nxt = ctx.serve.index_of(agent.update([AttributeFeedback("amplitude", 1)]))
    p = ctx.serve.proxies
    assert p[nxt, 0] > p[first, 0] and abs(p[nxt, 1] - p[first, 1]) < 0.2  # pace: silent, kept
    state = json.loads(json.dumps(agent.state_dict()))
    assert state["answers"] == [[0, p[first, 0], 1]]
    assert restore_agent(state, ctx).update([AttributeFeedback("pace", -1)]) == \
           agent.update([AttributeFeedback("pace", -1)])


def test_reference_rows_run_in_eval_but_the_web_app_does_not_offer_them():
    assert {m.name for m in methods()} == {"global", "local", "pbrl"}
    refs = {m.name: m.reference for m in methods(include_reference=True) if m.reference}
    assert refs == {"random": "floor", "oracle": "ceiling"}
    assert get_method("oracle").label_for("language") == "Oracle" and get_method("random").model_kinds == ()


def test_paper_tables_put_the_floor_first_the_ceiling_last_and_high_precision_first():
    paper_tables = load_benchmark("paper_tables")
    assert paper_tables.LABELS[0] == "Random" and paper_tables.LABELS[-1] == "Oracle"
    assert "RBA-Global" in paper_tables.LABELS[1:-1] and paper_tables.PRECISIONS[0] == "high"


class Scripted:
    """An agent that shows the given clips in order, one per update (and counts its updates)."""

    feedback_kind = "attribute"

    def __init__(self, serve, order):
        self.serve, self.order, self.updates = serve, list(order), 0

    def first_query(self):
        return self.serve.ids[self.order[0]]

    def update(self, feedback):
        self.updates += 1
        return self.serve.ids[self.order[min(self.updates, len(self.order) - 1)]]


class Skipper(SimulatedUser):
    """Skips the first two rounds, then answers as the paper's user."""

    def respond(self, i):
        self.calls = getattr(self, "calls", 0) + 1
        return SKIP if self.calls <= 2 else super().respond(i)


def test_a_skipped_round_updates_nothing_and_shows_the_same_clip_again(serve):
    eps = get_domain("toy").epsilons(serve.proxies)
    target = serve.proxies[7]
    agent = Scripted(serve, [0, 7])
    trial = run_trial(agent, Skipper(target, eps, serve.attribute_names, serve.proxies), serve)
    assert trial.success and agent.updates == 1 and trial.rounds == 4
    assert trial.shown_ids == [serve.ids[0]] * 3 + [serve.ids[7]]
    assert trial.feedback_count == len(SimulatedUser(target, eps, serve.attribute_names, serve.proxies).respond(0))
    always = Skipper(target, eps, serve.attribute_names, serve.proxies)
    always.respond = lambda i: SKIP
    assert not run_trial(Scripted(serve, [0]), always, serve).success and MAX_ROUNDS == 1000


def test_a_user_who_misjudges_can_stop_on_a_miss(serve):
    eps = get_domain("toy").epsilons(serve.proxies)
    target = serve.proxies[0] + [2 * eps[0], 0]  # clip 0 is 2 ε off in amplitude...
    end = serve.proxies.copy()
    end[0, 0] += 4 * eps[0]  # ...but its end looks 2 ε too big the other way: half-half looks right
    user = MyopicUser(target, eps, serve.attribute_names, serve.proxies, 0.5, end_proxies=end)
    trial = run_trial(Scripted(serve, [0]), user, serve)
    assert trial.rounds == 1 and trial.feedback_count == 0 and not trial.success

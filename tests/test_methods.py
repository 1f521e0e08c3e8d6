"""The method registry: every registered method conforms to the Method/Agent contract on the toy domain.

A new method gets these tests for free: its tiny preset trains and writes the model files its
record names, its agent's state survives JSON, and simulated users reach targets through the
evaluation's dispatch by feedback kind.
"""

import json
from dataclasses import replace

import pytest

from rba.cli import build_parser
from rba.core import methods
from rba.core.methods import Method, UnknownMethodError, get_method, method_names
from rba.core.store import ModelFiles
from rba.data.library import SkillLibrary
from rba.domains import get_domain
from rba.interact import AttributeFeedback, Preference, new_agent, restore_agent
from rba.interact.evaluate import TRIAL_LOOPS, evaluate, simulate
from rba.interact.local_agent import LocalAgent

BUILTIN = method_names()


class TwinAgent(LocalAgent):
    """RBA-Local under another name: a method a plugin could register."""

    method = "local_twin"


TWIN = replace(get_method("local"), agent=TwinAgent, label="RBA-Twin")


@pytest.fixture(scope="module", params=BUILTIN)
def trained(request, toy_roots, tmp_path_factory):
    """(record, data_root, models_root, metrics, context): the method's tiny preset trained on the toy libraries."""
    data, _, _ = toy_roots
    record = get_method(request.param)
    models = tmp_path_factory.mktemp(f"models_{record.name}")
    metrics = None
    if record.trainer is not None:
        assert "tiny" in record.presets
        metrics = record.trainer("toy", record.run_reps[0], "tiny", 0, data_root=data, models_root=models)
    return record, data, models, metrics, record.load_context("toy", record.run_reps[0], data, models)


def _unsatisfying_target(record: Method, ctx, test: SkillLibrary):
    """A test target the agent does not reach within its first two feedbacks (so a clone must carry on)."""
    eps = get_domain("toy").epsilons(ctx.serve.proxies)
    for target in test.proxies:
        if not simulate(new_agent(record.name, ctx), target, eps, ctx.serve, seed=3, max_feedback=2).success:
            return target
    raise AssertionError("every test target is reached within two feedbacks")


def test_record_is_complete_and_named_after_its_registry_key(trained):
    record, *_ = trained
    assert record.name in BUILTIN and record.label and record.feedback_kind in TRIAL_LOOPS
    assert record.agent.feedback_kind == record.feedback_kind
    assert (record.trainer is None) == (not record.presets)  # presets name the trainer's settings


def test_tiny_preset_writes_the_model_files_the_record_names(trained):
    record, _, models, metrics, ctx = trained  # and the context loaded from exactly these
    for kind in record.model_kinds:
        assert ModelFiles(models).complete("toy", kind, record.run_reps[0]), kind
    assert sorted(p.name for p in models.rglob("*.pt")) == sorted(f"{k}-{record.run_reps[0]}.pt"
                                                                  for k in record.model_kinds)
    assert (metrics is None) == (record.trainer is None) and ctx.serve.domain == "toy"


def test_state_roundtrips_through_json_and_continues_identically(trained):
    record, data, _, _, ctx = trained
    test = SkillLibrary.load("toy", "test", data)
    target, eps = _unsatisfying_target(record, ctx, test), get_domain("toy").epsilons(ctx.serve.proxies)
    agent = new_agent(record.name, ctx)
    fresh = agent.state_dict()
    simulate(agent, target, eps, ctx.serve, seed=3, max_feedback=2)  # a few rounds of feedback
    state = agent.state_dict()
    assert state["method"] == record.name and state != fresh
    clone = restore_agent(json.loads(json.dumps(state)), ctx)
    assert type(clone) is record.agent and clone.state_dict() == state
    after_clone = simulate(clone, target, eps, ctx.serve, seed=4, max_feedback=6)
    after_agent = simulate(agent, target, eps, ctx.serve, seed=4, max_feedback=6)
    assert after_clone.shown_ids == after_agent.shown_ids and len(after_agent.shown_ids) >= 2


def test_feedback_of_the_other_kind_is_refused(trained):
    record, *_, ctx = trained
    agent = new_agent(record.name, ctx)
    agent.first_query()
    wrong = Preference(None) if record.feedback_kind == "attribute" else [AttributeFeedback("pace", 1)]
    with pytest.raises(ValueError, match="this agent takes"):
        agent.update(wrong)


def test_simulated_users_reach_targets(trained):
    record, data, models, _, ctx = trained
    result = evaluate("toy", record.name, record.run_reps[0], targets=6, seed=1, data_root=data, models_root=models,
                      context=ctx)
    assert result.method == record.name and len(result.trials) == 6
    assert result.success_rate >= 0.5, [t.feedback_count for t in result.trials]


def test_unknown_method_names_the_valid_ones():
    with pytest.raises(UnknownMethodError, match="unknown method 'magic'; valid: global, local, pbrl, random, oracle"):
        get_method("magic")
    with pytest.raises(ValueError, match="unknown method 'magic'"):
        restore_agent({"method": "magic"}, None)


@pytest.fixture
def twin(monkeypatch):
    """``local_twin`` registered at run time (and gone afterwards)."""
    monkeypatch.setattr(methods.REGISTRY, "extra", {})
    methods.register("local_twin", "tests.test_methods:TWIN")
    yield
    get_method.cache_clear()


def test_a_method_registered_at_run_time_appears_everywhere(twin):
    from server.db.admin_tables import TrainCreate
    from server.runtime.catalog import attribute_methods

    assert method_names() == (*BUILTIN, "local_twin") and get_method("local_twin") is TWIN
    assert TWIN.label_for("language") == "RBA-Twin-L"
    args = build_parser().parse_args(["eval", "--domain", "toy", "--method", "local_twin"])
    assert args.method == "local_twin"
    assert build_parser().parse_args(["train", "toy", "--method", "local_twin"]).method == "local_twin"
    assert "local_twin" in attribute_methods()
    assert TrainCreate(domain="toy", method="local_twin").method == "local_twin"


def test_a_record_must_match_its_registry_name(monkeypatch):
    monkeypatch.setattr(methods.REGISTRY, "extra", {})
    methods.register("impostor", "tests.test_methods:TWIN")
    try:
        with pytest.raises(TypeError, match="is not the Method record of 'impostor'"):
            get_method("impostor")
    finally:
        get_method.cache_clear()

"""Every registered domain end to end: the tiny CI preset of the whole pipeline, and its shipped artifacts."""

import numpy as np
import pytest

from rba.artifacts import load_model
from rba.domains import domain_names, get_domain
from rba.evaluate import evaluate
from rba.library import SkillLibrary, build_all
from rba.settings import REPO_ROOT
from rba.training import GlobalTrainConfig, train_global

SHIPPED = [d for d in domain_names() if (REPO_ROOT / "models" / d / "ranker-onehot.pt").exists()]


@pytest.mark.slow
@pytest.mark.parametrize("domain", [d for d in domain_names() if d != "toy"])
def test_tiny_preset_end_to_end(domain, tmp_path):
    data, models = tmp_path / "data", tmp_path / "models"
    build_all(domain, seed=5, sizes={"train": 80, "serve": 160, "test": 12}, root=data, progress=False)
    metrics = train_global(domain, "onehot", GlobalTrainConfig.preset("tiny", seed=0), data_root=data,
                           models_root=models)
    for name, m in metrics["ranker"].items():
        assert m["pairwise_accuracy"] > 0.75, (name, metrics)
    result = evaluate(domain, "global", "onehot", targets=6, seed=0, data_root=data, models_root=models)
    assert sum(t.success for t in result.trials) >= 2, [t.feedback_count for t in result.trials]


def test_walker_and_at_least_one_more_domain_ship_artifacts():
    assert "walker" in SHIPPED and len(SHIPPED) >= 2, SHIPPED


@pytest.mark.parametrize("domain", SHIPPED)
def test_shipped_artifacts_serve_a_fresh_clone(domain):
    """The committed libraries and models load, match each other, and reach targets."""
    data, models = REPO_ROOT / "data", REPO_ROOT / "models"
    serve = SkillLibrary.load(domain, "serve", data)
    assert len(serve) >= 1000 and serve.meta["success_rate"] >= 0.9
    for rep in ("onehot", "language"):
        for kind in ("ranker", "global_reward"):
            card = load_model(domain, kind, rep, models).card
            assert card["data"]["serve"] == serve.version, f"{kind}-{rep} was trained on another library"
    result = evaluate(domain, "global", "onehot", targets=5, seed=1, data_root=data, models_root=models)
    assert result.success_rate >= 0.8


@pytest.mark.parametrize("domain", SHIPPED)
def test_epsilons_follow_the_design_contract(domain):
    """ARCHITECTURE §4: ε splits each proxy's range over the library into 5–10 buckets; high precision 5–10× finer."""
    serve = SkillLibrary.load(domain, "serve", REPO_ROOT / "data")
    spec = get_domain(domain)
    buckets = np.ptp(serve.proxies, axis=0) / spec.epsilons("normal")
    finer = (spec.epsilons("normal") / spec.epsilons("high")).round(6)
    assert np.all((buckets >= 5) & (buckets <= 10)), dict(zip(spec.attribute_names, buckets.round(1), strict=True))
    assert np.all((finer >= 5) & (finer <= 10)), dict(zip(spec.attribute_names, finer.round(1), strict=True))

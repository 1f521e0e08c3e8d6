"""benchmarks/zeta_residual.py: a tighter ε can only lower the share of ζσ-near clips that satisfy the user;
moved parameters move ζσ; a search made for a val clip's ζσ is scored against that clip's proxies."""

import itertools
import json

from tests.benchmark_scripts import load_benchmark

zeta_residual = load_benchmark("zeta_residual")


def test_high_precision_hits_fewer_and_spreads_wider_in_epsilon_units():
    high, normal = zeta_residual.measure("lane_change", "onehot", ["high", "normal"], local=6,
                                         generated=3, seeds=2)
    assert set(high["residual_over_epsilon"]) == {"sharpness", "gap"}
    assert 0.0 <= high["hit_share"] <= normal["hit_share"] <= 1.0
    assert all(high["residual_over_epsilon"][a] > normal["residual_over_epsilon"][a] for a in ("sharpness", "gap"))
    assert 0 < high["targets_with_near_clips"] <= high["targets"]
    table = zeta_residual.report([{**high, "measured": "`cmd`; today"}, {**normal, "measured": "`cmd`; today"}])
    assert "| lane_change | onehot | high | sharpness" in table and "Command: `cmd`; today (lane_change)." in table
    moves = [m["zeta_move"]["gap"] for m in high["local"]]
    assert [m["step"] for m in high["local"]] == list(zeta_residual.STEPS)
    assert all(m["clips"] > 0 for m in high["local"])
    assert moves == sorted(moves) and moves[0] > 0  # a larger parameter step moves ζσ farther
    assert "## Residuals after a small parameter move" in table and "| lane_change | 0.01 |" in table
    made = high["generated"]
    assert made["searches"] == 3 and 0 <= made["reached"] <= 3 and made["library_targets"] <= 3
    assert made["hit_share"] is None or 0.0 <= made["hit_share"] <= normal["generated"]["hit_share"] <= 1.0
    assert "## Clips made for a ζσ target" in table and "| lane_change | high | " in table
    assert [b["band"] for b in high["bands"]] == [list(b) for b in itertools.pairwise(zeta_residual.BANDS)]
    assert all(b["clips"] > 0 and 0.0 <= b["hit_share"] <= 1.0 for b in high["bands"])
    assert all(h["hit_share"] <= n["hit_share"] for h, n in zip(high["bands"], normal["bands"], strict=True))
    assert "## Hit share by ζσ distance to the target" in table
    assert high["seeds"]["clips"] == 2 and set(high["seeds"]["max"]) == {"sharpness", "gap"}
    assert all(v == 0.0 for v in high["seeds"]["max"].values())  # the lane change's skill ignores its seed
    assert "## The skill's own noise" in table and "| lane_change | 2 | sharpness 0.00" in table


def test_the_manipulators_tremor_spreads_its_instability_across_seeds():
    """What ``Manipulator.noisy_skill`` rests on: at one clip's parameters, other seeds move its instability."""
    val = zeta_residual.SkillLibrary.load("manipulator", "val")
    spread = zeta_residual._reseeded("manipulator", val, 2, 0)
    eps = zeta_residual.get_domain("manipulator").epsilons(val.proxies, "high")
    assert spread.shape == (2, 2) and (spread[:, 1] / eps[1]).max() > 0.5


def test_a_run_of_one_domain_keeps_the_others_rows_and_says_who_measured_them(tmp_path):
    """Re-measuring one domain (its library changed) keeps the other domains' rows and who measured them, in the
    report's order; with no earlier report the run's rows are the report."""
    earlier = [{"domain": d, "precision": p, "measured": "`old cmd`; 2026-12-01"}
               for d in ("walker", "lane_change", "snake") for p in ("high", "normal")]
    (tmp_path / "z.json").write_text(json.dumps(earlier))
    new = [{"domain": "lane_change", "precision": p, "measured": "`new`; today"} for p in ("high", "normal")]
    merged = zeta_residual.merge_rows(new, tmp_path / "z")
    assert [(r["domain"], r["precision"]) for r in merged] == [(r["domain"], r["precision"]) for r in earlier]
    assert [r["measured"] for r in merged] == ["`old cmd`; 2026-12-01"] * 2 + ["`new`; today"] * 2 + [
        "`old cmd`; 2026-12-01"] * 2
    assert zeta_residual.merge_rows(new, tmp_path / "absent") == new

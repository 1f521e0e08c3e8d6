"""benchmarks/reward_only.py on the toy domain: every profile is reported, a repeated one is not searched again."""

import json

from tests.benchmark_scripts import load_benchmark

reward_only = load_benchmark("reward_only")


def test_reports_every_profile_and_searches_each_chosen_rollout_once(toy_env, tmp_path):
    out = tmp_path / "r"
    assert reward_only.main(["--domain", "toy", "--profiles", "6", "--budget", "12", "--out", str(out)]) == 0
    report = json.loads(out.with_suffix(".json").read_text())
    results = report["results"]
    assert len(results) == 6 and report["within"] == sum(r["within"] for r in results)
    firsts = {}
    for r in results:
        if r["rollout_id"] in firsts:  # the same chosen clip: the first profile's search, named
            assert r["same_as"] == firsts[r["rollout_id"]]["profile"] and r["found"] == firsts[r["rollout_id"]]["found"]
        else:
            assert "same_as" not in r and r["evaluations"] >= 12
            firsts[r["rollout_id"]] = r
    assert len(firsts) < len(results)  # toy sessions (seed 0) end twice on one clip: the copy was taken
    assert f"in **{report['within']} of 6** profiles" in out.with_suffix(".md").read_text()


def test_ceiling_searches_by_zeta_distance_to_the_profiles_target(toy_env, tmp_path):
    """The ceiling's objective is zero at the profile's own rollout (v* is its ζσ) and positive elsewhere; each
    profile reports the ceiling's find, and the report its share."""
    from rba.core.artifacts import load_model
    from rba.data.export_zip import read_export
    from rba.domains import get_domain

    out = tmp_path / "r"
    assert reward_only.main(["--domain", "toy", "--profiles", "3", "--budget", "12", "--ceiling",
                             "--out", str(out)]) == 0
    report = json.loads(out.with_suffix(".json").read_text())
    assert report["ceiling_within"] == sum(r["ceiling"]["within"] for r in report["results"])
    assert all(r["ceiling"]["evaluations"] >= 12 and r["ceiling"]["loss_found"] >= 0 for r in report["results"])
    assert f"finds them in **{report['ceiling_within']} of 3**" in out.with_suffix(".md").read_text()

    args = reward_only.parse_args(["--domain", "toy", "--profiles", "1"])
    (path,) = reward_only.profiles(args, tmp_path)
    export, domain = read_export(path), get_domain("toy")
    loss = reward_only.ZetaLoss(load_model("toy", "ranker", "onehot").model,
                                load_model("toy", "global_reward", "onehot").model)
    own = domain.rollout(export.profile.params, export.profile.seed).states
    other = domain.rollout(domain.sample_params(__import__("numpy").random.default_rng(5)), export.profile.seed)
    assert loss(export, own) < 1e-4 < loss(export, other.states)
    first = report["results"][0]  # the reported distance is the ceiling's own at the parameters it found
    found = domain.rollout(first["ceiling"]["params"], export.profile.seed).states
    assert abs(loss(export, found) - first["ceiling"]["loss_found"]) < 1e-6


def test_the_ceilings_misses_are_told_apart_by_the_distance_it_was_left_with():
    def result(within, loss):
        return {"ceiling": {"within": within, "loss_found": loss}}

    text = reward_only._ceiling_summary([result(True, 0.001), result(False, 0.3), result(False, 0.01)])
    assert "finds them in **1 of 3** (33%)" in text
    assert "Of its 2 misses, 1 ended with the ζσ distance above 0.05" in text and "and 1 below it" in text
    old = reward_only._ceiling_summary([{"ceiling": {"within": False}}])  # a report from before the distance
    assert "finds them in **0 of 1**" in old and "misses" not in old


def test_a_report_names_the_reward_its_exports_carried(capsys):
    """Trained or re-fitted (and with which pull), also for reports from before either option existed."""
    import pytest

    kind = reward_only._reward_kind
    assert kind({}) == "rθ's trained weights"  # a report from before the re-fit
    assert "`--no-refit`" in kind(vars(reward_only.parse_args(["--no-refit"])))
    assert "re-fitted" in kind({"no_refit": False}) and "pull 0.01" in kind({"no_refit": False})  # before --refit-pull
    assert "pull 0.03" in kind(vars(reward_only.parse_args(["--refit-pull", "0.03"])))
    assert reward_only.parse_args(["--refit-pull", "0"]).refit_pull == 0.0  # a zero pull is a pull, not the default
    walker = reward_only.parse_args(["--domain", "walker"])  # the walker keeps rθ's trained weights (export_refit)
    assert reward_only._refit(walker) is None and "the domain's choice" in kind(vars(walker))
    assert reward_only._refit(reward_only.parse_args(["--domain", "walker", "--refit-pull", "0.01"])).pull == 0.01
    assert reward_only._refit(reward_only.parse_args(["--domain", "toy"])).pull == 0.01  # the toy domain re-fits
    with pytest.raises(SystemExit) as exit_:
        reward_only.parse_args(["--no-refit", "--refit-pull", "0.03"])
    assert exit_.value.code == 2 and "--no-refit turns off" in capsys.readouterr().err


def test_draws_of_the_skill_prior_start_the_search_from_their_best(toy_env, tmp_path, capsys):
    """``--draws``: the first rollouts of the budget are prior draws; what the search returns is no worse than the
    best of them, and the budget still bounds it. More draws than the budget is refused."""
    import pytest

    from rba.data.export_zip import read_export
    from rba.domains import get_domain

    args = reward_only.parse_args(["--domain", "toy", "--profiles", "1", "--budget", "16", "--draws", "8"])
    (path,) = reward_only.profiles(args, tmp_path)
    domain, export = get_domain("toy"), read_export(path)
    box = reward_only.prior_box(domain, 0)

    def loss(x) -> float:
        return reward_only.reward_loss(export, domain.rollout(reward_only.unit_params(domain, box, x),
                                                              export.profile.seed).states)

    r = reward_only.search(path, domain, box, 16, 0, draws=8)
    drawn = [loss(x) for x in reward_only.prior_draws(domain, box, 8, 1)]  # the search's draws: its seed + 1
    assert r["loss_found"] <= min(drawn) and 8 < r["evaluations"] <= 16 + 8  # CMA-ES's last generation may overrun
    found = domain.rollout(r["params"], export.profile.seed).states  # the reported loss is the returned params'
    assert abs(reward_only.reward_loss(export, found) - r["loss_found"]) < 1e-6
    with pytest.raises(SystemExit) as exit_:
        reward_only.parse_args(["--budget", "16", "--draws", "16"])
    assert exit_.value.code == 2 and "--draws is a part of --budget (16): 0 to 15" in capsys.readouterr().err


def test_each_profile_is_exported_when_its_session_ends(toy_env, tmp_path):
    """A run searches a profile before the next session runs: one profile asked for, one export on disk."""
    made = reward_only.profiles(reward_only.parse_args(["--domain", "toy", "--profiles", "3"]), tmp_path)
    first = next(made)
    assert [p.name for p in tmp_path.iterdir()] == [first.name] == ["profile-00.zip"]
    assert [p.name for p in made] == ["profile-01.zip", "profile-02.zip"]

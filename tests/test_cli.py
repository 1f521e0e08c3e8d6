"""The CLI: bad input is one line naming the valid choices, exit status 2."""

import dataclasses
import json

import pytest

from rba.cli import main


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["build", "atlantis"], "unknown domain 'atlantis'; valid: walker"),
        (["eval", "--domain", "walker", "--method", "magic"], "invalid choice: 'magic'"),
        (["eval", "--domain", "walker", "--user", "grumpy"],
         "unknown user kind 'grumpy'; valid: paper, mistake, skip, equal, myopic, boundary, inconsistent"),
        (["eval", "--domain", "walker", "--user", "mistake:0.7"],
         "user kind 'mistake' takes a flip probability in [0, 0.5), got 0.7"),
        (["eval", "--domain", "walker", "--user", "skip:often"], "user kind 'skip' takes a number"),
        (["eval", "--domain", "walker", "--user", "paper:1"], "user kind 'paper' takes no parameter"),
        (["train", "walker", "--rep", "braille"], "invalid choice: 'braille'"),
    ],
)
def test_bad_arguments_exit_2(argv, message, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    assert message in capsys.readouterr().err


def test_user_specs_parse_to_teacher_kinds():
    from rba.cli import build_parser
    from rba.interact.users import UserSpec

    assert build_parser().parse_args(["eval", "--domain", "walker", "--user", "equal:3"]).user == UserSpec("equal", 3.0)
    assert build_parser().parse_args(["eval", "--domain", "walker"]).user == UserSpec("paper", None)


def test_unknown_rollout_id_exits_2(capsys, tmp_path, monkeypatch):
    monkeypatch.setenv("RBA_DATA_DIR", str(tmp_path))
    assert main(["render", "walker", "../../etc/passwd", str(tmp_path / "x.mp4")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("rba: error: unknown rollout id '../../etc/passwd'") and err.count("\n") == 1


def test_states_pick_the_registered_view(capsys, tmp_path, monkeypatch):
    monkeypatch.setenv("RBA_DATA_DIR", str(tmp_path))
    assert main(["eval", "--domain", "walker", "--states", "image"]) == 2
    assert capsys.readouterr().err == "rba: error: domain 'walker' has no 'image' states; valid: kinematic, raw\n"
    assert main(["eval", "--domain", "lane_change", "--states", "colour"]) == 2
    assert "valid: kinematic, image, raw" in capsys.readouterr().err
    # --states image reaches the lane_change_image domain (whose library this empty data dir lacks)
    assert main(["render", "lane_change", "serve-00001", str(tmp_path / "x.mp4"), "--states", "image"]) == 2
    assert "run `rba build lane_change_image`" in capsys.readouterr().err


def test_missing_library_exits_2(capsys, tmp_path, monkeypatch):
    monkeypatch.setenv("RBA_DATA_DIR", str(tmp_path))
    assert main(["render", "walker", "serve-00001", str(tmp_path / "x.mp4")]) == 2
    assert "run `rba build walker`" in capsys.readouterr().err


def test_eval_and_render_on_toy(toy_roots, tmp_path, monkeypatch, capsys):
    data, models, _ = toy_roots
    monkeypatch.setenv("RBA_DATA_DIR", str(data))
    monkeypatch.setenv("RBA_MODELS_DIR", str(models))
    out = tmp_path / "r.json"
    assert main(["eval", "--domain", "toy", "--targets", "3", "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    assert set(result) >= {"success_rate", "avg_feedback", "std_feedback", "trials"}
    assert len(result["trials"]) == 3 and "shown" in result["trials"][0]
    assert "| toy | global | onehot | normal |" in capsys.readouterr().out
    clip = tmp_path / "c.mp4"
    assert main(["render", "toy", "serve-00003", str(clip)]) == 0
    head = clip.read_bytes()[:64]
    assert b"ftyp" in head and b"moov" in clip.read_bytes()[:4096]  # faststart: moov before mdat


def test_cache_renders_every_clip_once(toy_roots, tmp_path, monkeypatch, capsys):
    from rba.cli import main

    data, _, _ = toy_roots
    monkeypatch.setenv("RBA_DATA_DIR", str(data))
    monkeypatch.setenv("RBA_CACHE_DIR", str(tmp_path / "clips"))
    assert main(["cache", "toy", "--split", "test", "--width", "64", "--height", "48"]) == 0
    assert len(list((tmp_path / "clips").rglob("*.mp4"))) == 40
    assert "40 rendered" in capsys.readouterr().out
    assert main(["cache", "toy", "--split", "test", "--width", "64", "--height", "48"]) == 0
    out = capsys.readouterr().out
    assert "0 rendered" in out and "40 were cached already" in out


# what `rba eval --help` offers: what a user needs; generation's research settings are one file (--gen-config)
EVAL_OPTIONS = {"-h", "--help", "--domain", "--method", "--rep", "--targets", "--seed", "--precision", "--split",
                "--beyond", "--serve-size", "--user", "--all-methods", "--json", "--generate", "--no-generate",
                "--gen-config", "--workers", "--ray", "--states"}
# every GenerationConfig field away from its default, surface off so the session's re-fit may be on
EVERY_SETTING = {"budget": 16, "seconds": 30.0, "threshold": 0.03, "generate_spread": 0.25, "zeta_noise": 0.05,
                 "belief_prior": 0.04, "zeta_surface": 0, "session_refit": True, "noisy_skill": True}


def _eval_parser():
    from rba.cli import build_parser

    sub = next(a for a in build_parser()._actions if a.dest == "command")
    return sub.choices["eval"]


def test_eval_help_lists_no_tuning_knob(capsys):
    assert {s for a in _eval_parser()._actions for s in a.option_strings} == EVAL_OPTIONS
    with pytest.raises(SystemExit):
        main(["eval", "--help"])
    text = capsys.readouterr().out
    assert len(text.splitlines()) < 60 and text.count("--gen-") == text.count("--gen-config")


def test_gen_config_round_trips_every_field(tmp_path):
    from rba.generate.config import GenerationConfig
    from tests.test_generate import gen_config_file

    assert set(EVERY_SETTING) == set(GenerationConfig.names())
    want = GenerationConfig(**EVERY_SETTING)
    assert all(getattr(want, k) != getattr(GenerationConfig(), k) for k in EVERY_SETTING)
    for suffix in (".toml", ".json"):
        parsed = _eval_parser().parse_args(["--domain", "toy", "--gen-config",
                                            str(gen_config_file(tmp_path, EVERY_SETTING, suffix))]).gen_config
        assert parsed == want
        assert GenerationConfig.from_file(gen_config_file(tmp_path, parsed.to_json(), ".json")) == want
    assert GenerationConfig.from_file(gen_config_file(tmp_path, {"budget": 16}, ".json")) == GenerationConfig(
        budget=16)  # a file names only what it changes


def test_every_field_of_gen_config_reaches_the_generating_agent(gap_roots, monkeypatch, tmp_path):
    from rba.generate.cma import SearchConfig
    from rba.interact.generating_agent import GenerationContext
    from tests.test_generate import gen_config_file

    monkeypatch.setenv("RBA_DATA_DIR", str(gap_roots[0]))
    monkeypatch.setenv("RBA_MODELS_DIR", str(gap_roots[1]))
    asked, load = [], GenerationContext.load.__func__

    def recording_load(cls, base, models_root=None, **options):
        asked.append(options)
        return load(cls, base, models_root, **options)

    monkeypatch.setattr(GenerationContext, "load", classmethod(recording_load))
    config = gen_config_file(tmp_path, EVERY_SETTING)
    assert main(["eval", "--domain", "toy", "--targets", "1", "--workers", "1", "--gen-config", str(config)]) == 0
    assert asked == [{"config": SearchConfig(budget=16, seconds=30.0, vary_seed=True), "threshold": 0.03,
                      "spread": 0.25, "zeta_noise": 0.05, "prior_width": 0.04, "surface": 0, "refit": True}]


def test_by_default_the_agent_gets_its_domains_settings(gap_roots):
    """No config: what the agent was made with before it existed (each setting the domain's, the search's own)."""
    from rba.domains import get_domain
    from rba.generate.config import GenerationConfig
    from rba.interact import load_context
    from rba.interact.generating_agent import GenerationContext
    from tests.toy import Toy

    ctx = load_context("toy", "global", "onehot", *gap_roots)
    plain = GenerationContext.load(ctx, gap_roots[1])
    configured = GenerationContext.load(ctx, gap_roots[1], **GenerationConfig().context_options(get_domain("toy")))
    for name in ("threshold", "spread", "zeta_noise", "prior_width", "surface", "refit"):
        assert getattr(configured, name) == getattr(plain, name), name
    assert configured.config == dataclasses.replace(plain.config, vary_seed=Toy.noisy_skill)  # None: the domain's
    walker = GenerationConfig().resolved(get_domain("walker"))
    assert (walker.zeta_surface, walker.generate_spread, walker.seconds, walker.threshold) == (96, 0.5, None, None)


@pytest.mark.parametrize(("content", "suffix", "message"), [
    ("bugdet = 16\n", ".toml", "unknown generation setting 'bugdet'; valid: budget, seconds, threshold, "
                               "generate_spread, zeta_noise, belief_prior, zeta_surface, session_refit, noisy_skill"),
    ('{"budget": "16"}', ".json", "generation setting budget must be a whole number ≥ 1, got '16'"),
    ('{"budget": 0}', ".json", "generation setting budget must be a whole number ≥ 1, got 0"),
    ("session_refit = 1\n", ".toml", "generation setting session_refit must be true or false, got 1"),
    ("[1, 2]", ".json", "must hold a table of settings; valid keys: budget, seconds"),
    ("budget = \n", ".toml", "is not valid TOML"),
    ("budget: 16\n", ".yaml", "a generation config is a .toml or .json file"),
])
def test_gen_config_refusals_exit_2_saying_what_is_valid(tmp_path, capsys, content, suffix, message):
    path = tmp_path / f"gen{suffix}"
    path.write_text(content)
    with pytest.raises(SystemExit) as exit_:
        main(["eval", "--domain", "toy", "--gen-config", str(path)])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert "argument --gen-config: " in err and message in err, err


def test_gen_config_needs_generation(tmp_path, capsys):
    from tests.test_generate import gen_config_file

    config = str(gen_config_file(tmp_path, {"budget": 16}))
    assert main(["eval", "--domain", "toy", "--no-generate", "--gen-config", config]) == 2
    assert "--gen-config tunes generation, which is off here" in capsys.readouterr().err
    assert main(["eval", "--domain", "toy", "--all-methods", "--gen-config", config]) == 2
    assert "give --method, not --all-methods" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_:
        main(["eval", "--domain", "toy", "--gen-config", str(tmp_path / "missing.toml")])
    assert exit_.value.code == 2 and "No such file" in capsys.readouterr().err


def test_every_gen_config_field_is_documented_and_the_domain_ones_are_domain_attributes():
    from rba.domains.base import Domain
    from rba.generate.config import GenerationConfig

    described = GenerationConfig.describe().splitlines()
    assert [line.split(" ", 1)[0] for line in described] == list(GenerationConfig.names())
    assert all(len(f.metadata["doc"]) > 40 for f in dataclasses.fields(GenerationConfig))
    assert {k for k in GenerationConfig.names() if hasattr(Domain, k)} == {
        "generate_spread", "zeta_noise", "belief_prior", "zeta_surface", "session_refit", "noisy_skill"}


def test_every_domains_generation_settings_pass_the_configs_checks():
    from rba.domains import domain_names, get_domain
    from rba.generate.config import GenerationConfig

    for name in domain_names():
        resolved = GenerationConfig().resolved(get_domain(name))  # checked as a file's values would be
        assert None not in (resolved.zeta_noise, resolved.zeta_surface, resolved.noisy_skill), name
        assert 0.0 < get_domain(name).generate_seconds < float("inf"), name

"""`rba build | train | eval | render | cache | serve | export | replay`: the command line over the library.

Bad input prints one line naming the valid choices and exits with status 2.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from rba.compute import Compute
    from rba.generate.cma import Simulate
    from rba.generate.config import GenerationConfig
    from rba.interact.users import UserSpec

log = logging.getLogger("rba")


def _domain(name: str) -> str:
    from rba.domains import domain_names

    if name not in domain_names():
        raise argparse.ArgumentTypeError(f"unknown domain {name!r}; valid: {', '.join(domain_names())}")
    return name


def _with_states(domain: str, states: str) -> str:
    """The registered domain for ``domain`` seen through ``states``: ``<domain>_<states>``, e.g. lane_change_image."""
    from rba.domains import domain_names

    if states == "kinematic":
        return domain
    kinds = ["kinematic"] + [n.removeprefix(f"{domain}_") for n in domain_names() if n.startswith(f"{domain}_")]
    if f"{domain}_{states}" not in domain_names():
        raise LookupError(f"domain {domain!r} has no {states!r} states; valid: {', '.join(kinds)}")
    return f"{domain}_{states}"


def _positive(text: str) -> int:
    value = int(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text}")
    return value


def _number(text: str) -> float:
    """``text`` as a float; NaN (which every range check refuses) when it is not a number."""
    try:
        return float(text)
    except ValueError:
        return float("nan")


def seconds_arg(text: str) -> float:
    """A search's time bound in seconds (> 0, finite): the benchmarks' ``--gen-seconds`` options."""
    value = _number(text)
    if not 0.0 < value < math.inf:
        raise argparse.ArgumentTypeError(f"must be a number of seconds > 0, got {text}")
    return value


def _share(text: str) -> float:
    """A share in (0, 0.5]: how far beyond the serve range targets may lie (``rba eval --beyond``)."""
    value = _number(text)
    if not 0.0 < value <= 0.5:
        raise argparse.ArgumentTypeError(f"must be a share in (0, 0.5], e.g. 0.1 for 10 %; got {text}")
    return value


def _gen_config(text: str) -> GenerationConfig:
    """``--gen-config FILE``: the generating agent's research settings (``rba.generate.config``), checked whole."""
    from rba.generate.config import GenerationConfig

    try:
        return GenerationConfig.from_file(Path(text))
    except (ValueError, OSError) as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _user(text: str) -> UserSpec:
    from rba.interact.users import parse_user

    try:
        return parse_user(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def cmd_build(args) -> int:
    from rba.compute import make_compute
    from rba.core.settings import LibrarySettings
    from rba.data.library import build_all
    from rba.learn.training import prepare_states

    prepare_states(args.domain, args.seed)  # a learned state encoder the rollouts load, trained if missing
    sizes = {"train": args.train, "serve": args.serve, "val": args.val, "test": args.test}
    settings = LibrarySettings(compute_workers=args.workers, compute_nice=0)  # nothing else runs: no need to yield
    with make_compute(settings, args.ray) as compute:
        libs = build_all(args.domain, seed=args.seed, sizes=sizes, compute=compute, splits=tuple(args.splits))
    for split, lib in libs.items():
        m = lib.meta
        print(f"{args.domain}/{split}: {len(lib)} rollouts, success {m['success_rate']:.1%} of {m['attempted']}, "
              f"{m['build_seconds']:.1f} s on {m['workers']} workers, version {lib.version}")
    return 0


def cmd_train(args) -> int:
    from rba.core.methods import get_method, trainable

    if args.remeasure:
        from rba.learn.embed import REPRESENTATIONS
        from rba.learn.training import remeasure

        for rep in REPRESENTATIONS if args.rep == "all" else (args.rep,):
            print(json.dumps({"domain": args.domain, "rep": rep, **remeasure(args.domain, rep)}, indent=2))
        return 0
    chosen = trainable() if args.method == "all" else (get_method(args.method),)
    for method in chosen:
        if args.preset not in method.presets:
            raise ValueError(f"{method.name} has no preset {args.preset!r}; valid: {', '.join(method.presets)}")
        for rep in method.run_reps if args.rep == "all" else (args.rep,):
            metrics = method.trainer(args.domain, rep, args.preset, args.seed)
            print(json.dumps({"domain": args.domain, "method": method.name, "rep": rep, **metrics}, indent=2))
    return 0


def cmd_eval(args) -> int:
    from rba.core.fileio import save_json
    from rba.interact.evaluate import can_generate, evaluate, format_table

    if args.all_methods:
        from rba.core.methods import methods

        if args.generate or args.gen_config is not None:
            raise ValueError("--generate and --gen-config work with one method (the rows of --all-methods are the "
                             "library alone): give --method, not --all-methods")
        args.generate = False  # every method and reference row over the library alone: comparable rows
        if args.serve_size is not None:
            raise ValueError("--serve-size works with one method (global): give --method, not --all-methods")

        runs = [(m.name, r) for m in methods(include_reference=True) for r in m.run_reps]
        results = [evaluate(args.domain, m, r, args.targets, args.seed, args.precision, args.user, split=args.split,
                            beyond=args.beyond)
                   for m, r in runs]
        print(format_table(results))
        if args.json:
            save_json(Path(args.json), [r.to_json() for r in results])
        return 0
    if args.generate is None:
        args.generate = can_generate(args.method, args.user)
    if args.gen_config is not None and not args.generate:
        raise ValueError(f"--gen-config tunes generation, which is off here (method {args.method}, user "
                         f"{args.user}): give --generate with method global, or leave --gen-config out")
    simulate, compute = _simulation(args)
    try:
        result = evaluate(args.domain, args.method, args.rep, args.targets, args.seed, args.precision, args.user,
                          split=args.split, generate=args.generate, gen_config=args.gen_config, beyond=args.beyond,
                          serve_size=args.serve_size, simulator=simulate)
    finally:
        if compute is not None:
            compute.close()
    print(format_table([result]))
    if result.generation:
        print("generation: " + ", ".join(f"{k} {v}" for k, v in result.generation.items()))
    if args.json:
        save_json(Path(args.json), result.to_json())
    return 0


def _simulation(args) -> tuple[Simulate | None, Compute | None]:
    """What simulates a search's candidates with ``--generate``, and the compute backend to close after:
    ``--workers`` local processes or ``--ray``; one worker (or no generation): this process (None)."""
    if not args.generate or (not args.ray and args.workers == 1):
        return None, None
    from rba.compute import make_compute
    from rba.core.settings import LibrarySettings

    compute = make_compute(LibrarySettings(compute_workers=args.workers), args.ray)
    return compute.simulate, compute


def cmd_render(args) -> int:
    from rba.data.library import SPLITS, SkillLibrary
    from rba.domains import get_domain
    from rba.media.video import write_mp4

    split = args.rollout_id.split("-", 1)[0]
    if split not in SPLITS:
        raise LookupError(f"unknown rollout id {args.rollout_id!r}; ids look like serve-00012 "
                          f"(splits: {', '.join(SPLITS)})")
    lib = SkillLibrary.load(args.domain, split)
    rollout = lib.rollout(lib.index_of(args.rollout_id))
    domain = get_domain(args.domain)
    n = write_mp4(domain.render(rollout, args.width, args.height), Path(args.out), domain.frame_rate)
    print(f"wrote {args.out}: {n} frames at {domain.frame_rate:g} fps, proxies {rollout.proxies}")
    return 0


def cmd_cache(args) -> int:
    """Render every clip of a split into the app's clip cache on the compute layer, so no one waits for a render."""
    import time

    from tqdm import tqdm

    from rba.compute import make_compute
    from rba.core.settings import LibrarySettings
    from rba.core.store import Store
    from rba.data.library import SkillLibrary
    from rba.media.clip_cache import ClipCache

    settings = LibrarySettings()
    store = Store.from_settings(settings)
    lib = SkillLibrary.load(args.domain, args.split, store.data_dir)
    start = time.perf_counter()
    with make_compute(settings, args.ray) as compute, tqdm(total=len(lib), desc=f"{args.domain}/{args.split} clips",
                                                          unit="clip") as bar:
        cache = ClipCache(store.clips(), compute, args.width or settings.clip_width,
                          args.height or settings.clip_height)
        made = cache.fill(((cache.key(lib, rid), lib) for rid in lib.ids), on_done=lambda key, rendered: bar.update())
    print(f"{len(lib)} clips of {args.domain}/{args.split} in {store.cache_dir}: {made} rendered in "
          f"{time.perf_counter() - start:.0f} s on {compute.name} ({compute.capacity} workers), "
          f"{len(lib) - made} were cached already")
    return 0


SERVER_ENTRY = "server.main:run"  # the web app, imported only by `rba serve`: the library never imports it
# `rba export` reads the app's database with the app's settings
EXPORT_ENTRY = "server.ops.session_export:export_to_file"
SESSION_DATASET_ENTRY = "server.ops.dataset_export:session_to_dataset"  # `--format minari --session`
LABELS_DATASET_ENTRY = "server.ops.dataset_export:labels_to_dataset"  # `--format minari --labels`


def _server_function(entry: str):
    """A function of the app by its import path: the library never imports ``server`` itself."""
    import importlib

    module, name = entry.split(":")
    return getattr(importlib.import_module(module), name)


def cmd_serve(args) -> int:
    _server_function(SERVER_ENTRY)(host=args.host, port=args.port, ray_address=args.ray)
    return 0


MINARI_USAGE = ("--format minari exports one of: --session ID (a session's clips), --domain D --split SPLIT (a "
                "skill library), --labels --domain D (the admin page's labels), into --out DIR")


def cmd_export(args) -> int:
    """Write a satisfied session's export zip (``rba.data.export_zip``) from the app's database and files, or with
    ``--format minari`` clips as a Minari dataset (``rba.data.minari_export``)."""
    if args.format == "minari":
        return _export_minari(args)
    minari_only = [f"--{k}" for k in ("session", "domain", "split", "labels", "profile") if getattr(args, k)]
    if minari_only or args.out_dir:
        raise ValueError(f"{', '.join(minari_only or ['--out'])}: only with --format minari; the zip export is "
                         "`rba export SESSION_ID OUT.zip`")
    if not (args.session_id and args.out):
        raise ValueError(f"the zip export is `rba export SESSION_ID OUT.zip`; {MINARI_USAGE}")
    profile = _server_function(EXPORT_ENTRY)(args.session_id, Path(args.out))
    reward = profile.reward["kind"] if profile.reward else f"none ({profile.reward_note})"
    print(f"wrote {args.out}: {profile.domain} {profile.rollout_id} (seed {profile.seed}), {profile.method}/"
          f"{profile.rep}, reward {reward}")
    return 0


def _export_minari(args) -> int:
    from tqdm import tqdm

    from rba.data.minari_export import check_domain, library_source, write_dataset

    chosen = [k for k in ("session", "split", "labels") if getattr(args, k)]
    if args.session_id or args.out:
        raise ValueError(f"--format minari takes no positional arguments; {MINARI_USAGE}")
    if len(chosen) != 1 or not args.out_dir:
        raise ValueError(f"{MINARI_USAGE}; got {' '.join(f'--{k}' for k in chosen) or 'none of them'}"
                         f"{'' if args.out_dir else ' and no --out'}")
    if bool(args.domain) == bool(args.session):
        raise ValueError("--session takes its domain from the session" if args.session else
                         f"--{chosen[0]} needs --domain D")
    if args.domain:
        check_domain(args.domain)
    out, profile = Path(args.out_dir), Path(args.profile) if args.profile else None
    bars: list[tqdm] = []  # shown from the first clip on: a refused export prints its one line alone

    def step(_done: int) -> None:
        bars[:] = bars or [tqdm(unit="clip", desc="re-simulated")]
        bars[0].update()

    try:
        if args.split:
            written = write_dataset(out, library_source(args.domain, args.split), profile, step)
        elif args.session:
            written = _server_function(SESSION_DATASET_ENTRY)(args.session, out, profile, on_episode=step)
        else:
            written = _server_function(LABELS_DATASET_ENTRY)(args.domain, out, profile, on_episode=step)
    finally:
        for bar in bars:
            bar.close()
    print(f"wrote {written.dataset_id} ({written.episodes} episodes, {written.steps} steps) to {written.path}; "
          f"read it with MINARI_DATASETS_PATH={out} and minari.load_dataset({written.dataset_id!r})")
    return 0


def cmd_replay(args) -> int:
    """Simulate an export's behaviour again from its params and seed: 0 if its attributes match, 1 if not (an
    invalid zip is an ``ExportError``, exit 2, before anything is simulated)."""
    from rba.data.export_zip import replay

    result = replay(Path(args.zip))
    p = result.profile
    print(f"{p.domain} {p.rollout_id}, seed {p.seed}, params {p.params}")
    print(f"{'attribute':<16} {'profile':>14} {'replayed':>14}")
    for name, want in p.proxies.items():
        print(f"{name:<16} {want:>14.6g} {result.measured[name]:>14.6g}")
    print("match" if result.matches else "MISMATCH: the replayed attributes differ from the profile's "
          f"(simulators then: {p.simulators})")
    return 0 if result.matches else 1


def _ray_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--ray", metavar="ADDRESS", default=None,
                        help="simulate and render on a Ray cluster: auto (the one running on this machine), local "
                             "(start one here), host:port or ray://host:port; default: RBA_RAY_ADDRESS, else local "
                             "worker processes")


def _build_command(sub) -> argparse.ArgumentParser:
    from rba.data.library import SPLITS

    b = sub.add_parser("build", help="simulate the train / serve / val / test skill libraries")
    b.add_argument("domain", type=_domain)
    b.add_argument("--seed", type=int, default=0)
    b.add_argument("--train", type=_positive, default=300, help="rollouts in train (labels come from these)")
    b.add_argument("--serve", type=_positive, default=None,
                   help="rollouts the agent chooses from (default: the domain's serve_size)")
    b.add_argument("--val", type=_positive, default=120, help="held-out behaviours for tuning and model selection")
    b.add_argument("--test", type=_positive, default=120, help="held-out target behaviours (only `rba eval`)")
    b.add_argument("--splits", nargs="+", choices=SPLITS, default=list(SPLITS),
                   help="build only these splits; the others stay as they are")
    b.add_argument("--workers", type=_positive, default=2, help="simulation processes (without --ray)")
    _ray_option(b)
    b.set_defaults(func=cmd_build)
    return b


def _train_command(sub) -> argparse.ArgumentParser:
    from rba.core.methods import train_presets, trainable
    from rba.learn.embed import REPRESENTATIONS

    t = sub.add_parser("train", help=f"train the models of {' and/or '.join(m.label for m in trainable())} "
                                     "and write model cards")
    t.add_argument("domain", type=_domain)
    t.add_argument("--method", choices=(*(m.name for m in trainable()), "all"), default="all",
                   help="which models to train")
    t.add_argument("--rep", choices=(*REPRESENTATIONS, "all"), default="all")
    t.add_argument("--preset", choices=train_presets(), default="default",
                   help="'quick': a shorter rθ; 'tiny': the CI smoke preset; 'pairwise' (global only): "
                        "ζσ from a simulated annotator's 1,000 noisy pairs instead of a perfect ordering")
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--remeasure", action="store_true",
                   help="train nothing: recompute the saved models' held-out card numbers on val with today's ε")
    t.set_defaults(func=cmd_train)
    return t


def _cache_command(sub) -> argparse.ArgumentParser:
    from rba.data.library import SPLITS

    c = sub.add_parser("cache", help="render every clip of a split into the app's clip cache (RBA_CACHE_DIR)")
    c.add_argument("domain", type=_domain)
    c.add_argument("--split", choices=SPLITS, default="serve")
    c.add_argument("--width", type=_positive, default=None, help="default: RBA_CLIP_WIDTH (320)")
    c.add_argument("--height", type=_positive, default=None, help="default: RBA_CLIP_HEIGHT (240)")
    _ray_option(c)
    c.set_defaults(func=cmd_cache)
    return c


def _eval_command(sub) -> argparse.ArgumentParser:
    from rba.core.methods import method_names
    from rba.data.library import HELD_OUT
    from rba.interact.users import USER_KINDS
    from rba.learn.embed import REPRESENTATIONS

    e = sub.add_parser("eval", help="run the paper's protocol with simulated users")
    e.add_argument("--domain", type=_domain, required=True)
    e.add_argument("--method", choices=method_names(), default="global")
    e.add_argument("--rep", choices=REPRESENTATIONS, default="onehot")
    e.add_argument("--targets", type=_positive, default=20)
    e.add_argument("--seed", type=int, default=0)
    e.add_argument("--precision", choices=("normal", "high"), default="normal")
    e.add_argument("--split", choices=HELD_OUT, default="test",
                   help="where targets come from: val to tune or choose models, test for reported numbers")
    e.add_argument("--beyond", type=_share, default=None, metavar="SHARE",
                   help="targets outside the serve library's proxy range by up to SHARE of it on each side, "
                        "from rollouts the skill made (seeded; instead of --split's)")
    e.add_argument("--serve-size", type=_positive, default=None, metavar="N",
                   help="the agent chooses among the serve library's first N rollouts only (RBA-Global; how "
                        "small a library generation needs)")
    e.add_argument("--user", type=_user, default="paper", metavar="KIND[:param]",
                   help=f"the simulated user: {', '.join(USER_KINDS)} (e.g. mistake:0.2; without a param the "
                        "kind's default strength; see rba/interact/users.py)")
    e.add_argument("--all-methods", action="store_true",
                   help="evaluate every method and representation, the random and oracle reference rows too "
                        "(ignores --method/--rep); JSON is a list")
    e.add_argument("--json", help="write the full result (trials included) here")
    e.add_argument("--generate", action=argparse.BooleanOptionalAction, default=None,
                   help="let the agent make clips beyond the serve library when none is close to its target; "
                        "default: on where the method can (RBA-Global) and the user can judge new clips (not "
                        "myopic); --no-generate: the library alone, to compare")
    e.add_argument("--gen-config", type=_gen_config, default=None, metavar="FILE",
                   help="research settings of generation, to tune on --split val: a TOML or JSON file of the "
                        "keys it changes (rba.generate.config.GenerationConfig; docs/guide.md); default: the "
                        "domain's, chosen on val")
    e.add_argument("--workers", type=_positive, default=2,
                   help="local processes simulating generation's candidates (1: this process; without --ray)")
    _ray_option(e)
    e.set_defaults(func=cmd_eval)
    return e


def _render_command(sub) -> argparse.ArgumentParser:
    r = sub.add_parser("render", help="render a library rollout to an MP4 (H.264)")
    r.add_argument("domain", type=_domain)
    r.add_argument("rollout_id", help="e.g. serve-00012")
    r.add_argument("out", help="output .mp4 path")
    r.add_argument("--width", type=_positive, default=320)
    r.add_argument("--height", type=_positive, default=240)
    r.set_defaults(func=cmd_render)
    return r


def _serve_command(sub) -> argparse.ArgumentParser:
    s = sub.add_parser("serve", help="start the web app")
    s.add_argument("--host", default=None)
    s.add_argument("--port", type=int, default=None)
    _ray_option(s)
    s.set_defaults(func=cmd_serve)
    return s


def _export_commands(sub) -> None:
    from rba.data.library import SPLITS

    e = sub.add_parser("export", help="write a satisfied session's behaviour (profile, clip, reward) to a zip, or "
                                      "clips as a Minari dataset (--format minari)")
    e.add_argument("session_id", nargs="?", help="the session's id (the page's URL and the API name it)")
    e.add_argument("out", nargs="?", help="output .zip path (written atomically)")
    e.add_argument("--format", choices=("zip", "minari"), default="zip",
                   help="zip (default): SESSION_ID OUT; minari: " + MINARI_USAGE.removeprefix("--format minari "))
    e.add_argument("--out", dest="out_dir", help="minari: the datasets folder (the dataset is rba/<name>-v0 in it)")
    e.add_argument("--session", help="minari: a session's clips, in the order shown")
    e.add_argument("--domain", type=_domain, help="minari: the domain of --split or --labels")
    e.add_argument("--split", choices=SPLITS, help="minari: a skill library of --domain")
    e.add_argument("--labels", action="store_true", help="minari: the clips the admin page's labels refer to")
    e.add_argument("--profile", help="minari: an export zip whose reward rθ(s | v*) gives the rewards (else 0)")
    e.set_defaults(func=cmd_export)
    r = sub.add_parser("replay", help="re-simulate an export's behaviour and compare its attributes (exit 1 if "
                                      "they differ, 2 if the zip is not a valid export: nothing is simulated)")
    r.add_argument("zip", help="a zip `rba export` or the page wrote")
    r.set_defaults(func=cmd_replay)


DOMAIN_COMMANDS = (_build_command, _train_command, _cache_command, _eval_command, _render_command)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="rba", description="RBA Studio: tune agent behaviour by relative attributes.")
    p.add_argument("-v", "--verbose", action="store_true", help="log progress at INFO level")
    sub = p.add_subparsers(dest="command", required=True)
    for add_command in DOMAIN_COMMANDS:  # every command that names a domain can pick its view
        add_command(sub).add_argument("--states", default="kinematic",
                                      help="kinematic (default) or another registered view, e.g. image for lane_change")
    _serve_command(sub)
    _export_commands(sub)
    return p


def main(argv: list[str] | None = None) -> int:
    os.environ.setdefault("MUJOCO_GL", "egl")  # off-screen, as the compute workers: `rba render` gives their bytes
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(asctime)s %(name)s %(levelname)s %(message)s")
    try:
        if hasattr(args, "states"):
            args.domain = _with_states(args.domain, args.states)
        return args.func(args)
    except (LookupError, ValueError, FileNotFoundError, OSError) as exc:
        msg = exc.args[0] if isinstance(exc, KeyError) and exc.args else exc
        print(f"rba: error: {msg}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())

"""Is the exported reward usable on its own? A parameter search that sees only rθ(s | v*) of an export.

Profiles come from simulated-user sessions (``rba.interact.evaluate.simulate``, the paper's user at normal precision):
each trial that ends satisfied within ε is exported (``rba.data.export_zip.write_export``) and read back
(``read_export``). CMA-ES (the ``cma`` package) then searches the skill's parameters, with the profile's
seed, for the largest return Σ_t rθ(s_t | v*) of the simulated rollout: no proxies, no library (the box it
searches is the skill prior's, from ``Domain.sample_params``). A profile is reproduced when the best
parameters' measured attributes are within ε (``Domain.epsilons(serve proxies, "normal")``) of the profile's.

The export re-fits rθ's last layer for v* on the serve library's ζσ ranking (``refit_for_target``) where the
domain chooses it (``Domain.export_refit``); ``--no-refit`` exports the trained weights, ``--refit-pull P`` re-fits
in any domain, to compare.

``--ceiling`` runs the same search a second time with rθ replaced by what it was trained to rank by: the
distance of a rollout's standardised ζσ (the ranker's) to v*. That distance is 0 at the profile's own
parameters (v* is their ζσ), so a miss it reports with its distance still above ``ZETA_REACHED`` is the
search's (it did not find the optimum within the budget), and one below is ζσ's (it cannot tell the found
behaviour from the chosen one within ε). Not a strict bound on rθ: the same search may happen to climb rθ
where it stalls on the distance.

    python benchmarks/reward_only.py --domain walker     # 20 profiles from test sessions
"""

from __future__ import annotations

import argparse
import logging
import os
import platform
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import cma
import numpy as np
import torch

from rba.core.artifacts import load_model
from rba.core.fileio import save_report
from rba.core.store import model_files
from rba.data.export_zip import Export, ExportSource, read_export, write_export
from rba.data.library import HELD_OUT, SkillLibrary
from rba.domains import Domain, get_domain
from rba.interact import load_context, new_agent
from rba.interact.evaluate import simulate
from rba.learn.common import Ragged
from rba.learn.global_reward import GlobalReward, RefitConfig
from rba.learn.ranker import AttributeRanker

log = logging.getLogger("reward_only")
RESULTS = Path(__file__).resolve().parent / "results"
OUTPUTS = (  # what this script writes into benchmarks/results/ (tests/test_results_files.py)
    "reward_only_*.json", "reward_only_*.md",
)
PRIOR_SAMPLES = 2000  # draws of sample_params that bound the searched box
ZETA_REACHED = 0.05  # the ceiling's distance to v* (standardised ζσ) below which it found ζσ's optimum
DRAWN_SIGMA = 0.1  # CMA-ES's first step from the best prior draw (``--draws``; 0.3 from the box's centre)
DRAWN_SHARE = 3  # by default a third of the budget is prior draws (val: snake 12 → 15 of 20, the others held)


def prior_box(domain: Domain, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """The skill prior's parameter box (min / max of many ``sample_params`` draws), in ``param_names`` order."""
    rng = np.random.default_rng(seed)
    draws = np.array([[p[k] for k in domain.param_names] for p in (domain.sample_params(rng)
                                                                   for _ in range(PRIOR_SAMPLES))])
    return draws.min(0), draws.max(0)


def unit_params(domain: Domain, box: tuple[np.ndarray, np.ndarray], x: np.ndarray) -> dict[str, float]:
    """The parameters at ``x`` of the box scaled to [0, 1] (clipped to it)."""
    lo, hi = box
    return dict(zip(domain.param_names, (lo + np.clip(x, 0, 1) * (hi - lo)).tolist(), strict=True))


def prior_draws(domain: Domain, box: tuple[np.ndarray, np.ndarray], n: int, seed: int) -> list[np.ndarray]:
    """``n`` draws of the skill prior as points of the box scaled to [0, 1] (clipped to it)."""
    rng, (lo, hi) = np.random.default_rng(seed), box
    return [np.clip((np.array([q[k] for k in domain.param_names]) - lo) / (hi - lo), 0, 1)
            for q in (domain.sample_params(rng) for _ in range(n))]


def profiles(args: argparse.Namespace, folder: Path) -> Iterator[Path]:
    """Exports of simulated sessions that ended satisfied within ε, ``args.profiles`` of them at most, each as soon
    as its session ends: a run's log then reports each profile's search before the next session runs."""
    domain = get_domain(args.domain)
    ctx = load_context(args.domain, "global", args.rep)
    serve, targets = ctx.serve, SkillLibrary.load(args.domain, args.split)
    eps = domain.epsilons(serve.proxies, "normal")
    version = ctx.model_version
    made = 0
    for n, t in enumerate(np.random.default_rng(args.seed).permutation(len(targets))):
        if made == args.profiles:
            return
        trial = simulate(new_agent("global", ctx), targets.proxies[t], eps, serve, "paper", args.seed * 1000 + n)
        if not trial.success:
            continue
        shown = trial.shown_ids
        rounds = [{"step": i, "feedback": "simulated user (paper)", "rollout_before": a, "rollout_after": b}
                  for i, (a, b) in enumerate(zip(shown, [*shown[1:], shown[-1]], strict=True))]
        src = ExportSource(args.domain, "global", args.rep, version, "builtin", model_files().root, serve,
                           shown[-1], rounds, clip=b"",
                           refit=_refit(args))
        path = folder / f"profile-{made:02d}.zip"
        write_export(path, src)
        made += 1
        yield path


def _refit(args: argparse.Namespace) -> RefitConfig | None:
    """The export's re-fit: none with ``--no-refit``, or where the domain keeps rθ's trained weights and no
    ``--refit-pull`` asks for one."""
    return None if args.no_refit or args.refit_pull is None else RefitConfig(pull=args.refit_pull)


Loss = Callable[[Export, np.ndarray], float]  # (export, a rollout's states) -> what the search minimises


def reward_loss(export: Export, states: np.ndarray) -> float:
    """−Σ_t rθ(s_t | v*): the export's own reward, all the benchmark's search may see."""
    return -export.reward.total(states)


class ZetaLoss:
    """‖standardised ζσ(τ) − v*‖: the ranking rθ was trained to reproduce (the ceiling's objective)."""

    def __init__(self, ranker: AttributeRanker, reward: GlobalReward) -> None:
        self.ranker, self.reward = ranker, reward

    def __call__(self, export: Export, states: np.ndarray) -> float:
        zeta = self.ranker.score(Ragged.from_numpy(states, np.array([0, len(states)])))
        with torch.no_grad():
            v = self.reward.zeta_norm(torch.as_tensor(zeta, dtype=torch.float32)).numpy()[0]
        return float(np.linalg.norm(v - np.asarray(export.reward.condition["v_star"])))


def search(path: Path, domain: Domain, box: tuple[np.ndarray, np.ndarray], budget: int, seed: int,
           loss_of: Loss = reward_loss, draws: int = 0) -> dict:
    """CMA-ES over the box (scaled to [0, 1]) minimising ``loss_of`` (by default: maximising the export's return);
    the best params' attributes. With ``draws``, that many of the budget's rollouts are draws of the skill prior
    (``Domain.sample_params``), and CMA-ES starts from the best of them with a narrower step (``DRAWN_SIGMA``)."""
    export = read_export(path)
    p = export.profile

    def loss(x: np.ndarray) -> float:
        return loss_of(export, domain.rollout(unit_params(domain, box, np.asarray(x)), p.seed).states)

    start = time.perf_counter()
    x0, sigma0, f0 = np.full(len(box[0]), 0.5), 0.3, np.inf
    if draws:
        xs = prior_draws(domain, box, draws, seed + 1)
        fs = [loss(x) for x in xs]
        x0, sigma0, f0 = xs[int(np.argmin(fs))], DRAWN_SIGMA, float(min(fs))
    es = cma.CMAEvolutionStrategy(x0, sigma0, {"bounds": [0, 1], "maxfevals": budget - draws, "seed": seed + 1,
                                               "verbose": -9})
    while not es.stop():
        xs = es.ask()
        es.tell(xs, [loss(x) for x in xs])
    xbest, fbest = (es.result.xbest, float(es.result.fbest)) if es.result.fbest <= f0 else (x0, f0)
    best = unit_params(domain, box, xbest)
    measured = domain.rollout(best, p.seed).proxies
    return {"profile": path.name, "rollout_id": p.rollout_id, "target": p.proxies, "found": measured,
            "params": best, "evaluations": draws + int(es.result.evaluations),
            "seconds": round(time.perf_counter() - start, 1),
            "return_found": export.reward.total(domain.rollout(best, p.seed).states),
            "return_profile": export.reward.total(domain.rollout(p.params, p.seed).states),
            "loss_found": fbest}


def _search_once(path: Path, domain: Domain, box: tuple[np.ndarray, np.ndarray], args: argparse.Namespace,
                 searched: dict[str, dict], ceiling: ZetaLoss | None) -> dict:
    """``search`` (and with ``ceiling`` the ceiling's, under "ceiling"), or the result of an earlier profile that
    chose the same rollout: the same v*, seed and search.

    Sessions often end on the same clip; its export's reward is rθ(· | ζσ of that clip), so the search would
    repeat itself exactly. The copy names the profile it repeats (``same_as``).
    """
    rollout_id = read_export(path).profile.rollout_id
    if rollout_id in searched:
        first = searched[rollout_id]
        return {**first, "profile": path.name, "same_as": first["profile"], "seconds": 0.0}
    r = search(path, domain, box, args.budget, args.seed, draws=args.draws)
    if ceiling is not None:
        c = search(path, domain, box, args.budget, args.seed, ceiling, args.draws)
        r["ceiling"] = {k: c[k] for k in ("found", "params", "evaluations", "seconds", "loss_found")}
    searched[rollout_id] = r
    return r


def _within(found: dict[str, float], target: dict[str, float], eps: np.ndarray) -> bool:
    return bool(np.all(np.abs(np.array(list(found.values())) - np.array(list(target.values()))) <= eps))


def _fmt(values: dict[str, float]) -> str:
    return ", ".join(f"{k} {v:.3f}" for k, v in values.items())


def _ceiling_cells(c: dict) -> str:
    loss = "–" if c.get("loss_found") is None else f"{c['loss_found']:.3f}"
    return f" {_fmt(c['found'])} | {loss} | {'yes' if c['within'] else 'no'} |"


def _ceiling_summary(results: list[dict]) -> str:
    """The ceiling's share, and whose its misses are: the search's (ζσ distance left) or ζσ's (none left)."""
    n, within = len(results), sum(r["ceiling"]["within"] for r in results)
    text = (f" The same search by ζσ distance to v* (the ceiling: what rθ was trained to rank by) finds them in "
            f"**{within} of {n}** ({within / max(n, 1):.0%}).")
    missed = [r["ceiling"].get("loss_found") for r in results if not r["ceiling"]["within"]]
    if missed and None not in missed:
        short = sum(loss > ZETA_REACHED for loss in missed)
        text += (f" Of its {len(missed)} misses, {short} ended with the ζσ distance above {ZETA_REACHED} (0 at the "
                 f"profile's own parameters: the search stopped short) and {len(missed) - short} below it (ζσ cannot "
                 "tell the found behaviour from the chosen one within ε).")
    return text


def _reward_kind(args: dict) -> str:
    if "no_refit" not in args:  # a report from before the re-fit
        return "rθ's trained weights"
    if args["no_refit"]:
        return "rθ's trained weights (`--no-refit`)"
    pull = args.get("refit_pull")
    if pull is None and "refit_pull" in args:  # no pull asked, in a domain that keeps its trained weights
        return "rθ's trained weights (the domain's choice, `Domain.export_refit`)"
    pull = RefitConfig().pull if pull is None else pull  # absent before the option: the default
    return f"rθ with its last layer re-fitted for v* (`rba.data.export_zip`; pull {pull})"


def markdown(report: dict) -> str:
    ceiling = "ceiling_within" in report
    head = "| profile | target | found | within ε | return: found / profile's params | rollouts |"
    rows = [head + (" ceiling: found | its ζσ distance to v* | within ε |" if ceiling else ""),
            "|---" * (9 if ceiling else 6) + "|"]
    for r in report["results"]:
        row = (f"| {r['profile']} ({r['rollout_id']}) | {_fmt(r['target'])} | {_fmt(r['found'])} | "
               f"{'yes' if r['within'] else 'no'} | {r['return_found']:.2f} / {r['return_profile']:.2f} | "
               f"{r['evaluations']} |")
        rows.append(row + (_ceiling_cells(r["ceiling"]) if ceiling else ""))
    eps = ", ".join(f"{k} {v:.3f}" for k, v in report["epsilon"].items())
    budget, n, draws = report["args"]["budget"], len(report["results"]), report["args"].get("draws", 0)
    drawn = f", the first {draws} of them draws of the skill prior, CMA-ES from the best" if draws else ""
    return (f"# Reward-only search\n\nA search that sees only an export's rθ(s | v*) (CMA-ES, {budget}"
            f" rollouts{drawn}) finds skill parameters within ε of the profile in **{report['within']} of "
            f"{n}** profiles ({report['share']:.0%}).{_ceiling_summary(report['results']) if ceiling else ''}\n\n"
            f"- Setting: {report['args']['domain']}, RBA-Global/{report['args']['rep']}, profiles from simulated "
            f"sessions on `{report['args']['split']}` targets (paper user, normal precision), ε = {eps}; the "
            f"export's reward: {_reward_kind(report['args'])}.\n"
            f"- Command: `{report['command']}` ({report['date']}, {report['machine']}).\n"
            "- A found return above the profile's own with the attributes outside ε is the reward's error, not the "
            "search's.\n\n" + "\n".join(rows) + "\n")


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--domain", default="walker")
    p.add_argument("--rep", default="onehot")
    p.add_argument("--profiles", type=int, default=20)
    p.add_argument("--split", choices=HELD_OUT, default="test", help="where the sessions' targets come from")
    p.add_argument("--budget", type=int, default=240, help="simulated rollouts per search")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--draws", type=int, default=None,
                   help="rollouts of the budget spent on draws of the skill prior first; CMA-ES then starts from "
                        "the best of them (0: from the box's centre); default: a third of the budget (chosen on "
                        "val: decision 0013); tune on --split val")
    p.add_argument("--ceiling", action="store_true",
                   help="search each profile again by ζσ distance to v* (what rθ was trained to rank by): what the "
                        "labels rθ learns from can tell apart, under the same search")
    p.add_argument("--no-refit", action="store_true",
                   help="export rθ's trained weights, not its last layer re-fitted for v* (the export's default)")
    p.add_argument("--refit-pull", type=float, default=None,
                   help="re-fit with this pull back to the trained last layer, in any domain (default: the domain's "
                        "choice, Domain.export_refit, with RefitConfig.pull; tune on --split val)")
    p.add_argument("--out", type=Path, default=None, help="writes <out>.json and <out>.md; default "
                   "benchmarks/results/reward_only_<domain>")
    args = p.parse_args(argv)
    args.draws = args.budget // DRAWN_SHARE if args.draws is None else args.draws
    if not 0 <= args.draws < args.budget:
        p.error(f"--draws is a part of --budget ({args.budget}): 0 to {args.budget - 1}, got {args.draws}")
    if args.no_refit and args.refit_pull is not None:
        p.error("--refit-pull sets the re-fit that --no-refit turns off; give one of them")
    if not args.no_refit and args.refit_pull is None and get_domain(args.domain).export_refit:
        args.refit_pull = RefitConfig().pull  # the domain re-fits with the default
    args.out = args.out or RESULTS / f"reward_only_{args.domain}"
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    domain = get_domain(args.domain)
    run = {"command": "python benchmarks/reward_only.py " + " ".join(argv if argv is not None else sys.argv[1:]),
           "date": time.strftime("%Y-%m-%d %H:%M"),
           "machine": f"{os.cpu_count()} cores, {platform.machine()}, Python {platform.python_version()}"}
    eps = domain.epsilons(SkillLibrary.load(args.domain, "serve").proxies, "normal")
    box = prior_box(domain, args.seed)
    ceiling = (ZetaLoss(load_model(args.domain, "ranker", args.rep).model,
                        load_model(args.domain, "global_reward", args.rep).model) if args.ceiling else None)
    with tempfile.TemporaryDirectory(prefix="rba-reward-only-") as folder:
        results, searched = [], {}  # rollout id -> its first profile's result
        for path in profiles(args, Path(folder)):
            r = _search_once(path, domain, box, args, searched, ceiling)
            r["within"] = _within(r["found"], r["target"], eps)
            if "ceiling" in r:
                r["ceiling"] = {**r["ceiling"], "within": _within(r["ceiling"]["found"], r["target"], eps)}
            log.info("%s: within ε %s after %d rollouts (%.0f s)", path.name, r["within"], r["evaluations"],
                     r["seconds"])
            results.append(r)
    within = sum(r["within"] for r in results)
    report = {**run, "args": {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()},
              "epsilon": dict(zip(domain.attribute_names, eps.tolist(), strict=True)), "results": results,
              "within": within, "share": within / len(results) if results else 0.0}
    if ceiling is not None:
        report["ceiling_within"] = sum(r["ceiling"]["within"] for r in results)
    save_report(args.out, report, markdown(report))
    log.info("wrote %s.json and %s.md", args.out, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Free-text feedback: accuracy of ``rba.interact.free_text`` per domain on hand-written phrasings, and how long the
first sentence after a server's start-up takes.

A phrasing counts as right when the set of (attribute, direction) pairs it maps to equals the
expected set exactly ("not understood" is the empty set). The phrasings are
``tests/data/interpret_phrasings.json``: ``val`` is what the anchors, ``THRESHOLD``, ``CUE_BONUS`` and
``LOW_CONFIDENCE`` were tuned on; ``test`` was written beforehand and is only measured. Per domain it also counts the
phrasings read with a low confidence (offered two readings: decision 0021) and those whose second reading was the
right one. The start-up part runs the operation behind ``POST /api/domains/{domain}/interpret`` in fresh processes:
with the warm start (the sentence model loads in the background at start-up) and without it (the first sentence
loads it). Writes ``benchmarks/results/interpret.md`` (the test split), with every miss.

    python benchmarks/interpret.py               # test split and start-up, writes the report
    python benchmarks/interpret.py --split val   # the tuning split, prints only
"""

from __future__ import annotations

import argparse
import json
import logging
import multiprocessing
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PHRASINGS = ROOT / "tests" / "data" / "interpret_phrasings.json"
REPORT = ROOT / "benchmarks" / "results" / "interpret.md"
OUTPUTS = ("interpret.md",)  # what this script writes into benchmarks/results/ (tests/test_results_files.py)
STARTUP_DOMAIN, LATER = "walker", 20  # the sentences after the first one, timed for the median
log = logging.getLogger("interpret")


def _setup() -> None:
    """What every process of this script needs: the repository on the path (the toy domain lives in tests/), offline
    models and one torch thread, as the server runs (Settings.torch_threads)."""
    if str(ROOT) not in sys.path:
        sys.path.insert(0, str(ROOT))
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    import torch

    torch.set_num_threads(1)


def measure(split: str) -> dict[str, dict]:
    """Per domain: accuracy, phrasing count, misses (text, expected, got), low-confidence counts, ms per sentence."""
    from rba.domains import get_domain, register
    from rba.interact.free_text import Interpreter, NotUnderstood

    register("toy", "tests.toy:Toy")
    cases = json.loads(PHRASINGS.read_text())[split]
    out = {}
    for name, items in cases.items():
        interpreter = Interpreter.for_domain(get_domain(name))
        start = time.perf_counter()
        read = []
        for text, _ in items:
            try:
                read.append(interpreter.interpret(text))
            except NotUnderstood:
                read.append(None)
        seconds = (time.perf_counter() - start) / len(items)

        def pairs(feedback) -> set[str]:
            return {f"{a}:{d}" for a, d in feedback}

        got = [pairs(r.feedback) if r else set() for r in read]
        misses = [(text, sorted(want), sorted(g)) for (text, want), g in zip(items, got, strict=True)
                  if set(want) != g]
        unsure = [(r, set(want)) for r, (_, want) in zip(read, items, strict=True) if r and r.alternatives]
        out[name] = {"accuracy": 1 - len(misses) / len(items), "n": len(items), "misses": misses, "seconds": seconds,
                     "unsure": len(unsure), "second_right": sum(pairs(r.alternatives[1]) == want for r, want in unsure)}
    return out


def startup_probe(warm: bool) -> dict[str, float]:
    """In a fresh process: start the app's services (no libraries needed), then time the first interpret (after the
    background load ended, when warm) and the ``LATER`` after it."""
    _setup()
    from server.common.app_settings import Settings
    from server.ops import text_feedback
    from server.runtime.services import Services

    texts = [t for t, want in json.loads(PHRASINGS.read_text())["val"][STARTUP_DOMAIN] if want]
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        settings = Settings(data_dir=root / "data", models_dir=root / "models", cache_dir=root / "clips",
                            database_url=f"sqlite:///{root / 'rba.db'}", warm_start=warm, prerender=False,
                            prerender_library=False)
        started = time.perf_counter()
        svc = Services.start(settings)
        try:
            if svc.reading is not None:
                svc.reading.join()
            loaded = time.perf_counter() - started
            ms = []
            for i in range(LATER + 1):
                t = time.perf_counter()
                text_feedback.interpret(svc, STARTUP_DOMAIN, texts[i % len(texts)])
                ms.append(1000 * (time.perf_counter() - t))
        finally:
            svc.stop()
    return {"load_s": loaded if warm else 0.0, "first_ms": ms[0], "later_ms": statistics.median(ms[1:])}


def startup() -> dict[str, dict[str, float]]:
    """The probe with and without the warm start, each in its own fresh (spawned) process."""
    spawn = multiprocessing.get_context("spawn")
    out = {}
    for warm in (True, False):
        with spawn.Pool(1) as pool:
            out["warm start" if warm else "no warm start"] = pool.apply(startup_probe, (warm,))
    return out


def report(results: dict[str, dict], split: str, starts: dict[str, dict[str, float]], load: tuple) -> str:
    lines = ["# Free-text feedback: accuracy per domain", "",
             f"`python benchmarks/interpret.py` on the `{split}` phrasings of `tests/data/interpret_phrasings.json` "
             "(exact match of the set of (attribute, direction) pairs; \"not understood\" is the empty set). "
             "The anchors and thresholds were tuned on the `val` split only. *Two readings*: phrasings read with a "
             "confidence below `LOW_CONFIDENCE`, offered with their second likeliest reading (decision 0021); "
             "*second right*: of those, the ones whose second reading was the expected one.", "",
             "| domain | phrasings | accuracy | two readings | second right | ms per sentence |",
             "|---|---|---|---|---|---|"]
    lines += [f"| {d} | {r['n']} | {r['accuracy']:.3f} | {r['unsure']} | {r['second_right']} | "
              f"{1000 * r['seconds']:.0f} |" for d, r in results.items()]
    lines += [] if not starts else ["", "## The first sentence after start-up", "",
              f"`Services.start` in a fresh process with no libraries, then `{LATER + 1}` {STARTUP_DOMAIN} sentences "
              "through the operation behind `POST /api/domains/{domain}/interpret` (`server.ops.text_feedback`), "
              "one torch thread. *Warm start*: the sentence model and every domain's anchors load in the background at "
              "start-up (`Services.reading`), timed until done; the first sentence comes after. *No warm start*: the "
              f"first sentence loads them. Load average (1, 5, 15 min) before: {load[0]:.2f}, {load[1]:.2f}, "
              f"{load[2]:.2f}; after: {load[3]:.2f}.", "",
              "| start | background load (s) | first sentence (ms) | later sentences, median (ms) |",
              "|---|---|---|---|", *(f"| {mode} | {s['load_s']:.1f} | {s['first_ms']:.0f} | {s['later_ms']:.0f} |"
                                     for mode, s in starts.items())]
    lines += ["", "## Misses", ""]
    for d, r in results.items():
        lines += [f"- {d}: {text!r}: expected {want or 'not understood'}, got {got or 'not understood'}"
                  for text, want, got in r["misses"]]
    return "\n".join(lines) + "\n"


def main() -> None:
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--split", choices=("test", "val"), default="test")
    args = p.parse_args()
    _setup()
    before = os.getloadavg()
    results = measure(args.split)
    if args.split == "val":
        log.info("%s", report(results, args.split, {}, (*before, os.getloadavg()[0])))
        return
    starts = startup()
    text = report(results, args.split, starts, (*before, os.getloadavg()[0]))
    log.info("%s", text)
    from rba.core.fileio import save_markdown

    save_markdown(REPORT, text)


if __name__ == "__main__":
    main()

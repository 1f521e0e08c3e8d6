"""Free-text feedback: accuracy of ``rba.interact.free_text`` per domain on hand-written phrasings.

A phrasing counts as right when the set of (attribute, direction) pairs it maps to equals the
expected set exactly ("not understood" is the empty set). The phrasings are
``tests/data/interpret_phrasings.json``: ``val`` is what the anchors, ``THRESHOLD`` and ``CUE_BONUS``
were tuned on; ``test`` was written beforehand and is only measured. Writes
``benchmarks/results/interpret.md`` (the test split), with every miss.

    python benchmarks/interpret.py               # test split, writes the report
    python benchmarks/interpret.py --split val   # the tuning split, prints only
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PHRASINGS = ROOT / "tests" / "data" / "interpret_phrasings.json"
REPORT = ROOT / "benchmarks" / "results" / "interpret.md"
OUTPUTS = ("interpret.md",)  # what this script writes into benchmarks/results/ (tests/test_results_files.py)
log = logging.getLogger("interpret")


def measure(split: str) -> dict[str, dict]:
    """Per domain: accuracy, phrasing count, misses (text, expected, got) and mean seconds per sentence."""
    from rba.domains import get_domain, register
    from rba.interact.free_text import Interpreter, understood

    register("toy", "tests.toy:Toy")
    cases = json.loads(PHRASINGS.read_text())[split]
    out = {}
    for name, items in cases.items():
        interpreter = Interpreter.for_domain(get_domain(name))
        start = time.perf_counter()
        got = [understood(interpreter, text) for text, _ in items]
        seconds = (time.perf_counter() - start) / len(items)
        misses = [(text, sorted(want), sorted(g)) for (text, want), g in zip(items, got, strict=True)
                  if set(want) != g]
        out[name] = {"accuracy": 1 - len(misses) / len(items), "n": len(items), "misses": misses, "seconds": seconds}
    return out


def report(results: dict[str, dict], split: str) -> str:
    lines = ["# Free-text feedback: accuracy per domain", "",
             f"`python benchmarks/interpret.py` on the `{split}` phrasings of `tests/data/interpret_phrasings.json` "
             "(exact match of the set of (attribute, direction) pairs; \"not understood\" is the empty set). "
             "The anchors and thresholds were tuned on the `val` split only.", "",
             "| domain | phrasings | accuracy | ms per sentence |", "|---|---|---|---|"]
    lines += [f"| {d} | {r['n']} | {r['accuracy']:.3f} | {1000 * r['seconds']:.0f} |" for d, r in results.items()]
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
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    import torch

    torch.set_num_threads(1)  # as the server runs it (Settings.torch_threads): more threads only sync
    results = measure(args.split)
    text = report(results, args.split)
    log.info("%s", text)
    if args.split == "test":
        tmp = REPORT.with_suffix(".md.tmp")
        tmp.write_text(text)
        tmp.replace(REPORT)


if __name__ == "__main__":
    main()

"""Minari export of whole serve libraries: how long ``rba export --format minari --domain D --split serve`` takes
per domain, how big the dataset is, and that ``minari.load_dataset`` reads it back whole.

Each domain's serve library is exported into a temporary datasets folder (``rba.data.minari_export``: every
clip re-simulated in its ``rba.gym`` env and checked against the stored states), then loaded with
``minari.load_dataset`` (``MINARI_DATASETS_PATH`` set to that folder): the episode count must be the library's,
and every episode's recorded observations must be its clip's stored states (within ``STATES_ATOL``). The
unit tests round-trip a fixed subset of each library (tests/test_minari_export.py); this runs the whole ones.
Rows of an earlier run in the same setting are kept for the domains this run does not measure. Writes
``benchmarks/results/minari_export.md`` and ``.json``.

    python benchmarks/minari_export.py                          # the four domains' whole serve libraries
    python benchmarks/minari_export.py --domains lane_change    # one row, the others kept
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from rba.core.fileio import report_to_extend, save_report
from rba.data.library import SkillLibrary
from rba.data.minari_export import STATES_ATOL, STATES_RTOL, library_source, write_dataset

RESULTS = Path(__file__).resolve().parent / "results"
OUTPUTS = (  # what this script writes into benchmarks/results/ (tests/test_results_files.py)
    "minari_export.json", "minari_export.md",
)
DOMAINS = ("walker", "lane_change", "manipulator", "snake")  # the report's row order


def folder_bytes(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())


def load_and_check(datasets: Path, dataset_id: str, library: SkillLibrary) -> float:
    """Seconds to load the dataset and read every episode; ``AssertionError`` if it is not the library."""
    import minari

    os.environ["MINARI_DATASETS_PATH"] = str(datasets)  # load_dataset reads its folder from here only
    start = time.perf_counter()
    ds = minari.load_dataset(dataset_id)
    assert ds.total_episodes == len(library), (ds.total_episodes, len(library))
    for i, episode in enumerate(ds.iterate_episodes()):
        states = episode.observations[episode.infos["recorded"]].astype(np.float32)
        np.testing.assert_allclose(states, library.trajectory(i), rtol=STATES_RTOL, atol=STATES_ATOL)
        assert len(episode.actions) == len(episode.observations) - 1 == len(episode.rewards)
    return time.perf_counter() - start


def measure(domain: str, limit: int | None) -> dict:
    library = SkillLibrary.load(domain, "serve")
    picked = list(range(min(limit, len(library)))) if limit else None
    source = library_source(domain, "serve", indices=picked)
    if picked:
        library = library.subset(np.array(picked))
    root = Path(tempfile.mkdtemp(prefix="rba-minari-bench-"))
    try:
        load = os.getloadavg()[0]
        start = time.perf_counter()
        written = write_dataset(root, source)
        seconds = time.perf_counter() - start
        load_seconds = load_and_check(root, written.dataset_id, library)
        return {"domain": domain, "episodes": written.episodes, "steps": written.steps,
                "export_seconds": round(seconds, 1), "ms_per_episode": round(1000 * seconds / written.episodes, 1),
                "load_seconds": round(load_seconds, 1), "megabytes": round(folder_bytes(written.path) / 2**20, 1),
                "load_average": [round(load, 2), round(os.getloadavg()[0], 2)]}
    finally:
        shutil.rmtree(root, ignore_errors=True)


def markdown(report: dict) -> str:
    rows = sorted(report["rows"], key=lambda r: DOMAINS.index(r["domain"]) if r["domain"] in DOMAINS else 99)
    lines = ["# Minari export of the serve libraries", "",
             "`rba export --format minari --domain D --split serve --out DIR`: every clip re-simulated in its "
             "`rba.gym` env, checked against the stored states, written as a Minari dataset; then "
             "`minari.load_dataset` reads every episode back and its recorded observations are checked against the "
             "library's states. One process, one core.", "",
             f"`{report['command']}` on {report['machine']}.", "",
             "| domain | episodes | env steps | export (s) | ms per episode | load + check (s) | size (MB) | "
             "load average (before, after) |",
             "|---|---:|---:|---:|---:|---:|---:|---|"]
    lines += [f"| {r['domain']} | {r['episodes']} | {r['steps']} | {r['export_seconds']} | {r['ms_per_episode']} | "
              f"{r['load_seconds']} | {r['megabytes']} | {r['load_average'][0]}, {r['load_average'][1]} |"
              for r in rows]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--domains", nargs="+", default=list(DOMAINS))
    p.add_argument("--limit", type=int, default=None, help="the first N clips only (a quick look)")
    p.add_argument("--out", type=Path, default=RESULTS / "minari_export")
    args = p.parse_args(argv)
    command = "python benchmarks/minari_export.py " + " ".join(argv if argv is not None else sys.argv[1:])
    report = report_to_extend(args.out, {"split": "serve", "limit": args.limit}, command.strip())
    for domain in args.domains:
        row = measure(domain, args.limit)
        print(row, flush=True)
        report["rows"] = [r for r in report["rows"] if r["domain"] != domain] + [row]
        save_report(args.out, report, markdown(report))
    return 0


if __name__ == "__main__":
    sys.exit(main())

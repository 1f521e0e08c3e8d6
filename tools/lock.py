"""The lock file: every package a fresh ``pip install -e ".[dev]"`` resolves, pinned to the versions CI tested.

``constraints.txt`` at the repository root is a pip constraints file. The README's install command and
``.ci/run`` pass it with ``-c``, so a fresh machine gets exactly what the test suite last passed with, however
many releases came out since. ``pyproject.toml`` keeps honest ranges; the lock picks one version inside them.

    python tools/lock.py check      # does the installed environment match the lock, and the lock pyproject.toml?
    python tools/lock.py freeze     # rewrite the lock from the installed environment (after a green test run)
    python tools/lock.py upgrade    # fresh venv, newest allowed releases, run the tests; rewrite the lock if green

``upgrade`` is how the project moves forward on purpose: run it when you want newer libraries (a fix, a
security release), commit ``constraints.txt`` with the green run, and narrow a range in ``pyproject.toml`` when a
new release breaks something (then run it again). It never touches the lock when the suite fails.
Exit status: 0 ok, 1 a check or the test suite failed, 2 bad usage.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import tomllib
from importlib import metadata
from pathlib import Path

from packaging.markers import Marker
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from packaging.version import Version

REPO_ROOT = Path(__file__).resolve().parents[1]
LOCK = REPO_ROOT / "constraints.txt"
PYPROJECT = REPO_ROOT / "pyproject.toml"
PROJECT = "rba-studio"
EXTRAS = ("dev",)
# Installed on its own first: the CPU build lies on the machine's disk; through the resolver, pip takes CUDA.
TORCH = "torch==2.13.0"
HEADER = """\
# Every package `pip install -e ".[dev]"` resolves, at the versions the test suite passed with.
# Written by `python tools/lock.py freeze` or `upgrade`; do not edit by hand (see tools/lock.py).
"""


def _applies(marker: Marker | None, extras: set[str]) -> bool:
    """Whether a requirement's environment marker holds here for any of the requested extras."""
    if marker is None:
        return True
    return any(marker.evaluate({"extra": extra}) for extra in (extras or {""}))


def resolved(project: str = PROJECT, extras: tuple[str, ...] = EXTRAS) -> dict[str, str]:
    """Canonical name -> installed version of every distribution ``project[extras]`` needs, transitively.

    Walks the installed metadata, so packages that happen to be on the machine but that nothing asks for
    are left out. A requirement that is not installed is an error: the environment is broken.
    """
    found: dict[str, str] = {}
    stack = [(canonicalize_name(project), set(extras))]
    seen: set[tuple[str, frozenset[str]]] = set()
    while stack:
        name, wanted = stack.pop()
        if (name, frozenset(wanted)) in seen:
            continue
        seen.add((name, frozenset(wanted)))
        dist = metadata.distribution(name)
        if name != canonicalize_name(project):
            found[name] = dist.version
        for text in dist.requires or []:
            req = Requirement(text)
            if _applies(req.marker, wanted):
                stack.append((canonicalize_name(req.name), set(req.extras)))
    return found


def read_lock(path: Path = LOCK) -> dict[str, str]:
    """Canonical name -> pinned version; every non-comment line must be ``name==version``."""
    pins = {}
    for number, line in enumerate(path.read_text().splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        match = re.fullmatch(r"([A-Za-z0-9][A-Za-z0-9._-]*)==(\S+)", line)
        if not match:
            raise ValueError(f"{path.name}:{number}: {line!r} is not 'name==version'")
        pins[canonicalize_name(match[1])] = match[2]
    return pins


def write_lock(pins: dict[str, str], path: Path = LOCK) -> None:
    """Atomically replace the lock (temp file + rename): a crash leaves the old lock or the new one."""
    text = HEADER + "".join(f"{name}=={pins[name]}\n" for name in sorted(pins))
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def declared(pyproject: Path = PYPROJECT, extras: tuple[str, ...] = EXTRAS) -> list[Requirement]:
    """The direct requirements ``pyproject.toml`` declares, with the requested extras."""
    project = tomllib.loads(pyproject.read_text())["project"]
    texts = list(project["dependencies"])
    for extra in extras:
        texts += project["optional-dependencies"][extra]
    return [Requirement(text) for text in texts]


def problems(pins: dict[str, str], installed: dict[str, str], requirements: list[Requirement]) -> list[str]:
    """Why the lock, the installed environment and pyproject.toml disagree (empty when they agree)."""
    found = [f"{name} {version} is installed but not pinned" for name, version in sorted(installed.items())
             if name not in pins]
    found += [f"{name}=={pins[name]} is pinned but {version} is installed"
              for name, version in sorted(installed.items())
              if name in pins and Version(pins[name]) != Version(version)]
    found += [f"{name}=={pins[name]} is pinned but nothing needs it" for name in sorted(pins) if name not in installed]
    return found + outside_ranges(pins, requirements)


def outside_ranges(pins: dict[str, str], requirements: list[Requirement]) -> list[str]:
    """The pyproject.toml requirements the pins miss or fall outside of."""
    found = []
    for req in requirements:
        name = canonicalize_name(req.name)
        if name not in pins:
            found.append(f"pyproject.toml asks for {req} but the lock has no {name}")
        elif not req.specifier.contains(pins[name], prereleases=True):
            found.append(f"pyproject.toml asks for {req} but the lock pins {name}=={pins[name]}")
    return found


def check() -> int:
    issues = problems(read_lock(), resolved(), declared())
    for line in issues:
        print(line)
    print(f"{LOCK.name}: {'out of date' if issues else 'matches the environment and pyproject.toml'}")
    return 1 if issues else 0


def freeze() -> int:
    pins = resolved()
    issues = outside_ranges(pins, declared())
    if issues:
        print("\n".join(issues))
        return 1
    write_lock(pins)
    print(f"wrote {LOCK.name}: {len(pins)} packages")
    return 0


def upgrade(keep: bool) -> int:
    """Newest releases pyproject.toml allows, in a fresh venv; the suite must pass before the lock changes."""
    venv = Path(tempfile.mkdtemp(prefix="rba-relock-"))
    python = venv / "bin" / "python"
    steps = [[sys.executable, "-m", "venv", str(venv)],
             [str(python), "-m", "pip", "install", "-q", TORCH],
             [str(python), "-m", "pip", "install", "-q", "-e", f".[{','.join(EXTRAS)}]"],
             [str(python), "-m", "pytest", "-q"]]
    env = {**os.environ, "PIP_DISABLE_PIP_VERSION_CHECK": "1"}
    for step in steps:
        print("+", " ".join(step), flush=True)
        if subprocess.run(step, cwd=REPO_ROOT, env=env).returncode != 0:
            print(f"failed: {' '.join(step)}; {LOCK.name} is unchanged (the venv is kept at {venv})")
            return 1
    status = subprocess.run([str(python), __file__, "freeze"], cwd=REPO_ROOT).returncode
    if status == 0 and not keep:
        shutil.rmtree(venv)
    return status


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("check", help="the installed environment matches the lock, and the lock pyproject.toml")
    sub.add_parser("freeze", help="rewrite the lock from the installed environment")
    up = sub.add_parser("upgrade", help="re-resolve to the newest allowed releases, test, rewrite the lock if green")
    up.add_argument("--keep-venv", action="store_true", help="keep the fresh venv after a green run")
    args = parser.parse_args(argv)
    if args.command == "upgrade":
        return upgrade(args.keep_venv)
    return {"check": check, "freeze": freeze}[args.command]()


if __name__ == "__main__":
    sys.exit(main())

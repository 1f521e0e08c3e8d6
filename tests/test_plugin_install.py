"""Installing the example plugin domain (``examples/halfcheetah``) adds it to rba without touching rba's own files,
and uninstalling it takes it away cleanly: in a venv on top of this environment, offline."""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
from pathlib import Path

import pytest

from rba.core.settings import REPO_ROOT
from rba.domains import plugin_package
from tests.example_domain import EXAMPLE_DIR, NAME

SHIPPED = ("walker", "manipulator", "snake", "lane_change")
# in the venv: the example's package and whether it has an rba.gym env, then the domains the rba CLI lists (the
# error of an unknown domain names every valid one, exit 2)
CHECK = ("import gymnasium, rba.gym; from rba.domains import plugin_package; from rba.cli import main; "
         f"print(plugin_package({NAME!r}), rba.gym.env_id({NAME!r}) in gymnasium.registry, flush=True); "
         "main(['build', 'no_such_domain'])")


def tree_hashes(*folders: str) -> dict[str, str]:
    """sha256 of every file under the repository's ``folders`` (byte-code caches left out)."""
    return {str(p.relative_to(REPO_ROOT)): hashlib.sha256(p.read_bytes()).hexdigest()
            for folder in folders for p in sorted((REPO_ROOT / folder).rglob("*"))
            if p.is_file() and "__pycache__" not in p.parts}


def run(python: Path, *args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "MUJOCO_GL": "egl", "PIP_NO_INPUT": "1"}
    return subprocess.run([str(python), *args], capture_output=True, text=True, timeout=180, cwd=cwd, env=env)


@pytest.mark.slow
def test_installing_the_example_adds_its_domain_and_uninstalling_removes_it(tmp_path):
    if plugin_package(NAME) is not None:
        pytest.skip(f"the example is installed here ({plugin_package(NAME)}): a venv on top would see it anyway")
    before = tree_hashes("rba", "server")
    subprocess.run([sys.executable, "-m", "venv", "--system-site-packages", "--without-pip", str(tmp_path / "venv")],
                   check=True, timeout=60)
    python = tmp_path / "venv" / "bin" / "python"  # its pip is this environment's, installing into the venv

    install = run(python, "-m", "pip", "install", "--no-index", "--no-build-isolation", "--no-deps", "-e",
                  str(EXAMPLE_DIR), cwd=tmp_path)
    assert install.returncode == 0, install.stderr
    checked = run(python, "-c", CHECK, cwd=tmp_path)
    assert checked.stdout.split() == ["rba-halfcheetah", "True"], checked.stderr
    assert checked.returncode == 2 and f", {NAME}" in checked.stderr and "PluginWarning" not in checked.stderr
    assert tree_hashes("rba", "server") == before

    uninstall = run(python, "-m", "pip", "uninstall", "-y", "rba-halfcheetah", cwd=tmp_path)
    assert uninstall.returncode == 0, uninstall.stderr
    checked = run(python, "-c", CHECK, cwd=tmp_path)
    assert checked.stdout.split() == ["None", "False"], checked.stderr
    assert checked.returncode == 2 and NAME not in checked.stderr and all(s in checked.stderr for s in SHIPPED)
    assert tree_hashes("rba", "server") == before
    assert not list(EXAMPLE_DIR.glob("*.egg-info")) and not (EXAMPLE_DIR / "build").exists()

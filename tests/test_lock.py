"""The lock file: a fresh install gets exactly what CI tested, and nothing it resolves floats."""

import importlib.util
import re
import sys

import pytest
from packaging.requirements import Requirement

from rba.core.settings import REPO_ROOT


def _load_lock_tool():
    spec = importlib.util.spec_from_file_location("lock_tool", REPO_ROOT / "tools" / "lock.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["lock_tool"] = module
    spec.loader.exec_module(module)
    return module


lock = _load_lock_tool()


def test_the_lock_pins_every_installed_package_and_agrees_with_pyproject():
    pins, installed = lock.read_lock(), lock.resolved()
    assert len(installed) > 50, "the walk from rba-studio[dev] found too few packages to be the real install"
    assert lock.problems(pins, installed, lock.declared()) == []


def test_the_walk_follows_extras_and_markers():
    installed = lock.resolved()
    assert {"pytest", "schemathesis", "torch", "uvicorn"} <= set(installed)  # [dev] and direct dependencies
    assert "uvloop" in installed and "psycopg-binary" in installed  # uvicorn[standard], psycopg[binary]
    assert "rba-studio" not in installed


def test_problems_names_every_kind_of_disagreement():
    pins = {"numpy": "2.0.0", "stale": "1.0"}
    installed = {"numpy": "2.1.0", "scipy": "1.14.0"}
    found = lock.problems(pins, installed, [Requirement("numpy<2"), Requirement("fastapi>=0.1")])
    assert found == [
        "scipy 1.14.0 is installed but not pinned",
        "numpy==2.0.0 is pinned but 2.1.0 is installed",
        "stale==1.0 is pinned but nothing needs it",
        "pyproject.toml asks for numpy<2 but the lock pins numpy==2.0.0",
        "pyproject.toml asks for fastapi>=0.1 but the lock has no fastapi",
    ]


def test_a_lock_line_that_is_not_an_exact_pin_is_refused(tmp_path):
    path = tmp_path / "constraints.txt"
    path.write_text("# comment\nnumpy==2.0.0\nscipy>=1.11\n")
    with pytest.raises(ValueError, match=r"constraints.txt:3: 'scipy>=1.11' is not 'name==version'"):
        lock.read_lock(path)


def test_write_lock_round_trips_sorted_and_leaves_no_temp_file(tmp_path):
    path = tmp_path / "constraints.txt"
    lock.write_lock({"b-pkg": "1.0", "a-pkg": "2.0+cpu"}, path)
    assert lock.read_lock(path) == {"a-pkg": "2.0+cpu", "b-pkg": "1.0"}
    assert path.read_text().splitlines()[-2:] == ["a-pkg==2.0+cpu", "b-pkg==1.0"]
    assert [p.name for p in tmp_path.iterdir()] == ["constraints.txt"]


def test_the_readme_install_and_ci_use_the_lock():
    readme = (REPO_ROOT / "README.md").read_text()
    first_block = re.search(r"```bash\n(.*?)```", readme, re.S)[1]
    assert "-c constraints.txt" in first_block and "rba serve" in first_block
    assert "-c constraints.txt" in (REPO_ROOT / ".ci" / "run").read_text()

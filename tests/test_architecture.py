"""The shape rules of docs/ARCHITECTURE.md, checked on the source: imports run one way, no cycles, short functions."""

from pathlib import Path

import pytest

from tests.benchmark_scripts import load_benchmark

REPO_ROOT = Path(__file__).resolve().parents[1]

code_shape = load_benchmark("code_shape")

MAX_FUNCTION_LINES = 60


def _tree(root, files: dict[str, str]):
    for name, text in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return root


def test_the_checker_sees_back_edges_and_cycles_even_inside_functions(tmp_path):
    root = _tree(tmp_path, {
        "rba/__init__.py": "", "rba/cli.py": "def serve():\n    from server.main import run\n",
        "server/__init__.py": "", "server/main.py": "from server import jobs\n",
        "server/jobs.py": "def run():\n    from . import main\n",
        "server/typed.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from server import main\n",
    })
    graph = code_shape.import_graph(root)
    assert code_shape.back_edges(graph) == [("rba.cli", "server.main")]
    assert code_shape.cycles(graph) == [["server.jobs", "server.main"]]
    assert "server.main" not in graph["server.typed"]


def test_the_library_never_imports_the_server():
    assert code_shape.back_edges(code_shape.import_graph()) == []


def test_no_import_cycles():
    assert code_shape.cycles(code_shape.import_graph()) == []


@pytest.mark.parametrize("package", code_shape.PACKAGES)
def test_functions_are_short_enough_to_read_at_once(package):
    long = [f for f in code_shape.functions(package=package) if f.lines > MAX_FUNCTION_LINES]
    assert not long, "\n".join(f"{f.file}:{f.line} {f.name}: {f.lines} lines" for f in long)


# server/services.py's docstring: the modules below ``services`` (tables, rules and tools) import nothing above them.
SERVER_LOW = ("settings", "errors", "feedback", "models", "admin_models", "db", "migrations", "migrations.env",
              "uploads", "transitions", "background", "catalog", "labeldata", "processes", "jobs")


def test_low_server_modules_never_import_the_services_or_anything_above_them():
    graph = code_shape.import_graph()
    low = {f"server.{name}" for name in SERVER_LOW}
    assert low <= set(graph), low - set(graph)
    above = {name: sorted(m for m in graph[name] if m.startswith("server.") and m not in low) for name in sorted(low)}
    assert not any(above.values()), above

"""The shape rules of docs/architecture.md, checked on the source: imports run one way, no cycles, short functions."""

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


def test_no_module_name_is_used_in_both_the_library_and_the_server():
    assert code_shape.shared_names() == []


@pytest.mark.parametrize("package", code_shape.PACKAGES)
def test_functions_are_short_enough_to_read_at_once(package):
    long = [f for f in code_shape.functions(package=package) if f.lines > MAX_FUNCTION_LINES]
    assert not long, "\n".join(f"{f.file}:{f.line} {f.name}: {f.lines} lines" for f in long)


# The server's layers are its folders, lowest first (server/runtime/services.py's docstring): a module imports only
# from its own layer and those below it; ``server.main``, which builds the app, sits above them all.
SERVER_LAYERS = ("server.common", "server.db", "server.runtime", "server.ops", "server.api")
SERVER_TOP = ("server", "server.main")


def _layer(module: str) -> int:
    """Where ``module`` sits: the index of its folder in ``SERVER_LAYERS``; ``server.main`` above them all."""
    if module == "server.main":
        return len(SERVER_LAYERS)
    return next(i for i, layer in enumerate(SERVER_LAYERS) if module == layer or module.startswith(f"{layer}."))


def test_every_server_module_sits_in_a_layer_folder():
    graph = code_shape.import_graph()
    loose = sorted(m for m in graph if m.split(".")[0] == "server" and m not in SERVER_TOP
                   and not any(m == layer or m.startswith(f"{layer}.") for layer in SERVER_LAYERS))
    assert not loose, loose


def test_server_layers_never_import_a_layer_above_them():
    graph = code_shape.import_graph()
    server = [m for m in graph if m.split(".")[0] == "server" and m != "server"]
    up = {m: sorted(t for t in graph[m] if t.split(".")[0] == "server" and t != "server" and _layer(t) > _layer(m))
          for m in sorted(server)}
    assert not any(up.values()), {m: t for m, t in up.items() if t}


def test_the_runtime_parts_never_import_the_services_that_hold_them():
    graph = code_shape.import_graph()
    runtime = [m for m in graph if m.startswith("server.runtime.") and m != "server.runtime.services"]
    assert runtime
    assert not [m for m in runtime if "server.runtime.services" in graph[m]]


def test_the_layer_check_sees_an_import_from_above(tmp_path):
    root = _tree(tmp_path, {
        "rba/__init__.py": "", "server/__init__.py": "", "server/main.py": "from server.api import deps\n",
        "server/api/__init__.py": "", "server/api/deps.py": "from server.db import engine\n",
        "server/db/__init__.py": "", "server/db/engine.py": "def f():\n    from server.ops import views\n",
        "server/ops/__init__.py": "", "server/ops/views.py": "",
    })
    graph = code_shape.import_graph(root)
    up = [(m, t) for m in graph for t in graph[m] if t.startswith("server.") and _layer(t) > _layer(m)]
    assert up == [("server.db.engine", "server.ops.views")]


def test_only_the_resolver_asks_where_a_rollout_came_from():
    assert code_shape.kind_checks() == []


def test_the_kind_check_sees_a_caller_bypassing_the_resolver(tmp_path):
    root = _tree(tmp_path, {
        "rba/__init__.py": "", "server/__init__.py": "",
        "server/runtime/clip_sources.py": "from rba.generate.cma import is_generated\nis_generated('gen-1')\n",
        "server/ops/views.py": "from rba.generate.cma import is_generated\n\ndef f(r):\n    return is_generated(r)\n",
        "server/ops/steps.py": "def g(c):\n    return isinstance(c, GenerationContext)\n",
        "server/ops/key.py": "from server.runtime.clip_sources import MADE\n",
    })
    assert code_shape.kind_checks(root) == [("server/ops/key.py", 1, "MADE"),
                                 ("server/ops/steps.py", 2, "isinstance GenerationContext"),
                                 ("server/ops/views.py", 4, "is_generated")]

"""The server's modules import one way (services' docstring): no cycles, function-level imports counted."""

from __future__ import annotations

import ast
import graphlib
from pathlib import Path

SERVER = Path(__file__).resolve().parents[2] / "server"
LOW = {"settings", "errors", "feedback", "models", "admin_models", "db", "uploads", "transitions", "background",
       "locks", "clips", "catalog", "labeldata", "jobs"}


def imports() -> dict[str, set[str]]:
    """Module (dotted, under server) -> the server modules it imports anywhere in its body."""
    modules = {".".join(p.relative_to(SERVER).with_suffix("").parts).removesuffix("__init__").rstrip(".") or "server": p
               for p in SERVER.rglob("*.py")}
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        found: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("server"):
                base = node.module.removeprefix("server").lstrip(".")
                found |= {f"{base}.{a.name}".lstrip(".") for a in node.names} | {base}
            elif isinstance(node, ast.Import):
                found |= {a.name.removeprefix("server.") for a in node.names if a.name.startswith("server.")}
        graph[name] = {m for m in found if m in modules and m != name}
    return graph


def test_the_import_graph_has_no_cycles():
    graph = imports()
    assert {"sessions", "views", "prerender", "labelling", "jobs"} <= set(graph)
    graphlib.TopologicalSorter(graph).prepare()  # raises CycleError naming the cycle


def test_low_modules_never_import_the_services_or_anything_above_them():
    graph = imports()
    for name in LOW:
        assert graph[name] <= LOW, (name, graph[name] - LOW)

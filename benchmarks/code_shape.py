"""The shape of the code: the import graph of ``rba/`` and ``server/``, the longest functions, what a newcomer meets.

``tests/test_architecture.py`` holds the rules (``rba`` never imports ``server``; no import cycles; short functions);
this script prints the numbers and writes ``benchmarks/results/code_shape.md``:

    python benchmarks/code_shape.py
    python benchmarks/code_shape.py --root ../other-checkout --no-write    # the same numbers for another checkout

Every ``import`` statement counts, inside functions too (a lazy import is still a dependency), except those under
``if TYPE_CHECKING:``. An import names the deepest module it reaches: ``from rba.domains import get_domain`` is an
edge to ``rba.domains``; ``from rba.learn import ranker`` to ``rba.learn.ranker``.
"""

from __future__ import annotations

import argparse
import ast
import os
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("rba", "server")
RESULTS = REPO_ROOT / "benchmarks" / "results" / "code_shape.md"
OUTPUTS = ("code_shape.md",)  # what this script writes into benchmarks/results/ (tests/test_results_files.py)


def module_files(root: Path = REPO_ROOT) -> dict[str, Path]:
    """Dotted module name -> file, for every module of ``PACKAGES``."""
    found = {}
    for package in PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            parts = path.relative_to(root).with_suffix("").parts
            found[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return found


def _is_type_checking(node: ast.If) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _imports(tree: ast.AST) -> list[ast.Import | ast.ImportFrom]:
    """Every import statement of ``tree`` except those guarded by ``if TYPE_CHECKING:``."""
    found, stack = [], [tree]
    while stack:
        node = stack.pop()
        if isinstance(node, ast.If) and _is_type_checking(node):
            stack.extend(node.orelse)
            continue
        if isinstance(node, ast.Import | ast.ImportFrom):
            found.append(node)
        stack.extend(ast.iter_child_nodes(node))
    return found


def _resolve(name: str, modules: dict[str, Path]) -> str | None:
    """The deepest known module that ``name`` (a dotted path) lies in, or None if it is outside the project."""
    parts = name.split(".")
    for end in range(len(parts), 0, -1):
        candidate = ".".join(parts[:end])
        if candidate in modules:
            return candidate
    return None


def _targets(node: ast.Import | ast.ImportFrom, module: str, is_package: bool) -> list[str]:
    if isinstance(node, ast.Import):
        return [alias.name for alias in node.names]
    base = node.module or ""
    if node.level:  # relative: from .x import y
        anchor = module.split(".") if is_package else module.split(".")[:-1]
        anchor = anchor[: len(anchor) - (node.level - 1)]
        base = ".".join([*anchor, base] if base else anchor)
    return [f"{base}.{alias.name}" for alias in node.names]


def import_graph(root: Path = REPO_ROOT) -> dict[str, set[str]]:
    """Module -> the project modules it imports (self-edges dropped)."""
    modules = module_files(root)
    graph: dict[str, set[str]] = {}
    for module, path in modules.items():
        edges = set()
        for node in _imports(ast.parse(path.read_text(), str(path))):
            for target in _targets(node, module, path.name == "__init__.py"):
                resolved = _resolve(target, modules)
                if resolved is not None and resolved != module:
                    edges.add(resolved)
        graph[module] = edges
    return graph


def back_edges(graph: dict[str, set[str]]) -> list[tuple[str, str]]:
    """Imports of ``server`` from ``rba`` (the library must not know the web app)."""
    return sorted((a, b) for a, edges in graph.items() for b in edges
                  if a.split(".")[0] == "rba" and b.split(".")[0] == "server")


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(found)


def folders(root: Path = REPO_ROOT, package: str = "rba") -> dict[str, list[str]]:
    """``package``'s modules by folder: ``""`` -> the modules at its top, ``"core"`` -> those in ``core/`` (any depth),
    each by its own name (packages' ``__init__`` and ``__main__`` left out)."""
    found: dict[str, list[str]] = {}
    for module, path in module_files(root).items():
        parts = module.split(".")
        if parts[0] != package or path.name in ("__init__.py", "__main__.py"):
            continue
        found.setdefault(parts[1] if len(parts) > 2 else "", []).append(parts[-1])
    return {folder: sorted(names) for folder, names in sorted(found.items())}


def shared_names(root: Path = REPO_ROOT) -> list[str]:
    """Module names used in more than one of ``PACKAGES`` (one name should say one thing across the repository)."""
    names = [{name for found in folders(root, package).values() for name in found} for package in PACKAGES]
    return sorted(set.intersection(*names))


@dataclass(frozen=True)
class Function:
    file: str
    name: str
    line: int
    lines: int


def functions(root: Path = REPO_ROOT, package: str | None = None) -> list[Function]:
    """Every function and method of ``PACKAGES`` (or of one ``package``), longest first."""
    found = []
    for module, path in module_files(root).items():
        if package and module.split(".")[0] != package:
            continue
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                found.append(Function(str(path.relative_to(root)), node.name, node.lineno,
                                      node.end_lineno - node.lineno + 1))
    return sorted(found, key=lambda f: (-f.lines, f.file, f.line))


# Where a rollout came from (a serve library or a search) is told in one module, the resolver every caller asks
# (docs/architecture.md §5): an id's kind (``is_generated``), the made clips' key version (``MADE``, once
# ``GENERATED``) or a generating context's type checked anywhere else is a caller bypassing it. The generating step
# alone asks its agent's state what it made (``made_clip``): to store that clip's row and render it at once.
RESOLVER = "server/runtime/clip_sources.py"
ALLOWED_KIND_CHECKS = {("server/ops/session_searches.py", "made_clip")}


def _kind_check(node: ast.AST) -> str | None:
    """What ``node`` asks if it tells a made rollout from a serve one, else None."""
    if isinstance(node, ast.Call):
        name = getattr(node.func, "id", getattr(node.func, "attr", None))
        if name in ("is_generated", "made_clip"):
            return name
        if name == "isinstance" and len(node.args) == 2 and "GenerationContext" in ast.unparse(node.args[1]):
            return "isinstance GenerationContext"
    name = node.id if isinstance(node, ast.Name) else node.name if isinstance(node, ast.alias) else None
    return name if name in ("GENERATED", "MADE") else None


def kind_checks(root: Path = REPO_ROOT) -> list[tuple[str, int, str]]:
    """(file, line, what) of every place outside the resolver that tells a made rollout from a serve one."""
    found = []
    for path in sorted(p for package in PACKAGES for p in (root / package).rglob("*.py")):
        rel = path.relative_to(root).as_posix()
        if rel == RESOLVER:
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            what = _kind_check(node)
            if what is not None and (rel, what) not in ALLOWED_KIND_CHECKS:
                found.append((rel, getattr(node, "lineno", 0), what))
    return found


def _lines(path: Path) -> int:
    return len(path.read_text().splitlines()) if path.exists() else 0


def house(root: Path = REPO_ROOT) -> dict[str, int]:
    """What a newcomer meets before the code: the documents' lengths, the reports, the CLI's help."""
    docs = root / "docs"
    architecture = docs / "architecture.md" if (docs / "architecture.md").exists() else docs / "ARCHITECTURE.md"
    command = "import sys; from rba.cli import main; sys.argv = ['rba', 'eval', '--help']; main()"
    env = {**os.environ, "PYTHONPATH": str(root)}
    helped = subprocess.run([sys.executable, "-c", command], cwd=root, env=env, capture_output=True, text=True)
    return {"README.md lines": _lines(root / "README.md"),
            "architecture document lines": _lines(architecture),
            "files in benchmarks/results/": sum(1 for p in (root / "benchmarks" / "results").rglob("*") if p.is_file()),
            "generated-clip checks outside the resolver": len(kind_checks(root)),
            "`rba eval --help` lines": len(helped.stdout.splitlines())}


def report(root: Path = REPO_ROOT, top: int = 8) -> str:
    graph = import_graph(root)
    lines = ["# The shape of the code", "",
             f"{len(graph)} modules in {', '.join(PACKAGES)}; "
             f"{sum(len(e) for e in graph.values())} import edges (function-level imports included).", "",
             f"- rba → server imports (back-edges): {len(back_edges(graph))}"]
    lines += [f"  - {a} → {b}" for a, b in back_edges(graph)]
    lines.append(f"- import cycles: {len(cycles(graph))}")
    lines += [f"  - {' ↔ '.join(c)}" for c in cycles(graph)]
    for package in PACKAGES:
        found = folders(root, package)
        loose = found.pop("", [])
        lines.append(f"- modules at the top of `{package}/`: {len(loose)} ({', '.join(loose)}); folders: "
                     + ", ".join(f"{folder}/ ({len(names)})" for folder, names in found.items()))
    shared = shared_names(root)
    lines.append(f"- module names used in both {' and '.join(PACKAGES)}: {len(shared)}"
                 + (f" ({', '.join(shared)})" if shared else ""))
    lines += [f"- {what}: {count}" for what, count in house(root).items()]
    for package in PACKAGES:
        lines += ["", f"Longest functions in `{package}/`:", "", "| lines | function |", "|---|---|"]
        lines += [f"| {f.lines} | `{f.file}:{f.line}` {f.name} |" for f in functions(root, package)[:top]]
    lines += ["", "Command: `python benchmarks/code_shape.py`."]
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, default=REPO_ROOT, help="a checkout to measure (default: this one)")
    parser.add_argument("--no-write", action="store_true", help="print only; leave the results file alone")
    args = parser.parse_args()
    text = report(args.root.resolve())
    print(text, end="")
    if not args.no_write:
        tmp = RESULTS.with_name(RESULTS.name + ".tmp")  # temp file + rename: never a half-written report
        tmp.write_text(text)
        os.replace(tmp, RESULTS)


if __name__ == "__main__":
    main()

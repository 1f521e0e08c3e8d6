"""Load a script of ``benchmarks/`` as a module, for the tests that check a benchmark on a tiny run."""

import importlib.util
import sys
from types import ModuleType

from rba.core.settings import REPO_ROOT


def load_benchmark(name: str) -> ModuleType:
    """``benchmarks/<name>.py`` executed afresh (the scripts are not a package); registered under ``name`` in
    ``sys.modules`` because dataclasses look their module up there."""
    spec = importlib.util.spec_from_file_location(name, REPO_ROOT / "benchmarks" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module

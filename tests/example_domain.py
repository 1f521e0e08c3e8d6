"""The example plugin domain (``examples/halfcheetah``) for tests, whether or not its package is installed."""

from __future__ import annotations

import sys

from rba.core.settings import REPO_ROOT

EXAMPLE_DIR = REPO_ROOT / "examples" / "halfcheetah"
NAME, TARGET = "halfcheetah", "rba_halfcheetah.domain:HalfCheetah"  # its pyproject's entry point


def example_target() -> str:
    """The example domain's import path, importable from here on (the package's folder on ``sys.path`` if it is
    not installed)."""
    if str(EXAMPLE_DIR) not in sys.path:
        sys.path.append(str(EXAMPLE_DIR))
    return TARGET

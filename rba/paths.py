"""Where data and models live: the repository's ``data/`` and ``models/`` unless overridden.

Never relative to the working directory: ``RBA_DATA_DIR`` / ``RBA_MODELS_DIR`` override.
"""

from __future__ import annotations

import os
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]


def data_dir() -> Path:
    return Path(os.environ.get("RBA_DATA_DIR", REPO_ROOT / "data"))


def models_dir() -> Path:
    return Path(os.environ.get("RBA_MODELS_DIR", REPO_ROOT / "models"))

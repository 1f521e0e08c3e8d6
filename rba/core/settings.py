"""Where the library's files live and how big clips are: one settings source, ``RBA_``-prefixed env vars.

The server's settings extend this class with its own fields (host, port, database, ...), so the
library and the app always agree on the folders. Defaults are the repository's ``data/`` and
``models/``, never the working directory.
"""

from __future__ import annotations

from pathlib import Path

from pydantic import Field, field_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

REPO_ROOT = Path(__file__).resolve().parents[2]


class LibrarySettings(BaseSettings):
    """What ``rba`` commands and the app share: data, models, clip cache and clip size."""

    # a refused value is not echoed: RBA_ADMIN_TOKEN and database passwords stay out of logs
    model_config = SettingsConfigDict(env_prefix="RBA_", extra="ignore", hide_input_in_errors=True)

    data_dir: Path = Field(default=REPO_ROOT / "data", description="skill libraries <domain>/<split>.npz")
    models_dir: Path = Field(default=REPO_ROOT / "models", description="trained models <domain>/<kind>-<rep>.pt")
    cache_dir: Path | None = Field(default=None, description="rendered clips; default <data_dir>/cache/clips")
    clip_width: int = Field(default=320, ge=16, le=1920)
    clip_height: int = Field(default=240, ge=16, le=1080)
    ray_address: str | None = Field(default=None, description="run simulation and rendering on Ray: 'auto' (the "
                                    "cluster on this machine), 'local' (start one), host:port or ray://host:port; "
                                    "unset: local worker processes")
    compute_workers: int = Field(default=2, ge=1, le=64, description="local worker processes per pool (urgent "
                                 "renders and simulations; guesses have a pool of the same size)")
    compute_nice: int = Field(default=5, ge=0, le=19, description="CPU niceness of the urgent pool: below the API")
    background_nice: int = Field(default=15, ge=0, le=19, description="CPU niceness of the guess pool (prerender, "
                                 "rba cache): below the urgent pool")

    train_threads: int = Field(default=2, ge=1, le=64, description="torch threads while training ζσ, rθ and the "
                               "VAE; 1 lets two trainings share 2 cores side by side")
    wandb_project: str | None = Field(default=None, description="also log training curves to this Weights & Biases "
                                      "project (needs the wandb extra; WANDB_MODE, WANDB_API_KEY and WANDB_DIR "
                                      "apply); unset: TensorBoard event files only")

    @field_validator("data_dir", "models_dir", "cache_dir")
    @classmethod
    def _absolute(cls, value: Path | None) -> Path | None:
        return None if value is None else value.expanduser().resolve()

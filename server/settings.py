"""One settings class for the web app; every field comes from an ``RBA_``-prefixed env var."""

from __future__ import annotations

from pathlib import Path

from pydantic import Field, field_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

from rba.paths import data_dir, models_dir


class Settings(BaseSettings):
    """What ``rba serve`` and the tests configure; defaults run the app from the repository."""

    model_config = SettingsConfigDict(env_prefix="RBA_", extra="ignore")

    data_dir: Path = Field(default_factory=data_dir, description="skill libraries <domain>/<split>.npz")
    models_dir: Path = Field(default_factory=models_dir, description="trained models <domain>/<kind>-<rep>.pt")
    database_url: str | None = Field(
        default=None, description="SQLAlchemy URL; default: an SQLite file <data_dir>/rba.db. "
        "Postgres: postgresql+psycopg://user:password@host/db")
    cache_dir: Path | None = Field(default=None, description="rendered clips; default <data_dir>/cache/clips")
    host: str = "127.0.0.1"
    port: int = Field(default=8000, ge=1, le=65535)
    admin_token: str | None = Field(default=None, description="bearer token of the admin routes; unset = no admin")
    clip_width: int = Field(default=320, ge=16, le=1920)
    clip_height: int = Field(default=240, ge=16, le=1080)
    prerender: bool = Field(default=True, description="render the clips each possible next feedback would show")
    prerender_workers: int = Field(default=2, ge=1, le=8, description="background render threads (a session's "
                                   "next clips render in parallel)")
    background_nice: int = Field(default=10, ge=0, le=19, description="CPU niceness of the background render threads")
    render_concurrency: int = Field(default=2, ge=1, le=16, description="clips rendered at once on request")
    torch_threads: int = Field(default=1, ge=1, le=64, description="intra-op threads per request (requests run "
                               "in parallel threads; more oversubscribes the cores)")
    upload_max_bytes: int = Field(default=50 * 2**20, ge=1024, description="largest dataset upload (bytes), "
                                  "enforced while the body streams in")
    upload_max_uncompressed: int = Field(default=200 * 2**20, ge=1024, description="what an uploaded .npz may "
                                         "expand to (bytes): refuses zip bombs")
    prerender_library: bool = Field(default=True, description="after the warm-up, render every serve clip not "
                                    "cached yet (background, niced; once: the cache is on disk): then no one waits "
                                    "for a render")
    warm_start: bool = Field(default=True, description="load models and render first clips after start-up")
    log_level: str = "info"

    @field_validator("data_dir", "models_dir", "cache_dir")
    @classmethod
    def _absolute(cls, value: Path | None) -> Path | None:
        return None if value is None else value.expanduser().resolve()

    @property
    def db_url(self) -> str:
        return self.database_url or f"sqlite:///{self.data_dir / 'rba.db'}"

    @property
    def clip_dir(self) -> Path:
        return self.cache_dir or self.data_dir / "cache" / "clips"

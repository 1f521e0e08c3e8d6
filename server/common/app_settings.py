"""The web app's settings: the library's (folders, clip size) plus the server's own, all ``RBA_`` env vars."""

from __future__ import annotations

import os
import socket

from pydantic import Field, field_validator, model_validator

from rba.core.settings import LibrarySettings
from rba.core.store import Store
from rba.domains import get_domain

ADMIN_TOKEN_MIN = 16  # characters of RBA_ADMIN_TOKEN (see Settings.admin_token)


def cores() -> int:
    """The cores this process may run on (its CPU affinity where the system tells it)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


class Settings(LibrarySettings):
    """What ``rba serve`` and the tests configure; defaults run the app from the repository."""

    database_url: str | None = Field(
        default=None, description="SQLAlchemy URL; default: an SQLite file <data_dir>/rba.db. "
        "Postgres: postgresql+psycopg://user:password@host/db")
    host: str = "127.0.0.1"
    port: int = Field(default=8000, ge=1, le=65535)
    admin_token: str | None = Field(
        default=None, description="bearer token of the admin routes; unset = no admin. "
        f"At least {ADMIN_TOKEN_MIN} characters: the right token gets in even while its address waits for its wrong "
        "ones, so its length, not the wait, is what stops guessing. Make one with "
        "python -c 'import secrets; print(secrets.token_urlsafe(24))'")
    prerender: bool = Field(default=True, description="render the clips each possible next feedback would show")
    prerender_window: int | None = Field(default=None, ge=1, le=1024, description="guessed renders in flight at "
                                         "once; default: the compute layer's capacity (more only queues them)")
    prerender_tree_min_share: float = Field(default=1e-3, gt=0, le=1, description="walk the shared answer trees "
                                            "down to nodes this share of sessions is expected to reach")
    default_domain: str = Field(default="walker", max_length=64, description="the domain warmed up first")
    torch_threads: int = Field(default=1, ge=1, le=64, description="intra-op threads per request (requests run "
                               "in parallel threads; more oversubscribes the cores)")
    upload_max_bytes: int = Field(default=50 * 2**20, ge=1024, description="largest dataset upload (bytes), "
                                  "enforced while the body streams in")
    upload_max_uncompressed: int = Field(default=200 * 2**20, ge=1024, description="what an uploaded .npz may "
                                         "expand to (bytes): refuses zip bombs")
    json_max_bytes: int = Field(default=2**20, ge=1024, description="largest request body of every route but the "
                                "dataset upload (bytes), counted while it streams in")
    admin_failures_per_minute: int = Field(default=10, ge=1, le=10_000, description="wrong admin tokens one client "
                                           "may send in a minute; then it waits (429 with Retry-After)")
    prerender_library: bool = Field(default=True, description="after the warm-up, render every serve clip not "
                                    "cached yet (background, niced; once: the cache is on disk): then no one waits "
                                    "for a render")
    generate: bool = Field(default=False, description="RBA-Global sessions make a new behaviour (a CMA-ES "
                           "search on the compute layer) when no serve clip is near the agent's target; a session "
                           "may ask otherwise at creation (`generate`). Off by default: a search makes the person wait "
                           "(docs/results.md, Latency: made clips)")
    generate_spread: float | None = Field(default=None, ge=0, allow_inf_nan=False,
                                          description="a generating session searches only "
                                          "where the serve clip misses the agent's target by more than this share of "
                                          "its belief's half interquartile range (and the threshold): early answers, "
                                          "while the belief is wide, show serve clips at once; 0: search whenever the "
                                          "threshold is missed; default: the domain's Domain.generate_spread")
    generate_seconds: float | None = Field(
        default=None, gt=0, allow_inf_nan=False, description="a search stops before a CMA-ES generation that would "
        "end later than this many seconds after the search began, and one running past it ends with the candidates "
        "simulated by then (rba.generate.cma.SearchConfig); default: per domain, chosen on val (walker and "
        "manipulator 1 s, snake 1.25 s, the others 2 s: Domain.generate_seconds, docs/decisions/0005); a value here "
        "bounds every domain's searches, a large one leaves the 48-simulation budget alone to bound them. How long "
        "people then wait: benchmarks/results/generation_latency.md")
    warm_start: bool = Field(default=True, description="load models and render first clips after start-up")
    replica: str | None = Field(default=None, max_length=120, description="this server's name among the API "
                                "replicas on one database; default <hostname>:<port>. A restarted replica fails "
                                "the training jobs it ran before at once (others wait for their heartbeat)")
    job_heartbeat_seconds: float = Field(default=5.0, gt=0, le=300, description="how often a server marks the "
                                         "training jobs it runs alive in the database")
    job_stale_seconds: float = Field(default=30.0, gt=0, description="a training job not marked alive for this "
                                     "long lost its server: any replica fails it and frees its domain")
    heavy_workers: int = Field(default_factory=lambda: max(2, cores()), ge=1, le=32, description="heavy requests "
                               "(interpreting text, starting or answering sessions, clips, exports, uploads: "
                               "server.api.admission) running at once; default: the cores, at least 2. At most 32 "
                               "of the 40 request threads, so light requests always find one")
    heavy_queue: int = Field(default_factory=lambda: 8 * max(2, cores()), ge=0, le=10_000, description="heavy "
                             "requests waiting for a running one to end; beyond them the server answers 503 with "
                             "Retry-After; default: 8 per heavy worker")
    heavy_per_client: int = Field(default_factory=lambda: 4 * max(2, cores()), ge=1, le=10_000, description="heavy "
                                  "requests one client (address) may have running or waiting; beyond them it gets "
                                  "429 with Retry-After; default: 4 per heavy worker, so no one client fills the queue")
    train_max_jobs: int = Field(default_factory=lambda: max(1, cores() // 2), ge=1, le=64, description="training "
                                "jobs this server runs at once; more wait, queued, for one to end; default: one per "
                                "two cores, at least 1")
    train_nice: int = Field(default=10, ge=0, le=19, description="niceness a training process adds to its "
                            "server's: the server's requests go first")
    log_level: str = "info"

    @field_validator("admin_token", mode="before")
    @classmethod
    def _long_token(cls, token: object) -> object:
        """A token long enough to stop guessing; "" (docker-compose's unset variable) means no admin, as unset does."""
        if token == "":
            return None
        if isinstance(token, str) and len(token) < ADMIN_TOKEN_MIN:
            raise ValueError(f"RBA_ADMIN_TOKEN is {len(token)} characters; it must be at least {ADMIN_TOKEN_MIN} "
                             "characters (its length is what stops guessing). Make one with: python -c 'import "
                             "secrets; print(secrets.token_urlsafe(24))'")
        return token

    @model_validator(mode="after")
    def _heartbeat_before_stale(self) -> Settings:
        if self.job_stale_seconds <= 2 * self.job_heartbeat_seconds:
            raise ValueError(f"job_stale_seconds ({self.job_stale_seconds:g}) must exceed twice "
                             f"job_heartbeat_seconds ({self.job_heartbeat_seconds:g}), or live jobs look dead")
        return self

    def search_seconds(self, domain: str) -> float:
        """The time bound of a search in ``domain``: ``generate_seconds`` (RBA_GENERATE_SECONDS) if set, else the
        domain's own, chosen on val (``Domain.generate_seconds``, docs/decisions/0005-search-time-bound.md)."""
        if self.generate_seconds is not None:
            return self.generate_seconds
        return get_domain(domain).generate_seconds

    @property
    def replica_name(self) -> str:
        """This server among the replicas: ``replica``, else <hostname>:<port> (unique per container or port)."""
        return self.replica or f"{socket.gethostname()}:{self.port}"

    @property
    def db_url(self) -> str:
        return self.database_url or f"sqlite:///{Store.from_settings(self).database_file}"

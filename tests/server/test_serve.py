"""`rba serve` and the settings: RBA_-prefixed env vars, an SQLite file under data/ by default."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx

from rba.core.store import Store
from server.common.app_settings import Settings

REPO = Path(__file__).resolve().parents[2]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_settings_come_from_rba_env_vars(monkeypatch, tmp_path):
    monkeypatch.setenv("RBA_DATA_DIR", str(tmp_path / "d"))
    monkeypatch.setenv("RBA_PORT", "8123")
    monkeypatch.setenv("RBA_ADMIN_TOKEN", "s3cret-serve-token")
    monkeypatch.setenv("RBA_PRERENDER", "false")
    s = Settings()
    assert (s.port, s.admin_token, s.prerender) == (8123, "s3cret-serve-token", False)
    assert s.db_url == f"sqlite:///{tmp_path / 'd' / 'rba.db'}"
    assert Store.from_settings(s).cache_dir == tmp_path / "d" / "cache" / "clips"
    monkeypatch.setenv("RBA_DATABASE_URL", "postgresql+psycopg://u:p@127.0.0.1/rba")
    assert Settings().db_url == "postgresql+psycopg://u:p@127.0.0.1/rba"


def test_rba_serve_serves_the_page_within_15_seconds(tmp_path):
    port = free_port()
    env = {**os.environ, "RBA_DATA_DIR": str(tmp_path / "data"), "RBA_MODELS_DIR": str(tmp_path / "models"),
           "RBA_WARM_START": "false", "RBA_LOG_LEVEL": "warning"}
    start = time.monotonic()
    proc = subprocess.Popen([sys.executable, "-m", "rba.cli", "serve", "--host", "127.0.0.1", "--port", str(port)],
                            cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        page = None
        while time.monotonic() - start < 15 and proc.poll() is None:
            try:
                page = httpx.get(f"http://127.0.0.1:{port}/", timeout=1)
                break
            except httpx.TransportError:
                time.sleep(0.2)
        assert page is not None, proc.stdout.read().decode() if proc.poll() is not None else "no answer in 15 s"
        assert page.status_code == 200 and "RBA Studio" in page.text
        domains = httpx.get(f"http://127.0.0.1:{port}/api/domains", timeout=5).json()
        assert domains["domains"][0]["name"] == "walker"
        assert (tmp_path / "data" / "rba.db").exists()
    finally:
        proc.terminate()
        proc.wait(10)

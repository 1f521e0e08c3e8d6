"""A plugin domain reaches the page through the registry alone: listed with its attributes, and until it is built,
with the command that builds it (the page shows that instead of a session)."""

from __future__ import annotations

import pytest

import rba.domains as domains
from rba.domains import get_domain, register
from tests.example_domain import NAME, example_target


@pytest.fixture
def plugged(monkeypatch):
    """The example registered as its entry point registers it when installed; undone afterwards."""
    monkeypatch.setattr(domains.REGISTRY, "extra", dict(domains.REGISTRY.extra))
    register(NAME, example_target())
    yield
    get_domain.cache_clear()


def test_a_plugin_domain_is_listed_and_says_how_to_build_it(plugged, client):
    listed = {d["name"]: d for d in client.get("/api/domains").json()["domains"]}
    cheetah = listed[NAME]
    assert [a["name"] for a in cheetah["attributes"]] == ["speed", "bounce"] and cheetah["states"] == "features"
    assert cheetah["available"] == [] and f"run `rba build {NAME}`" in cheetah["missing"]
    r = client.post("/api/sessions", json={"domain": NAME, "method": "global", "rep": "onehot"})
    assert r.status_code == 422 and f"rba build {NAME}" in r.text

"""The app's settings that come from the library: a search's time bound is the domain's own
(``Domain.generate_seconds``, docs/decisions/0005-search-time-bound.md) unless ``RBA_GENERATE_SECONDS`` says
otherwise for every domain."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from rba.domains import domain_names, get_domain
from server.common.app_settings import Settings
from tests.toy import Toy


@pytest.fixture
def unset(monkeypatch) -> None:
    monkeypatch.delenv("RBA_GENERATE_SECONDS", raising=False)


def test_each_domain_bounds_its_searches_by_its_own_seconds(unset, monkeypatch):
    settings = Settings()
    assert {d: settings.search_seconds(d) for d in ("walker", "manipulator", "snake", "lane_change")} == {
        "walker": 1.0, "manipulator": 1.0, "snake": 1.25, "lane_change": 2.0}
    # the views were not measured: they keep the default (the image view renders every candidate)
    assert [settings.search_seconds(f"{d}_raw") for d in ("walker", "manipulator", "snake")] == [2.0] * 3
    assert all(settings.search_seconds(d) == get_domain(d).generate_seconds for d in domain_names())
    monkeypatch.setattr(Toy, "generate_seconds", 0.4)  # a domain's attribute is the app's default
    assert settings.search_seconds("toy") == 0.4


def test_rba_generate_seconds_bounds_every_domain_alike(unset, monkeypatch):
    monkeypatch.setenv("RBA_GENERATE_SECONDS", "3.5")
    settings = Settings()
    assert [settings.search_seconds(d) for d in ("walker", "snake", "toy")] == [3.5] * 3
    for bad in ("0", "inf", "nan"):
        monkeypatch.setenv("RBA_GENERATE_SECONDS", bad)
        with pytest.raises(ValidationError, match="generate_seconds"):
            Settings()


def test_the_admin_token_is_long_enough_to_stop_guessing(monkeypatch, capsys):
    """The right token gets in while its address waits for its wrong ones, so only its length stops guessing: a short
    one is refused (``rba serve`` exits 2 saying how to make one); "" (compose's unset variable) means no admin."""
    assert Settings(admin_token="x" * 16).admin_token == "x" * 16
    assert Settings(admin_token="").admin_token is None
    with pytest.raises(ValidationError, match="9 characters; it must be at least 16 characters"):
        Settings(admin_token="change-me")
    monkeypatch.setenv("RBA_ADMIN_TOKEN", "short")
    from rba.cli import main
    assert main(["serve", "--port", "1"]) == 2
    err = capsys.readouterr().err
    assert "admin_token" in err and "at least 16 characters" in err and "short" not in err  # not echoed

"""Plugin domains: what ``rba.domains.discover`` registers from entry points, and what it refuses and says why."""

from __future__ import annotations

import re
from importlib.metadata import EntryPoint
from types import SimpleNamespace

import pytest

import rba.domains as domains
from rba.domains import PluginWarning, discover, domain_names, domain_target, get_domain, plugin_package
from tests.toy import Toy


class ToyPlugin(Toy):
    name = "toy_plugin"


class NotADomain:
    name = "stray"


@pytest.fixture(autouse=True)
def own_registry(monkeypatch):
    """Each test discovers into copies of the run-time registrations (the toy's kept), undone afterwards."""
    monkeypatch.setattr(domains.REGISTRY, "extra", dict(domains.REGISTRY.extra))
    monkeypatch.setattr(domains, "_PLUGINS", {})
    yield
    get_domain.cache_clear()


def entry(name: str, value: str, package: str = "rba-toy-plugin") -> EntryPoint:
    """An entry point of the group ``rba.domains`` as the installed ``package`` declares it."""
    return EntryPoint(name, value, domains.ENTRY_POINT_GROUP)._for(SimpleNamespace(name=package))


def test_a_plugin_is_registered_with_its_package():
    assert discover([entry("toy_plugin", "tests.domains.test_plugins:ToyPlugin")]) == ["toy_plugin"]
    assert domain_names()[-1] == "toy_plugin" and plugin_package("toy_plugin") == "rba-toy-plugin"
    assert isinstance(get_domain("toy_plugin"), ToyPlugin) and plugin_package("walker") is None


@pytest.mark.parametrize(("name", "value", "why"), [
    ("walker", "tests.domains.test_plugins:ToyPlugin", "'walker' is a domain rba ships; a plugin cannot replace it"),
    ("toy_plugin", "rba_no_such_module.domain:Thing", "importing 'rba_no_such_module.domain:Thing' failed: "
                                                      "ModuleNotFoundError"),
    ("toy_plugin", "tests.domains.test_plugins:Missing", "failed: AttributeError"),
    ("stray", "tests.domains.test_plugins:NotADomain", "is not a subclass of rba.domains.Domain"),
    ("other_name", "tests.domains.test_plugins:ToyPlugin", "has name 'toy_plugin', not the entry point's 'other_name'"),
    ("../evil", "tests.domains.test_plugins:ToyPlugin", "is not a domain name"),
    ("toy_plugin", "tests.domains.test_plugins", "is not \"module:Class\""),
])
def test_a_bad_plugin_is_refused_naming_its_package_and_the_shipped_domains_stay(name, value, why):
    before = domains.REGISTRY.targets()
    with pytest.warns(PluginWarning, match=rf"plugin domain '{name}' from package 'rba-toy-plugin' was not "
                                           rf"registered: .*{re.escape(why)}"):
        assert discover([entry(name, value)]) == []
    assert domains.REGISTRY.targets() == before
    assert domain_target("walker") == "rba.domains.walker:Walker" and plugin_package(name) is None


def test_a_name_two_packages_claim_is_refused_for_both_and_the_others_register():
    found = [entry("toy_plugin", "tests.domains.test_plugins:ToyPlugin", "rba-first"),
             entry("toy_plugin", "tests.toy:Toy", "rba-second"),
             entry("toy_plugin", "tests.toy:Toy", "rba-second")]
    with pytest.warns(PluginWarning, match="the packages rba-first, rba-second all register 'toy_plugin'; none is "
                                           "used") as caught:
        assert discover(found) == []
    assert len(caught) == 1 and "toy_plugin" not in domain_names()


def test_a_package_listed_twice_registers_once():
    ep = entry("toy_plugin", "tests.domains.test_plugins:ToyPlugin")
    assert discover([ep, ep]) == ["toy_plugin"] and domain_names().count("toy_plugin") == 1

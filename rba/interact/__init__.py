"""Agents (one per method) and simulated users. ``METHODS`` maps a method name to its agent."""

from __future__ import annotations

from rba.interact.base import SATISFIED, Agent, AttributeFeedback, Feedback, validate_feedback
from rba.interact.global_agent import GlobalAgent, GlobalContext
from rba.interact.local_agent import LocalAgent, LocalContext
from rba.interact.pbrl_agent import PbRLAgent, PbRLContext

METHODS: dict[str, tuple[type[Agent], type]] = {
    "global": (GlobalAgent, GlobalContext),
    "local": (LocalAgent, LocalContext),
    "pbrl": (PbRLAgent, PbRLContext),
}

__all__ = ["METHODS", "SATISFIED", "Agent", "AttributeFeedback", "Feedback", "check_method", "load_context",
           "new_agent", "validate_feedback"]


def check_method(method: str) -> str:
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; valid: {', '.join(METHODS)}")
    return method


def load_context(domain: str, method: str, rep: str, data_root=None, models_root=None):
    """Load what every agent of (domain, method, rep) shares: models and the serve library."""
    return METHODS[check_method(method)][1].load(domain, rep, data_root, models_root)


def new_agent(method: str, context) -> Agent:
    return METHODS[check_method(method)][0](context)


def restore_agent(state: dict, context) -> Agent:
    return METHODS[check_method(state["method"])][0].from_state(state, context)

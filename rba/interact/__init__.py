"""Agents (one per method, each beside its ``Method`` record) and simulated users.

The functions here go through the method registry (``rba.core.methods``), so they work for every
registered method, plugins included.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rba.core.methods import get_method
from rba.interact.base import (
    SATISFIED,
    Agent,
    AttributeFeedback,
    Feedback,
    FeedbackKind,
    Preference,
    validate_feedback,
)

__all__ = ["SATISFIED", "Agent", "AttributeFeedback", "Feedback", "FeedbackKind", "Preference",
           "load_context", "new_agent", "restore_agent", "validate_feedback"]


def load_context(domain: str, method: str, rep: str, data_root: Path | None = None,
                 models_root: Path | None = None) -> Any:
    """Load what every agent of (domain, method, rep) shares: models and the serve library."""
    return get_method(method).load_context(domain, rep, data_root, models_root)


def new_agent(method: str, context: Any) -> Agent:
    return get_method(method).agent(context)


def restore_agent(state: dict, context: Any) -> Agent:
    """The agent whose ``state_dict()`` was ``state`` (its ``"method"`` names the record)."""
    return get_method(state["method"]).agent.from_state(state, context)

"""The Agent contract (docs/architecture.md §4) and the feedback records that drive it.

An agent turns feedback into the next rollout to show. It takes one kind of feedback (its
``feedback_kind``): more/less about attributes, or the answer to an A/B question. It never
reads proxies. Its whole state is a JSON-able dict, so a web session survives a server restart;
the heavy, shareable parts (models, the serve library) live in a separate *context* object.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import ClassVar, Literal, Protocol

SATISFIED: Literal["satisfied"] = "satisfied"
# Rounds a rollout that got feedback stays excluded from what an agent shows: no clip is excluded for good
# by one answer (a user whose target drifts, or who misjudged, can come back to it).
REJECT_MEMORY = 40


@dataclass(frozen=True)
class AttributeFeedback:
    """"More" (+1) or "less" (-1) of one attribute."""

    attribute: str
    direction: int

    def __post_init__(self) -> None:
        if self.direction not in (1, -1):
            raise ValueError(f"direction must be +1 (more) or -1 (less), got {self.direction!r}")


@dataclass(frozen=True)
class Preference:
    """The answer to an A/B query: the id of the preferred rollout, or None for "equally good"."""

    preferred: str | None


FeedbackKind = Literal["attribute", "preference"]
Feedback = list[AttributeFeedback] | Preference | Literal["satisfied"]


class FeedbackSource(Protocol):
    """Whoever judges a shown rollout: a simulated user in evaluation, a person on the web."""

    def respond(self, rollout_index: int) -> Feedback: ...


class Agent(ABC):
    """A small state machine over rollouts of the ``serve`` library (ids are library ids)."""

    method: ClassVar[str]
    feedback_kind: ClassVar[FeedbackKind]

    @abstractmethod
    def first_query(self) -> str:
        """The first rollout to show."""

    def _is_satisfied(self, feedback: Feedback, attribute_names: tuple[str, ...]) -> bool:
        """Shared preamble of ``update``: order of calls and feedback validity checked once, here."""
        if getattr(self, "shown", None) is None:
            raise RuntimeError("update() before first_query()")
        validate_feedback(feedback, self.feedback_kind, attribute_names)
        return feedback == SATISFIED

    @abstractmethod
    def update(self, feedback: Feedback) -> str:
        """Take one round of feedback about the rollout shown last; return the next to show."""

    @abstractmethod
    def state_dict(self) -> dict:
        """Everything needed to resume, as plain JSON types."""

    @classmethod
    @abstractmethod
    def from_state(cls, state: dict, context) -> Agent:
        """Rebuild an agent from ``state_dict()`` output and a loaded context."""

    def target_ranks(self, mass: float = 0.5) -> dict[str, tuple[float, float]] | None:
        """Where the agent believes the target is, per attribute: the central ``mass`` of its belief as
        fractions (0..1) of the serve library ranked by the attribute's learned score; None if it keeps no
        such belief. Ranks, not proxy values: the agent never reads proxies (the page maps ranks to them).
        """
        return None


def validate_feedback(feedback: Feedback, kind: FeedbackKind, attribute_names: tuple[str, ...]) -> Feedback:
    """Check that one round's feedback is of ``kind`` and well formed; raise ValueError if not.

    Attribute feedback: known attribute names, none asked both ways. Whether a preference names a
    rollout of the pending pair only the agent knows (its state).
    """
    if feedback == SATISFIED:
        return feedback
    if kind == "preference":
        if not isinstance(feedback, Preference):
            raise ValueError("this agent takes A/B answers: Preference(preferred=<rollout id> | None) or 'satisfied'")
        return feedback
    if isinstance(feedback, str | Preference):
        raise ValueError(f"this agent takes attribute feedback: a list of (attribute, more|less) or 'satisfied'; "
                         f"attributes: {', '.join(attribute_names)}")
    if not feedback:
        raise ValueError(f"feedback is empty; give at least one (attribute, more|less) or 'satisfied'; "
                         f"attributes: {', '.join(attribute_names)}")
    seen: dict[str, int] = {}
    for fb in feedback:
        if fb.attribute not in attribute_names:
            raise ValueError(f"unknown attribute {fb.attribute!r}; valid: {', '.join(attribute_names)}")
        if seen.get(fb.attribute, fb.direction) != fb.direction:
            raise ValueError(f"attribute {fb.attribute!r} asked both more and less in one round")
        seen[fb.attribute] = fb.direction
    return feedback

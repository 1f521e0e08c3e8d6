"""Every rule the API applies to a person's feedback, and its translation into the library's records.

One place: ``FeedbackCreate`` asks ``check_kind`` while parsing the body (so a malformed body is
422 before any session is read), and a session step asks ``parse_feedback`` once it knows the
session's attributes. The agents still run ``rba.interact.validate_feedback`` on what they get;
what passes here always passes there, so the server never relies on its ValueError.

Import direction: low; it imports only the library and ``server.common.errors``.
"""

from __future__ import annotations

from collections.abc import Sequence

from rba.interact import SATISFIED, AttributeFeedback, Feedback
from server.common.errors import invalid

DIRECTIONS = {"more": 1, "less": -1}
"""The API's words for a direction -> the library's sign."""


def check_kind(satisfied: bool, has_feedback: bool) -> None:
    """A body holds attribute feedback or ``satisfied: true``, exactly one; raise ValueError (pydantic's 422)."""
    if satisfied and has_feedback:
        raise ValueError("give either 'feedback' or 'satisfied': true, not both")
    if not satisfied and not has_feedback:
        raise ValueError("give 'feedback': [{'attribute': ..., 'direction': 'more' | 'less'}] or 'satisfied': true")


def parse_feedback(choices: Sequence[tuple[str, str]], satisfied: bool, domain: str,
                   valid: tuple[str, ...]) -> Feedback:
    """``[(attribute, "more" | "less")]`` (or satisfied) as the library's feedback; 422 naming what is wrong.

    ``valid`` is the attributes of the session's models (its version may add some to the domain's).
    """
    if satisfied:
        return SATISFIED
    seen: set[str] = set()
    for attribute, _direction in choices:
        if attribute not in valid:
            raise invalid(f"unknown attribute {attribute!r} for {domain}; valid: {', '.join(valid)}; "
                          "directions: more, less")
        if attribute in seen:
            raise invalid(f"attribute {attribute!r} appears more than once; give each attribute at most once")
        seen.add(attribute)
    return [AttributeFeedback(a, DIRECTIONS[d]) for a, d in choices]

"""Feedback in a person's own words: the operation behind POST /api/domains/{domain}/interpret."""

from __future__ import annotations

from rba.interact.free_text import NotUnderstood, Understood, interpreter_for
from server.common.errors import invalid
from server.runtime.services import Services


def interpret(svc: Services, domain: str, text: str) -> Understood:
    """What ``text`` asks of ``domain``'s attributes; 422 when nothing is close enough (the route checks the domain).

    The sentence model and the anchors load at start-up (``Services.reading``); a request before that ends waits
    for it (or, without a warm start, loads them itself, once per process).
    """
    interpreter = interpreter_for(svc.catalog.domain(domain))
    try:
        return interpreter.interpret(text)
    except NotUnderstood as exc:
        raise invalid(str(exc)) from None

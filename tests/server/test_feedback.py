"""The server's feedback rules (server.common.feedback) and the nearest-neighbour pick of clips to label."""

from __future__ import annotations

import numpy as np
import pytest
from fastapi import HTTPException

from rba.interact import SATISFIED, AttributeFeedback, validate_feedback
from server.common.feedback import check_kind, parse_feedback
from server.ops.label_admin import nearest

VALID = ("amplitude", "pace")


def test_choices_become_the_library_records_it_accepts():
    feedback = parse_feedback([("pace", "less"), ("amplitude", "more")], False, "toy", VALID)
    assert feedback == [AttributeFeedback("pace", -1), AttributeFeedback("amplitude", 1)]
    assert validate_feedback(feedback, "attribute", VALID) == feedback
    assert parse_feedback([], True, "toy", VALID) == SATISFIED


@pytest.mark.parametrize(("choices", "message"), [
    ([("speed", "more")], "unknown attribute 'speed' for toy; valid: amplitude, pace; directions: more, less"),
    ([("pace", "more"), ("pace", "more")], "attribute 'pace' appears more than once; give each attribute at most once"),
    ([("pace", "more"), ("pace", "less")], "attribute 'pace' appears more than once"),
])
def test_bad_choices_are_422_naming_the_problem(choices, message):
    with pytest.raises(HTTPException) as e:
        parse_feedback(choices, False, "toy", VALID)
    assert e.value.status_code == 422 and message in e.value.detail


@pytest.mark.parametrize(("satisfied", "has_feedback", "message"), [
    (True, True, "not both"), (False, False, "or 'satisfied': true")])
def test_a_body_holds_exactly_one_kind(satisfied, has_feedback, message):
    with pytest.raises(ValueError, match=message):
        check_kind(satisfied, has_feedback)
    check_kind(satisfied, not has_feedback)


def test_nearest_scales_each_attribute_to_its_range():
    proxies = np.array([[0.0, 0.0], [1.0, 100.0], [0.1, 90.0], [0.5, 0.0]])
    assert nearest(proxies, 0, 2) == [3, 2]  # 1 and 2 differ by ~all of the second attribute's range
    assert nearest(proxies, 1, 1) == [2]

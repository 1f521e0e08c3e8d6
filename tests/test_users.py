"""Simulated users: the attribute-feedback user and the PbRL teacher, on hand-made cases."""

import numpy as np
import pytest

from rba.interact import SATISFIED, AttributeFeedback
from rba.interact.users import PreferenceTeacher, SimulatedUser

NAMES = ("size", "speed")
EPS = np.array([1.0, 2.0])
# rows: (1.5, 0) is 1.5 ε away; (0, 2.5) is only 1.25 ε away although farther in raw units
PROXIES = np.array([[1.5, 0.0], [0.0, 2.5], [0.5, 0.5], [-1.5, 0.0], [0.0, -3.0]])


def teacher(noise=0.0, seed=0):
    return PreferenceTeacher(np.zeros(2), EPS, NAMES, PROXIES, noise, seed)


def test_teacher_prefers_the_closer_rollout_in_epsilon_units():
    t = teacher()
    assert t.distance(0) == pytest.approx(1.5) and t.distance(1) == pytest.approx(1.25)
    assert t.prefer(0, 1) == 0.0 and t.prefer(1, 0) == 1.0
    assert t.prefer(2, 4) == 1.0


def test_teacher_says_equal_for_equal_distances_even_when_noisy():
    assert teacher().prefer(0, 3) == 0.5
    assert {teacher(0.4, seed).prefer(0, 3) for seed in range(20)} == {0.5}


def test_teacher_noise_flips_at_the_stated_rate_and_is_seeded():
    answers = [teacher(0.2, seed=7).prefer(1, 0) for _ in range(3)]
    assert len(set(answers)) == 1  # same seed, same first answer
    t = teacher(0.2, seed=1)
    flips = np.mean([t.prefer(1, 0) == 0.0 for _ in range(4000)])
    assert 0.17 < flips < 0.23


def test_teacher_is_satisfied_within_epsilon():
    t = teacher()
    assert t.satisfied_with(2) and not t.satisfied_with(0)
    assert t.respond(2) == SATISFIED
    assert t.respond(0) == [AttributeFeedback("size", -1)]


def test_noise_must_be_below_one_half():
    with pytest.raises(ValueError, match=r"noise must be in \[0, 0.5\)"):
        teacher(0.5)


def test_noisy_attribute_feedback_is_seeded():
    def answers(seed):
        user = SimulatedUser(np.zeros(2), EPS, NAMES, PROXIES, noise=0.3, seed=seed)
        return [user.respond(4) for _ in range(30)]

    assert answers(5) == answers(5)
    flipped = [a for a in answers(5) if a != [AttributeFeedback("speed", 1)]]
    assert 0 < len(flipped) < 30

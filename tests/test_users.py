"""Simulated users: the attribute-feedback user, every teacher kind, the spec parser and the PbRL teacher, on
hand-made cases (seeded: the same seed gives the same answers)."""

import numpy as np
import pytest

from rba.interact import SATISFIED, AttributeFeedback
from rba.interact.users import (
    DRIFT_KEEP,
    SKIP,
    USER_KINDS,
    MyopicUser,
    PreferenceTeacher,
    SimulatedUser,
    UserSpec,
    last_part_proxies,
    parse_user,
)

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


# ---------------------------------------------------------------- teacher kinds (B-Pref's, for attribute feedback)
def user(spec: str, proxies=PROXIES, seed=0, target=(0.0, 0.0)):
    return USER_KINDS[parse_user(spec).kind].cls.from_library(parse_user(spec).strength, np.array(target), EPS,
                                                                 FakeServe(proxies), seed)


class FakeServe:
    """What a user reads of a library: names and proxies (and, for myopic, the replay: 4 frames per clip)."""

    def __init__(self, proxies):
        self.attribute_names = NAMES
        self.proxies = np.asarray(proxies, dtype=np.float64)
        self.replay = np.repeat(self.proxies, 4, axis=0).astype(np.float32)
        self.replay_offsets = np.arange(0, 4 * len(proxies) + 1, 4)


def test_specs_parse_in_one_place_with_defaults():
    assert parse_user("paper") == UserSpec("paper", None) and str(parse_user("paper")) == "paper"
    assert parse_user("mistake") == UserSpec("mistake", 0.1)
    assert parse_user("equal:3") == UserSpec("equal", 3.0) and str(parse_user("equal:3")) == "equal:3"
    assert {k: parse_user(k).strength for k in USER_KINDS} == {
        "paper": None, "mistake": 0.1, "skip": 0.2, "equal": 2.0, "myopic": 0.5, "boundary": 0.5,
        "inconsistent": 0.1}
    assert parse_user(parse_user("skip:0.3")) == UserSpec("skip", 0.3)


@pytest.mark.parametrize(("spec", "message"), [
    ("grumpy", "unknown user kind 'grumpy'; valid: paper, mistake, skip, equal, myopic, boundary, inconsistent "
     "(as KIND or KIND:param)"),
    ("paper:0.1", "user kind 'paper' takes no parameter, got '0.1'"),
    ("mistake:0.5", "user kind 'mistake' takes a flip probability in [0, 0.5), got 0.5"),
    ("skip:1", "user kind 'skip' takes a skip probability in [0, 1), got 1"),
    ("equal:0.5", "user kind 'equal' takes k >= 1 (silent within k·ε), got 0.5"),
    ("myopic:nan", "user kind 'myopic' takes a weight of the clip's end in [0, 1], got nan"),
    ("boundary:0", "user kind 'boundary' takes a logistic width in ε, > 0, got 0"),
    ("inconsistent:-1", "user kind 'inconsistent' takes a drift step in ε per round, >= 0, got -1"),
    ("boundary:wide", "user kind 'boundary' takes a number (a logistic width in ε, > 0), got 'wide'"),
])
def test_bad_specs_say_what_is_valid(spec, message):
    with pytest.raises(ValueError) as exc:
        parse_user(spec)
    assert str(exc.value) == message


def test_paper_user_and_mistake_zero_answer_alike():
    for i in range(len(PROXIES)):
        assert user("paper").respond(i) == user("mistake:0").respond(i)
    assert user("paper").respond(0) == [AttributeFeedback("size", -1)]
    assert user("paper").respond(2) == SATISFIED


def test_mistake_flips_at_its_rate_and_is_seeded():
    answers = [user("mistake:0.2", seed=4).respond(4) for _ in range(3)]
    assert len({str(a) for a in answers}) == 1
    u = user("mistake:0.2", seed=1)
    flips = np.mean([u.respond(4) == [AttributeFeedback("speed", -1)] for _ in range(4000)])
    assert 0.17 < flips < 0.23


def test_skip_gives_no_answer_at_its_rate_and_otherwise_the_paper_answer():
    u = user("skip:0.5", seed=2)
    answers = [u.respond(4) for _ in range(2000)]
    assert 0.46 < np.mean([a == SKIP for a in answers]) < 0.54
    assert {str(a) for a in answers if a != SKIP} == {str([AttributeFeedback("speed", 1)])}
    assert all(user("skip:0", seed=s).respond(4) != SKIP for s in range(20))


def test_equal_is_silent_within_k_epsilon_and_names_the_worst_when_all_are_close():
    proxies = [[1.5, 5.0], [1.5, 3.6], [1.5, 0.0], [0.5, -1.0], [3.0, -6.0]]
    u = user("equal:2", proxies)
    assert u.respond(0) == [AttributeFeedback("speed", -1)]  # size is 1.5 ε off: silent
    assert u.respond(1) == [AttributeFeedback("speed", -1)]  # both within 2 ε: only the worst (speed, 1.8 ε)
    assert u.respond(2) == [AttributeFeedback("size", -1)]
    assert u.respond(3) == SATISFIED
    assert u.respond(4) == [AttributeFeedback("size", -1), AttributeFeedback("speed", 1)]  # both 3 ε off
    assert user("equal:1", proxies).respond(0) == user("paper", proxies).respond(0)


def test_boundary_says_more_with_a_logistic_probability_in_epsilon_units():
    proxies = [[1.5, 0.0], [5.0, 0.0], [0.9, 0.0]]
    u = user("boundary:0.5", proxies, seed=3)
    more = np.mean([u.respond(0) == [AttributeFeedback("size", 1)] for _ in range(6000)])
    assert abs(more - 1 / (1 + np.exp(3.0))) < 0.01  # σ(−1.5 / 0.5) ≈ 0.047
    assert all(u.respond(1) == [AttributeFeedback("size", -1)] for _ in range(500))  # 5 ε off: σ(−10)
    assert u.respond(2) == SATISFIED  # within ε it is satisfied, as every kind
    assert [user("boundary", proxies, seed=9).respond(0) for _ in range(5)] == \
           [user("boundary", proxies, seed=9).respond(0) for _ in range(5)]


def test_inconsistent_targets_drift_by_steps_of_s_epsilon_after_unsatisfied_rounds():
    u = user("inconsistent:0.1", [[100.0, 100.0]], seed=5)  # a clip far off: never satisfied
    steps, offsets = [], []
    for _ in range(4000):
        before = u.target.copy()
        u.respond(0)
        steps.append((u.target - before) / EPS)
        offsets.append(u.target / EPS)
    assert np.allclose(np.std(steps, axis=0), 0.1, rtol=0.06) and np.allclose(np.mean(steps, axis=0), 0, atol=0.01)
    # pulled back to where it started: the spread settles at s / sqrt(1 - keep²) ≈ 0.32 ε (a walk would reach ~6 ε)
    assert np.allclose(np.std(offsets[500:], axis=0), 0.1 / np.sqrt(1 - DRIFT_KEEP**2), rtol=0.15)
    assert np.abs(offsets).max() < 1.5
    still = user("inconsistent:0.1", seed=5)
    still.respond(2)  # satisfied: the session is over, the target stays
    assert np.array_equal(still.target, np.zeros(2))
    assert np.array_equal(user("inconsistent:0").target, np.zeros(2))
    a, b = user("inconsistent", seed=8), user("inconsistent", seed=8)
    assert [a.respond(4) for _ in range(20)] == [b.respond(4) for _ in range(20)]
    assert np.array_equal(a.target, b.target)


def test_myopic_judges_by_the_end_and_can_stop_on_a_miss():
    u = MyopicUser(np.zeros(2), EPS, NAMES, np.array([[0.0, 0.0], [1.6, 0.0]]), 0.5,
                   end_proxies=np.array([[3.0, 0.0], [0.0, 0.0]]))
    assert u.respond(0) == [AttributeFeedback("size", -1)]  # right on target, but its end looks big
    assert not u.satisfied_with(0) and u.succeeded(0)
    assert u.respond(1) == SATISFIED and not u.succeeded(1)  # 1.6 ε off, its end looks right: a miss
    assert np.array_equal(MyopicUser(np.zeros(2), EPS, NAMES, PROXIES, 0.0, end_proxies=-PROXIES).seen, PROXIES)


def test_last_part_proxies_read_the_end_of_each_clip():
    rng = np.random.default_rng(0)
    proxies = rng.uniform(0, 1, (60, 2))
    clips = [np.vstack([rng.normal(0, 1, (6, 2)), np.repeat(p[None] * [2, -3], 2, 0)]) for p in proxies]
    offsets = np.concatenate([[0], np.cumsum([len(c) for c in clips])])
    end = last_part_proxies(np.vstack(clips), offsets, proxies)  # the last quarter (2 of 8 frames) is the proxy
    assert np.abs(end - proxies).max() < 0.02
    mixed = last_part_proxies(np.vstack([c[::-1] for c in clips]), offsets, proxies)  # the proxy at the start
    assert np.abs(mixed - proxies).mean() > 0.1  # the end says nothing: regressed towards the mean
    assert np.abs(mixed.mean(0) - proxies.mean(0)).max() < 1e-9


def test_last_part_proxies_read_speed_too():
    """Clips whose ends move at different speeds (and so end at different places) are told apart."""
    speeds = np.linspace(0.1, 2.0, 40)
    clips = [np.concatenate([np.zeros(12), np.cumsum(np.full(4, v))])[:, None] for v in speeds]
    clips = [np.hstack([c, np.zeros_like(c)]) for c in clips]
    offsets = np.concatenate([[0], np.cumsum([len(c) for c in clips])])
    proxies = np.stack([speeds, np.zeros_like(speeds)], 1)
    end = last_part_proxies(np.vstack(clips), offsets, proxies)
    assert np.abs(end - proxies).max() < 0.05


def test_myopic_user_reads_the_replay_of_the_library():
    """The myopic user's impression comes from the replay (the same whatever state view agents learn from)."""
    serve = FakeServe(PROXIES)
    serve.states = np.full((len(PROXIES), 3), np.nan)  # never read
    u = MyopicUser.from_library(0.5, np.zeros(2), EPS, serve, 0)
    expected = 0.5 * PROXIES + 0.5 * last_part_proxies(serve.replay, serve.replay_offsets, PROXIES)
    assert np.allclose(u.seen, expected)

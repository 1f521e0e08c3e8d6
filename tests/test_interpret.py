"""rba.interact.free_text: free-text feedback on every domain, with the shipped sentence model (loaded once)."""

from __future__ import annotations

import functools
import json
import threading
from pathlib import Path

import pytest

from rba.core.registry import import_object
from rba.domains import domain_names, domain_target, get_domain
from rba.interact import free_text
from rba.interact.free_text import FLIPS, KEEPS, Interpreter, NotUnderstood, clauses, stem, understood

PHRASINGS = json.loads((Path(__file__).parent / "data" / "interpret_phrasings.json").read_text())
TEST = PHRASINGS["test"]


@pytest.fixture(scope="module")
def interpreters() -> dict[str, Interpreter]:
    """One interpreter per domain of the test set (the model loads once; one torch thread, as the server)."""
    from rba.learn.common import torch_threads

    with torch_threads(1):
        yield {name: Interpreter.for_domain(get_domain(name)) for name in TEST}


def _domain_class(name: str) -> type:
    return import_object(domain_target(name))  # class attributes only: no simulator starts


# -- what needs no model ------------------------------------------------------------------------
def test_clauses_split_at_conjunctions_and_count_direction_flips():
    assert [(c.text, c.flips) for c in clauses("Bigger but softer steps, please")] == \
        [("bigger", 0), ("softer steps", 0)]
    assert [(c.text, c.flips) for c in clauses("don't stomp so much")] == [("do stomp", 1)]
    assert [(c.text, c.flips) for c in clauses("not fast enough")] == [("fast", 2)]  # the two cancel
    assert [(c.text, c.flips) for c in clauses("gentle rather than stompy")] == [("gentle", 0), ("stompy", 1)]
    assert [(c.text, c.flips) for c in clauses("faster with less shaking")] == [("faster", 0), ("shaking", 1)]
    assert [c.text for c in clauses("swing back and forth faster")] == ["swing back and forth faster"]
    assert clauses("more, please!") == []


def test_stems_match_comparatives_and_adverbs():
    assert {stem(w) for w in ("stomp", "stomps", "stomping", "stompy", "stompier")} == {"stomp"}
    assert {stem(w) for w in ("heavy", "heavier", "heavily")} == {"heav"}
    assert stem("bigger") == stem("big") and stem("wider") == stem("wide") and stem("speed") == "speed"
    assert stem("gently") == stem("gentle") and stem("wobbly") == stem("wobble") and stem("simply") == stem("simple")
    assert stem("small") == "small" and stem("careful") == "careful"


def test_two_readings_are_offered_only_when_unsure():
    more, less = (("gap", "more"),), (("gap", "less"),)
    sure, unsure = free_text.Understood(more, 0.9, less), free_text.Understood(more, 0.5, less)
    assert not sure.low_confidence and sure.alternatives == []
    assert unsure.low_confidence and unsure.alternatives == [more, less]
    assert free_text.Understood(more, 0.5).alternatives == []  # nothing else to offer


@pytest.mark.parametrize("name", domain_names())
def test_examples_come_from_the_domains_own_anchors(name):
    cls = _domain_class(name)
    shown = free_text.examples(cls)
    assert 2 <= len(shown) <= 3 and len(set(shown)) == len(shown)
    sides = [(p.less, p.more)[i % 2] for i, p in enumerate(cls.feedback_phrases[a.name] for a in cls.attributes)]
    assert all(text in side for text, side in zip(shown, sides, strict=False))


def test_a_request_during_the_background_load_waits_for_it_and_never_builds_twice(monkeypatch):
    built, building, release = [], threading.Event(), threading.Event()

    @functools.cache
    def slow(phrases):
        built.append(phrases)
        building.set()
        release.wait(30)
        return object()

    monkeypatch.setattr(free_text, "_interpreter", slow)
    walker = _domain_class("walker")
    loading = free_text.load_in_background([walker])
    assert building.wait(30)
    got: list = []
    request = threading.Thread(target=lambda: got.append(free_text.interpreter_for(walker)))
    request.start()
    request.join(0.5)  # the request is under way (and would build its own without the lock) ...
    release.set()  # ... before the load ends
    loading.join(30)
    request.join(30)
    assert built == [free_text.anchors(walker)] and got == [slow(free_text.anchors(walker))]


@pytest.mark.parametrize("name", domain_names())
def test_every_domain_has_anchors_for_exactly_its_attributes_without_direction_words(name):
    cls = _domain_class(name)
    assert set(cls.feedback_phrases) == {a.name for a in cls.attributes}
    for attribute, phrases in cls.feedback_phrases.items():
        assert len(phrases.more) >= 5 and len(phrases.less) >= 5, attribute
        words = {w for p in (*phrases.more, *phrases.less, *phrases.names) for w in p.lower().split()}
        assert not words & (FLIPS | KEEPS), (attribute, words & (FLIPS | KEEPS))


@pytest.mark.parametrize("name", domain_names())
def test_the_test_set_covers_every_domain_and_is_never_an_anchor(name):
    cls = _domain_class(name)
    covered = [d for d in TEST if _domain_class(d).feedback_phrases == cls.feedback_phrases]
    assert covered, f"{name}: no test phrasings for its anchors"  # lane_change_image shares lane_change's
    items = TEST[covered[0]]
    assert len(items) >= 60
    anchors = {p.lower() for ph in cls.feedback_phrases.values() for p in (*ph.more, *ph.less, *ph.names)}
    assert not {text.lower() for text, _ in items} & anchors
    assert not {text.lower() for text, _ in items} & {t.lower() for t, _ in PHRASINGS["val"].get(covered[0], [])}
    for attribute in cls.feedback_phrases:  # several per attribute and direction
        for direction in ("more", "less"):
            assert sum(f"{attribute}:{direction}" in want for _, want in items) >= 5, (attribute, direction)
    assert sum(len(want) > 1 for _, want in items) >= 5  # multi-attribute sentences
    assert sum(not want for _, want in items) >= 3  # and some it must not understand


# -- with the model -----------------------------------------------------------------------------
@pytest.mark.parametrize("name", list(TEST))
def test_accuracy_on_the_test_phrasings_is_at_least_0_9(interpreters, name):
    misses = [(text, want, sorted(got)) for text, want in TEST[name]
              if (got := understood(interpreters[name], text)) != set(want)]
    accuracy = 1 - len(misses) / len(TEST[name])
    assert accuracy >= 0.9, (accuracy, misses)


@pytest.mark.parametrize(("text", "expected"), [
    ("stomp less", [("softness", "more")]),
    ("less stompy", [("softness", "more")]),
    ("STOMP MORE!", [("softness", "less")]),
    ("don't land so gently", [("softness", "less")]),
    ("smaller steps", [("step_size", "less")]),
    ("take bigger steps", [("step_size", "more")]),
    ("more step size", [("step_size", "more")]),
    ("less step size", [("step_size", "less")]),
    ("your steps are too short", [("step_size", "more")]),
    ("bigger but softer steps", [("step_size", "more"), ("softness", "more")]),
    ("shorter steps, and stomp", [("step_size", "less"), ("softness", "less")]),
    ("gentle rather than stompy", [("softness", "more")]),
])
def test_negations_antonyms_and_several_attributes(interpreters, text, expected):
    result = interpreters["walker"].interpret(text)
    assert list(result.feedback) == expected
    assert 0.4 <= result.confidence <= 1.0


@pytest.mark.parametrize(("name", "text", "expected"), [
    ("lane_change", "turn more gently", [("sharpness", "less")]),
    ("lane_change", "change lanes more gently", [("sharpness", "less")]),
    ("lane_change_image", "turn more gently", [("sharpness", "less")]),
    ("lane_change_raw", "change lanes more gently", [("sharpness", "less")]),
    ("snake", "stay narrow", [("bend_width", "less")]),
    ("snake_raw", "stay narrow", [("bend_width", "less")]),
    ("walker", "softer landings please", [("softness", "more")]),
    ("walker_raw", "softer landings please", [("softness", "more")]),
    ("toy", "stay narrow", [("amplitude", "less")]),
])
def test_natural_phrasings_that_were_read_backwards(name, text, expected):
    from rba.learn.common import torch_threads

    with torch_threads(1):
        assert list(free_text.interpreter_for(get_domain(name)).interpret(text).feedback) == expected


def test_an_unsure_reading_has_a_second_one(interpreters):
    result = interpreters["manipulator"].interpret("steadier please")
    assert result.low_confidence and result.alternatives == [(("instability", "less"),), (("instability", "more"),)]
    assert interpreters["walker"].interpret("stomp less").alternatives == []


def test_nothing_close_enough_says_so_and_names_the_attributes(interpreters):
    for text in ("what a lovely day", "banana", "more", "not"):
        with pytest.raises(NotUnderstood) as err:
            interpreters["walker"].interpret(text)
        assert str(err.value).startswith(f"I didn't understand {text!r}; the attributes are: step size, softness.")


def test_an_attribute_without_anchors_is_still_matched_by_name(interpreters):
    from rba.domains.base import FeedbackPhrases
    from rba.learn.embed import sentence_embeddings

    plain = Interpreter([("step_size", FeedbackPhrases((), ())), ("softness", FeedbackPhrases((), ()))],
                        sentence_embeddings)
    assert plain.interpret("less step size").feedback == (("step_size", "less"),)
    assert plain.interpret("more softness").feedback == (("softness", "more"),)


def test_one_encode_per_sentence_and_anchors_encoded_once(interpreters):
    from rba.learn.embed import sentence_embeddings

    calls: list[list[str]] = []

    def counting(texts: list[str]):
        calls.append(texts)
        return sentence_embeddings(texts)

    walker = get_domain("walker")
    interpreter = Interpreter.for_domain(walker, counting)
    assert len(calls) == 1 and len(calls[0]) == sum(
        1 + len(p.names) + len(p.more) + len(p.less) for p in walker.feedback_phrases.values())
    interpreter.interpret("longer strides, softer landings and no stomping")
    assert calls[1:] == [["longer strides", "softer landings", "stomping"]]

"""Free-text feedback: "land more gently" -> [(softness, more)], with the shipped sentence model.

A sentence embedding tells *which* attribute a phrase is about well, but not which way: antonyms
("longer steps" / "shorter steps") embed almost alike. So the sentence is cut into clauses (at
"and", "but", commas; "rather than", "instead of" and "without" start a negated clause), each
clause's direction words are read as rules ("less", "not", "too", "reduce" flip it; "more",
"increase" keep it), and what is left is embedded against the domain's anchor phrases
(:class:`rba.domains.base.FeedbackPhrases`): the best attribute wins if it is close enough. Its
direction comes from the clause's cue words (stems found in one side's anchors only: "stomp" is
less softness), else from the side of the attribute's more/less axis the clause lies on, else
"more" when the clause just names the attribute ("more step size"). One encode per request; anchor
embeddings are computed once per set of anchors (a domain and its views share one).

A sentence read with a low confidence also gets its second likeliest reading, so a person can choose
(decision 0021): the weakest clause read as the runner-up attribute when that one scored within a cue
bonus of the best (one cue word would have swapped them), else as the same attribute the other way.
"""

from __future__ import annotations

import logging
import re
import threading
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, replace
from functools import cache

import numpy as np

from rba.domains.base import Domain, FeedbackPhrases
from rba.learn.embed import sentence_embeddings

log = logging.getLogger(__name__)
MAX_TEXT = 200  # characters: a sentence or two, not an essay
# tuned on tests/data/interpret_phrasings.json's "val" set only (never on "test"): the lowest clause
# score accepted, and what a cue word of an attribute adds to that attribute's score
THRESHOLD = 0.40
CUE_BONUS = 0.15
LOW_CONFIDENCE = 0.60  # below it, the second likeliest reading is offered too (decision 0021)
EXAMPLES = 3  # example sentences per domain, at most: one per attribute

Encode = Callable[[list[str]], np.ndarray]  # texts -> float32[n, E], L2-normalised rows

FLIPS = frozenset({"not", "no", "never", "less", "fewer", "too", "enough", "stop", "avoid", "reduce", "decrease",
                   "lower", "lessen", "minimise", "minimize", "quit", "_flip_"})
KEEPS = frozenset({"more", "increase", "raise", "boost", "add", "higher", "greater", "extra", "maximise",
                   "maximize"})
FILLERS = frozenset({"please", "just", "really", "very", "quite", "so", "slightly", "somewhat", "even", "way",
                     "much", "lot", "bit", "tad", "maybe", "try", "little_bit"})
SEPARATORS = frozenset({",", ";", ".", "!", "?", "and", "but", "while", "whilst", "yet", "though", "although",
                        "plus", "also", "however", "then"})
FUNCTION_WORDS = frozenset({"the", "a", "an", "to", "of", "in", "on", "at", "with", "its", "it", "your", "each",
                            "and", "for", "from", "into", "as", "is", "be", "by"})
_REWRITES = (  # (pattern, replacement) on the lower-cased text, in order
    (r"n't\b", " not"), (r"\bcan not\b", "cannot"),
    (r"\b(?:rather than|instead of|without)\b", " _neg_ "),
    (r"\b(?:tone|dial|calm|cut|ease) (?:it |things |that )?(?:down|back)(?: on)?\b", " _flip_ "),
    (r"\bback off(?: on)?\b", " _flip_ "),
    (r"\bnot too\b", "too"),
    (r"\b(?:a little bit|a little|a bit|a lot|a tad|a touch|kind of|sort of)\b", " "),
    (r"\b(back|up|in|to) and (forth|down|out|fro)\b", r"\1_and_\2"),
    (r"\bwith (?=(?:more|less|fewer|no|a|_flip_)\b)", ", "),  # "faster with less shaking": two clauses
)
_SUFFIXES = ("ingly", "ily", "iest", "ier", "ies", "ied", "ing", "edly", "ed", "est", "er", "ly", "es", "s", "y",
             "e")
_Y_SUFFIXES = frozenset({"ily", "iest", "ier", "ies", "ied"})  # "heavier" -> "heavy"
_MIN_BASE = {"ed": 4, "s": 4, "es": 4, "y": 4}  # "speed", "gas", "tiny" stay whole
_VOWELS = "aeiou"


def _undouble(base: str) -> str:
    """"bigg" -> "big", "slamm" -> "slam" (never "ll", "ss": "small", "less")."""
    return base[:-1] if len(base) > 3 and base[-1] == base[-2] and base[-1] not in _VOWELS + "ls" else base


def stem(word: str) -> str:
    """A crude stemmer, enough to match "stompier", "stomping" and "stomps" to "stomp"; no dictionary.

    A "-le" word loses its "l" too, so that "gentle" and "gently", "wobble" and "wobbly" meet.
    """
    while True:
        for suffix in _SUFFIXES:
            base = word[: -len(suffix)]
            if word.endswith(suffix) and len(base) >= _MIN_BASE.get(suffix, 3):
                word = base + "y" if suffix in _Y_SUFFIXES else _undouble(base)
                break
        else:
            if len(word) > 3 and word[-1] == "l" and word[-2] not in _VOWELS + "lrw":
                return _undouble(word[:-1])
            return word


@dataclass(frozen=True)
class Clause:
    """One clause of a sentence: its content words and how many times its direction flips."""

    words: tuple[str, ...]
    flips: int

    @property
    def text(self) -> str:
        return " ".join(self.words).replace("_", " ")


def _tokens(text: str) -> list[str]:
    text = text.lower().replace("’", "'")
    for pattern, replacement in _REWRITES:
        text = re.sub(pattern, replacement, text)
    return re.findall(r"[a-z_]+|[,;.!?]", text)


def clauses(text: str) -> list[Clause]:
    """The sentence's clauses with content words; clauses with none ("more, please") are left out."""
    out: list[Clause] = []
    words: list[str] = []
    flips = 0

    def close() -> None:
        if words:
            out.append(Clause(tuple(words), flips))

    for token in _tokens(text):
        if token in SEPARATORS or token == "_neg_":
            close()
            words, flips = [], int(token == "_neg_")
        elif token in FLIPS:
            flips += 1
        elif token not in KEEPS and token not in FILLERS:
            words.append(token)
    close()
    return out


def content_stems(phrase: str) -> set[str]:
    return {stem(w) for c in clauses(phrase) for w in c.words if w not in FUNCTION_WORDS}


@dataclass(frozen=True)
class Understood:
    """What a sentence asks for: (attribute, "more" | "less") pairs in the sentence's order."""

    feedback: tuple[tuple[str, str], ...]
    confidence: float  # the weakest understood clause's score (cosine similarity plus cue bonus), in [0, 1]
    second: tuple[tuple[str, str], ...] | None = None  # the second likeliest reading, if there is one

    @property
    def low_confidence(self) -> bool:
        return self.confidence < LOW_CONFIDENCE

    @property
    def alternatives(self) -> list[tuple[tuple[str, str], ...]]:
        """The two likeliest readings, likeliest first, for a person to choose from when unsure; else none."""
        return [self.feedback, self.second] if self.low_confidence and self.second is not None else []


class NotUnderstood(ValueError):
    """No clause of the sentence was close enough to any attribute."""

    def __init__(self, text: str, attributes: Sequence[str]) -> None:
        names = [a.replace("_", " ") for a in attributes]  # as the page shows them
        super().__init__(f"I didn't understand {text.strip()!r}; the attributes are: {', '.join(names)}. "
                         f"Try e.g. 'more {names[0]}' or 'less {names[-1]}'.")


@dataclass(frozen=True)
class _Attribute:
    """One attribute's anchors: rows of the anchor matrix, cue stems per side and its more/less axis."""

    name: str
    rows: slice  # names, then more, then less
    n_names: int
    n_more: int
    more_cues: frozenset[str]
    less_cues: frozenset[str]
    axis: np.ndarray | None  # unit vector from the less anchors' mean to the more anchors' mean
    offset: float  # the axis coordinate halfway between the two means


def _cues(phrases: FeedbackPhrases, name: str) -> tuple[frozenset[str], frozenset[str]]:
    """Stems on one side only (and not naming the attribute): that side's cue words."""
    more = set().union(*map(content_stems, phrases.more)) if phrases.more else set()
    less = set().union(*map(content_stems, phrases.less)) if phrases.less else set()
    names = set().union(*map(content_stems, (name, *phrases.names)))
    return frozenset(more - less - names), frozenset(less - more - names)


class Interpreter:
    """Maps sentences to attribute feedback for one domain's attributes (pure: ``encode`` is given)."""

    def __init__(self, phrases: Sequence[tuple[str, FeedbackPhrases]], encode: Encode = sentence_embeddings,
                 threshold: float = THRESHOLD, cue_bonus: float = CUE_BONUS) -> None:
        self.encode, self.threshold, self.cue_bonus = encode, threshold, cue_bonus
        texts: list[str] = []
        self.attributes: list[_Attribute] = []
        for name, p in phrases:
            names = (name.replace("_", " "), *p.names)
            start = len(texts)
            texts += [*names, *p.more, *p.less]
            self.attributes.append(_Attribute(name, slice(start, len(texts)), len(names), len(p.more),
                                              *_cues(p, name), None, 0.0))
        self.anchors = encode(texts)
        self.attributes = [self._with_axis(a) for a in self.attributes]

    @classmethod
    def for_domain(cls, domain: Domain, encode: Encode = sentence_embeddings) -> Interpreter:
        return cls(anchors(domain), encode)

    def _with_axis(self, a: _Attribute) -> _Attribute:
        rows = self.anchors[a.rows]
        more, less = rows[a.n_names: a.n_names + a.n_more], rows[a.n_names + a.n_more:]
        if not len(more) or not len(less):
            return a
        axis = more.mean(0) - less.mean(0)
        axis /= np.linalg.norm(axis) or 1.0
        return replace(a, axis=axis, offset=float(axis @ (more.mean(0) + less.mean(0)) / 2))

    @property
    def names(self) -> list[str]:
        return [a.name for a in self.attributes]

    def interpret(self, text: str) -> Understood:
        """The feedback ``text`` asks for; :class:`NotUnderstood` when no clause is close enough."""
        parts = clauses(text)
        if not parts:
            raise NotUnderstood(text, self.names)
        vectors = self.encode([c.text for c in parts])  # the request's one encode
        found: dict[str, _Match] = {}  # attribute -> its clearest clause's match, first mention first
        for clause, vector in zip(parts, vectors, strict=True):
            match = self._match(clause, vector)
            if match is not None and (match.attribute not in found or found[match.attribute].score < match.score):
                found[match.attribute] = match  # a contradiction keeps the clearer clause
        if not found:
            raise NotUnderstood(text, self.names)
        feedback = tuple((a, m.direction) for a, m in found.items())
        weakest = min(found.values(), key=lambda m: m.score)
        second = None  # the sentence with its weakest clause read the second likeliest way
        if weakest.second[0] == weakest.attribute or weakest.second[0] not in found:
            second = tuple(weakest.second if a == weakest.attribute else (a, d) for a, d in feedback)
        return Understood(feedback, weakest.score, second)

    def _match(self, clause: Clause, vector: np.ndarray) -> _Match | None:
        """The clause's closest attribute, its direction and its second likeliest reading; None below the
        threshold."""
        stems = {stem(w) for w in clause.words}
        sims = self.anchors @ vector
        ranked: list[tuple[float, int, tuple[int, int]]] = []  # (score, attribute index, cue hits), best first
        for i, a in enumerate(self.attributes):
            hits = (len(stems & a.more_cues), len(stems & a.less_cues))
            ranked.append((float(sims[a.rows].max()) + self.cue_bonus * (hits != (0, 0)), i, hits))
        ranked.sort(reverse=True)
        if not ranked or ranked[0][0] < self.threshold:
            return None

        def reading(rank: int, turn: int = 1) -> tuple[str, str]:
            _, i, hits = ranked[rank]
            a = self.attributes[i]
            sign = self._direction(a, sims[a.rows], hits, vector) * (-1) ** clause.flips * turn
            return a.name, "more" if sign > 0 else "less"

        close = len(ranked) > 1 and ranked[0][0] - ranked[1][0] < self.cue_bonus
        best = reading(0)
        return _Match(*best, min(ranked[0][0], 1.0), reading(1) if close else reading(0, -1))

    @staticmethod
    def _direction(a: _Attribute, sims: np.ndarray, hits: tuple[int, int], vector: np.ndarray) -> int:
        """+1 / -1 before the clause's flips: cue words, else naming the attribute, else the axis side."""
        if hits[0] != hits[1]:
            return 1 if hits[0] > hits[1] else -1
        if a.axis is None or sims[: a.n_names].max() >= sims[a.n_names:].max():
            return 1
        return 1 if float(vector @ a.axis) >= a.offset else -1


@dataclass(frozen=True)
class _Match:
    """How one clause was read: the attribute, its direction, the score, and the second likeliest reading."""

    attribute: str
    direction: str
    score: float
    second: tuple[str, str]


Anchors = tuple[tuple[str, FeedbackPhrases], ...]


def anchors(domain: Domain) -> Anchors:
    """The domain's attributes with their anchor phrases (none: matched by name), in the domain's order."""
    empty = FeedbackPhrases((), ())
    return tuple((a.name, domain.feedback_phrases.get(a.name, empty)) for a in domain.attributes)


def examples(domain: Domain) -> list[str]:
    """Sentences to show a person what to type, from the domain's own anchors (read back exactly): the first
    anchor of one attribute each, sides alternating less / more; an attribute without anchors by its name."""
    out = []
    for i, (name, phrases) in enumerate(anchors(domain)[:EXAMPLES]):
        side = phrases.more if i % 2 else phrases.less
        out.append(side[0] if side else f"{'more' if i % 2 else 'less'} {name.replace('_', ' ')}")
    return out


_build_lock = threading.Lock()


@cache
def _interpreter(phrases: Anchors) -> Interpreter:
    return Interpreter(phrases)


def interpreter_for(domain: Domain) -> Interpreter:
    """The domain's interpreter, built once per process (the sentence model and the anchors' one encode); a
    caller while another builds waits for that build rather than starting its own."""
    with _build_lock:
        return _interpreter(anchors(domain))


def load_in_background(domains: Iterable[Domain]) -> threading.Thread:
    """Build ``domains``' interpreters in a daemon thread, in order: loading the sentence model takes seconds
    (tens on a busy machine), so a server does it at start-up, and its first sentence is read as fast as the
    next ones."""
    def load() -> None:
        try:
            for domain in domains:
                interpreter_for(domain)
        except Exception:  # a request then tries again and answers the error
            log.exception("loading the sentence model or a domain's anchors failed")

    thread = threading.Thread(target=load, name="rba-sentence-model", daemon=True)
    thread.start()
    return thread


def understood(interpreter: Interpreter, text: str) -> frozenset[str]:
    """The pairs ``text`` maps to as ``"attribute:direction"`` strings; empty when not understood (for scoring)."""
    try:
        return frozenset(f"{a}:{d}" for a, d in interpreter.interpret(text).feedback)
    except NotUnderstood:
        return frozenset()

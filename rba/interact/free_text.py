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
embeddings are computed once per domain.
"""

from __future__ import annotations

import re
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from functools import cache

import numpy as np

from rba.domains.base import Domain, FeedbackPhrases
from rba.learn.embed import sentence_embeddings

MAX_TEXT = 200  # characters: a sentence or two, not an essay
# tuned on tests/data/interpret_phrasings.json's "val" set only (never on "test"): the lowest clause
# score accepted, and what a cue word of an attribute adds to that attribute's score
THRESHOLD = 0.40
CUE_BONUS = 0.15

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


def stem(word: str) -> str:
    """A crude stemmer, enough to match "stompier", "stomping" and "stomps" to "stomp"; no dictionary."""
    while True:
        for suffix in _SUFFIXES:
            base = word[: -len(suffix)]
            if word.endswith(suffix) and len(base) >= _MIN_BASE.get(suffix, 3):
                if suffix in _Y_SUFFIXES:
                    base += "y"
                elif len(base) > 3 and base[-1] == base[-2] and base[-1] not in "aeiouls":
                    base = base[:-1]  # "bigg" -> "big", "slamm" -> "slam"
                word = base
                break
        else:
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
        empty = FeedbackPhrases((), ())
        return cls([(a.name, domain.feedback_phrases.get(a.name, empty)) for a in domain.attributes], encode)

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
        found: dict[str, tuple[str, float]] = {}  # attribute -> (direction, score), first mention first
        for clause, vector in zip(parts, vectors, strict=True):
            match = self._match(clause, vector)
            if match is not None and (match[0] not in found or found[match[0]][1] < match[2]):
                found[match[0]] = match[1:]  # a contradiction keeps the clearer clause
        if not found:
            raise NotUnderstood(text, self.names)
        return Understood(tuple((a, d) for a, (d, _) in found.items()), min(s for _, s in found.values()))

    def _match(self, clause: Clause, vector: np.ndarray) -> tuple[str, str, float] | None:
        """(attribute, direction, score) of the clause's closest attribute, or None below the threshold."""
        stems = {stem(w) for w in clause.words}
        sims = self.anchors @ vector
        best: tuple[float, _Attribute, tuple[int, int]] | None = None
        for a in self.attributes:
            hits = (len(stems & a.more_cues), len(stems & a.less_cues))
            score = float(sims[a.rows].max()) + self.cue_bonus * (hits != (0, 0))
            if best is None or score > best[0]:
                best = (score, a, hits)
        if best is None or best[0] < self.threshold:
            return None
        score, a, hits = best
        sign = self._direction(a, sims[a.rows], hits, vector) * (-1) ** clause.flips
        return a.name, "more" if sign > 0 else "less", min(score, 1.0)

    @staticmethod
    def _direction(a: _Attribute, sims: np.ndarray, hits: tuple[int, int], vector: np.ndarray) -> int:
        """+1 / -1 before the clause's flips: cue words, else naming the attribute, else the axis side."""
        if hits[0] != hits[1]:
            return 1 if hits[0] > hits[1] else -1
        if a.axis is None or sims[: a.n_names].max() >= sims[a.n_names:].max():
            return 1
        return 1 if float(vector @ a.axis) >= a.offset else -1


_build_lock = threading.Lock()


@cache
def _interpreter(domain: Domain) -> Interpreter:
    return Interpreter.for_domain(domain)


def interpreter_for(domain: Domain) -> Interpreter:
    """The domain's interpreter, built once per process (the sentence model and the anchors' one encode)."""
    with _build_lock:
        return _interpreter(domain)


def understood(interpreter: Interpreter, text: str) -> frozenset[str]:
    """The pairs ``text`` maps to as ``"attribute:direction"`` strings; empty when not understood (for scoring)."""
    try:
        return frozenset(f"{a}:{d}" for a, d in interpreter.interpret(text).feedback)
    except NotUnderstood:
        return frozenset()

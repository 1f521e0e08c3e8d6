"""What an agent would show next for a given state and feedback, computed on a copy and memoised.

Agents are restored from their JSON state for every computation, so the session's stored
state is never mutated by a guess. Results are keyed by (model, state hash, feedback):
prerendering computes them while the person watches, and the real feedback request then
finds its answer already there. Sessions in the same state (every session starts in the
same state) share entries. A step that searched (a generating session) is time-bounded
(``RBA_GENERATE_SECONDS``), so it depends on how busy the machine was: its memo entry keeps what that
first search found, and another replica may find another clip for the same state and answer.
"""

from __future__ import annotations

import copy
import hashlib
import json
import threading
from collections import OrderedDict
from typing import Any

from rba.core.methods import Method
from rba.interact import SATISFIED, Agent, Feedback

FeedbackKey = tuple[tuple[str, int], ...] | str


def state_hash(state: dict) -> str:
    return hashlib.sha256(json.dumps(state, sort_keys=True, separators=(",", ":")).encode()).hexdigest()[:32]


def feedback_key(feedback: Feedback) -> FeedbackKey:
    if feedback == SATISFIED:
        return SATISFIED
    return tuple(sorted((fb.attribute, fb.direction) for fb in feedback))


class Transitions:
    """An LRU memo of agent steps: (context, state, feedback) -> (next rollout id, next state)."""

    def __init__(self, maxsize: int = 4096) -> None:
        self.maxsize = maxsize
        self._memo: OrderedDict[tuple, tuple[str, dict]] = OrderedDict()
        self._lock = threading.Lock()
        self.hits = 0
        self.misses = 0

    @staticmethod
    def _context_key(ctx: Any, method: Method) -> tuple:
        """What names a context and the agent stepping it: a method's generating form steps otherwise than its
        base, over the same models (copies of one context made per step share their key)."""
        return ctx.domain, method.name, ctx.rep, ctx.model_version, method.agent

    def _key(self, ctx: Any, method: Method, state: dict, feedback: Feedback) -> tuple:
        return (*self._context_key(ctx, method), state_hash(state), feedback_key(feedback))

    def first(self, ctx: Any, method: Method) -> tuple[str, dict]:
        """A new agent's first rollout and state (agents are deterministic: every session starts alike)."""
        key = (*self._context_key(ctx, method), "first")
        with self._lock:
            hit = self._memo.get(key)
            if hit is not None:
                self.hits += 1
                return hit[0], copy.deepcopy(hit[1])
        agent = method.agent(ctx)
        rollout_id = agent.first_query()
        state = json.loads(json.dumps(agent.state_dict()))
        with self._lock:
            self.misses += 1
            self._memo[key] = (rollout_id, state)
        return rollout_id, copy.deepcopy(state)

    def advance(self, ctx: Any, method: Method, state: dict, feedback: Feedback, memo: bool = True
                ) -> tuple[str, dict]:
        """The next rollout id and agent state after ``feedback``; raises ValueError for bad feedback.

        ``memo=False`` (walking the shared trees) neither reads nor fills the memo: those steps are used once,
        and would push out the steps the sessions' next answers need.
        """
        if not memo:
            return self._step(ctx, method, state, feedback)
        key = self._key(ctx, method, state, feedback)
        with self._lock:
            hit = self._memo.get(key)
            if hit is not None:
                self._memo.move_to_end(key)
                self.hits += 1
                return hit[0], copy.deepcopy(hit[1])
        rollout_id, new_state = self._step(ctx, method, state, feedback)
        with self._lock:
            self.misses += 1
            self._memo[key] = (rollout_id, new_state)
            while len(self._memo) > self.maxsize:
                self._memo.popitem(last=False)
        return rollout_id, copy.deepcopy(new_state)

    @staticmethod
    def _step(ctx: Any, method: Method, state: dict, feedback: Feedback) -> tuple[str, dict]:
        agent = restore_agent(method, copy.deepcopy(state), ctx)
        rollout_id = agent.update(feedback)
        return rollout_id, json.loads(json.dumps(agent.state_dict()))  # exactly what the database will hold


def restore_agent(method: Method, state: dict, ctx: Any) -> Agent:
    """The agent of ``state`` as ``method`` (a registered method, or its generating form) steps it over ``ctx``."""
    return method.agent.from_state(state, ctx)

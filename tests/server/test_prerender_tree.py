"""The shared answer tree: walked best-first by the share of sessions expected at each node."""

from __future__ import annotations

from fastapi.testclient import TestClient

from rba.core.methods import get_method
from server.main import create_app
from server.ops.prerender import AnswerCounts, answer_order, first_steps, tree_clips
from tests.server.conftest import more


def _walk(svc, counts, starts, min_share):
    """The clips in the order the tree yields them."""
    return list(tree_clips(svc, counts, starts, min_share, lambda: False))


def test_an_unvisited_tree_is_walked_breadth_first(make_settings, local_compute):
    with TestClient(create_app(make_settings(), local_compute)) as client:
        svc = client.app.state.services
        starts = first_steps(svc)
        assert [s[0][:3] for s in starts] == [("toy", "global", "onehot")]
        (key, first, state), = starts
        ctx = svc.catalog.context(*key)
        answers = answer_order(ctx.attribute_names, None)
        depth1 = [svc.transitions.advance(ctx, get_method("global"), state, a)[0] for a in answers]
        counts = AnswerCounts.load(svc)
        clips = _walk(svc, counts, starts, 1 / len(answers) ** 2)  # down to depth 2, nothing deeper
        assert clips[0].rollout_id == first and clips[1:1 + len(answers)] == [(key[0], r) for r in depth1]
        assert len(clips) == 1 + len(answers) + len(answers) ** 2


def test_what_sessions_answered_comes_first(make_settings, local_compute):
    with TestClient(create_app(make_settings(), local_compute)) as client:
        svc = client.app.state.services
        for _ in range(3):  # three people all said "less pace" first
            s = client.post("/api/sessions", json={"domain": "toy"}).json()
            assert client.post(f"/api/sessions/{s['id']}/feedback", json=more("pace", 0, "less")).status_code == 200
        counts = AnswerCounts.load(svc)
        starts = first_steps(svc)
        (key, _, state), = starts
        assert counts.sessions[key] == 3 and counts.after[key, ()][(("pace", -1),)] == 3
        ctx = svc.catalog.context(*key)
        answers = answer_order(ctx.attribute_names, None)
        less_pace = next(a for a in answers if [(f.attribute, f.direction) for f in a] == [("pace", -1)])
        _, after_less = svc.transitions.advance(ctx, get_method("global"), state, less_pace)
        favourite = [svc.transitions.advance(ctx, get_method("global"), after_less, a)[0] for a in answers]
        clips = [c.rollout_id for c in _walk(svc, counts, starts, 1e-3)]
        # the visited branch's children come right after depth 1, before any other depth-2 node
        assert clips[1 + len(answers):1 + 2 * len(answers)] == favourite

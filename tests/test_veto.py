"""A veto gives what the panel said: the next proposal is the best remaining alternative the vetoed one listed,
never the same block, and its score is on the scale the table showed. Run through the real engine."""

from __future__ import annotations

import math
from collections.abc import Callable

import pytest

from aeni_console.testkit.live import LiveRun
from core.plan import Decision
from core.runview import Command, CommandKind

LiveRunFactory = Callable[..., LiveRun]


def waiting_past_the_seeds(run: LiveRun) -> Decision:
    while True:
        snap = run.until_awaiting()
        assert snap.pending is not None
        if snap.pending.phase != "seed" and snap.pending.alternatives:
            return snap.pending
        run.send(Command(CommandKind.APPROVE, "script"))


def next_decision(run: LiveRun, after: Decision) -> Decision:
    """The decision the engine made for the same block after the veto (waiting, or already running)."""
    snap = run.snapshot()
    new = snap.pending if snap.pending is not None else snap.last_decision
    assert new is not None and new.block.block_id == after.block.block_id
    return new


@pytest.mark.parametrize("policy", ["cost-aware", "aeni"])
def test_a_veto_brings_the_listed_next_best(live_run: LiveRunFactory, policy: str) -> None:
    run = live_run(policy=policy)
    first = waiting_past_the_seeds(run)
    vetoed: list[tuple[float, float]] = []
    for _ in range(3):  # veto after veto: each time the block the table listed first
        listed = first.alternatives[0]
        # one scale: the table's scores are gains per second of a block, like the headline
        assert all(a.score <= first.score * 1.5 for a in first.alternatives)
        out = run.send(Command(CommandKind.VETO, "operator", {"block_id": first.block.block_id}))
        assert out["outcome"] == "accepted"
        vetoed.append((first.block.center_x_um, first.block.center_y_um))
        new = next_decision(run, first)
        centre = (new.block.center_x_um, new.block.center_y_um)
        assert centre not in vetoed and new.block.indents != first.block.indents
        assert centre == pytest.approx((listed.center_x_um, listed.center_y_um))
        assert new.block.kind == listed.kind
        assert math.isclose(new.score, listed.score, rel_tol=0.25), (new.score, listed.score)
        if run.snapshot().pending is None or not new.alternatives:
            break  # the new proposal is already running (a stay in supervised mode)
        first = new

"""The approval countdown (issue 23): with ``approval_timeout_s`` the console shows how long a waiting
decision has and what the engine will do then; the deadline travels in the engine's ApprovalAsked event,
and the countdown goes on between snapshots until the engine answers the decision itself."""

from __future__ import annotations

from collections.abc import Callable

from aeni_console.console.app import ConsoleApp
from aeni_console.testkit.live import LiveRun, settle, wait_until, widget_text
from core.journal import JournalReader
from core.runview import EngineState

LiveRunFactory = Callable[..., LiveRun]


async def test_the_countdown_runs_and_the_engine_answers_at_zero(live_run: LiveRunFactory) -> None:
    run = live_run(approval_timeout_s=30.0, on_timeout="approve")
    snap = run.snapshot()
    assert snap.state is EngineState.AWAITING_APPROVAL and snap.pending is not None
    assert snap.approval_deadline is not None and snap.approval_deadline.on_timeout == "approve"
    waited = [0.0]  # the console's wall clock runs on from the journal's while the run waits
    app = ConsoleApp(
        run.source(),
        poll_s=0.02,
        max_rate_hz=50.0,
        clock=lambda: run.clock.time() + waited[0],
        author="tester",
        cursor_blink=False,
    )
    async with app.run_test(size=(100, 30)) as pilot:
        await settle(pilot)
        panel = app.query_one("#decision")
        assert "answer in 0:30 → approve" in widget_text(panel)
        waited[0] = 12.0  # no new snapshot: the countdown goes on by itself
        await wait_until(pilot, lambda: "answer in 0:18 → approve" in widget_text(panel), what="countdown")
        run.pass_wall_time(31.0)  # nobody answers: the engine approves the block itself
        await wait_until(
            pilot,
            lambda: app.snapshot is not None and app.snapshot.state is EngineState.RUNNING,
            what="timeout",
        )
        await settle(pilot)
        assert app.snapshot is not None and app.snapshot.approval_deadline is None
        assert "answer in" not in widget_text(panel)
        assert any("timed out" in e.text for e in app.snapshot.log)
    with JournalReader(run.path) as r:
        first = r.decisions()[0]
    assert first.decision.block == snap.pending.block and first.status == "approved"


async def test_no_countdown_without_a_timeout(live_run: LiveRunFactory) -> None:
    run = live_run()
    snap = run.snapshot()
    assert snap.state is EngineState.AWAITING_APPROVAL and snap.approval_deadline is None

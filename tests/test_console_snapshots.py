"""SVG snapshots of the main screens (pytest-textual-snapshot), from fixed fake data and a fixed clock.

Update after an intended change of the look: pytest tests/test_console_snapshots.py --snapshot-update
"""

from __future__ import annotations

import time
from collections.abc import Iterator

import pytest

from aeni_console.app import ConsoleApp
from aeni_console.fake import FakeRun, run_fake
from aeni_console.testing import settle, wait_until
from aeni_console.widgets.adjust import AdjustScreen
from aeni_console.widgets.help import HelpScreen
from core.runview import Command, CommandKind, EngineState


@pytest.fixture(autouse=True)
def utc(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    monkeypatch.setenv("TZ", "UTC")
    monkeypatch.delenv("NO_COLOR", raising=False)
    time.tzset()
    yield
    monkeypatch.undo()
    time.tzset()


def waiting_run() -> FakeRun:
    """Supervised fake: seven blocks done, a global jump waiting for approval."""
    run = FakeRun(seed=0)
    for _ in range(400):
        if run.state is EngineState.AWAITING_APPROVAL:
            if len(run.tested) >= 7:
                break
            run.send(Command(CommandKind.APPROVE, "operator"))
        run.advance()
    assert run.state is EngineState.AWAITING_APPROVAL
    return run


def console(run: FakeRun, **kw: object) -> ConsoleApp:
    return ConsoleApp(
        run, poll_s=0.02, max_rate_hz=50.0, clock=lambda: 0.0, author="operator", cursor_blink=False, **kw
    )  # type: ignore[arg-type]


async def ready(pilot) -> None:  # type: ignore[no-untyped-def]
    app = pilot.app
    if app.replay_mode:
        await wait_until(
            pilot, lambda: app.replay_count > 0 and app.snapshot is not None, what="replay loaded"
        )
    await settle(pilot)
    app.clear_notifications()
    await pilot.pause()


def test_awaiting_approval_100x30(snap_compare) -> None:  # type: ignore[no-untyped-def]
    assert snap_compare(console(waiting_run()), terminal_size=(100, 30), run_before=ready)


def test_awaiting_approval_80x24(snap_compare) -> None:  # type: ignore[no-untyped-def]
    assert snap_compare(console(waiting_run()), terminal_size=(80, 24), run_before=ready)


def test_running_epistemic_map(snap_compare) -> None:  # type: ignore[no-untyped-def]
    run = run_fake(9, seed=1)
    run.advance(1)  # the next block is under way

    async def before(pilot) -> None:  # type: ignore[no-untyped-def]
        await ready(pilot)
        await pilot.press("m")
        await settle(pilot)

    assert snap_compare(console(run), terminal_size=(100, 30), run_before=before)


def test_adjust_form(snap_compare) -> None:  # type: ignore[no-untyped-def]
    async def before(pilot) -> None:  # type: ignore[no-untyped-def]
        await ready(pilot)
        await pilot.press("e")
        await wait_until(pilot, lambda: isinstance(pilot.app.screen, AdjustScreen), what="form")
        pilot.app.screen.query_one("#f-target_sem_gpa").value = "0"
        pilot.app.screen.validate_form()
        await pilot.pause()

    assert snap_compare(console(waiting_run()), terminal_size=(100, 30), run_before=before)


def test_help(snap_compare) -> None:  # type: ignore[no-untyped-def]
    async def before(pilot) -> None:  # type: ignore[no-untyped-def]
        await ready(pilot)
        await pilot.press("question_mark")
        await wait_until(pilot, lambda: isinstance(pilot.app.screen, HelpScreen), what="help")
        await pilot.pause()

    assert snap_compare(console(waiting_run()), terminal_size=(100, 30), run_before=before)


def test_replay(snap_compare) -> None:  # type: ignore[no-untyped-def]
    run = run_fake(6, seed=2)

    async def before(pilot) -> None:  # type: ignore[no-untyped-def]
        await ready(pilot)
        await pilot.press("left")
        await wait_until(pilot, lambda: pilot.app.snapshot.n_blocks == 5, what="one block back")
        await settle(pilot)

    assert snap_compare(console(run, replay=True), terminal_size=(100, 30), run_before=before)

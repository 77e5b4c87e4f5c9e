"""SVG snapshots of the main screens (pytest-textual-snapshot), from the real engine and a fixed clock.

Each run is ``aeni_console.testkit.live.LiveRun`` (the real engine, a seeded emulator, the journal's wall
clock tied to the instrument clock), so the screens repeat exactly. Update after an intended change of
the look: pytest tests/test_console_snapshots.py --snapshot-update
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from aeni_console.console.app import ConsoleApp
from aeni_console.console.feed import RunSource
from aeni_console.console.widgets.adjust import AdjustScreen
from aeni_console.console.widgets.help import HelpScreen
from aeni_console.testkit.live import LiveRun, settle, wait_until
from core.runview import Command, CommandKind

LiveRunFactory = Callable[..., LiveRun]


@pytest.fixture(autouse=True)
def utc(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    monkeypatch.setenv("TZ", "UTC")
    monkeypatch.delenv("NO_COLOR", raising=False)
    time.tzset()
    yield
    monkeypatch.undo()
    time.tzset()


@pytest.fixture(scope="module")
def waiting(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LiveRun]:
    """Supervised: the operator approved every jump until seven blocks were done; a global jump waits.

    One run for the screens that only look at it (they send no command), so it is built once.
    """
    with LiveRun(tmp_path_factory.mktemp("waiting"), name="run0") as run:
        while run.until_awaiting().n_blocks < 7:
            run.send(Command(CommandKind.APPROVE, "operator"))
        yield run


def auto_run(live_run: LiveRunFactory, blocks: int) -> LiveRun:
    run = live_run(supervision="auto")
    for _ in range(blocks):
        run.finish_block()
    return run


def console(source: RunSource, **kw: Any) -> ConsoleApp:
    return ConsoleApp(
        source, poll_s=0.02, max_rate_hz=50.0, clock=lambda: 0.0, author="operator", cursor_blink=False, **kw
    )


async def ready(pilot) -> None:  # type: ignore[no-untyped-def]
    app = pilot.app
    if app.replay_mode:
        await wait_until(
            pilot, lambda: app.replay_count > 0 and app.snapshot is not None, what="replay loaded"
        )
    await settle(pilot)
    app.clear_notifications()
    await pilot.pause()


def test_awaiting_approval_100x30(snap_compare, waiting) -> None:  # type: ignore[no-untyped-def]
    source = waiting.source()
    assert snap_compare(console(source), terminal_size=(100, 30), run_before=ready)


def test_awaiting_approval_80x24(snap_compare, waiting) -> None:  # type: ignore[no-untyped-def]
    source = waiting.source()
    assert snap_compare(console(source), terminal_size=(80, 24), run_before=ready)


def test_running_epistemic_map(snap_compare, live_run) -> None:  # type: ignore[no-untyped-def]
    run = auto_run(live_run, 9)
    run.advance(7)  # the next block is under way

    async def before(pilot) -> None:  # type: ignore[no-untyped-def]
        await ready(pilot)
        await pilot.press("m")
        await settle(pilot)

    assert snap_compare(console(run.source()), terminal_size=(100, 30), run_before=before)


def test_adjust_form(snap_compare, waiting) -> None:  # type: ignore[no-untyped-def]
    async def before(pilot) -> None:  # type: ignore[no-untyped-def]
        await ready(pilot)
        await pilot.press("e")
        await wait_until(pilot, lambda: isinstance(pilot.app.screen, AdjustScreen), what="form")
        pilot.app.screen.query_one("#f-target_sem_gpa").value = "0"
        pilot.app.screen.validate_form()
        await pilot.pause()

    assert snap_compare(console(waiting.source()), terminal_size=(100, 30), run_before=before)


def test_help(snap_compare, waiting) -> None:  # type: ignore[no-untyped-def]
    async def before(pilot) -> None:  # type: ignore[no-untyped-def]
        await ready(pilot)
        await pilot.press("question_mark")
        await wait_until(pilot, lambda: isinstance(pilot.app.screen, HelpScreen), what="help")
        await pilot.pause()

    assert snap_compare(console(waiting.source()), terminal_size=(100, 30), run_before=before)


def test_replay(snap_compare, live_run) -> None:  # type: ignore[no-untyped-def]
    run = auto_run(live_run, 6)
    run.close()  # the run has ended; replay reads its journal

    async def before(pilot) -> None:  # type: ignore[no-untyped-def]
        await ready(pilot)
        await pilot.press("left")
        await wait_until(pilot, lambda: pilot.app.snapshot.n_blocks == 5, what="one block back")
        await settle(pilot)

    assert snap_compare(console(run.replay(), replay=True), terminal_size=(100, 30), run_before=before)


NITICU = Path(__file__).resolve().parents[1] / "docs" / "examples" / "NiTiCu-library-07.toml"


@pytest.fixture(scope="module")
def on_sample(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LiveRun]:
    """The worked example's sample (outline, a round and a polygonal exclusion, earlier indents) under the
    scattered-singles planner; the instrument reported a few indents failed or not run; a proposal waits."""
    from core.sample.load import load_sample

    failed = {(1, 2): "failed", (1, 5): "not_run", (2, 1): "failed", (2, 3): "not_run"}
    with LiveRun(
        tmp_path_factory.mktemp("sample"),
        name="niticu",
        policy="aeni",
        sample=load_sample(NITICU),
        unmeasured=failed,  # type: ignore[arg-type]
    ) as run:
        while run.until_awaiting().n_blocks < 3:
            run.send(Command(CommandKind.APPROVE, "operator"))
        yield run


def test_map_with_a_sample_80x24(snap_compare, on_sample) -> None:  # type: ignore[no-untyped-def]
    assert snap_compare(console(on_sample.source()), terminal_size=(80, 24), run_before=ready)


def test_map_with_a_sample_no_color_100x30(snap_compare, on_sample, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    monkeypatch.setenv("NO_COLOR", "1")
    assert snap_compare(console(on_sample.source()), terminal_size=(100, 30), run_before=ready)

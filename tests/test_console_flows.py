"""Operator flows through the real console (Pilot, headless) against the in-memory fake run."""

from __future__ import annotations

import pytest

from aeni_console.app import ConsoleApp
from aeni_console.fake import FakeRun, run_fake
from aeni_console.testing import settle, wait_until, widget_text
from aeni_console.widgets.adjust import AdjustScreen
from aeni_console.widgets.confirm import ConfirmScreen
from aeni_console.widgets.help import HelpScreen
from aeni_console.widgets.mapview import HeatmapView, MapPanel
from core.runview import Command, CommandKind, EngineState

SIZES = [(100, 30), (80, 24)]


def make_app(run: FakeRun, **kw: object) -> ConsoleApp:
    return ConsoleApp(
        run, poll_s=0.02, max_rate_hz=50.0, clock=lambda: 0.0, author="tester", cursor_blink=False, **kw
    )  # type: ignore[arg-type]


def awaiting(run: FakeRun) -> FakeRun:
    """Advance a supervised fake until it waits for the operator."""
    for _ in range(200):
        if run.state is EngineState.AWAITING_APPROVAL:
            return run
        run.advance()
    raise AssertionError("the fake never asked for approval")


def approve(run: FakeRun) -> None:
    run.send(Command(CommandKind.APPROVE, "script"))


def footer_keys(app: ConsoleApp) -> set[str]:
    """The actions the footer shows right now."""
    return {b.binding.action for b in app.screen.active_bindings.values() if b.binding.show}


@pytest.mark.parametrize("size", SIZES)
async def test_approve_runs_the_proposed_block(size: tuple[int, int]) -> None:
    run = awaiting(FakeRun(seed=1))
    proposed = run.pending
    assert proposed is not None
    app = make_app(run)
    async with app.run_test(size=size) as pilot:
        await settle(pilot)
        assert app.snapshot is not None and app.snapshot.state is EngineState.AWAITING_APPROVAL
        assert {"approve", "veto", "pause"} <= footer_keys(app)
        assert "resume" not in footer_keys(app)
        await pilot.press("a")
        await wait_until(pilot, lambda: len(run.commands) == 1, what="approve reaches the run")
        cmd = run.commands[0]
        assert cmd.kind is CommandKind.APPROVE and cmd.author == "tester"
        assert cmd.payload["block_id"] == proposed.block.block_id
        assert cmd.shown_scores["score"] == pytest.approx(proposed.score)
        await settle(pilot)
        assert app.snapshot.state is EngineState.RUNNING
        assert app.snapshot.current_block == proposed.block
        assert "approve" not in footer_keys(app)
        run.advance(1)
        await settle(pilot)
        first = app.snapshot.tested[0]
        assert (first.x_um, first.y_um) == (proposed.block.center_x_um, proposed.block.center_y_um)


async def test_veto_offers_the_next_best() -> None:
    run = awaiting(FakeRun(seed=2))
    first = run.pending
    assert first is not None
    expected_next = first.alternatives[0]
    app = make_app(run)
    async with app.run_test(size=(100, 30)) as pilot:
        await settle(pilot)
        await pilot.press("v")
        await wait_until(
            pilot, lambda: run.commands and run.commands[-1].kind is CommandKind.VETO, what="veto sent"
        )
        await settle(pilot)
        new = app.snapshot.pending
        assert new is not None and new != first
        assert (new.block.center_x_um, new.block.center_y_um) == (
            expected_next.center_x_um,
            expected_next.center_y_um,
        )
        assert app.snapshot.state is EngineState.AWAITING_APPROVAL
        # the decision panel and the map's "next" marker follow the new proposal
        text = widget_text(app.query_one("#decision"))
        assert f"({new.block.center_x_um:.0f}, {new.block.center_y_um:.0f})" in text
        assert run.commands[-1].payload["center_um"] == [first.block.center_x_um, first.block.center_y_um]


async def test_adjust_target_sem_makes_later_grids_larger() -> None:
    run = awaiting(FakeRun(seed=0))
    assert run.pending is not None and run.pending.block.grid_g == 2
    app = make_app(run)
    async with app.run_test(size=(80, 24)) as pilot:
        await settle(pilot)
        await pilot.press("e")
        await wait_until(pilot, lambda: isinstance(app.screen, AdjustScreen), what="adjust form")
        form = app.screen
        sem = form.query_one("#f-target_sem_gpa")
        sem.value = "-1"  # invalid: refused with a message, nothing sent
        await pilot.press("enter")
        await pilot.pause()
        assert isinstance(app.screen, AdjustScreen)
        assert "target SEM" in widget_text(form.query_one("#adjust-error"))
        sem.value = "0.015"
        await pilot.press("enter")
        await wait_until(pilot, lambda: not isinstance(app.screen, AdjustScreen), what="form closes")
        await wait_until(
            pilot, lambda: any(c.kind is CommandKind.ADJUST for c in run.commands), what="adjust sent"
        )
        adjust = next(c for c in run.commands if c.kind is CommandKind.ADJUST)
        assert adjust.payload == {"target_sem_gpa": 0.015}
        await settle(pilot)
        assert app.snapshot.settings.target_sem_gpa == 0.015
        # like the engine, the proposal already made keeps its grid; the change applies from the next one
        assert app.snapshot.pending is not None and app.snapshot.pending.block.grid_g == 2
        await pilot.press("a")
        await wait_until(pilot, lambda: run.commands[-1].kind is CommandKind.APPROVE, what="approve sent")
        for _ in range(40):
            run.advance()
            if run.state is EngineState.AWAITING_APPROVAL:
                approve(run)
        await settle(pilot)
        assert len(app.snapshot.tested) >= 4
        later = [c.kind for c in run.commands]
        assert later.count(CommandKind.APPROVE) >= 2
        grids = [q.grid_g for q in app.snapshot.queue] + [app.snapshot.last_decision.block.grid_g]
        assert min(grids) >= 3  # σ_noise / 0.015 GPa ≥ 3 everywhere on the ternary library
        queue_text = widget_text(app.query_one("#queue"))
        assert f"  {grids[0]}  " in queue_text


async def test_pause_and_resume() -> None:
    run = FakeRun(supervision="auto", seed=3)
    run.advance(3)
    app = make_app(run)
    async with app.run_test(size=(100, 30)) as pilot:
        await settle(pilot)
        assert "pause" in footer_keys(app) and "resume" not in footer_keys(app)
        await pilot.press("space")
        await wait_until(
            pilot, lambda: run.state in (EngineState.PAUSING, EngineState.PAUSED), what="pause applied"
        )
        run.advance(5)  # the running block finishes, then the engine holds
        await settle(pilot)
        assert app.snapshot.state is EngineState.PAUSED
        assert "resume" in footer_keys(app) and "pause" not in footer_keys(app)
        assert "PAUSED" in widget_text(app.query_one("#status"))
        held = app.snapshot.n_indents
        run.advance(5)
        await settle(pilot)
        assert app.snapshot.n_indents == held  # nothing runs while paused
        await pilot.press("space")
        await wait_until(pilot, lambda: run.state is EngineState.RUNNING, what="resume applied")
        run.advance(5)
        await settle(pilot)
        assert app.snapshot.n_indents > held


async def test_step_mode_runs_one_block_at_a_time() -> None:
    run = awaiting(FakeRun(supervision="supervised", seed=4))
    app = make_app(run)
    async with app.run_test(size=(100, 30)) as pilot:
        await settle(pilot)
        assert "step" in footer_keys(app)
        blocks_before = len(run.tested)
        await pilot.press("s")
        await wait_until(
            pilot, lambda: run.supervision == "step" and run.state is EngineState.RUNNING, what="step"
        )
        kinds = [c.kind for c in run.commands]
        assert kinds == [CommandKind.ADJUST, CommandKind.STEP]
        assert run.commands[0].payload == {"supervision": "step"}
        run.advance(20)  # however long we wait, exactly one block runs
        await settle(pilot)
        assert len(run.tested) == blocks_before + 1
        assert app.snapshot.state is EngineState.AWAITING_APPROVAL and app.snapshot.supervision == "step"
        await pilot.press("s")
        await wait_until(pilot, lambda: run.state is EngineState.RUNNING, what="second step")
        assert run.commands[-1].kind is CommandKind.STEP and len(run.commands) == 3  # no second adjust
        run.advance(20)
        await settle(pilot)
        assert len(run.tested) == blocks_before + 2


async def test_collapse_alarm_waits_for_the_operator() -> None:
    run = FakeRun(supervision="supervised", seed=5, collapse_at_block=1)
    for _ in range(100):  # approve global jumps until the alarm fires
        awaiting(run)
        if run.collapse:
            break
        approve(run)
    assert run.collapse and run.state is EngineState.AWAITING_APPROVAL
    app = make_app(run)
    async with app.run_test(size=(100, 30)) as pilot:
        await settle(pilot)
        assert "COLLAPSE" in widget_text(app.query_one("#status"))
        decision = app.query_one("#decision")
        assert decision.has_class("-alarm")
        assert "length-scale collapse" in widget_text(decision)
        n = len(run.tested)
        run.advance(10)  # the engine does not go on by itself
        assert len(run.tested) == n
        await pilot.press("a")
        await wait_until(pilot, lambda: not run.collapse, what="alarm acknowledged")
        run.advance(3)
        await settle(pilot)
        assert not app.snapshot.gp.collapse_alarm
        assert "COLLAPSE" not in widget_text(app.query_one("#status"))
        assert not decision.has_class("-alarm")


async def test_abort_asks_first_and_stop_after_block() -> None:
    run = FakeRun(supervision="auto", seed=6)
    run.advance(1)  # a block is running
    app = make_app(run)
    async with app.run_test(size=(100, 30)) as pilot:
        await settle(pilot)
        await pilot.press("x")
        await wait_until(pilot, lambda: isinstance(app.screen, ConfirmScreen), what="confirm")
        await pilot.press("n")
        await pilot.pause()
        assert not isinstance(app.screen, ConfirmScreen) and run.commands == []
        await pilot.press("b")
        await wait_until(pilot, lambda: run.state is EngineState.STOPPING, what="stop after block")
        await settle(pilot)
        assert "STOPPING" in widget_text(app.query_one("#status"))
        run.advance(5)
        await settle(pilot)
        assert len(run.tested) == 1  # the running block finished, no other started
        assert app.snapshot.finished and app.snapshot.state is EngineState.STOPPED
        assert not (
            footer_keys(app) & {"pause", "approve", "veto", "adjust", "abort", "step", "stop_after_block"}
        )


async def test_abort_confirmed() -> None:
    run = FakeRun(supervision="auto", seed=6)
    run.advance(2)
    app = make_app(run)
    async with app.run_test(size=(80, 24)) as pilot:
        await settle(pilot)
        await pilot.press("x")
        await wait_until(pilot, lambda: isinstance(app.screen, ConfirmScreen), what="confirm")
        await pilot.press("y")
        await wait_until(pilot, lambda: run.finished, what="abort applied")
        assert [c.kind for c in run.commands] == [CommandKind.ABORT]


async def test_leaving_does_not_stop_the_run() -> None:
    run = FakeRun(supervision="auto", seed=7)
    run.advance(2)
    app = make_app(run)
    async with app.run_test(size=(100, 30)) as pilot:
        await settle(pilot)
        await pilot.press("q")
        await pilot.pause()
    assert run.commands == [] and run.state is EngineState.RUNNING
    assert app.feed is not None and app.feed.stopped


async def test_read_only_viewer_gets_no_command_keys() -> None:
    run = awaiting(FakeRun(seed=8, can_command=False))
    app = make_app(run)
    async with app.run_test(size=(100, 30)) as pilot:
        await settle(pilot)
        keys = footer_keys(app)
        assert not keys & {"approve", "veto", "pause", "adjust", "abort"}
        assert {"cycle_map", "help", "leave"} <= keys
        assert "read-only" in widget_text(app.query_one("#status"))
        await pilot.press("a")
        await pilot.pause()
        assert run.commands == []


async def test_a_refused_command_is_shown_not_fatal() -> None:
    run = awaiting(FakeRun(seed=9))
    app = make_app(run)
    async with app.run_test(size=(100, 30)) as pilot:
        await settle(pilot)
        run.can_command = False  # ownership changed behind the console's back
        await pilot.press("a")
        await wait_until(pilot, lambda: app.inflight is None and app.sent, what="refusal handled")
        await pilot.pause(0.05)
        log_text = " ".join(" ".join(str(line.text) for line in app.query_one("#log").lines).split())
        assert "approve refused" in log_text and "does not own" in log_text


async def test_map_cycles_fields_and_redraws_off_the_ui_thread() -> None:
    run = run_fake(6, seed=10)
    app = make_app(run)
    async with app.run_test(size=(100, 30)) as pilot:
        await settle(pilot)
        panel = app.query_one(MapPanel)
        assert "mean hardness" in str(panel.border_title)
        first = app.query_one(HeatmapView).image
        assert first is not None and first.field_key == "mean"
        seen = []
        for _ in range(4):
            await pilot.press("m")
            await settle(pilot)
            seen.append(app.query_one(HeatmapView).image.field_key)
        assert seen == ["epistemic", "noise", "total", "mean"]
        assert "mean hardness" in str(panel.border_title)
        assert panel.builds >= 5
        # every tested centre is drawn, the newest with its own marker
        plain = app.query_one(HeatmapView)._text.plain
        assert plain.count("◉") == 1


async def test_command_palette_lists_only_valid_commands() -> None:
    run = awaiting(FakeRun(seed=11))
    app = make_app(run)
    async with app.run_test(size=(100, 30)) as pilot:
        await settle(pilot)
        titles = [c.title for c in app.get_system_commands(app.screen)]
        assert "Approve the proposal" in titles and "Veto the proposal" in titles
        assert "Resume the run" not in titles and "Replay: next block" not in titles


async def test_help_screen_opens_and_closes() -> None:
    run = run_fake(2, seed=12)
    app = make_app(run)
    async with app.run_test(size=(80, 24)) as pilot:
        await settle(pilot)
        await pilot.press("question_mark")
        await wait_until(pilot, lambda: isinstance(app.screen, HelpScreen), what="help")
        await pilot.press("escape")
        await wait_until(pilot, lambda: not isinstance(app.screen, HelpScreen), what="help closed")


async def test_replay_steps_forward_and_back() -> None:
    run = run_fake(5, seed=13)
    assert run.n_blocks() == 5
    app = make_app(run, replay=True)
    async with app.run_test(size=(100, 30)) as pilot:
        await wait_until(
            pilot, lambda: app.replay_count == 5 and app.snapshot is not None, what="replay loaded"
        )
        await settle(pilot)
        assert app.replay_index == 4 and app.snapshot.n_blocks == 5
        assert "replay_next" not in footer_keys(app) and "replay_prev" in footer_keys(app)
        assert not footer_keys(app) & {"approve", "pause", "adjust"}
        await pilot.press("left")
        await pilot.press("left")
        await wait_until(pilot, lambda: app.snapshot.n_blocks == 3, what="two blocks back")
        await settle(pilot)
        assert app.replay_index == 2
        assert len(app.snapshot.tested) == 3
        assert app.query_one(MapPanel).fields.snapshot_id == 3
        assert "REPLAY 3/5" in widget_text(app.query_one("#status"))
        await pilot.press("home")
        await wait_until(pilot, lambda: app.snapshot.n_blocks == 1, what="first block")
        assert "replay_prev" not in footer_keys(app)
        await pilot.press("right")
        await wait_until(pilot, lambda: app.snapshot.n_blocks == 2, what="one forward")
        await pilot.press("end")
        await wait_until(pilot, lambda: app.snapshot.n_blocks == 5, what="last block")
        assert run.commands == []


async def test_no_color_map_stays_legible(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("NO_COLOR", "1")
    run = run_fake(4, seed=14)
    app = make_app(run)
    assert app.no_color
    async with app.run_test(size=(100, 30)) as pilot:
        await settle(pilot)
        plain = app.query_one(HeatmapView)._text.plain
        # shading characters carry the levels, letters carry the markers
        assert sum(plain.count(c) for c in "░▒▓") > 50
        assert "@" in plain and "█" in plain

"""Operator flows through the console (Pilot, headless) against the real engine.

Each test starts ``aeni_console.testkit.live.LiveRun``: the real engine, campaign and journal, with the
simulated instrument run an indent at a time by the test. The console reads the run through the same
``JournalSource`` as ``aeni console``, and its keys reach the engine through the journal's command table.
"""

from __future__ import annotations

import contextlib
import json
import threading
from collections.abc import AsyncIterator, Callable
from dataclasses import replace
from typing import Any

import pytest
from textual.pilot import Pilot

from aeni_console.console.app import ConsoleApp
from aeni_console.console.feed import RunSource
from aeni_console.console.journal_source import JournalSource
from aeni_console.console.widgets import mapview
from aeni_console.console.widgets.adjust import AdjustScreen
from aeni_console.console.widgets.confirm import ConfirmScreen
from aeni_console.console.widgets.help import HelpScreen
from aeni_console.console.widgets.mapview import HeatmapView, MapPanel
from aeni_console.testkit.live import CannedSource, LiveRun, settle, wait_until, widget_text
from core.runview import Command, CommandKind, EngineState, RunSnapshot

SIZES = [(100, 30), (80, 24)]
LiveRunFactory = Callable[..., LiveRun]


def make_app(source: RunSource, **kw: Any) -> ConsoleApp:
    return ConsoleApp(
        source, poll_s=0.02, max_rate_hz=50.0, clock=lambda: 0.0, author="tester", cursor_blink=False, **kw
    )


@contextlib.asynccontextmanager
async def attached(
    source: RunSource, size: tuple[int, int], **kw: Any
) -> AsyncIterator[tuple[ConsoleApp, Pilot[None]]]:
    """A console on ``source``, settled on what the run shows now; the source is closed on the way out."""
    app = make_app(source, **kw)
    try:
        async with app.run_test(size=size) as pilot:
            await settle(pilot)
            yield app, pilot
    finally:
        if isinstance(source, JournalSource):
            source.close()


def footer_keys(app: ConsoleApp) -> set[str]:
    """The actions the footer shows right now."""
    return {b.binding.action for b in app.screen.active_bindings.values() if b.binding.show}


def shown(app: ConsoleApp) -> RunSnapshot:
    assert app.snapshot is not None
    return app.snapshot


def commands(run: LiveRun) -> list[dict[str, Any]]:
    """The operator commands the engine received, with what it made of them."""
    return [
        dict(c, payload=json.loads(c["payload_json"]), scores=json.loads(c["shown_scores_json"]))
        for c in run.commands()
    ]


def past_the_seeds(run: LiveRun) -> RunSnapshot:
    """Approve the two seed grids; return the first planned global jump waiting for the operator."""
    while True:
        snap = run.until_awaiting()
        if snap.pending is not None and snap.pending.phase != "seed":
            return snap
        run.send(Command(CommandKind.APPROVE, "script"))
        run.finish_block()


def running_block(run: LiveRun) -> RunSnapshot:
    """Auto supervision, a block under way (a few of its indents done)."""
    run.advance(3)
    snap = run.snapshot()
    assert snap.state is EngineState.RUNNING and snap.current_block is not None
    return snap


@pytest.mark.parametrize("size", SIZES)
async def test_approve_runs_the_proposed_block(live_run: LiveRunFactory, size: tuple[int, int]) -> None:
    run = live_run()
    proposed = run.snapshot().pending
    assert proposed is not None and proposed.is_global_jump
    async with attached(run.source(), size) as (app, pilot):
        assert shown(app).state is EngineState.AWAITING_APPROVAL
        assert {"approve", "veto", "pause"} <= footer_keys(app)
        assert "resume" not in footer_keys(app)
        await pilot.press("a")
        await wait_until(pilot, lambda: shown(app).state is EngineState.RUNNING, what="block approved")
        [cmd] = commands(run)
        assert cmd["kind"] == "approve" and cmd["author"] == "tester" and cmd["outcome"] == "accepted"
        assert cmd["payload"]["block_id"] == proposed.block.block_id
        assert cmd["scores"]["predicted_cost_s"] == pytest.approx(proposed.predicted_cost_s)
        await settle(pilot)
        assert shown(app).current_block == proposed.block
        assert "approve" not in footer_keys(app)
        assert run.finish_block() == proposed.block.n_indents
        await settle(pilot)
        first = shown(app).tested[0]
        assert (first.x_um, first.y_um) == (proposed.block.center_x_um, proposed.block.center_y_um)
        assert shown(app).n_indents == proposed.block.n_indents
        assert shown(app).ledger["indent"] > 0


async def test_veto_offers_the_next_best(live_run: LiveRunFactory) -> None:
    run = live_run()
    first = past_the_seeds(run).pending
    assert first is not None and first.alternatives
    async with attached(run.source(), (100, 30)) as (app, pilot):
        await pilot.press("v")
        await wait_until(pilot, lambda: commands(run)[-1]["processed"] == 1, what="veto processed")
        await settle(pilot)
        veto = commands(run)[-1]
        assert veto["kind"] == "veto" and veto["outcome"] == "accepted"
        assert veto["payload"]["center_um"] == [first.block.center_x_um, first.block.center_y_um]
        # the planner offers its next best for the same block: a jump to wait for, or a stay that runs
        snap = shown(app)
        new = snap.pending if snap.pending is not None else snap.last_decision
        assert new is not None and new.block.block_id == first.block.block_id
        centre = (new.block.center_x_um, new.block.center_y_um)
        assert centre != (first.block.center_x_um, first.block.center_y_um)
        # the decision panel follows the new proposal
        text = widget_text(app.query_one("#decision"))
        assert f"({centre[0]:.0f}, {centre[1]:.0f})" in text


async def test_adjust_validates_like_the_engine_and_changes_later_blocks(live_run: LiveRunFactory) -> None:
    run = live_run()
    waiting = past_the_seeds(run).pending
    assert waiting is not None and waiting.block.hold_s == 80.0
    async with attached(run.source(), (80, 24)) as (app, pilot):
        await pilot.press("e")
        await wait_until(pilot, lambda: isinstance(app.screen, AdjustScreen), what="adjust form")
        form = app.screen
        error = form.query_one("#adjust-error")
        edge = form.query_one("#f-edge_penalty")
        hold = form.query_one("#f-fixed_hold_s")
        edge.value = "0.99"  # the engine allows 0 to 0.95: refused here, nothing sent
        await pilot.press("enter")
        await pilot.pause()
        assert isinstance(app.screen, AdjustScreen)
        assert "edge penalty" in widget_text(error) and "0.95" in widget_text(error)
        edge.value = "0.3"
        hold.value = "60"  # not one of the profile's holds
        await pilot.pause()
        assert "fixed hold" in widget_text(error) and "0, 5, 80" in " ".join(widget_text(error).split())
        hold.value = "5"
        await pilot.press("enter")
        await wait_until(pilot, lambda: not isinstance(app.screen, AdjustScreen), what="form closes")
        await wait_until(
            pilot, lambda: shown(app).settings.fixed_hold_s == 5.0, what="the engine took the adjust"
        )
        adjust = commands(run)[-1]
        assert adjust["kind"] == "adjust" and adjust["outcome"] == "accepted"
        assert adjust["payload"] == {"edge_penalty": 0.3, "fixed_hold_s": 5.0}
        await settle(pilot)
        # the proposal already made keeps its hold; the change applies from the next decision
        assert shown(app).pending == waiting
        await pilot.press("a")
        await wait_until(pilot, lambda: shown(app).state is EngineState.RUNNING, what="approved")
        run.finish_block()
        await settle(pilot)
        snap = shown(app)
        later = snap.pending if snap.pending is not None else snap.last_decision
        assert later is not None and later.block.block_id == waiting.block.block_id + 1
        assert later.block.hold_s == 5.0
        assert "hold 5 s " in widget_text(app.query_one("#decision"))


async def test_pause_and_resume(live_run: LiveRunFactory) -> None:
    run = live_run(supervision="auto")
    running_block(run)
    async with attached(run.source(), (100, 30)) as (app, pilot):
        assert "pause" in footer_keys(app) and "resume" not in footer_keys(app)
        await pilot.press("space")
        await wait_until(pilot, lambda: len(run.commands()) == 1, what="pause queued")
        held = run.advance(1)  # the engine sees the pause after the indent under way
        assert held == 1
        await wait_until(pilot, lambda: shown(app).state is EngineState.PAUSED, what="paused")
        await settle(pilot)
        assert "resume" in footer_keys(app) and "pause" not in footer_keys(app)
        assert "PAUSED" in widget_text(app.query_one("#status"))
        n = shown(app).n_indents
        assert run.advance(5) == 0  # nothing runs while paused
        await settle(pilot)
        assert shown(app).n_indents == n
        await pilot.press("space")
        await wait_until(pilot, lambda: shown(app).state is EngineState.RUNNING, what="resumed")
        assert run.advance(5) == 5
        await settle(pilot)
        assert shown(app).n_indents == n + 5
        assert [c["kind"] for c in commands(run)] == ["pause", "resume"]


async def test_step_mode_runs_one_block_at_a_time(live_run: LiveRunFactory) -> None:
    run = live_run()
    async with attached(run.source(), (100, 30)) as (app, pilot):
        assert "step" in footer_keys(app)
        await pilot.press("s")
        await wait_until(
            pilot,
            lambda: shown(app).supervision == "step" and shown(app).state is EngineState.RUNNING,
            what="step",
        )
        sent = commands(run)
        assert [c["kind"] for c in sent] == ["adjust", "step"]
        assert sent[0]["payload"] == {"supervision": "step"}
        assert all(c["outcome"] == "accepted" for c in sent)
        run.advance(200)  # however many indents it may run, exactly one block runs
        await settle(pilot)
        assert shown(app).n_blocks == 1
        assert shown(app).state is EngineState.AWAITING_APPROVAL and shown(app).supervision == "step"
        await pilot.press("s")
        await wait_until(pilot, lambda: shown(app).state is EngineState.RUNNING, what="second step")
        assert [c["kind"] for c in commands(run)] == ["adjust", "step", "step"]  # no second adjust
        run.advance(200)
        await settle(pilot)
        assert shown(app).n_blocks == 2 and shown(app).state is EngineState.AWAITING_APPROVAL


async def test_stop_after_block(live_run: LiveRunFactory) -> None:
    run = live_run(supervision="auto")
    block = running_block(run).current_block
    assert block is not None
    async with attached(run.source(), (100, 30)) as (app, pilot):
        await pilot.press("x")
        await wait_until(pilot, lambda: isinstance(app.screen, ConfirmScreen), what="confirm")
        await pilot.press("n")  # abort asks first; "no" sends nothing
        await pilot.pause()
        assert not isinstance(app.screen, ConfirmScreen) and run.commands() == []
        await pilot.press("b")
        await wait_until(pilot, lambda: len(run.commands()) == 1, what="stop-after-block queued")
        run.advance(1)
        await settle(pilot)
        assert commands(run)[0]["reason"] == "stopping after the current block"
        run.advance(200)  # the running block finishes; no other starts
        await wait_until(pilot, lambda: shown(app).finished, what="the run stops")
        await settle(pilot)
        assert shown(app).state is EngineState.STOPPED and shown(app).n_blocks == 1
        assert shown(app).n_indents == block.n_indents
        assert "STOPPED" in widget_text(app.query_one("#status"))
        assert not (
            footer_keys(app) & {"pause", "approve", "veto", "adjust", "abort", "step", "stop_after_block"}
        )


async def test_abort_confirmed_stops_after_the_indent(live_run: LiveRunFactory) -> None:
    run = live_run(supervision="auto")
    done = running_block(run).n_indents
    async with attached(run.source(), (80, 24)) as (app, pilot):
        await pilot.press("x")
        await wait_until(pilot, lambda: isinstance(app.screen, ConfirmScreen), what="confirm")
        await pilot.press("y")
        await wait_until(pilot, lambda: len(run.commands()) == 1, what="abort queued")
        assert run.advance(5) == 1  # the indent under way finishes, then the tip lifts and the run stops
        await wait_until(pilot, lambda: shown(app).finished, what="the run stops")
        await settle(pilot)
        assert shown(app).state is EngineState.STOPPED and shown(app).n_indents == done + 1
        [abort] = commands(run)
        assert abort["kind"] == "abort" and abort["outcome"] == "accepted"
        assert any("aborted by tester" in e.text for e in shown(app).log)


async def test_detach_and_reattach(live_run: LiveRunFactory) -> None:
    run = live_run()
    proposed = run.snapshot().pending
    async with attached(run.source(), (100, 30)) as (app, pilot):
        await pilot.press("q")
        await pilot.pause()
    assert app.feed is not None and app.feed.stopped
    # leaving did not stop the run: it still waits for the operator, with nothing sent
    assert run.commands() == [] and not run.ended
    assert run.snapshot().state is EngineState.AWAITING_APPROVAL and run.snapshot().pending == proposed
    async with attached(run.source(), (100, 30)) as (again, pilot):
        assert shown(again).pending == proposed and shown(again).can_command
        await pilot.press("a")
        await wait_until(pilot, lambda: shown(again).state is EngineState.RUNNING, what="approved")
    assert [c["author"] for c in commands(run)] == ["tester"]


async def test_read_only_viewer_gets_no_command_keys(live_run: LiveRunFactory) -> None:
    run = live_run()
    viewer = run.source(reader_user=2_000_000_000)  # a uid that does not own the journal
    async with attached(viewer, (100, 30)) as (app, pilot):
        keys = footer_keys(app)
        assert not keys & {"approve", "veto", "pause", "adjust", "abort"}
        assert {"cycle_map", "help", "leave"} <= keys
        assert "read-only" in widget_text(app.query_one("#status"))
        await pilot.press("a")
        await pilot.pause()
        assert run.commands() == []


async def test_a_refused_command_is_shown_not_fatal(live_run: LiveRunFactory) -> None:
    run = live_run()
    async with attached(run.source(), (100, 30)) as (app, pilot):
        assert app.feed is not None
        app.feed.stop()  # the view goes stale (a slow link) while the run ends behind it
        run.close()
        await pilot.press("a")
        await wait_until(pilot, lambda: app.inflight is None and bool(app.sent), what="refusal handled")
        await pilot.pause(0.05)
        log_text = " ".join(" ".join(str(line.text) for line in app.query_one("#log").lines).split())
        assert "approve refused" in log_text and "no engine is running" in log_text


async def test_map_cycles_fields_and_redraws_off_the_ui_thread(
    live_run: LiveRunFactory, monkeypatch: pytest.MonkeyPatch
) -> None:
    builders: list[threading.Thread] = []
    render = mapview.render_heatmap

    def spy(*args: Any, **kwargs: Any) -> Any:
        builders.append(threading.current_thread())
        return render(*args, **kwargs)

    monkeypatch.setattr(mapview, "render_heatmap", spy)
    run = live_run(supervision="auto")
    for _ in range(3):
        run.finish_block()
    async with attached(run.source(), (100, 30)) as (app, pilot):
        panel = app.query_one(MapPanel)
        assert "mean hardness" in str(panel.border_title)
        first = app.query_one(HeatmapView).image
        assert first is not None and first.field_key == "mean"
        seen: list[str] = []
        for _ in range(8):  # the hardness fields, then (both maps by default) the modulus ones, back to mean
            await pilot.press("m")
            await settle(pilot)
            image = app.query_one(HeatmapView).image
            assert image is not None
            seen.append(image.field_key)
            if image.field_key == "mean":
                break
        assert seen[:3] == ["epistemic", "noise", "total"] and seen[-1] == "mean"
        assert "modulus" in seen
        assert "mean hardness" in str(panel.border_title)
        assert panel.builds >= 5
        # every tested centre is drawn, the newest with its own marker
        plain = app.query_one(HeatmapView)._text.plain
        assert plain.count("◉") == 1
    # every picture was built in a worker thread, never on the UI (main) thread
    assert len(builders) >= 5 and threading.main_thread() not in builders


async def test_command_palette_lists_only_valid_commands(live_run: LiveRunFactory) -> None:
    run = live_run()
    async with attached(run.source(), (100, 30)) as (app, pilot):
        titles = [c.title for c in app.get_system_commands(app.screen)]
        assert "Approve the proposal" in titles and "Veto the proposal" in titles
        assert "Resume the run" not in titles and "Replay: next block" not in titles
        await pilot.press("question_mark")
        await wait_until(pilot, lambda: isinstance(app.screen, HelpScreen), what="help")
        await pilot.press("escape")
        await wait_until(pilot, lambda: not isinstance(app.screen, HelpScreen), what="help closed")


async def test_a_demo_console_says_that_leaving_stops_its_engine(live_run: LiveRunFactory) -> None:
    """`aeni demo` stops its engine when its console quits: help and palette must not promise otherwise."""
    for stops, says in ((False, "the run keeps going"), (True, "finishes the indent, lifts and stops")):
        run = live_run()
        async with attached(run.source(), (100, 40), leaving_stops_engine=stops) as (app, pilot):
            leave = [c.help for c in app.get_system_commands(app.screen) if c.title == "Leave the console"]
            assert len(leave) == 1 and says.lower() in leave[0].lower()
            await pilot.press("question_mark")
            await wait_until(pilot, lambda: isinstance(app.screen, HelpScreen), what="help")
            await settle(pilot)
            shown = " ".join(
                " ".join(widget_text(w).split()) for w in app.screen.query("#help-dialog Static")
            )
            assert says in shown
            await pilot.press("escape")


async def test_replay_steps_forward_and_back(live_run: LiveRunFactory) -> None:
    run = live_run(supervision="auto")
    for _ in range(4):
        run.finish_block()
    run.close()  # the run ends; replay reads the finished journal
    replay = run.replay()
    app = make_app(replay, replay=True)
    async with app.run_test(size=(100, 30)) as pilot:
        await wait_until(pilot, lambda: app.replay_count == 4 and app.snapshot is not None, what="replay")
        await settle(pilot)
        assert app.replay_index == 3 and shown(app).n_blocks == 4
        assert "replay_next" not in footer_keys(app) and "replay_prev" in footer_keys(app)
        assert not footer_keys(app) & {"approve", "pause", "adjust"}
        await pilot.press("left")
        await pilot.press("left")
        await wait_until(pilot, lambda: shown(app).n_blocks == 2, what="two blocks back")
        await settle(pilot)
        assert app.replay_index == 1 and len(shown(app).tested) == 2
        fields = app.query_one(MapPanel).fields
        assert fields is not None and fields.snapshot_id == shown(app).gp.snapshot_id
        assert "REPLAY 2/4" in widget_text(app.query_one("#status"))
        await pilot.press("home")
        await wait_until(pilot, lambda: shown(app).n_blocks == 1, what="first block")
        assert "replay_prev" not in footer_keys(app)
        await pilot.press("right")
        await wait_until(pilot, lambda: shown(app).n_blocks == 2, what="one forward")
        await pilot.press("end")
        await wait_until(pilot, lambda: shown(app).n_blocks == 4, what="last block")
        assert run.commands() == []
    replay.close()


async def test_no_color_map_stays_legible(live_run: LiveRunFactory, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("NO_COLOR", "1")
    run = live_run(supervision="auto")
    for _ in range(3):
        run.finish_block()
    async with attached(run.source(), (100, 30)) as (app, _):
        assert app.no_color
        plain = app.query_one(HeatmapView)._text.plain
        # shading characters carry the levels, letters carry the markers
        assert sum(plain.count(c) for c in "░▒▓") > 50
        assert "@" in plain and "█" in plain


async def test_collapse_alarm_is_shown_until_acknowledged(live_run: LiveRunFactory) -> None:
    """Rendering only: a run of the real engine, its snapshot given a length-scale collapse alarm."""
    run = live_run(supervision="auto")
    for _ in range(3):
        run.finish_block()
    source = run.source()
    real = source.snapshot()
    assert real.gp.snapshot_id is not None and real.last_decision is not None
    alarm = replace(
        real,
        state=EngineState.AWAITING_APPROVAL,
        pending=real.last_decision,
        gp=replace(real.gp, collapse_alarm=True, collapse_reason="ℓx 12 µm < floor 20 µm"),
    )
    canned = CannedSource(alarm, source.map_fields(real.gp.snapshot_id))
    source.close()
    async with attached(canned, (100, 30)) as (app, pilot):
        assert "COLLAPSE" in widget_text(app.query_one("#status"))
        decision = app.query_one("#decision")
        assert decision.has_class("-alarm")
        assert "length-scale collapse" in widget_text(decision) and "12 µm" in widget_text(decision)
        await pilot.press("a")
        await wait_until(pilot, lambda: bool(canned.sent), what="approve sent")
        assert canned.sent[0].kind is CommandKind.APPROVE


async def test_adjust_at_the_first_proposal_of_the_aeni_policy_applies(live_run: LiveRunFactory) -> None:
    """Issue 38: the form hides `fixed hold (s)` for `aeni` (it picks every hold) and must not require it."""
    run = live_run(policy="aeni")
    first = run.until_awaiting().pending
    assert first is not None and shown_policy(run) == "aeni"
    async with attached(run.source(), (80, 24)) as (app, pilot):
        await pilot.press("e")
        await wait_until(pilot, lambda: isinstance(app.screen, AdjustScreen), what="adjust form")
        form = app.screen
        assert not form.query("#f-fixed_hold_s")  # not shown: the policy's holds
        form.query_one("#f-edge_penalty").value = "0.3"
        await pilot.pause()
        assert widget_text(form.query_one("#adjust-error")).strip() == ""
        await pilot.press("ctrl+s")
        await wait_until(pilot, lambda: not isinstance(app.screen, AdjustScreen), what="form closes")
        await wait_until(pilot, lambda: shown(app).settings.edge_penalty == 0.3, what="the engine took it")
        adjust = commands(run)[-1]
        assert adjust["kind"] == "adjust" and adjust["outcome"] == "accepted"
        assert adjust["payload"] == {"edge_penalty": 0.3}


def shown_policy(run: LiveRun) -> str:
    return run.snapshot().policy


@pytest.mark.parametrize("size", SIZES)
async def test_away_until_is_in_the_footer_and_in_help(
    live_run: LiveRunFactory, size: tuple[int, int]
) -> None:
    """Issue 38: `w` (away until a time: the run plans for nobody until then) is shown, not a hidden key."""
    run = live_run()
    run.until_awaiting()
    async with attached(run.source(), size) as (app, pilot):
        assert "away_until" in footer_keys(app)
        keys = [k for k in app.query("FooterKey") if k.display]
        shown_keys = ["".join(widget_text(k).split()) for k in keys]  # "w Away", or "wAway" at 80 columns
        assert "wAway" in shown_keys and shown_keys[-1] == "qLeave", shown_keys
        assert all(k.region.right <= size[0] for k in keys), [
            (t, k.region) for t, k in zip(shown_keys, keys, strict=True)
        ]
        await pilot.press("question_mark")
        await wait_until(pilot, lambda: isinstance(app.screen, HelpScreen), what="help")
    from rich.console import Console

    from aeni_console.console.widgets.help import help_text

    console = Console(width=90, record=True)
    console.print(help_text())
    assert any(ln.split()[:2] == ["w", "away"] for ln in console.export_text().splitlines()), "w not in help"


@pytest.mark.parametrize("size", SIZES)
async def test_the_approval_pop_up_leaves_the_log_and_the_decision_visible(
    live_run: LiveRunFactory, size: tuple[int, int]
) -> None:
    """Issue 38: the AWAITING APPROVAL notification sat over the log; it goes over the cost panel now."""
    from textual.widgets._toast import Toast, ToastRack

    run = live_run()
    run.until_awaiting()
    source = run.source()
    app = make_app(source)
    try:
        async with app.run_test(size=size, notifications=True) as pilot:
            # no settle first: a pop-up lives 5 s of wall time, and a busy machine can take longer to settle
            rack = app.screen.get_child_by_type(ToastRack)
            await wait_until(pilot, lambda: any(rack.walk_children(Toast)), what="the approval pop-up")
            await pilot.pause()
            toasts = list(rack.walk_children(Toast))
            assert any("AWAITING APPROVAL" in widget_text(t) for t in toasts)
            for toast in toasts:
                for panel in (app.log_panel, app.decision_panel, app.queue_panel):
                    assert not toast.region.overlaps(panel.region), (toast.region, panel.id, panel.region)
                assert toast.region.right <= app.cost_panel.region.right
    finally:
        source.close()


async def test_the_next_best_coordinates_fit_at_80x24(live_run: LiveRunFactory) -> None:
    """Issue 38: on a real stage (five-digit µm) the next best's coordinates wrapped and were cut at 80×24."""
    from core.sample import parse_sample

    corners = {
        k: {"x_um": x, "y_um": y, "z_um": 10.0}
        for k, x, y in (
            ("tl", 30000.0, 22000.0),
            ("tr", 32000.0, 22000.0),
            ("br", 32000.0, 20000.0),
            ("bl", 30000.0, 20000.0),
        )
    }
    run = live_run(sample=parse_sample({"name": "far", "corners": corners}))
    while run.until_awaiting().n_blocks < 3:
        run.send(Command(CommandKind.APPROVE, "script"))
    pending = run.snapshot().pending
    assert pending is not None and pending.alternatives
    best = pending.alternatives[0]
    async with attached(run.source(), (80, 24)) as (app, _pilot):
        text = widget_text(app.decision_panel)
        assert f"({best.center_x_um:.0f}, {best.center_y_um:.0f})" in text, text
        import re

        assert re.search(r"#\d+ around \(3\d{4}, 2\d{4}\) µm", text), text  # the proposal's own place, whole

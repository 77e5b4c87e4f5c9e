"""End to end: a real engine process on a real journal, the console attached, the operator deciding.

The engine runs as fast as it can (no speed factor) in supervised mode, so it stops at every global
jump and waits for the console's keys; then the finished journal is stepped through in replay.
"""

from __future__ import annotations

import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest

from aeni_console.cli.console import leave_message
from aeni_console.cli.main import main as cli_main
from aeni_console.console.app import ConsoleApp
from aeni_console.console.journal_source import JournalReplay, JournalSource
from aeni_console.console.widgets.confirm import ConfirmScreen
from aeni_console.testkit.live import settle, wait_until
from core.runview import EngineState

pytestmark = pytest.mark.slow


@pytest.fixture
def engine(tmp_path: Path) -> Iterator[tuple[Path, subprocess.Popen[bytes]]]:
    from aeni_console.cli.run import start_engine_process
    from core.campaign_config import CampaignConfig

    journal = tmp_path / "e2e.sqlite"
    proc = start_engine_process(CampaignConfig(name="e2e", seed=3, lattice_n=30), journal, "supervised", None)
    assert isinstance(proc, subprocess.Popen)
    try:
        yield journal, proc
    finally:
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=10)


async def test_console_drives_a_real_engine_then_replays_it(
    engine: tuple[Path, subprocess.Popen[bytes]],
) -> None:
    journal, proc = engine
    source = JournalSource(journal)
    app = ConsoleApp(source, poll_s=0.05, max_rate_hz=20.0, author="e2e", cursor_blink=False)

    def state() -> EngineState | None:
        return app.snapshot.state if app.snapshot is not None else None

    async with app.run_test(size=(100, 30)) as pilot:
        await wait_until(pilot, lambda: state() is EngineState.AWAITING_APPROVAL, 40, "first proposal")
        first = app.snapshot.pending
        assert first is not None and first.is_global_jump
        assert app.snapshot.can_command
        await pilot.press("a")  # approve the first seed grid
        await wait_until(
            pilot,
            lambda: (
                app.snapshot.n_blocks >= 1
                and state() is EngineState.AWAITING_APPROVAL
                and app.snapshot.pending != first
            ),
            40,
            "first block done, next jump proposed",
        )
        await settle(pilot, timeout_s=20)
        assert (app.snapshot.tested[0].x_um, app.snapshot.tested[0].y_um) == (
            first.block.center_x_um,
            first.block.center_y_um,
        )
        assert app.snapshot.ledger["indent"] > 0 and app.snapshot.instrument_s > 0
        second = app.snapshot.pending
        await pilot.press("v")  # veto: the planner must offer something else
        await wait_until(
            pilot,
            lambda: app.snapshot.pending is not None and app.snapshot.pending != second,
            40,
            "next best after the veto",
        )
        assert (app.snapshot.pending.block.center_x_um, app.snapshot.pending.block.center_y_um) != (
            second.block.center_x_um,
            second.block.center_y_um,
        )
        await pilot.press("x")
        await wait_until(pilot, lambda: isinstance(app.screen, ConfirmScreen), 5, "abort confirmation")
        await pilot.press("y")
        await wait_until(pilot, lambda: app.snapshot.finished, 40, "the engine stops")
        assert app.snapshot.state is EngineState.STOPPED
    source.close()
    assert proc.wait(timeout=20) == 0
    assert "has ended" in leave_message(journal)

    replay = JournalReplay(journal)
    rapp = ConsoleApp(replay, replay=True, clock=lambda: 0.0, cursor_blink=False)
    async with rapp.run_test(size=(80, 24)) as pilot:
        await wait_until(
            pilot, lambda: rapp.replay_count >= 1 and rapp.snapshot is not None, 20, "replay loaded"
        )
        await settle(pilot, timeout_s=20)
        n = rapp.replay_count
        assert rapp.snapshot.n_blocks == n and not rapp.snapshot.can_command
        kinds = [c["kind"] for c in replay._reader.commands()]
        assert kinds == ["approve", "veto", "abort"]
        if n > 1:
            await pilot.press("left")
            await wait_until(pilot, lambda: rapp.snapshot.n_blocks == n - 1, 10, "one block back")
    replay.close()


def test_console_command_refuses_a_missing_run(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = cli_main(["console", str(tmp_path / "nope.sqlite")])
    assert code == 2
    err = capsys.readouterr().err
    assert err.startswith("aeni: error:") and "nope.sqlite" in err and len(err.strip().splitlines()) == 1


def test_demo_rejects_a_bad_speed(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        cli_main(["demo", "--speed", "0"])
    assert exc.value.code == 2
    assert "--speed must be > 0" in capsys.readouterr().err


def test_demo_starts_a_detached_engine_and_leaving_keeps_it_running(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    import os
    import re
    import signal
    import time

    from core.journal import JournalReader, engine_running

    journal = tmp_path / "demo.sqlite"
    seen: list[EngineState] = []

    def fake_console_run(self: ConsoleApp) -> None:  # the operator looks, then presses q at once
        deadline = time.monotonic() + 40
        while time.monotonic() < deadline:
            snap = self.source.snapshot()
            if snap.state is EngineState.AWAITING_APPROVAL:
                seen.append(snap.state)
                return
            time.sleep(0.1)

    monkeypatch.setattr(ConsoleApp, "run", fake_console_run)
    # --stay: without it, quitting the demo's console stops its engine (tests/test_cli_demo.py)
    code = cli_main(["demo", "--journal", str(journal), "--speed", "1000", "--seed", "1", "--stay"])
    out = capsys.readouterr().out
    pid_match = re.search(r"PID (\d+)", out)
    assert pid_match, out
    pid = int(pid_match.group(1))
    try:
        assert code == 0 and seen == [EngineState.AWAITING_APPROVAL]
        assert f"aeni console {journal}" in out and "keeps going" in out
        assert engine_running(journal)  # leaving the console did not stop the run
        with JournalReader(journal) as reader:
            assert reader.snapshot().supervision == "supervised"
    finally:
        os.kill(pid, signal.SIGTERM)  # the engine we started; it aborts cleanly on SIGTERM
        deadline = time.monotonic() + 30
        while engine_running(journal) and time.monotonic() < deadline:
            time.sleep(0.1)
    assert not engine_running(journal)

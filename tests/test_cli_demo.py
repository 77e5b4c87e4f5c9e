"""`aeni demo` never leaves an engine behind: quitting its console stops its engine, unless --stay."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import pytest

from aeni_console.cli.main import main
from core.journal import JournalReader, engine_running
from core.runview import EngineState


class _QuitWhenWaiting:
    """Stands in for the operator: opens no screen, waits until the engine asks for approval, presses q."""

    def __init__(self, source: object, **_kw: object) -> None:
        self.journal = Path(str(source.path))  # type: ignore[attr-defined]

    def run(self) -> None:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            with JournalReader(self.journal) as r:
                if r.state()[0] == EngineState.AWAITING_APPROVAL:
                    return
            time.sleep(0.1)
        raise TimeoutError("the demo's engine never asked for approval")


@pytest.fixture
def no_screen(monkeypatch: pytest.MonkeyPatch) -> None:
    import aeni_console.console.app

    # where it is defined: `aeni console` imports it when it opens the screen (not at startup)
    monkeypatch.setattr(aeni_console.console.app, "ConsoleApp", _QuitWhenWaiting)


def test_quitting_the_demo_console_stops_its_engine(
    tmp_path: Path, no_screen: None, capsys: pytest.CaptureFixture[str]
) -> None:
    journal = tmp_path / "demo.sqlite"
    assert main(["demo", "--journal", str(journal), "--speed", "100000"]) == 0
    out = capsys.readouterr().out
    assert "the demo's engine" in out and "stopped" in out and "--replay" in out
    assert not engine_running(journal)
    with JournalReader(journal) as r:
        state, finished = r.state()
    assert finished and state == EngineState.STOPPED


def test_stay_keeps_the_demo_engine_running(
    tmp_path: Path, no_screen: None, capsys: pytest.CaptureFixture[str]
) -> None:
    journal = tmp_path / "demo.sqlite"
    assert main(["demo", "--journal", str(journal), "--speed", "100000", "--stay"]) == 0
    out = capsys.readouterr().out
    assert "keeps going" in out
    assert engine_running(journal)
    with JournalReader(journal) as r:
        pid = int(r.q.engine_row()["pid"])
    os.kill(pid, signal.SIGTERM)
    deadline = time.monotonic() + 30
    while engine_running(journal) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not engine_running(journal)

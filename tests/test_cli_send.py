"""`aeni send` says what became of a command: the engine's verdict, and an exit code a script can use."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from aeni_console.cli.main import main
from aeni_console.cli.run import SEND_NO_VERDICT, SEND_REJECTED, start_engine_process, wait_for_verdict
from core.campaign_config import CampaignConfig
from core.journal import JournalReader
from core.plan import PlannerSettings
from core.runview import EngineState


def _run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    try:
        code = main(list(argv))
    except SystemExit as exc:
        code = int(exc.code or 0)
    out, err = capsys.readouterr()
    return code, out, err


def _wait_state(path: Path, state: EngineState, timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        with JournalReader(path) as r:
            if r.state()[0] == state:
                return
        time.sleep(0.1)
    raise TimeoutError(f"engine never reached {state}")


@pytest.fixture
def waiting_engine(tmp_path: Path):  # type: ignore[no-untyped-def]
    """A supervised engine process waiting for approval of its first block."""
    journal = tmp_path / "live.sqlite"
    config = CampaignConfig(name="live", settings=PlannerSettings(budget_s=200_000))
    proc = start_engine_process(config, journal, "supervised", speed=1e5)
    assert not isinstance(proc, int)
    try:
        _wait_state(journal, EngineState.AWAITING_APPROVAL)
        yield journal
    finally:
        proc.terminate()
        proc.wait(timeout=60)


def test_send_prints_the_verdict_and_exits_by_it(
    waiting_engine: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    j = str(waiting_engine)
    # a loaded machine can keep the engine in a GP fit past the default 5 s; exit 3 has its own test below
    wait = ("--wait-s", "60")
    code, out, _ = _run(capsys, "send", j, "resume", *wait)
    assert code == SEND_REJECTED == 1
    assert "(resume) rejected: not paused" in out
    code, out, _ = _run(capsys, "send", j, "approve", *wait)
    assert code == 0 and "(approve) accepted" in out
    code, out, _ = _run(capsys, "send", j, "abort", *wait)
    assert code == 0 and "(abort) accepted" in out


def test_no_wait_only_queues(waiting_engine: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = _run(capsys, "send", str(waiting_engine), "resume", "--no-wait")
    assert code == 0 and "queued" in out and "rejected" not in out
    with JournalReader(waiting_engine) as r:
        cid = r.commands()[-1]["command_id"]
    assert wait_for_verdict(waiting_engine, cid, 10.0) == ("rejected", "not paused")


def test_no_verdict_in_time_says_so(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """An engine that is alive but busy (here: a lock held, no engine loop) gives no verdict: exit 3."""
    import fcntl
    import os
    import shutil

    from aeni_console.cli.run import run_engine
    from core.journal import lock_path_for
    from core.runconfig import RunOptions

    done = tmp_path / "done.sqlite"
    run_engine(
        done, create=(CampaignConfig(settings=PlannerSettings(indent_budget=1)), RunOptions()), quiet=True
    )
    busy = tmp_path / "busy.sqlite"
    shutil.copy(done, busy)
    fd = os.open(lock_path_for(busy), os.O_RDWR | os.O_CREAT, 0o640)
    fcntl.flock(fd, fcntl.LOCK_EX)
    try:
        code, out, _ = _run(capsys, "send", str(busy), "pause", "--wait-s", "0.3")
    finally:
        os.close(fd)
    assert code == SEND_NO_VERDICT == 3
    assert "no verdict within 0.3 s" in out


def test_away_until_is_sent_as_a_local_time_and_accepted(
    waiting_engine: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    j = str(waiting_engine)
    code, out, _ = _run(capsys, "send", j, "away-until", "08:00")
    assert code == 0 and "(away-until) accepted: away until" in out and "08:00" in out
    code, _, err = _run(capsys, "send", j, "away-until", "25:00")
    assert code == 2 and "away-until" in err and "not a time of day" in err
    code, _, err = _run(capsys, "send", j, "away-until")
    assert code == 2 and "expected `aeni send RUN away-until HH:MM`" in err

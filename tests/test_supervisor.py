"""The engine's supervisor (issue 38): real engine processes, a real kill -9, alerts through apprise to a
receiver on 127.0.0.1 (never a mock of the sender). A killed detached engine is journaled, alerted as a
`failure` naming the cause and resumed with nothing lost or measured twice; a crash loop stops with an alert;
a finished run is never resumed."""

from __future__ import annotations

import contextlib
import os
import signal
import sqlite3
import subprocess
import threading
import time
from collections.abc import Callable
from pathlib import Path

from apprise_receiver import Receiver

from aeni_console.cli.host import child_env as _child_env
from aeni_console.cli.host import engine_argv
from aeni_console.cli.main import main
from aeni_console.cli.runs import format_runs, list_runs
from aeni_console.cli.supervisor import SUPERVISED_ENV, Supervisor, describe_exit, resume_argv, supervisor_pid
from core.journal import JournalReader, engine_running
from core.notifyconfig import NotifyConfig
from core.run.spec import RunSpec
from core.runconfig import make_campaign_config


def _wait(pred: Callable[[], object], timeout_s: float = 120.0) -> None:  # a loaded 2-core machine
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and not pred():
        time.sleep(0.05)
    assert pred(), "timed out"


def _engine_pid(journal: Path) -> int | None:
    """The PID of the engine holding the journal now (None: none, or the journal is still being made)."""
    if not engine_running(journal):
        return None
    try:
        with contextlib.closing(sqlite3.connect(f"file:{journal}?mode=ro", uri=True)) as c:
            row = c.execute("SELECT pid FROM engine_state").fetchone()
    except sqlite3.Error:
        return None
    return int(row[0]) if row and row[0] else None


def _supervisor_rows(journal: Path) -> list[str]:
    with contextlib.closing(sqlite3.connect(f"file:{journal}?mode=ro", uri=True)) as c:
        return [
            r[0] for r in c.execute("SELECT text FROM events WHERE category = 'supervisor' ORDER BY event_id")
        ]


def _indents(journal: Path) -> list[tuple[int, int, str, float | None]]:
    try:
        with contextlib.closing(sqlite3.connect(f"file:{journal}?mode=ro", uri=True)) as c:
            return c.execute(
                "SELECT block_id, indent_index, status, hardness_gpa FROM indents ORDER BY block_id, indent_index"
            ).fetchall()
    except sqlite3.Error:
        return []


def _leave_nothing(journal: Path) -> None:
    """A test that failed half-way leaves no supervisor or engine running behind it."""
    for pid in (supervisor_pid(journal), _engine_pid(journal)):
        if pid is not None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)


def test_a_killed_detached_engine_is_journaled_alerted_and_resumed(
    receiver: Receiver, tmp_path: Path
) -> None:
    """`aeni run --detach` (the rules from its run file: backoff 0.2 s), its engine killed -9: the supervisor
    journals and alerts the death and resumes the run; the probe (this process, which reads the journal
    throughout as a console does) sees the new engine; SIGTERM to the supervisor stops the resumed engine as
    Ctrl-C would."""
    run_file = tmp_path / "run.toml"
    run_file.write_text(
        'name = "night"\n[campaign]\nlattice_n = 12\nseed = 4\n[planner]\nindent_budget = 2000\n'
        f'[run]\nspeed = 1000.0\nresume_backoff_s = 0.2\n[notify]\nurls = ["{receiver.url}"]\n'
    )
    journal = tmp_path / "runs" / "night.sqlite"
    assert main(["run", str(run_file), "--detach", "--journal", str(journal)]) == 0
    try:
        sup = supervisor_pid(journal)
        assert sup is not None
        _wait(lambda: _engine_pid(journal) and len(_indents(journal)) >= 2)
        first = _engine_pid(journal)
        assert first is not None and first != sup
        row = next(r for r in list_runs(journal.parent) if r.journal == str(journal))
        assert (row.pid, row.supervisor_pid) == (first, sup)  # `aeni runs` shows both
        assert f"PID {sup}" in format_runs([row])
        os.kill(first, signal.SIGKILL)
        _wait(lambda: receiver.of("failure"))
        assert "engine killed by SIGKILL" in receiver.of("failure")[0], receiver.got
        assert "resuming (attempt 1 of 3) in 0.2 s" in receiver.of("failure")[0]
        _wait(lambda: (_engine_pid(journal) or first) != first)  # a new engine, started by nobody but it
        resumed = _engine_pid(journal)
        before = _indents(journal)
        _wait(lambda: len(_indents(journal)) > len(before) + 1)
        os.kill(sup, signal.SIGTERM)  # stops the run as Ctrl-C would (the supervisor does not resume it)
        _wait(lambda: supervisor_pid(journal) is None and not engine_running(journal), 60.0)
    finally:
        _leave_nothing(journal)
    with JournalReader(journal) as r:
        state = r.q.engine_row()
        sessions = r.table("sessions")[1]
    died = _supervisor_rows(journal)
    assert len(died) == 1 and "killed by SIGKILL" in died[0], died
    assert state["state"] == "stopped" and not state["completed"]
    assert [s[1] for s in sessions] == ["start", "resume"] and sessions[0][-1] == "failed"
    assert [s[2] for s in sessions] == [first, resumed] and sessions[1][-1] == "stopped"
    after = _indents(journal)
    # nothing lost or changed: every indent before the kill is in the journal as it was, each once
    assert after[: len(before)] == before
    assert len({(b, i) for b, i, _, _ in after}) == len(after)
    assert [i for b, i, _, _ in after if b == 0] == list(range(sum(1 for b, *_ in after if b == 0)))


def _engine(
    journal: Path, budget: int, notify: NotifyConfig | None, speed: float | None = 1000.0
) -> Callable[[], subprocess.Popen[bytes]]:
    cfg = make_campaign_config(journal.stem, lattice_n=12, seed=5, settings={"indent_budget": budget})

    def launch() -> subprocess.Popen[bytes]:
        proc = subprocess.Popen(
            [*engine_argv(journal), "--quiet"],
            stdin=subprocess.PIPE,
            env={**_child_env(), SUPERVISED_ENV: "1"},  # as the supervisor launches it
            stdout=subprocess.DEVNULL,
        )
        assert proc.stdin is not None
        spec = RunSpec(campaign=cfg, speed=speed, notify=notify or NotifyConfig())
        proc.stdin.write(spec.to_json().encode("utf-8"))
        proc.stdin.close()
        return proc

    return launch


def test_a_crash_loop_stops_with_an_alert_after_n_attempts(receiver: Receiver, tmp_path: Path) -> None:
    """The engine is killed; each resume dies before it starts (here: a resume that cannot start): after
    auto_resume attempts in a row the supervisor stops and says so."""
    journal = tmp_path / "loop.sqlite"
    log = tmp_path / "loop.log"

    def bad_resume() -> subprocess.Popen[bytes]:
        with log.open("ab") as fh:  # exits 2 at once, its reason as its last line
            return subprocess.Popen(
                [*resume_argv(journal), "--speed", "-1"],
                stdout=fh,
                stderr=subprocess.STDOUT,
                env=_child_env(),
            )

    sup = Supervisor(
        journal,
        _engine(journal, 2000, NotifyConfig(urls=(receiver.url,))),
        bad_resume,
        auto_resume=2,
        backoff_s=0.05,
        log=log,
        say=lambda line: None,
    )

    def killer() -> None:
        try:
            _wait(lambda: _engine_pid(journal))  # it began its session: a death, not a failed start
        finally:  # the engine dies in any case (the test then fails on what it finds, never hangs)
            pid = _engine_pid(journal) or (sup.child.pid if sup.child is not None else None)
            if pid is not None:
                os.kill(pid, signal.SIGKILL)

    t = threading.Thread(target=killer)
    t.start()
    code = sup.run()
    t.join()
    assert code != 0 and sup.deaths == 3  # the kill, then two resumes that did not start
    alerts = receiver.of("failure")
    assert len(alerts) == 3, receiver.got
    assert "killed by SIGKILL" in alerts[0] and "attempt 1 of 2" in alerts[0]
    assert (
        "did not start" in alerts[1] and "--speed must be > 0" in alerts[1] and "attempt 2 of 2" in alerts[1]
    )
    assert "crash loop" in alerts[2] and f"aeni resume {journal}" in alerts[2]
    with JournalReader(journal) as r:
        state = r.q.engine_row()
    died = _supervisor_rows(journal)
    assert len(died) == 3 and "crash loop" in died[-1]
    assert state["state"] == "failed" and not engine_running(journal)


def test_a_finished_run_is_never_resumed(receiver: Receiver, tmp_path: Path) -> None:
    journal = tmp_path / "done.sqlite"
    resumed: list[int] = []

    def resume() -> subprocess.Popen[bytes]:
        resumed.append(1)
        raise AssertionError("a finished run must not be resumed")

    sup = Supervisor(
        journal, _engine(journal, 8, NotifyConfig(urls=(receiver.url,)), None), resume, say=lambda line: None
    )
    assert sup.run() == 0
    assert sup.deaths == 0 and not resumed
    with JournalReader(journal) as r:
        assert r.q.engine_row()["completed"]
    assert not _supervisor_rows(journal)
    assert not receiver.of("failure")


def test_the_cause_names_the_signal_or_the_last_line_of_the_log(tmp_path: Path) -> None:
    log = tmp_path / "x.log"
    log.write_text("journal x\nTraceback (most recent call last):\nValueError: boom\nsupervisor: PID 1\n")
    assert describe_exit(-9, log)[0].startswith("engine killed by SIGKILL")
    assert describe_exit(-15, log) == ("engine killed by SIGTERM", None, "SIGTERM")
    assert describe_exit(1, log) == ("engine exited with code 1: ValueError: boom", 1, None)


def test_a_killed_foreground_engine_is_journaled_and_alerted_not_resumed(
    receiver: Receiver, tmp_path: Path
) -> None:
    """A foreground `aeni run` cannot report its own kill -9; the watcher it starts beside itself (when the
    run has alerts) does, and leaves the resume to the person at the terminal."""
    run_file = tmp_path / "run.toml"
    run_file.write_text(
        'name = "fg"\n[campaign]\nlattice_n = 12\nseed = 6\n[planner]\nindent_budget = 2000\n'
        f'[run]\nspeed = 1000.0\n[notify]\nurls = ["{receiver.url}"]\n'
    )
    journal = tmp_path / "fg.sqlite"
    engine = subprocess.Popen(
        [*resume_argv(journal)[:3], "run", str(run_file), "--journal", str(journal), "--quiet"],
        env=_child_env(),
        stdout=subprocess.DEVNULL,
    )
    try:
        _wait(lambda: supervisor_pid(journal) and len(_indents(journal)) >= 1)
        engine.send_signal(signal.SIGKILL)
        engine.wait()
        _wait(lambda: receiver.of("failure"))
    finally:
        if engine.poll() is None:
            engine.kill()
    alert = receiver.of("failure")[0]
    assert "a foreground engine" in alert and "not resumed" in alert and f"aeni resume {journal}" in alert
    _wait(lambda: supervisor_pid(journal) is None)
    assert _supervisor_rows(journal) and not engine_running(journal)
    with JournalReader(journal) as r:
        assert r.q.engine_row()["state"] == "failed"

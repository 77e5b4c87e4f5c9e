"""Alerts through apprise, against a real HTTP receiver on 127.0.0.1 (apprise's json:// URL), never a mock of
the sender; the URLs stay out of the journal, the log and the engine's command line."""

from __future__ import annotations

import os
import sqlite3
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from apprise_receiver import SECRET, Receiver

from aeni_console.alerts import AlertWatcher
from aeni_console.cli.main import main
from core.errors import InputError
from core.journal import append_event
from core.notifyconfig import NotifyConfig, notify_path_for
from core.runconfig import RunOptions, load_run_config, make_campaign_config


def _wait(pred: object, timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and not pred():  # type: ignore[operator]
        time.sleep(0.05)


def test_a_run_that_ends_alerts_and_keeps_the_url_out_of_the_journal(
    receiver: Receiver, tmp_path: Path
) -> None:
    from aeni_console.cli.run import run_engine

    cfg = make_campaign_config("alerted", policy="cost-aware", lattice_n=30, settings={"indent_budget": 50})
    path = tmp_path / "alerted.sqlite"
    notify = NotifyConfig(urls=(receiver.url,))
    assert run_engine(path, create=(cfg, RunOptions()), quiet=True, notify=notify) == 0
    _wait(lambda: receiver.got)
    assert any("run ended" in b and "indent budget" in b for b in receiver.bodies()), receiver.bodies()
    assert receiver.got[0]["path"] == f"/{SECRET}"
    side = notify_path_for(path)
    assert (side.stat().st_mode & 0o777) == 0o600  # for aeni resume, owner-only
    for f in path.parent.iterdir():
        if f != side:
            assert SECRET.encode() not in f.read_bytes(), f


def test_a_supervised_decision_alerts_and_a_failed_send_is_journaled_without_the_url(
    receiver: Receiver, tmp_path: Path
) -> None:
    from aeni_console.cli.run import run_engine
    from core.journal import JournalReader, engine_running, send_command
    from core.runview import Command, CommandKind

    cfg = make_campaign_config("sup", policy="cost-aware", lattice_n=30, settings={"indent_budget": 200})
    path = tmp_path / "sup.sqlite"
    dead = f"json://127.0.0.1:9/{SECRET}"  # nothing listens on the discard port
    notify = NotifyConfig(urls=(receiver.url,))
    opts = RunOptions(supervision="supervised")
    engine = threading.Thread(
        target=run_engine, args=(path,), kwargs={"create": (cfg, opts), "quiet": True, "notify": notify}
    )
    engine.start()
    _wait(lambda: any("waits for approval" in b for b in receiver.bodies()))
    assert any("waits for approval" in b for b in receiver.bodies()), receiver.bodies()
    assert engine_running(path)
    # the watcher on its own: a send to a dead URL fails, is journaled, and the engine runs on
    watcher = AlertWatcher(path, NotifyConfig(urls=(dead,)))
    watcher.check()
    watcher._alert("interlock", "safety interlock refused block 3: test")
    send_command(path, Command(CommandKind.ABORT, author="tester"))
    engine.join(120)
    with JournalReader(path) as r:
        texts = [e.text for e in r.events()]
    assert any(t.startswith("alert not sent (interlock)") for t in texts), texts
    assert SECRET.encode() not in path.read_bytes()
    _wait(lambda: any("run ended" in b for b in receiver.bodies()))


def test_repeated_alerts_are_rate_limited(receiver: Receiver, tmp_path: Path) -> None:
    from aeni_console.cli.run import run_engine

    cfg = make_campaign_config("rl", policy="cost-aware", lattice_n=30, settings={"indent_budget": 25})
    path = tmp_path / "rl.sqlite"
    run_engine(path, create=(cfg, RunOptions()), quiet=True)
    now = [0.0]
    w = AlertWatcher(path, NotifyConfig(urls=(receiver.url,), repeat_s=600.0), clock=lambda: now[0])
    for t in (0.0, 10.0, 599.0, 601.0):
        now[0] = t
        w._alert("interlock", "safety interlock refused a block")
    assert [k for k, _ in w.sent] == ["interlock", "interlock"]  # at 0 s and at 601 s
    assert len(receiver.got) == 2


def test_urls_file_must_be_owner_only_and_notify_test_sends(receiver: Receiver, tmp_path: Path) -> None:
    urls = tmp_path / "alerts.txt"
    urls.write_text(f"# where alerts go\n{receiver.url}\n")
    run_file = tmp_path / "r.toml"
    run_file.write_text('[notify]\nurls_file = "alerts.txt"\n')
    urls.chmod(0o644)
    with pytest.raises(InputError, match="readable by others"):
        load_run_config(run_file)
    urls.chmod(0o600)
    assert load_run_config(run_file).notify.urls == (receiver.url,)
    assert main(["notify", "test", str(run_file)]) == 0
    _wait(lambda: receiver.got)
    assert "test alert" in receiver.bodies()[0]


def test_the_detached_engine_gets_no_config_on_its_command_line(receiver: Receiver, tmp_path: Path) -> None:
    from aeni_console.cli.run import engine_argv, start_engine_process
    from core.journal import JournalReader

    cfg = make_campaign_config("det", policy="cost-aware", lattice_n=30, settings={"indent_budget": 25})
    argv = engine_argv(tmp_path / "x.sqlite")
    assert "--spec-stdin" in argv and not any("policy" in a or "{" in a for a in argv)
    path = tmp_path / "det.sqlite"
    proc = start_engine_process(cfg, path, notify=NotifyConfig(urls=(receiver.url,)))
    assert isinstance(proc, subprocess.Popen)
    assert proc.wait(120) == 0
    with JournalReader(path) as r:
        assert r.q.engine_row()["completed"]
    _wait(lambda: receiver.got)
    assert any("run ended" in b for b in receiver.bodies())
    log = path.with_name(path.name + ".log")
    assert SECRET not in log.read_text() and SECRET.encode() not in path.read_bytes()
    assert os.path.exists(notify_path_for(path))
    assert sys.executable  # the engine ran as its own process


def test_a_silent_instrument_and_a_lost_exchange_folder_alert(receiver: Receiver, tmp_path: Path) -> None:
    """A KLA run whose ticket nobody runs: the silence alert; then the folder goes: its alert."""
    from aeni_console.cli.run import run_engine
    from core.campaign_config import CampaignConfig
    from core.journal import JournalReader, send_command
    from core.runview import Command, CommandKind

    exchange = tmp_path / "exchange"
    exchange.mkdir()
    path = tmp_path / "silent.sqlite"
    cfg = CampaignConfig(name="silent", driver_options={"scenario": "ternary"})
    notify = NotifyConfig(urls=(receiver.url,), instrument_silence_s=2.0)
    engine = threading.Thread(
        target=run_engine,
        args=(path,),
        kwargs={
            "create": (cfg, RunOptions(driver="kla", exchange=str(exchange))),
            "quiet": True,
            "notify": notify,
        },
    )
    engine.start()
    try:
        _wait(lambda: any("has not answered" in b for b in receiver.bodies()))
        assert any("has not answered" in b for b in receiver.bodies()), receiver.bodies()
        # Renamed away in one step, as a dropped share goes: an rmtree races the engine's own writes into
        # the folder (it can find a file made after it listed the folder: "Directory not empty").
        exchange.rename(tmp_path / "unmounted")
        _wait(lambda: any("exchange folder" in b for b in receiver.bodies()))
        assert any("exchange folder" in b and "missing" in b for b in receiver.bodies()), receiver.bodies()
        with JournalReader(path) as r:
            assert r.q.engine_row()["state"] == "waiting-for-instrument"  # a wait, not a crash
    finally:
        send_command(path, Command(CommandKind.ABORT, author="tester"))
        engine.join(120)


def test_a_supervised_run_nobody_answers_goes_on_after_the_timeout_and_alerts(
    receiver: Receiver, tmp_path: Path
) -> None:
    """Issue 23's done-when: supervised, approval_timeout_s set, nobody at the keys; the global jumps are
    approved by the timeout (journaled), the run reaches its budget, and the receiver got the alerts."""
    from aeni_console.cli.run import run_engine
    from core.journal import JournalReader

    cfg = make_campaign_config("alone", policy="cost-aware", lattice_n=30, settings={"indent_budget": 60})
    path = tmp_path / "alone.sqlite"
    opts = RunOptions(supervision="supervised", approval_timeout_s=1.0, on_timeout="approve")
    notify = NotifyConfig(urls=(receiver.url,))
    assert run_engine(path, create=(cfg, opts), quiet=True, notify=notify) == 0
    with JournalReader(path) as r:
        snap = r.snapshot()
        texts = [e.text for e in r.events()]
        reason = str(r.q.engine_row().get("stop_reason"))
    assert snap.n_indents >= 50 and "indent budget" in reason, reason
    timed_out = [t for t in texts if "timed out after 1 s: approve" in t]
    assert len(timed_out) >= 2, texts  # every global jump went ahead on its own
    _wait(
        lambda: (
            any("timed out" in b for b in receiver.bodies())
            and any("run ended" in b for b in receiver.bodies())
        )
    )
    bodies = receiver.bodies()
    assert any("waits for approval" in b for b in bodies), bodies
    assert any("timed out" in b for b in bodies), bodies
    assert any("run ended" in b for b in bodies), bodies


def test_an_approval_that_timed_out_between_two_looks_is_still_told(
    receiver: Receiver, tmp_path: Path
) -> None:
    """The watcher reads who was asked from the decisions table, not from the engine's state: a look that
    comes after a 1 s approval timed out (a loaded machine) still sends "waits for approval"."""
    from aeni_console.cli.run import run_engine

    cfg = make_campaign_config("late", policy="cost-aware", lattice_n=30, settings={"indent_budget": 30})
    path = tmp_path / "late.sqlite"
    opts = RunOptions(supervision="supervised", approval_timeout_s=1.0, on_timeout="approve")
    assert run_engine(path, create=(cfg, opts), quiet=True) == 0  # no watcher while it ran
    w = AlertWatcher(path, NotifyConfig(urls=(receiver.url,)))
    w._started = True  # its first look is now, after every approval timed out and the run stopped
    w.check()
    _wait(lambda: any("run ended" in b for b in receiver.bodies()))
    bodies = receiver.bodies()
    assert sum("waits for approval" in b for b in bodies) == 1, bodies  # told once for the look
    w.check()  # nothing new: nothing told again
    time.sleep(0.5)
    assert sum("waits for approval" in b for b in receiver.bodies()) == 1


def test_every_alert_carries_apprises_severity_and_names_its_cause(
    receiver: Receiver, tmp_path: Path
) -> None:
    """Issue 38: the severity is apprise's NotifyType, chosen by what happened; the title names the cause."""
    from aeni_console.alerts import Severity, send
    from aeni_console.cli.run import run_engine

    cfg = make_campaign_config("sev", policy="cost-aware", lattice_n=30, settings={"indent_budget": 25})
    path = tmp_path / "sev.sqlite"
    run_engine(path, create=(cfg, RunOptions()), quiet=True)
    w = AlertWatcher(path, NotifyConfig(urls=(receiver.url,)))
    w._alert("failed", "run failed: the engine died (signal 9)")
    w._alert("interlock", "safety interlock refused block 3: too close to an exclusion")
    w._alert("ended", "run ended: indent budget reached")
    assert send((receiver.url,), "the engine died (SIGKILL)", Severity.FAILURE, "the engine died")[0]
    _wait(lambda: len(receiver.got) == 4)
    got = [(m["type"], m["title"]) for m in receiver.got]
    assert got == [
        ("failure", "AE-NI failure: the run failed"),
        ("warning", "AE-NI warning: the safety interlock refused a block"),
        ("info", "AE-NI info: the run ended"),
        ("failure", "AE-NI failure: the engine died"),
    ]
    assert w.severities == [Severity.FAILURE, Severity.WARNING, Severity.INFO]
    assert "too close to an exclusion" in receiver.bodies()[1]


def test_a_refused_export_is_alerted_once_as_refused_not_as_a_silent_instrument(
    receiver: Receiver, tmp_path: Path
) -> None:
    """A flipped-Y export of a cut block is refused; the engine then waits for a corrected export until the
    deadline. One `warning` alert names the refusal and its reason; no "has not answered" follows it."""
    from dataclasses import replace

    from aeni_console.cli.run import run_engine
    from core.campaign_config import CampaignConfig
    from core.plan import PlannerSettings
    from core.profile import load_profile
    from drivers.kla.fake_inview import FakeInView, parse_fault
    from drivers.sim.scenarios import make_scenario

    exchange = tmp_path / "exchange"
    exchange.mkdir()
    profile_file = tmp_path / "fast.toml"
    profile_file.write_text(
        'extends = "kla-imicro"\n[inview]\nstable_polls = 2\npoll_s = 0.05\ndeadline_margin_s = 8.0\n'
    )
    profile = load_profile(str(profile_file))
    fake = FakeInView(
        exchange,
        profile,
        make_scenario("ternary", 0).make_emulator,
        speed=1e6,
        faults=(parse_fault("flipped-y@0"),),
        invalid_rate=0.0,
        write_s=0.02,
        log=lambda _line: None,
    )
    stop = threading.Event()
    server = threading.Thread(target=fake.serve_forever, kwargs={"poll_s": 0.02, "stop": stop.is_set})
    server.start()
    cfg = CampaignConfig(
        name="flip",
        policy="cost-aware",
        profile=str(profile_file),
        settings=PlannerSettings(budget_s=2500.0),  # cuts block 0 to 16 sites: flipped is no permutation
        driver_options={"scenario": "ternary"},
    )
    notify = replace(NotifyConfig(urls=(receiver.url,)), instrument_silence_s=1.0, repeat_s=0.0)
    try:
        code = run_engine(
            tmp_path / "flip.sqlite",
            create=(cfg, RunOptions(driver="kla", exchange=str(exchange), speed=1e6)),
            quiet=True,
            notify=notify,
        )
    finally:
        stop.set()
        server.join()
    assert code == 0
    _wait(lambda: any("run ended" in b for b in receiver.bodies()))
    titles = [str(m["title"]) for m in receiver.got]
    refused = [m for m in receiver.got if m["title"] == "AE-NI warning: an export was refused"]
    assert len(refused) == 1, titles
    assert "Y axis is flipped" in str(refused[0]["message"]) and refused[0]["type"] == "warning"
    after = titles[titles.index("AE-NI warning: an export was refused") :]
    assert "AE-NI warning: the instrument is silent" not in after, titles
    # a night's wait for a corrected export lasts hours: the watcher on a clock of its own, the same journal
    # put back in the wait, the refusal journaled; then hours of silence say nothing more
    journal = tmp_path / "flip.sqlite"
    with sqlite3.connect(journal) as conn:
        conn.execute("UPDATE engine_state SET state = 'waiting-for-instrument', completed = 0")
    conn.close()
    receiver.got.clear()
    now = [0.0]
    w = AlertWatcher(journal, notify, clock=lambda: now[0])
    w.check()
    append_event(journal, "warn", refused[0]["message"].split(": ", 1)[1], "inbox")
    w.check()
    for hour in range(1, 6):
        now[0] = 3600.0 * hour
        w.check()
    assert [k for k, _ in w.sent] == ["refused"]
    # news from the instrument ends it: a later silence is alerted again
    append_event(journal, "info", "block 0: instrument: started", "instrument")
    now[0] += 1.0
    w.check()
    with sqlite3.connect(journal) as conn:
        conn.execute("UPDATE engine_state SET state = 'running'")
    now[0] += 1.0
    w.check()
    with sqlite3.connect(journal) as conn:
        conn.execute("UPDATE engine_state SET state = 'waiting-for-instrument'")
    now[0] += 1.0
    w.check()
    now[0] += 3600.0
    w.check()
    assert [k for k, _ in w.sent] == ["refused", "silence"]


def test_the_alert_kinds_in_docs_are_the_code_s() -> None:
    """docs/alerts.md's table lists every kind with its severity and cause, as aeni_console.alerts.KINDS has it."""
    from aeni_console.alerts import KINDS

    doc = (Path(__file__).resolve().parents[1] / "docs" / "alerts.md").read_text(encoding="utf-8")
    rows = {
        ln.split("|")[1].strip().strip("`"): ln.split("|") for ln in doc.splitlines() if ln.startswith("| `")
    }
    assert set(rows) == set(KINDS)
    for kind, what in KINDS.items():
        assert rows[kind][2].strip().startswith(what.severity.value) and rows[kind][3].strip() == what.cause

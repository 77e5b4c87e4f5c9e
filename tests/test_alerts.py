"""Alerts through apprise, against a real HTTP receiver on 127.0.0.1 (apprise's json:// URL), never a mock of
the sender; the URLs stay out of the journal, the log and the engine's command line."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest

from aeni_console.alerts import AlertWatcher
from aeni_console.cli import main
from core.errors import InputError
from core.notifyconfig import NotifyConfig, notify_path_for
from core.runconfig import RunOptions, load_run_config, make_campaign_config

SECRET = "s3cr3t-token"


class Receiver:
    def __init__(self) -> None:
        got: list[dict[str, object]] = []

        class Handler(BaseHTTPRequestHandler):
            def do_POST(self) -> None:
                body = self.rfile.read(int(self.headers.get("Content-Length", 0)))
                got.append({"path": self.path, **json.loads(body or b"{}")})
                self.send_response(200)
                self.end_headers()

            def log_message(self, *args: object) -> None:
                pass

        self.got = got
        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.port = self.server.server_address[1]
        self.thread = threading.Thread(target=self.server.serve_forever, daemon=True)

    @property
    def url(self) -> str:
        return f"json://127.0.0.1:{self.port}/{SECRET}"

    def bodies(self) -> list[str]:
        return [str(m.get("message", "")) for m in self.got]


@pytest.fixture
def receiver() -> Iterator[Receiver]:
    r = Receiver()
    r.thread.start()
    yield r
    r.server.shutdown()


def _wait(pred: object, timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and not pred():  # type: ignore[operator]
        time.sleep(0.05)


def test_a_run_that_ends_alerts_and_keeps_the_url_out_of_the_journal(
    receiver: Receiver, tmp_path: Path
) -> None:
    from aeni_console.commands.run import run_engine

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
    from aeni_console.commands.run import run_engine
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
    from aeni_console.commands.run import run_engine

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
    from aeni_console.commands.run import engine_argv, start_engine_process
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
    from aeni_console.commands.run import run_engine
    from core.campaign import CampaignConfig
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
    from aeni_console.commands.run import run_engine
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

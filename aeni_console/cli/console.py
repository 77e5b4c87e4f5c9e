"""``aeni console RUN [--replay]`` and ``aeni demo``: the operator console on a run's journal.

The console attaches to the journal, never to the engine process: leaving it (``q``) never stops the
run, and any number of consoles may watch (only the owner's may command). ``aeni demo`` starts an
emulator run as a detached engine process, slowed to a watchable pace, and attaches to it; when that
console quits, the demo's engine is stopped too (``--stay`` keeps it), so demos never pile up. ``aeni demo
--driver kla`` runs the KLA driver instead, against a fake InView process on a temporary exchange folder:
that instrument belongs to the demo, so leaving the console always stops it, and the run with it.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from aeni_console.cli.common import check_new_journal, positive_float, seed_arg
from aeni_console.cli.host import child_env, launch_engine
from aeni_console.cli.run import resolve_run
from core.errors import InputError
from core.run.machine import SUPERVISION_MODES
from drivers.sim.failures import REALISTIC_FAILURE_RATE

DEMO_SPEED = 600.0  # instrument seconds per wall second: a 5×5 block (~55 min) passes in about 6 s


def leave_message(journal: Path, pid: int | None = None) -> str:
    """What to print after the console closes while the engine runs on."""
    # imported here, not at the top: the journal pulls scipy, the console textual; `aeni --help` must start fast
    from core.journal import JournalReader

    try:
        with JournalReader(journal) as reader:
            state, finished = reader.state()
    except InputError:
        return f"journal {journal}"
    if finished:
        return f"The run has ended ({state.label}). Step through it: aeni console --replay {journal}"
    lines = [
        f"The run keeps going ({state.label}) in its own process" + (f" (PID {pid})." if pid else "."),
        f"  reattach:  aeni console {journal}",
        "  stop it:   reattach and press b (stop after this block) or x (abort)"
        + (f", or: kill {pid}" if pid else ""),
        f"  one line:  aeni status {journal}",
    ]
    return "\n".join(lines)


def run_console(
    journal: Path, replay: bool = False, pid: int | None = None, *, leave: bool = True, **app_kwargs: Any
) -> int:
    from aeni_console.console.app import ConsoleApp
    from aeni_console.console.journal_source import JournalReplay, JournalSource

    source = JournalReplay(journal) if replay else JournalSource(journal)
    try:
        ConsoleApp(source, replay=replay, **app_kwargs).run()
    finally:
        source.close()
    if not replay and leave:
        print(leave_message(journal, pid))
    return 0


def stop_engine(pid: int, journal: Path, grace_s: float = 30.0) -> str:
    """Stop an engine process as Ctrl-C would (finish the indent, lift, stop; the journal stays resumable).

    SIGTERM first; SIGKILL only if it has not ended after ``grace_s`` (every finished indent is already in
    the journal, so even that loses nothing). Returns what happened, in words.
    """
    from core.journal import engine_running

    try:
        os.kill(pid, signal.SIGTERM)
    except ProcessLookupError:
        return "the engine had already ended"
    deadline = time.monotonic() + grace_s
    while engine_running(journal) and time.monotonic() < deadline:
        time.sleep(0.05)
    if engine_running(journal):
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
        return f"the engine (PID {pid}) did not stop within {grace_s:g} s and was killed"
    return f"the demo's engine (PID {pid}) stopped"


def _cmd_console(args: argparse.Namespace) -> int:

    return run_console(resolve_run(args.run), replay=args.replay)


def _cmd_demo(args: argparse.Namespace) -> int:
    from core.journal import default_journal_path
    from core.run.spec import EngineRules, RunSpec
    from core.runconfig import make_campaign_config

    # the simulated instrument fails now and then, as a real one does (a KLA demo's fake InView has its own)
    failure_rate = args.failure_rate
    if failure_rate is None and args.driver == "sim":
        failure_rate = REALISTIC_FAILURE_RATE
    config = make_campaign_config(
        "demo",
        source="command line",
        policy=args.policy,
        scenario=args.scenario,
        seed=args.seed,
        failure_rate=failure_rate,
    )
    journal = Path(args.journal) if args.journal else default_journal_path("demo", args.runs_dir)
    check_new_journal(journal)  # a bad --journal is refused before anything is said or started
    kla = args.driver == "kla"
    if kla and args.stay:
        raise InputError(
            "--stay", "a KLA demo's fake InView stops with its console; --stay needs --driver sim"
        )
    what = "a KLA run against a fake InView" if kla else "an emulator run"
    print(
        f"starting {what} ({config.policy}, {args.scenario}, seed {config.seed}, "
        f"{args.supervision}, ×{args.speed:g}) → {journal}"
        + (
            ""
            if args.stay
            else "\nleaving this console (q) stops the demo's engine"
            + (" and its fake InView" if kla else "; `aeni demo --stay` keeps it")
        ),
        flush=True,
    )
    if kla:
        with kla_demo(config, journal, args.supervision, args.speed) as (_, engine, _):
            run_console(journal, pid=engine.pid, leave=False, leaving_stops_engine=True)
        print(
            f"The demo's engine and fake InView stopped; step through the run: aeni console --replay {journal}"
        )
        return 0
    spec = RunSpec(campaign=config, speed=args.speed, rules=EngineRules(args.supervision))
    # the PID of the engine's supervisor: stopping it stops the engine
    pid = launch_engine(spec, journal, detach=True, auto_resume=spec.rules.auto_resume).pid
    if args.stay:
        return run_console(journal, pid=pid)
    try:
        run_console(journal, pid=pid, leave=False, leaving_stops_engine=True)
    finally:
        print(f"{stop_engine(pid, journal)}; step through the run: aeni console --replay {journal}")
    return 0


def _stop(proc: subprocess.Popen[bytes], wait_s: float = 30.0) -> None:
    """SIGTERM (the engine aborts after the current indent, at once while it waits for the instrument;
    the fake InView ends like Ctrl-C), then SIGKILL if it does not end in time."""
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout=wait_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=10)


@contextlib.contextmanager
def kla_demo(
    config: Any, journal: Path, supervision: str, speed: float
) -> Iterator[tuple[Path, subprocess.Popen[bytes], subprocess.Popen[bytes]]]:
    """A fake InView process on a temporary exchange folder and an engine with the KLA driver beside it:
    yields (exchange, engine, fake InView). On leaving, the engine is stopped (its journal keeps every
    measured indent), then the fake InView, and the exchange folder is removed (the accepted exports are
    archived next to the journal)."""
    from core.run.spec import EngineRules, RunSpec

    options = config.driver_options
    exchange = Path(tempfile.mkdtemp(prefix="aeni-demo-exchange-"))
    for box in ("outbox", "inbox"):  # laid out before either process starts, not by whichever comes first
        (exchange / box).mkdir()
    journal.parent.mkdir(parents=True, exist_ok=True)
    argv = [
        sys.executable, "-m", "aeni_console.cli.main", "kla", "fake-inview",
        "--exchange", str(exchange), "--speed", repr(float(speed)),
        "--scenario", str(options.get("scenario", "ternary")), "--seed", str(config.seed),
    ]  # fmt: skip
    for key in ("noise", "drift"):  # the fake InView plays the run's scenario as the run names it
        if options.get(key) is not None:
            argv += [f"--{key}", str(options[key])]
    if config.profile is not None:
        argv += ["--profile", str(config.profile)]
    try:
        with open(journal.with_name(journal.name + ".fake-inview.log"), "ab") as log:
            fake = subprocess.Popen(
                argv, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT, env=child_env()
            )
        try:
            kla = dataclasses.replace(config, driver_options={**options, "exchange": str(exchange)})
            spec = RunSpec(campaign=kla, driver="kla", speed=speed, rules=EngineRules(supervision))
            engine = launch_engine(
                spec, journal, auto_resume=spec.rules.auto_resume
            )  # the engine's supervisor
            try:
                yield exchange, engine, fake
            finally:
                _stop(engine)
        finally:
            _stop(fake)
    finally:
        shutil.rmtree(exchange, ignore_errors=True)


def register(subparsers: Any) -> None:
    con = subparsers.add_parser(
        "console",
        help="attach the operator console to a run (or step through a finished one)",
        description="Watch and steer a run from its journal. Leaving (q) never stops the run.",
    )
    con.add_argument("run", metavar="RUN", help="journal path or part of a run name under ./runs")
    con.add_argument("--replay", action="store_true", help="step through the run block by block (← →)")
    con.set_defaults(func=_cmd_console)

    demo = subparsers.add_parser(
        "demo",
        help="start an emulator run in the background and attach the console",
        description="An emulated campaign, slowed so a person can watch it, with the console attached. "
        "In the default supervised mode every global jump waits for you: a approves, v vetoes.",
    )
    demo.add_argument(
        "--speed",
        type=positive_float("--speed"),
        default=DEMO_SPEED,
        help=f"instrument seconds per wall second (default {DEMO_SPEED:g})",
    )
    demo.add_argument("--seed", type=seed_arg, default=0, help="random seed (default 0)")
    demo.add_argument("--policy", help="planning policy (default aeni, the recommended one)")
    demo.add_argument("--scenario", default="ternary", help="emulator scenario (default ternary)")
    demo.add_argument(
        "--supervision",
        choices=SUPERVISION_MODES,
        default="supervised",
        help="auto | supervised (default: global jumps wait) | step (every block waits)",
    )
    demo.add_argument(
        "--driver",
        choices=("sim", "kla"),
        default="sim",
        help="sim (default) | kla: the KLA driver against a fake InView on a temporary exchange folder",
    )
    demo.add_argument(
        "--failure-rate",
        dest="failure_rate",
        type=float,
        default=None,
        help="share of indents the simulated instrument fails (default 0.015, about a real one's)",
    )
    demo.add_argument("--journal", help="journal path (default ./runs/<UTC time>-demo.sqlite)")
    demo.add_argument(
        "--stay",
        action="store_true",
        help="keep the engine running after the console quits (default: quitting stops the demo's engine)",
    )
    demo.add_argument("--runs-dir", dest="runs_dir", default="runs", help=argparse.SUPPRESS)
    demo.set_defaults(func=_cmd_demo)

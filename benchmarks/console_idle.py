"""Console at rest: CPU of an idle console waiting for approval, and the time it takes to quit.

    python benchmarks/console_idle.py                 # 100 indents in auto, then 60 s idle, then quit
    python benchmarks/console_idle.py --indents 200 --idle-s 60

A real engine process runs a simulated campaign as fast as it can (auto) while a headless console
(its own process, 100×30) follows the journal. After ``--indents`` indents the benchmark switches the run
to supervised, so the engine stops at its next proposal and waits for approval: nothing new reaches the
journal. The console's CPU (utime + stime from /proc/<pid>/stat) is then read over ``--idle-s`` seconds;
then the console is told to quit (the ``q`` key) and the time to the key's handling, to the app's end and
to the process's exit is measured, with the CPU the process spent on it (on a loaded machine the wall
time of the interpreter's own teardown varies several-fold; its CPU does not). Prints one table and writes benchmarks/results/console_idle.md.
Targets (issue 28): under 2 % of a core idle, quitting within 1 s.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

CLK_TCK = os.sysconf("SC_CLK_TCK")


def cpu_s(pid: int) -> float:
    """User + system CPU seconds of a process (all its threads) so far."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLK_TCK  # utime, stime (fields 14, 15 of stat)


def child(journal: str, ready: str) -> int:
    """The console, headless: quits on SIGUSR1 as if the operator pressed q; prints the quit timings."""
    from textual import events

    from aeni_console.console.app import ConsoleApp
    from aeni_console.console.journal_source import JournalSource

    app = ConsoleApp(JournalSource(journal))
    marks: dict[str, float] = {}
    original_leave = app.action_leave

    def leave() -> None:
        marks["handled"] = time.perf_counter()
        original_leave()

    app.action_leave = leave  # type: ignore[method-assign]

    async def main() -> None:
        loop = asyncio.get_running_loop()

        def press_q() -> None:
            marks["signal"] = time.perf_counter()
            app.post_message(events.Key("q", "q"))

        loop.add_signal_handler(signal.SIGUSR1, press_q)
        Path(ready).write_text(str(os.getpid()))
        await app.run_async(headless=True, size=(100, 30))
        marks["ended"] = time.perf_counter()

    asyncio.run(main())
    t0 = marks.get("signal", float("nan"))
    print(
        f"QUIT handled_s={marks.get('handled', float('nan')) - t0:.4f} ended_s={marks['ended'] - t0:.4f} "
        f"builds={app.map_panel.builds} posted={app.feed.posted if app.feed else 0} "
        f"polls={app.feed.polls if app.feed else 0}",
        flush=True,
    )
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--indents", type=int, default=100, help="indents run in auto before the idle wait")
    ap.add_argument("--idle-s", type=float, default=60.0, help="seconds of idle measurement (default 60)")
    ap.add_argument("--child", nargs=2, metavar=("JOURNAL", "READY"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        return child(*args.child)

    from aeni_console.cli.run import start_engine_process
    from core.campaign_config import CampaignConfig
    from core.journal import JournalReader, send_command
    from core.runview import Command, CommandKind, EngineState

    env = dict(os.environ, PYTHONPATH=str(ROOT), OMP_NUM_THREADS="1")
    with tempfile.TemporaryDirectory() as tmp:
        journal = Path(tmp) / "idle.sqlite"
        ready = Path(tmp) / "console.pid"
        engine = start_engine_process(CampaignConfig(name="idle", seed=0), journal, "auto", None)
        assert not isinstance(engine, int)
        console = subprocess.Popen(
            [sys.executable, __file__, "--child", str(journal), str(ready)],
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        try:
            t_start = time.monotonic()
            while not ready.exists():
                time.sleep(0.05)
            reader = JournalReader(journal)
            while reader.snapshot().n_indents < args.indents:
                if engine.poll() is not None:
                    raise SystemExit("the engine ended before the idle phase")
                time.sleep(0.5)
            send_command(journal, Command(CommandKind.ADJUST, "bench", {"supervision": "supervised"}))
            while reader.snapshot().state is not EngineState.AWAITING_APPROVAL:
                time.sleep(0.2)
            session_s = time.monotonic() - t_start
            n_indents = reader.snapshot().n_indents
            reader.close()
            time.sleep(3.0)  # let the console take in the last snapshot and build its map
            c0, e0, t0 = cpu_s(console.pid), cpu_s(engine.pid), time.monotonic()
            time.sleep(args.idle_s)
            c1, e1, t1 = cpu_s(console.pid), cpu_s(engine.pid), time.monotonic()
            c_quit0 = cpu_s(console.pid)
            sent = time.monotonic()
            console.send_signal(signal.SIGUSR1)
            _, status, usage = os.wait4(console.pid, 0)  # the rusage of the whole process, to its exit
            exit_s = time.monotonic() - sent
            console.returncode = os.waitstatus_to_exitcode(status)
            assert console.stdout is not None
            out = console.stdout.read()
            quit_cpu_s = usage.ru_utime + usage.ru_stime - c_quit0
        finally:
            if console.poll() is None:
                console.kill()
            engine.terminate()
            engine.wait(timeout=30)
    quit_line = next((ln for ln in out.splitlines() if ln.startswith("QUIT")), "")
    if not quit_line:
        print(out)
        raise SystemExit("the console did not report its quit")
    q = dict(kv.split("=") for kv in quit_line.split()[1:])
    rows = [
        ("session before idle", f"{session_s:.0f} s, {n_indents} indents"),
        (f"console CPU idle over {t1 - t0:.0f} s", f"{100 * (c1 - c0) / (t1 - t0):.2f} % of a core"),
        (f"engine CPU idle over {t1 - t0:.0f} s", f"{100 * (e1 - e0) / (t1 - t0):.2f} % of a core"),
        ("quit: q handled", f"{float(q['handled_s']):.3f} s"),
        ("quit: app ended", f"{float(q['ended_s']):.3f} s"),
        ("quit: process exited", f"{exit_s:.3f} s"),
        ("quit: CPU spent from q to exit", f"{quit_cpu_s:.3f} s"),
        ("console feed: snapshots posted / polls", f"{q['posted']} / {q['polls']}"),
        ("console map builds", q["builds"]),
    ]
    title = "AE-NI console at rest (headless 100×30, engine process awaiting approval)"
    print(title)
    for name, value in rows:
        print(f"{name:<42} {value}")
    md = [f"# {title}", "", f"Load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores.", ""]
    md += ["| measure | value |", "|---|---|"] + [f"| {n} | {v} |" for n, v in rows]
    out_dir = ROOT / "benchmarks" / "results"
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "console_idle.md").write_text("\n".join(md) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())

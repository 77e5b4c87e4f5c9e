"""The engine's supervisor: a small parent process that notices when the engine dies and resumes its run.

An engine cannot report its own kill -9 or the out-of-memory killer (its alert sender dies with it); its
parent can. ``aeni run --detach``, ``aeni resume --detach`` and ``aeni demo`` start this process, which runs
the engine as its child. When the engine ends without ending its run, the supervisor journals the death
(``EngineDied``, through the journal's writer), sends a ``failure`` alert naming the cause and resumes the
run through ``aeni resume`` (the one resume path: every indent the journal holds stays as it is, the rest is
measured once), at most ``[run] auto_resume`` times in a row with a pause that doubles each time; then it
stops with an alert (a crash loop). A run that ended (finished, stopped or aborted by the operator), or
that was paused or stopping by the operator's word when its engine died, is never resumed by it.

The engine's launch is opaque here (an argv and the bytes for its stdin): how a run is described and
handed to an engine is the caller's business. The supervisor holds ``<journal>.supervisor`` (its PID, under
a lock) for its life, so ``aeni runs`` shows it beside the engine's PID.
"""

from __future__ import annotations

import argparse
import contextlib
import fcntl
import os
import signal
import sqlite3
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

from aeni_console.alerts import Severity, send
from core.errors import InputError
from core.journal import Journal, engine_running
from core.journal import lock_path_for as engine_lock
from core.notifyconfig import load_run_notify
from core.run.events import EngineDied
from core.run.spec import EngineRules

# resumes in a row without a new indent before it is a crash loop; the first pause before a resume, doubled for
# each further attempt in a row (a run's own are in its spec's rules)
DEFAULT_AUTO_RESUME = EngineRules.auto_resume
DEFAULT_BACKOFF_S = EngineRules.resume_backoff_s
PROGRESS_RESET_S = 600.0  # an engine that ran this long (or journaled a new indent) ends a crash loop
SUPERVISOR_MODULE = "aeni_console.cli.supervisor"
LOG_PREFIX = "supervisor: "
# when its engine died in these states the operator had said stop or wait: not resumed automatically
OPERATOR_HELD = {"paused": "paused by the operator", "stopping": "stopping"}

SUPERVISED_ENV = "AENI_SUPERVISED"  # set in a supervised engine's environment: it needs no watcher of its own


class EngineProcess(Protocol):
    """What the supervisor needs of an engine process: a child (Popen) or an adopted foreground engine."""

    @property
    def pid(self) -> int: ...

    def wait(self) -> int: ...

    def poll(self) -> int | None: ...

    def send_signal(self, sig: int) -> None: ...


Launch = Callable[[], EngineProcess]
NO_STATUS = -1_000_000  # an adopted engine's end: not our child, so no exit status to read


class Adopted:
    """A foreground engine (``aeni run`` in a terminal) watched from beside it: it is not our child, so
    its end is seen through its journal lock (released when its process ends, however it ends)."""

    def __init__(self, journal: Path, pid: int) -> None:
        self.journal, self.pid = journal, pid
        self._ended = False

    def wait(self) -> int:

        fd = os.open(engine_lock(self.journal), os.O_RDONLY)
        try:
            fcntl.flock(fd, fcntl.LOCK_SH)  # blocks, without a poll, until the engine lets go
            fcntl.flock(fd, fcntl.LOCK_UN)
        finally:
            os.close(fd)
        self._ended = True
        return NO_STATUS

    def poll(self) -> int | None:
        return NO_STATUS if self._ended else None

    def send_signal(self, sig: int) -> None:
        os.kill(self.pid, sig)


def lock_path_for(journal: str | Path) -> Path:
    p = Path(journal)
    return p.with_name(p.name + ".supervisor")


def supervisor_pid(journal: str | Path) -> int | None:
    """The PID of the supervisor watching this journal right now, or None."""
    path = lock_path_for(journal)
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except OSError:  # held: a supervisor is alive
            text = os.pread(fd, 32, 0).decode(errors="replace").strip()
            return int(text) if text.isdigit() else None
        fcntl.flock(fd, fcntl.LOCK_UN)
        return None
    finally:
        os.close(fd)


def supervisor_argv(
    journal: str | Path,
    engine_argv: Sequence[str],
    *,
    auto_resume: int = DEFAULT_AUTO_RESUME,
    backoff_s: float = DEFAULT_BACKOFF_S,
    stdin: bool = False,
    log: str | Path | None = None,
) -> list[str]:
    """The command line of a supervisor that runs ``engine_argv`` first (``stdin``: it hands the engine
    the bytes it was given on its own stdin)."""
    argv = [
        sys.executable, "-m", SUPERVISOR_MODULE, "--journal", str(journal),
        "--auto-resume", str(int(auto_resume)), "--backoff-s", repr(float(backoff_s)),
    ]  # fmt: skip
    if stdin:
        argv.append("--stdin")
    if log is not None:
        argv += ["--log", str(log)]
    return [*argv, "--", *engine_argv]


def resume_argv(journal: str | Path) -> list[str]:
    """How the supervisor resumes a run: ``aeni resume`` in the foreground of its own child process."""
    return [sys.executable, "-m", "aeni_console.cli.main", "resume", str(journal), "--quiet"]


# --------------------------------------------------------------------------------------------------
# what the journal says about a run, read-only


@dataclass(frozen=True)
class RunState:
    state: str
    completed: bool
    stop_reason: str
    indents: int
    sessions_of: frozenset[int]  # the PIDs of every engine that began a session on it


def read_run(journal: Path) -> RunState | None:
    """None while the journal does not exist or cannot be read."""
    if not journal.is_file():
        return None
    try:
        conn = sqlite3.connect(f"file:{journal}?mode=ro", uri=True, timeout=10.0)
        try:
            state, completed, reason = conn.execute(
                "SELECT state, completed, stop_reason FROM engine_state"
            ).fetchone()
            (indents,) = conn.execute("SELECT COUNT(*) FROM indents").fetchone()
            pids = frozenset(int(r[0]) for r in conn.execute("SELECT pid FROM sessions"))
        finally:
            conn.close()
    except (sqlite3.Error, TypeError):
        return None
    return RunState(str(state), bool(completed), str(reason or ""), int(indents), pids)


def ended_by_itself(run: RunState) -> str | None:
    """Why this run must not be resumed (it ended, or the operator held it), or None."""
    if run.completed:
        return f"the run finished ({run.stop_reason or 'done'})"
    if run.state == "stopped":
        return f"the run was stopped ({run.stop_reason or 'by the operator'})"
    if run.state == "failed" and run.stop_reason == "interrupted":
        return "the engine was interrupted on purpose (Ctrl-C twice)"
    return None


def last_log_line(log: Path | None) -> str:
    """The engine's last words in the log (the supervisor's own lines left out)."""
    if log is None:
        return ""
    try:
        with log.open("rb") as fh:
            fh.seek(max(0, fh.seek(0, os.SEEK_END) - 8192))
            text = fh.read().decode("utf-8", errors="replace")
    except OSError:
        return ""
    lines = [ln.strip() for ln in text.splitlines() if ln.strip() and not ln.startswith(LOG_PREFIX)]
    return lines[-1][:300] if lines else ""


def describe_exit(returncode: int, log: Path | None) -> tuple[str, int | None, str | None]:
    """(the cause in words, the exit code, the signal's name) of an engine process that ended."""
    if returncode == NO_STATUS:
        return (
            "engine ended without ending its run (a foreground engine: no exit status to read; kill -9, "
            "the out-of-memory killer or its terminal closed)",
            None,
            None,
        )
    if returncode < 0:
        try:
            name = signal.Signals(-returncode).name
        except ValueError:
            name = f"signal {-returncode}"
        why = " (kill -9, or the kernel's out-of-memory killer)" if name == "SIGKILL" else ""
        return f"engine killed by {name}{why}", None, name
    said = last_log_line(log)
    return f"engine exited with code {returncode}" + (f": {said}" if said else ""), returncode, None


# --------------------------------------------------------------------------------------------------
# the supervisor


class Supervisor:
    """Runs ``first``, then (after a death) ``resume``, until the run ends or a crash loop stops it."""

    def __init__(
        self,
        journal: str | Path,
        first: Launch,
        resume: Launch,
        *,
        auto_resume: int = DEFAULT_AUTO_RESUME,
        backoff_s: float = DEFAULT_BACKOFF_S,
        log: str | Path | None = None,
        poll_s: float = 0.2,
        say: Callable[[str], None] | None = None,
    ) -> None:
        self.journal = Path(journal)
        self.first = first
        self.resume = resume
        self.auto_resume = max(0, int(auto_resume))
        self.backoff_s = max(0.0, float(backoff_s))
        self.log = Path(log) if log is not None else self.journal.with_name(self.journal.name + ".log")
        self.poll_s = poll_s
        self.say = say or _say
        self.child: EngineProcess | None = None
        self.stopping = False
        self.deaths = 0  # every engine death seen (for the report and tests)

    # -- signals ---------------------------------------------------------------------------------
    def stop(self, signum: int = signal.SIGTERM) -> None:
        """Stop supervising and ask the engine to stop as Ctrl-C would (it finishes the indent)."""
        self.stopping = True
        child = self.child
        if child is not None and child.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                child.send_signal(signum)

    def install_signals(self) -> None:
        for sig in (signal.SIGTERM, signal.SIGINT):
            signal.signal(sig, lambda signum, _frame: self.stop(signal.SIGTERM))
        signal.signal(signal.SIGHUP, signal.SIG_IGN)  # a closed terminal is no reason to stop a night's run

    # -- the loop --------------------------------------------------------------------------------
    def run(self) -> int:
        launch, attempt, code = self.first, 0, 0
        while True:
            before = read_run(self.journal)
            started_at = time.monotonic()
            self.child = launch()
            pid = self.child.pid
            self.say(f"PID {os.getpid()} supervises engine PID {pid}")
            code = self._wait(self.child)
            after = read_run(self.journal)
            began = after is not None and pid in after.sessions_of
            if self.stopping:
                self.say(f"stopped; the engine ended with {code}")
                return code
            if launch is self.first and not began and code >= 0:
                return code  # the engine never started its run: whoever started us says why (its log)
            if after is None:
                self.say(f"the engine ended with {code} and its journal cannot be read: not resuming")
                return code
            held = ended_by_itself(after)
            if held is not None and (code >= 0 or code == NO_STATUS):
                self.say(f"the engine ended: {held}")
                return code
            if self._someone_else_runs_it():
                self.say("another engine runs this journal now: not supervising it any more")
                return code
            self.deaths += 1
            cause, exit_code, sig = describe_exit(code, self.log)
            if code == NO_STATUS and after.state == "failed" and after.stop_reason:
                cause = f"engine failed: {after.stop_reason}"
            if not began:
                cause = f"the resumed engine did not start ({cause})"
            progressed = (
                before is not None and after.indents > before.indents
            ) or time.monotonic() - started_at >= PROGRESS_RESET_S
            attempt = 1 if progressed or launch is self.first else attempt + 1
            reason = OPERATOR_HELD.get(after.state)
            if held is not None:  # killed after it had ended (while closing the journal): nothing to do
                self._died(pid, cause, exit_code, sig, f"not resumed: {held}", "warning")
                return code
            if reason is not None:
                action = f"not resumed: the run was {reason} (`aeni resume {self.journal}` when ready)"
                self._died(pid, cause, exit_code, sig, action, "failure")
                return code or 1
            if attempt > self.auto_resume:
                n = self.auto_resume
                if code == NO_STATUS:
                    action = (
                        f"not resumed: it ran in the foreground (`aeni resume {self.journal}`; a run started "
                        "with --detach is resumed by its supervisor)"
                    )
                elif n:
                    action = (
                        f"not resumed: {n} automatic resume(s) in a row ended the same way (a crash loop); "
                        f"`aeni resume {self.journal}` once the cause is fixed"
                    )
                else:
                    action = f"not resumed ([run] auto_resume = 0): `aeni resume {self.journal}`"
                self._died(pid, cause, exit_code, sig, action, "failure")
                return code or 1
            wait_s = self.backoff_s * 2 ** (attempt - 1)
            self._died(
                pid,
                cause,
                exit_code,
                sig,
                f"resuming (attempt {attempt} of {self.auto_resume}) in {wait_s:g} s",
            )
            if self._sleep(wait_s):
                self.say("stopped while waiting to resume")
                return code
            if self._someone_else_runs_it():
                self.say("another engine runs this journal now: not supervising it any more")
                return 0
            launch = self.resume

    def _wait(self, child: EngineProcess) -> int:
        while True:
            try:
                return child.wait()
            except InterruptedError:  # pragma: no cover (PEP 475 retries; kept for clarity)
                continue

    def _sleep(self, seconds: float) -> bool:
        """Sleep, True when asked to stop meanwhile."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            if self.stopping:
                return True
            time.sleep(min(self.poll_s, max(end - time.monotonic(), 0.0)))
        return self.stopping

    def _someone_else_runs_it(self) -> bool:
        return engine_running(self.journal)

    # -- telling ---------------------------------------------------------------------------------
    def _died(
        self,
        pid: int,
        cause: str,
        exit_code: int | None,
        sig: str | None,
        action: str,
        severity: str = "failure",
    ) -> None:
        """Journal the death, then alert (an alert is sent even when the journal cannot take the row)."""
        self.say(f"{cause}; {action}")
        journaled = self._journal(pid, cause, exit_code, sig, action)
        body = f"{self.journal.name}: {cause}; {action}"
        if journaled:
            body += f" ({journaled})"
        self._alert(body, severity, cause)

    def _journal(self, pid: int, cause: str, exit_code: int | None, sig: str | None, action: str) -> str:
        """'' when journaled, else why not (in words)."""
        try:
            journal = Journal.open_writer(self.journal)
        except (InputError, OSError, sqlite3.Error) as exc:
            return f"not journaled: {getattr(exc, 'problem', exc)}"
        try:
            (t_s,) = journal.conn.execute("SELECT COALESCE(MAX(t_s), 0.0) FROM events").fetchone()
            journal.emit(EngineDied(float(t_s), cause, pid, exit_code, sig, action))
        except (sqlite3.Error, OSError) as exc:
            return f"not journaled: {exc}"
        finally:
            with contextlib.suppress(sqlite3.Error, OSError):
                journal.close(compact=False)
        return ""

    def _alert(self, body: str, severity: str, cause: str) -> None:
        try:
            notify = load_run_notify(self.journal)
        except InputError as exc:
            self.say(f"no alert sent: {exc}")
            return
        if not notify.enabled:
            return
        try:
            ok, how = send(notify.urls, body, severity=Severity(severity), cause=cause)
        except Exception as exc:  # a sender that raises is a failed send; the supervisor goes on
            ok, how = False, type(exc).__name__
        self.say(f"alert {'sent' if ok else 'not sent'} ({severity}): {how}")


def _say(line: str) -> None:
    """A line in the log; a log on a full disk must not take the supervisor down with it."""
    with contextlib.suppress(OSError):
        print(LOG_PREFIX + line, flush=True)


def _hold_lock(journal: Path) -> int:
    """Take ``<journal>.supervisor`` for this process's life (the PID in it); SystemExit(2) when another
    supervisor holds it."""
    path = lock_path_for(journal)
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o600)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "?"
        os.close(fd)
        print(
            f"aeni: error: {journal}: a supervisor (PID {holder}) already watches this run", file=sys.stderr
        )
        raise SystemExit(2) from None
    os.ftruncate(fd, 0)
    os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
    return fd


def watch_foreground(journal: Path, log: Path, env: dict[str, str]) -> int | None:
    """Start a supervisor beside this foreground engine (which holds the journal): when this process dies
    without ending the run it journals and alerts the death; it does not resume a foreground run (someone
    at the terminal may be resuming it by hand). None when this engine is itself supervised."""
    if os.environ.get(SUPERVISED_ENV):
        return None
    argv = [
        sys.executable, "-m", SUPERVISOR_MODULE, "--journal", str(journal), "--log", str(log),
        "--adopt", str(os.getpid()), "--auto-resume", "0",
    ]  # fmt: skip
    with open(log, "ab") as fh:
        proc = subprocess.Popen(
            argv,
            stdin=subprocess.DEVNULL,
            stdout=fh,
            stderr=subprocess.STDOUT,
            start_new_session=True,  # it outlives this process and its terminal
            env={**env, SUPERVISED_ENV: "1"},
        )
    return proc.pid


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="aeni-supervisor", description=__doc__.split("\n\n")[0])
    ap.add_argument("--journal", required=True, type=Path)
    ap.add_argument("--log", type=Path, default=None)
    ap.add_argument("--auto-resume", dest="auto_resume", type=int, default=DEFAULT_AUTO_RESUME)
    ap.add_argument("--backoff-s", dest="backoff_s", type=float, default=DEFAULT_BACKOFF_S)
    ap.add_argument("--stdin", action="store_true", help="hand this process's stdin to the first engine")
    ap.add_argument("--adopt", type=int, default=None, help="watch this foreground engine PID (no resume)")
    ap.add_argument("engine", nargs=argparse.REMAINDER, help="-- the engine's command line")
    args = ap.parse_args(argv)
    engine = args.engine[1:] if args.engine[:1] == ["--"] else args.engine
    if not engine and args.adopt is None:
        ap.error("the engine's command line is missing (after --)")
    data = sys.stdin.buffer.read() if args.stdin else None
    journal: Path = args.journal
    fd = _hold_lock(journal)

    env = {**os.environ, SUPERVISED_ENV: "1"}

    def launch(argv: Sequence[str], payload: bytes | None) -> subprocess.Popen[bytes]:
        proc = subprocess.Popen(
            list(argv), stdin=subprocess.PIPE if payload is not None else subprocess.DEVNULL, env=env
        )
        if payload is not None:
            assert proc.stdin is not None
            with contextlib.suppress(BrokenPipeError):  # an engine that died at once says why in its log
                proc.stdin.write(payload)
            with contextlib.suppress(BrokenPipeError):
                proc.stdin.close()
        return proc

    adopt: int | None = args.adopt
    first: Launch = (lambda: Adopted(journal, adopt)) if adopt is not None else (lambda: launch(engine, data))
    sup = Supervisor(
        journal,
        first,
        lambda: launch(resume_argv(journal), None),
        auto_resume=0 if adopt is not None else args.auto_resume,
        backoff_s=args.backoff_s,
        log=args.log,
    )
    sup.install_signals()
    try:
        return sup.run()
    finally:
        os.close(fd)


if __name__ == "__main__":
    sys.exit(main())

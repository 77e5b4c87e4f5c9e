"""The engine host: a run's engine as its own process, on its journal.

One JSON crosses the process boundary: the :class:`~core.run.spec.RunSpec`, written to the engine's stdin by
:func:`launch_engine` (never on its command line, which ``ps`` shows every user), read by ``aeni run
--spec-stdin``. The journal keeps the spec (without its alert URLs, which stay owner-only beside it) and
``aeni resume`` reads it back. :func:`run_engine` composes the run (``core.run.compose``) and runs it here.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from aeni_console.cli.common import check_new_journal, check_resumable_journal
from core.access import journal_gid, protect
from core.errors import InputError
from core.notifyconfig import load_run_notify, notify_path_for, write_private
from core.run.machine import EngineState
from drivers.kla.exchange import check_exchange_dir

if TYPE_CHECKING:
    from core.campaign import Campaign
    from core.journal import Journal
    from core.run.spec import RunSpec

ENGINE_MODULE = "aeni_console.cli.main"
_REPO_ROOT = Path(__file__).resolve().parents[2]


def child_env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(_REPO_ROOT), env.get("PYTHONPATH", "")) if p)
    # one BLAS/torch thread: the GP is small, and a fixed thread count keeps a resumed run bit-identical
    env.setdefault("OMP_NUM_THREADS", "1")
    return env


def engine_argv(journal_path: str | Path, *, resume: bool = False) -> list[str]:
    """The command line of an engine process: the journal only; its spec comes on stdin."""
    argv = [sys.executable, "-m", ENGINE_MODULE, "run", "--spec-stdin", "--journal", str(journal_path)]
    return [*argv, "--resume"] if resume else argv


def launch_engine(
    spec: RunSpec | str,
    journal_path: str | Path,
    *,
    resume: bool = False,
    detach: bool = False,
    log_path: str | Path | None = None,
    wait_s: float = 60.0,
    auto_resume: int | None = None,
    resume_backoff_s: float | None = None,
) -> subprocess.Popen[bytes]:
    """Start an engine process for ``spec`` (a RunSpec or its JSON) on a new journal, or (``resume``) on the
    run's existing journal, and return it once the engine holds the journal (so a console can attach at once).

    Output goes to ``<journal>.log``. With ``detach`` the process runs in its own session and survives the
    caller's terminal closing. InputError, with the log's last line, when the engine exits before that.
    ``auto_resume``: the engine runs under its supervisor (aeni_console.cli.supervisor), which hands it the spec,
    journals and alerts its death and resumes it that many times in a row (the spec's ``rules.auto_resume``
    for a run as its file says), the first after ``resume_backoff_s`` (None: the spec's); the process is then
    the supervisor's.
    """
    # imported here, not at the top: the run's spec and journal pull scipy, the engine torch; `aeni --help` must start fast
    from aeni_console.cli.supervisor import supervisor_argv
    from core.journal import engine_running
    from core.run.spec import RunSpec

    text = spec if isinstance(spec, str) else spec.to_json()
    parsed = RunSpec.from_json(text, "run spec")
    group = parsed.group
    journal = Path(journal_path) if resume else check_new_journal(journal_path)
    log = Path(log_path) if log_path is not None else journal.with_name(journal.name + ".log")
    argv = engine_argv(journal, resume=resume)
    if auto_resume is not None:  # the supervisor hands the engine its stdin and resumes it when it dies
        backoff_s = parsed.rules.resume_backoff_s if resume_backoff_s is None else resume_backoff_s
        argv = supervisor_argv(
            journal, argv, auto_resume=auto_resume, backoff_s=backoff_s, stdin=True, log=log
        )
    with open(log, "ab") as fh:
        protect(log, journal_gid(group))  # the log says what the journal says: same readers
        proc = subprocess.Popen(
            argv,
            stdin=subprocess.PIPE,
            stdout=fh,
            stderr=subprocess.STDOUT,
            start_new_session=detach,
            env=child_env(),
            cwd=os.getcwd(),
        )
    assert proc.stdin is not None
    with contextlib.suppress(BrokenPipeError):  # an engine that died at once says why in its log
        proc.stdin.write(text.encode("utf-8"))
    with contextlib.suppress(BrokenPipeError):
        proc.stdin.close()
    started = (lambda: engine_running(journal)) if resume else journal.exists
    deadline = time.monotonic() + wait_s
    while not started() and time.monotonic() < deadline:
        if proc.poll() is not None:
            break
        time.sleep(0.05)
    if not started() and proc.poll() is not None:
        tail = [ln for ln in log.read_text(encoding="utf-8", errors="replace").splitlines() if ln.strip()]
        why = tail[-1] if tail else f"exit code {proc.returncode}"
        raise InputError(str(journal), f"the engine did not start: {why}")
    if detach:
        threading.Thread(target=proc.wait, daemon=True).start()  # reap it if we outlive it
    return proc


def start_engine_process(
    config: Any,
    journal_path: str | Path,
    supervision: str = "auto",
    speed: float | None = None,
    detach: bool = False,
    *,
    log_path: str | Path | None = None,
    wait_s: float = 60.0,
    driver: str = "sim",
    exchange: str | None = None,
    group: str | None = None,
    notify: Any = None,
) -> subprocess.Popen[bytes] | int:
    """:func:`launch_engine` for a campaign config and a few run options (the console's demo, the tests):
    the Popen handle, or with ``detach`` the PID."""
    from core.runconfig import RunOptions, run_spec

    if exchange is not None:
        config = dataclasses.replace(config, driver_options={**config.driver_options, "exchange": exchange})
    options = RunOptions(driver=driver, supervision=supervision, speed=speed, group=group)
    proc = launch_engine(
        run_spec(config, options, notify), journal_path, detach=detach, log_path=log_path, wait_s=wait_s
    )
    return proc.pid if detach else proc


# --------------------------------------------------------------------------------------------------
# the engine process itself


def _prepare_process() -> None:
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    try:
        import torch

        torch.set_num_threads(1)
    except ImportError:  # pragma: no cover
        pass


def _print(line: str) -> None:
    print(line, flush=True)


def create_run_journal(path: Path, spec: RunSpec, campaign: Campaign) -> Journal:
    """A new journal for the run of ``spec`` (the engine process, and the console tests' engine): it keeps
    the spec (without its alert URLs) with the sample the campaign runs on."""
    from core.campaign_config import campaign_config_to_dict
    from core.journal import Journal

    return Journal.create(
        path,
        campaign_config_to_dict(campaign.config),  # with the sample the campaign runs on
        campaign.profile,
        campaign.calibration.to_dict(),
        supervision=spec.rules.supervision,
        driver=spec.driver,
        speed=spec.speed,
        grid_baseline_s=campaign.grid_baseline_s,
        stage_bounds_um=campaign.stage_bounds_um,
        name=spec.name,
        group_gid=journal_gid(spec.group),
        extra={"run_spec": spec.public().to_dict()},
    )


def _discard_new_journal(path: Path) -> None:
    """Remove a journal (and its side files) that a run created but never started on."""
    from core.journal import lock_path_for

    for p in (path, Path(f"{path}-wal"), Path(f"{path}-shm"), notify_path_for(path), lock_path_for(path)):
        with contextlib.suppress(FileNotFoundError):
            p.unlink()


def new_run_spec(spec: RunSpec) -> RunSpec:
    """A new run's spec as its engine runs it: a KLA run's exchange folder checked and made absolute (kept
    in the journal for a resume)."""
    if spec.driver != "kla":
        return spec
    exchange = check_exchange_dir(str(spec.driver_options.get("exchange") or ""))  # before any journal
    opts = {**spec.driver_options, "exchange": str(exchange.resolve())}
    return dataclasses.replace(spec, campaign=dataclasses.replace(spec.campaign, driver_options=opts))


def resumed_spec(path: Path, speed: float | None = None, supervision: str | None = None) -> RunSpec | None:
    """The spec a journal keeps, as a resume runs it (its supervision as the run last had it, unless
    ``supervision`` says otherwise; ``speed`` overrides the stored one); None when the run already finished.
    A journal written before the spec is read as the spec it describes."""
    from core.journal import JournalReader
    from core.run.spec import run_spec_from_meta

    with JournalReader(path) as reader:  # refuses a bad journal before anything opens it for writing
        meta = reader.meta
        row = reader.q.engine_row()
    if row.get("completed"):
        _print(f"{path}: run already finished ({row.get('stop_reason') or 'done'}); nothing to resume")
        return None
    check_resumable_journal(path)
    try:
        spec = run_spec_from_meta(meta, str(row.get("supervision") or "auto"))
    except InputError as exc:
        raise InputError(str(path), exc.problem) from None
    sup = supervision or str(row.get("supervision") or spec.rules.supervision)
    return dataclasses.replace(
        spec,
        speed=speed if speed is not None else spec.speed,
        rules=dataclasses.replace(spec.rules, supervision=sup),
    )


def run_engine(
    journal_path: str | Path,
    *,
    create: RunSpec | tuple[Any, Any] | None = None,
    resume_with: RunSpec | None = None,
    speed: float | None = None,
    supervision: str | None = None,
    quiet: bool = False,
    notify: Any = None,
    watch: bool = False,
) -> int:
    """Run ``create`` (a RunSpec, or a campaign config and its core.runconfig.RunOptions) on a new journal,
    or resume the run of an existing one, in this process (``resume_with``: the spec a detaching ``aeni resume``
    read from the journal and checked, handed over on stdin).

    The spec's alerts (or ``notify``) go out from a thread beside the engine; a new run keeps them beside its
    journal, owner-only, for ``aeni resume``. ``watch`` (a foreground run with alerts): a supervisor beside
    this process journals and alerts its death, which this process cannot (kill -9)."""
    from aeni_console.alerts import AlertWatcher
    from aeni_console.cli.supervisor import watch_foreground
    from core.journal import Journal
    from core.run.compose import Hosting, compose
    from core.run.spec import RunSpec
    from core.runconfig import run_spec
    from drivers.registry import DRIVERS

    _prepare_process()
    path = Path(journal_path)
    if create is not None:
        spec = create if isinstance(create, RunSpec) else run_spec(*create, notify)
        if notify is not None:
            spec = dataclasses.replace(spec, notify=notify)
        if speed is not None:
            spec = dataclasses.replace(spec, speed=speed)
        if supervision is not None:
            spec = dataclasses.replace(spec, rules=dataclasses.replace(spec.rules, supervision=supervision))
        spec = new_run_spec(spec)
    else:
        found = resume_with or resumed_spec(path, speed, supervision)
        if found is None:
            return 0
        spec = (
            found
            if found.notify.enabled
            else dataclasses.replace(found, notify=notify or load_run_notify(path))
        )
    opened: list[Journal] = []

    def record(composed: RunSpec, campaign: Campaign) -> Journal:
        journal = (
            create_run_journal(path, composed, campaign) if create is not None else Journal.open_writer(path)
        )
        opened.append(journal)
        if create is not None and spec.notify.enabled:
            write_private(notify_path_for(path), spec.notify.to_json())
        return journal

    try:
        run = compose(
            spec, DRIVERS, record, journal=path, hosting=Hosting(progress=None if quiet else _print)
        )
    except BaseException:
        for journal in opened:
            journal.close(compact=False)
        if (
            create is not None and opened
        ):  # nothing measured yet: leave nothing, so the same command runs again
            _discard_new_journal(path)
        raise
    journal, engine = opened[0], run.engine
    if not quiet:
        _print(f"journal {path} (engine PID {os.getpid()}, supervision {engine.supervision})")
    asked: list[int] = []

    def on_signal(signum: int, _frame: Any) -> None:
        if asked:  # a second Ctrl-C: stop now (the journal stays resumable)
            raise KeyboardInterrupt
        asked.append(signum)
        engine.request_abort()
        if not quiet:
            _print("stopping after the current indent (press Ctrl-C again to stop at once)")

    previous = {}
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(ValueError):  # not the main thread
            previous[sig] = signal.signal(sig, on_signal)
    alerts = None
    if spec.notify.enabled:
        alerts = AlertWatcher(path, spec.notify).start()
        if watch:
            watch_foreground(path, path.with_name(path.name + ".log"), child_env())
    try:
        state = engine.run()
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        journal.close()
        if alerts is not None:
            alerts.stop()
    if not quiet or state != EngineState.STOPPED:
        _print(f"{state.label}: {engine.stop_reason or 'done'}")
    return 0 if state == EngineState.STOPPED else 1


def preflight_resume(path: Path, speed: float | None) -> RunSpec | None:
    """What a resumed engine checks first, done before detaching so a refusal is an exit 2 and not a line in
    the log of a process that died: the journal, its spec and sample, the driver (a KLA run's exchange
    folder). The spec to resume with; None when the run already finished (nothing to start)."""
    from core.campaign import Campaign
    from drivers.registry import DRIVERS

    spec = resumed_spec(path, speed)
    if spec is None:
        return None
    try:
        campaign = Campaign(spec.campaign)
    except InputError as exc:
        raise InputError(str(path), exc.problem) from None
    DRIVERS.driver(spec, campaign.sample, campaign.profile, path)
    return spec

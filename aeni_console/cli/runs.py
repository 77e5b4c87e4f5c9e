"""``aeni runs [FOLDER]``: every run journal under a folder, so forgotten engines do not pile up.

One line per journal: its state, its owner, whether an engine process holds it right now (and its PID),
its age, its progress and the PID of the engine's supervisor (a detached run's). A journal that cannot be read is listed with the reason, not skipped.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import asdict, dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

from aeni_console.cli.common import dumps
from core.errors import InputError


@dataclass(frozen=True)
class RunRow:
    """What `aeni runs` shows about one journal."""

    journal: str
    name: str
    state: str
    owner: str
    engine_alive: bool
    pid: int | None
    age_s: float | None  # since the journal was created
    updated_s: float | None  # since the engine last wrote its state
    indents: int | None
    instrument_s: float | None
    problem: str = ""
    supervisor_pid: int | None = None  # the engine's supervisor (aeni_console.cli.supervisor), alive now


def _seconds_since(utc: str | None, now: float) -> float | None:
    if not utc:
        return None
    try:
        return max(0.0, now - datetime.fromisoformat(utc.replace("Z", "+00:00")).timestamp())
    except ValueError:
        return None


def run_row(path: Path, now: float | None = None) -> RunRow:
    """Read one journal read-only; an unreadable one becomes a row naming the problem."""
    # imported here, not at the top: the journal pulls scipy, and `aeni --help` must start fast
    from aeni_console.cli.supervisor import supervisor_pid
    from core.journal import JournalReader, engine_running, user_name

    now = time.time() if now is None else now
    alive = engine_running(path)
    sup = supervisor_pid(path)
    try:
        owner = user_name(path.stat().st_uid)
        with JournalReader(path) as reader:
            snap = reader.snapshot()
            row = reader.q.engine_row()
            created = reader.meta.get("created_utc")
    except (InputError, OSError) as exc:
        return RunRow(
            str(path), path.stem, "unreadable", "?", alive, None, None, None, None, None, str(exc), sup
        )
    return RunRow(
        journal=str(path),
        name=snap.run_name,
        state=snap.state.value,
        owner=owner,
        engine_alive=alive,
        pid=int(row["pid"]) if alive and row.get("pid") is not None else None,
        age_s=_seconds_since(created, now),
        updated_s=_seconds_since(row.get("updated_utc"), now),
        indents=snap.n_indents,
        instrument_s=snap.instrument_s,
        supervisor_pid=sup,
    )


def list_runs(folder: str | Path) -> list[RunRow]:
    """Every ``*.sqlite`` journal directly under ``folder``, oldest first."""
    d = Path(folder)
    if not d.exists():
        raise InputError(str(d), "no such folder (runs are kept in ./runs unless --journal said otherwise)")
    if not d.is_dir():
        raise InputError(str(d), "is a file, not a folder of runs (`aeni status FILE` shows one run)")
    paths = sorted(p for p in d.glob("*.sqlite") if p.is_file())
    return [run_row(p) for p in paths]


def _age(seconds: float | None) -> str:
    if seconds is None:
        return "—"
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 2 * 3600:
        return f"{seconds / 60:.0f} min"
    if seconds < 2 * 86400:
        return f"{seconds / 3600:.1f} h"
    return f"{seconds / 86400:.1f} d"


def format_runs(rows: list[RunRow]) -> str:
    if not rows:
        return "no runs"
    header = f"{'run':<34} {'state':<18} {'owner':<10} {'engine':<14} {'age':>8} {'indents':>7}  supervisor"
    lines = [header]
    for r in rows:
        engine = f"alive PID {r.pid}" if r.engine_alive and r.pid else ("alive" if r.engine_alive else "—")
        sup = f"  PID {r.supervisor_pid}" if r.supervisor_pid else ""
        if r.supervisor_pid and not r.engine_alive:
            sup += " (resuming the engine)"
        name = Path(r.journal).name
        if r.problem:
            lines.append(f"{name:<34} {'unreadable':<18} {r.owner:<10} {engine:<14}  {r.problem}{sup}")
            continue
        indents = "—" if r.indents is None else str(r.indents)
        lines.append(
            f"{name:<34} {r.state:<18} {r.owner:<10} {engine:<14} {_age(r.age_s):>8} {indents:>7}{sup}"
        )
    waiting = [r for r in rows if r.engine_alive and r.state == "awaiting-approval"]
    if waiting:
        lines.append(
            f"{len(waiting)} engine(s) wait for approval: `aeni console RUN` to answer, "
            "or `aeni send RUN abort` to end them"
        )
    return "\n".join(lines)


def _handler(args: argparse.Namespace) -> int:
    rows = list_runs(args.folder)
    if args.alive:
        rows = [r for r in rows if r.engine_alive]
    if args.json:
        print(dumps([asdict(r) for r in rows]))
    else:
        print(format_runs(rows))
    return 0


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "runs",
        help="list the runs under a folder: state, owner, engine alive, age",
        description="List the run journals under a folder (default ./runs) with their state, owner, "
        "whether an engine is running them, their age and their progress.",
    )
    p.add_argument("folder", nargs="?", default="runs", metavar="FOLDER", help="default ./runs")
    p.add_argument("--alive", action="store_true", help="only runs whose engine process is running")
    p.add_argument("--json", action="store_true", help="a JSON list, one object per journal")
    p.set_defaults(func=_handler)

"""A supervised emulator run answered by a script instead of a person: for examples, figures and tests.

The engine runs in a thread of this process on a new journal; the script answers each approval request
through the journal, exactly as a console would (``send_command``), vetoing or approving in the order
given and approving everything after that.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from aeni_console.cli.run import run_engine
from core.journal import JournalReader, send_command
from core.runconfig import load_run_config
from core.runview import Command, CommandKind, EngineState


def run_supervised(
    journal: str | Path,
    overrides: dict[str, Any],
    answers: Sequence[str] = ("veto", "approve"),
    timeout_s: float = 300.0,
) -> Path:
    """Run ``aeni run`` (with ``overrides`` such as ``planner.budget_s``) supervised to its end; returns the journal."""

    path = Path(journal)
    rc = load_run_config(None, {**overrides, "run.supervision": "supervised"})
    failure: list[BaseException] = []

    def engine() -> None:
        try:
            run_engine(path, create=rc.spec(), quiet=True)
        except BaseException as exc:  # pragma: no cover - reported below
            failure.append(exc)

    thread = threading.Thread(target=engine, name="scripted-engine", daemon=True)
    thread.start()
    todo = list(answers)
    answered: set[tuple[int, float, float]] = set()
    deadline = time.monotonic() + timeout_s
    while thread.is_alive():
        if time.monotonic() > deadline:
            raise TimeoutError(f"{path}: the scripted run did not finish within {timeout_s:g} s")
        time.sleep(0.05)
        if not path.exists():
            continue
        with JournalReader(path) as reader:
            snap = reader.snapshot()
        if snap.state != EngineState.AWAITING_APPROVAL or snap.pending is None:
            continue
        b = snap.pending.block
        key = (b.block_id, b.center_x_um, b.center_y_um)  # after a veto the next best has the same block id
        if key in answered:
            continue
        kind = todo.pop(0) if todo else "approve"
        answered.add(key)
        send_command(path, Command(CommandKind(kind), author="script"))
    if failure:
        raise failure[0]
    return path

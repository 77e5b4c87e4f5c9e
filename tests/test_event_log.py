"""The journal's event log: every engine event is written as the typed event it is, in order, and reads back
the same; a journal made before the log gets one rebuilt from its tables that folds to the same history."""

from __future__ import annotations

import dataclasses
import json
import shutil
import sqlite3
from pathlib import Path
from typing import Any

import pytest
from test_engine import FakeCampaign
from test_run_history import _comparable, crash_then_resume

from core.journal import Journal
from core.journal.eventlog import events_from_tables, read_events
from core.journal.schema import SCHEMA_VERSION
from core.journal.sink import fold_history
from core.run.events import ApprovalAsked, Observed, RunEvent
from core.run.history import HistoryFold

OLD = Path(__file__).parent / "data" / "journal_before_one_loop"


def _as_stored(event: RunEvent) -> Any:
    """An event as the log keeps it: the map fields stay in gp_snapshots, the planner state is JSON."""
    if isinstance(event, Observed):
        event = dataclasses.replace(event, fields=None)
    plan = getattr(event, "plan", None)
    if plan is not None:
        event = dataclasses.replace(
            event, plan=dataclasses.replace(plan, state=json.loads(json.dumps(plan.state)))
        )  # type: ignore[arg-type]
    return event


def _fold(events: Any) -> HistoryFold:
    fold = HistoryFold()
    for e in events:
        fold.emit(e)
    return fold


class LogsAlongside:
    """A sink after the journal: the log's last row is the event just emitted, and the tables, rebuilt into
    events the way a migration does, fold to the history the log folds to."""

    def __init__(self) -> None:
        self.journal: Journal | None = None
        self.seen: list[RunEvent] = []

    def emit(self, event: RunEvent) -> None:
        assert self.journal is not None
        conn = self.journal.conn
        self.seen.append(event)
        logged = list(read_events(conn))
        assert _as_stored(logged[-1]) == _as_stored(event)
        queued = len(self.journal.q.unprocessed_commands())
        from_log = _fold(logged).history(queued)
        assert _comparable(from_log) == _comparable(_fold(events_from_tables(conn)).history(queued)), event


def test_every_event_is_logged_typed_and_the_tables_rebuild_the_same_history(tmp_path: Path) -> None:
    checker = LogsAlongside()
    j2 = crash_then_resume(tmp_path, checker, approval_timeout_s=3600.0)
    kinds = [k for (k,) in j2.conn.execute("SELECT kind FROM run_events ORDER BY seq")]
    j2.close()
    assert len(kinds) == len(checker.seen) > 40
    assert any(isinstance(e, ApprovalAsked) for e in checker.seen) and "ApprovalAsked" in kinds
    assert {"Decided", "Resolved", "BlockStarted", "Indent", "Observed", "PlanChanged", "CommandDone"} <= set(
        kinds
    )


def test_a_journal_made_before_the_log_gets_it_rebuilt_once(tmp_path: Path) -> None:
    path = tmp_path / "aborted.sqlite"
    shutil.copy(OLD / "aborted.sqlite", path)
    path.chmod(0o640)
    with sqlite3.connect(path) as c:
        assert c.execute("SELECT version FROM schema_version").fetchone()[0] < SCHEMA_VERSION
        before = _fold(events_from_tables(c)).history()
    j = Journal.open_writer(path)
    try:
        version = j.conn.execute("SELECT version FROM schema_version").fetchone()[0]
        rebuilt = j.conn.execute("SELECT COUNT(*), MIN(rebuilt) FROM run_events").fetchone()
        history = fold_history(j)
    finally:
        j.close()
    assert version == SCHEMA_VERSION and rebuilt[0] > 5 and rebuilt[1] == 1
    assert history is not None and before is not None
    assert _comparable(history) == _comparable(before)
    indents = sum(len(r) for _, r in history.observed) + (
        len(history.open_block[1]) if history.open_block else 0
    )
    assert indents == 1  # the old run was stopped after its first indent


def test_a_sample_counts_the_indents_of_an_earlier_journal_and_refuses_a_file_that_is_none(
    tmp_path: Path,
) -> None:
    """The sample reads an earlier run's indents from its journal's indents table (the journal's public
    format: core.sample needs none of the journal's code, so the journal stays the layer above it)."""
    import tomllib

    from test_engine import run_engine

    from core.errors import InputError
    from core.journal import JournalReader
    from core.sample import SAMPLE_TEMPLATE, parse_sample

    _, journal = run_engine(tmp_path, FakeCampaign(n_blocks=2))
    with JournalReader(journal) as r:
        made = [(x.actual_x_um, x.actual_y_um) for x in r.results()]
    data = tomllib.loads(SAMPLE_TEMPLATE)
    data["earlier"] = {"journals": [journal.name]}
    sample = parse_sample(data, "s.toml", base_dir=tmp_path)
    assert len(made) == 8 and sorted(sample.earlier_indents_um) == sorted(made)
    (tmp_path / "notes.sqlite").write_text("not a journal at all" * 20)
    data["earlier"] = {"journals": ["notes.sqlite"]}
    with pytest.raises(InputError, match=r"field earlier\.journals: .*notes\.sqlite: not a readable journal"):
        parse_sample(data, "s.toml", base_dir=tmp_path)

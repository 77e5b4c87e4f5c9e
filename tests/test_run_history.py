"""Resume folds the run's events: the journal's rows, fed back through core.run.history's fold, give the
RunHistory that the same fold gives over the events as the engine emitted them, after every event of a
run with approvals, a veto, an adjust, a crash while a decision waits and a resume."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol

import pytest
from test_engine import Crash, FakeCampaign, Operator, cmd, make_driver, new_journal, when

from core.journal import Journal
from core.journal.sink import fold_history
from core.run.engine import Engine
from core.run.events import RunEvent, RunHistory
from core.run.headless import MemoryRecord
from core.run.history import HistoryFold
from core.runview import CommandKind, EngineState


def _comparable(h: RunHistory | None) -> Any:
    """A history with the planner state as JSON sees it (the journal stores it as JSON: tuples read back as lists)."""
    if h is None or h.plan is None:
        return h
    return h.__class__(**{**h.__dict__, "plan": (json.loads(json.dumps(h.plan[0])), h.plan[1])})


class FoldsAlongside:
    """A sink after the journal: folds each event live and checks the journal's fold says the same."""

    def __init__(self) -> None:
        self.fold = HistoryFold()
        self.journal: Journal | None = None
        self.checked = 0

    def emit(self, event: RunEvent) -> None:
        self.fold.emit(event)
        assert self.journal is not None
        queued = len(self.journal.q.unprocessed_commands())
        assert _comparable(self.fold.history(queued)) == _comparable(fold_history(self.journal)), event
        self.checked += 1


class JournalChecker(Protocol):
    """A sink after the journal that reads the journal it is given (``journal``) at every event."""

    journal: Journal | None

    def emit(self, event: RunEvent) -> None: ...


def crash_then_resume(
    tmp_path: Path,
    checker: JournalChecker,
    approval_timeout_s: float | None = None,
    on_crash: Callable[[], None] = lambda: None,
) -> Journal:
    """A supervised run of four blocks that sees a veto, an adjust and two approvals, dies while its next
    decision waits (``on_crash`` is called then), and is resumed and approved to the end, ``checker`` after
    the journal all along. Returns the resumed run's journal, still open."""
    j = new_journal(tmp_path, supervision="supervised")
    checker.journal = j
    rules = [
        when(EngineState.AWAITING_APPROVAL, cmd(CommandKind.VETO)),
        when(EngineState.AWAITING_APPROVAL, cmd(CommandKind.ADJUST, target_sem_gpa=0.2)),
        when(EngineState.AWAITING_APPROVAL, cmd(CommandKind.APPROVE)),
        when(EngineState.AWAITING_APPROVAL, cmd(CommandKind.APPROVE)),
    ]
    op = Operator(j.path, rules)
    ticks = {"n": 0}

    def sleep_then_crash(s: float) -> None:
        op.sleep(s)
        ticks["n"] += 1
        if not op.rules and ticks["n"] > 3:  # the next decision waits: the engine dies
            raise Crash

    eng = Engine(
        j,
        FakeCampaign(n_blocks=4),
        make_driver(),
        "step",
        poll_s=0.01,
        sleep=sleep_then_crash,
        watch_s=None,
        sinks=[checker],
        approval_timeout_s=approval_timeout_s,
    )
    op.engine = eng
    with pytest.raises(Crash):
        eng.run()
    j.close()
    on_crash()
    j2 = Journal.open_writer(j.path)
    checker.journal = j2
    op2 = Operator(j2.path, [when(EngineState.AWAITING_APPROVAL, cmd(CommandKind.APPROVE))] * 8)
    eng2 = Engine(
        j2,
        FakeCampaign(n_blocks=4),
        make_driver(),
        "supervised",
        poll_s=0.01,
        sleep=op2.sleep,
        watch_s=None,
        sinks=[checker],
    )
    op2.engine = eng2
    eng2.run()
    return j2


def test_the_journal_folds_to_the_history_of_the_events_it_received(tmp_path: Path) -> None:
    checker = FoldsAlongside()
    at_crash: list[int] = []
    j2 = crash_then_resume(tmp_path, checker, on_crash=lambda: at_crash.append(checker.checked))
    history = fold_history(j2)
    j2.close()
    assert at_crash[0] > 20 and checker.checked > at_crash[0]
    assert history is not None and history.completed and len(history.observed) == 4
    assert history.pending is None and history.open_block is None


def test_a_headless_record_folds_its_events_the_same_way() -> None:
    record = MemoryRecord()
    assert record.history() is None
    eng = Engine(record, FakeCampaign(n_blocks=3), make_driver(), "auto", watch_s=None)
    eng.run()
    h = record.history()
    assert h is not None and h.completed and [b.block_id for b, _ in h.observed] == [0, 1, 2]
    assert all(len(r) == b.n_indents for b, r in h.observed) and h.last_snapshot_id == 3


def test_replay_is_the_live_view_cut_off_after_a_block(tmp_path: Path) -> None:
    """One view: the last replay step of a finished run is the live view but for what came after the last
    block (the lift and stop), and every step counts only the rows up to its block."""
    from test_engine import run_engine

    from aeni_console.console.journal_source import JournalReplay, JournalSource

    _, path = run_engine(tmp_path, FakeCampaign(n_blocks=3))
    live = JournalSource(path).snapshot()
    replay = JournalReplay(path)
    steps = [replay.snapshot_at(i) for i in range(replay.n_blocks())]
    assert [s.n_blocks for s in steps] == [1, 2, 3] and [s.n_indents for s in steps] == [4, 8, 12]
    assert [len(s.indents) for s in steps] == [4, 8, 12] and [len(s.tested) for s in steps] == [1, 2, 3]
    assert [s.gp.snapshot_id for s in steps] == [1, 2, 3] and not any(s.can_command for s in steps)
    last = steps[-1]
    differs = {f for f in live.__dataclass_fields__ if getattr(live, f) != getattr(last, f)}
    assert differs <= {"instrument_s", "wall_s", "ledger", "log"}
    assert last.instrument_s <= live.instrument_s and last.ledger["indent"] == live.ledger["indent"]
    assert [s.pending is not None for s in steps] == [True, True, False]  # the decision that came next

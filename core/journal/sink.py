"""The journal as a run's record: it writes each engine event in one transaction, hands the engine the
operator's commands, and, when a run resumes, feeds its rows back through the one fold of a run's events
(core.run.history) into the RunHistory the engine starts from.

The engine never calls the journal's writing methods itself; it emits events (core.run.events) and this
module is where each one becomes rows.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

from core.driver import InstrumentWait
from core.journal.codec import (
    APPROVAL_CATEGORY,
)
from core.journal.eventlog import read_events
from core.journal.writer import JournalWriter
from core.run.events import (
    ApprovalAsked,
    BlockEnded,
    BlockStarted,
    CommandDone,
    Decided,
    EngineDied,
    Indent,
    Logged,
    Observed,
    PlanChanged,
    Resolved,
    RunEvent,
    RunHistory,
    SessionBegan,
    SessionEnded,
    StateChanged,
    Steps,
    Waiting,
)
from core.run.history import HistoryFold


def _plan(p: Any) -> tuple[int, str, dict[str, Any], Any] | None:
    return None if p is None else (p.block_id, p.point, p.state, p.settings)


def _waiting(j: Any, e: Waiting) -> None:
    """The wait itself is its row in the event log (the console reads it there); what it says for the log
    panel the engine logs (Logged events)."""


def _approval_asked(j: Any, e: ApprovalAsked) -> None:
    """A line for the log panel (the console counts down from the event itself: its wall time plus
    ``timeout_s``)."""
    j.log(
        "info",
        f"decision {e.decision_id} waits {e.timeout_s:g} s for an answer, then: {e.on_timeout}",
        category=APPROVAL_CATEGORY,
        block_id=e.block_id,
    )


_WRITERS: dict[type, Callable[[Any, Any], None]] = {
    SessionBegan: lambda j, e: j.begin_session(e.kind),
    SessionEnded: lambda j, e: j.end_session(e.state),
    StateChanged: lambda j, e: j.set_state(
        e.state, supervision=e.supervision, completed=e.completed, stop_reason=e.stop_reason
    ),
    Logged: lambda j, e: j.log(e.level, e.text, category=e.category, block_id=e.block_id, detail=e.detail),
    Decided: lambda j, e: j.record_decision(
        e.decision,
        e.t_s,
        e.status,
        e.why,
        text=e.text,
        plan=None if e.plan is None else (e.plan.state, e.plan.settings),
        decision_id=e.decision_id,
    ),
    Resolved: lambda j, e: j.resolve_decision(
        e.decision_id, e.status, e.by, e.command_id, campaign_state=_plan(e.plan)
    ),
    BlockStarted: lambda j, e: j.record_block_planned(
        e.block, e.decision_id, e.t_s, e.plan.state, e.plan.settings, resolve=e.resolution
    ),
    BlockEnded: lambda j, e: j.set_block_status(e.block_id, e.status, e.t_s if e.finished else None),
    Indent: lambda j, e: j.record_indent(e.result, e.steps, e.driver),
    Steps: lambda j, e: j.record_steps(
        e.steps, e.driver, text=e.text, category=e.category, block_id=e.block_id
    ),
    Waiting: _waiting,
    ApprovalAsked: _approval_asked,
    PlanChanged: lambda j, e: j.record_campaign_state(
        e.plan.block_id, e.plan.point, e.plan.state, e.plan.settings
    ),
    Observed: lambda j, e: j.record_observation(
        e.block_id,
        e.t_s,
        e.snapshot_id,
        e.hyper,
        e.fit.to_json_dict(),
        e.fields,
        e.plan.state,
        e.plan.settings,
        text=e.text,
    ),
    CommandDone: lambda j, e: j.mark_command(
        e.command_id, e.outcome, e.reason, e.t_s, e.state_before, e.text
    ),
    EngineDied: lambda j, e: j.record_engine_death(e),
}


def write_event(journal: JournalWriter, event: RunEvent) -> None:
    """One event, in one transaction: its row in the event log and the rows the readers query, with the
    journal's clock set to the event's instrument time."""
    journal.note_clock(event.t_s)
    with journal.transaction():
        _WRITERS[type(event)](journal, event)
        journal.record_event(event)


def fold_history(journal: JournalWriter) -> RunHistory | None:
    """The run so far: the journal's event log folded in order (core.run.history), as a record that saw
    the events live folds them. None: no engine has run on it yet."""
    if not journal.has_history():
        return None
    fold = HistoryFold()
    for event in read_events(journal.conn):
        fold.emit(event)
    return fold.history(queued_commands=len(journal.q.unprocessed_commands()))


class Journal(JournalWriter):
    """A journal as the engine's run record (core.run.events.RunRecord): it takes the engine's events and
    gives back the history a resume starts from. Create a run with :meth:`create`, reopen it with
    :meth:`open_writer`."""

    _last_wait: InstrumentWait | None = None  # the last instrument wait written (its countdown aside)

    def emit(self, event: RunEvent) -> None:
        """Write one engine event in one transaction (``write_event`` says which rows each becomes). The
        driver reports its wait every poll: the log keeps the ones that say something new."""
        if isinstance(event, Waiting):
            seen = dataclasses.replace(event.wait, seconds_left=0.0)
            if seen == self._last_wait:
                return
            self._last_wait = seen
        write_event(self, event)

    def history(self) -> RunHistory | None:
        return fold_history(self)

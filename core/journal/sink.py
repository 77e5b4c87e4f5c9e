"""The journal as a run's record: it writes each engine event in one transaction, hands the engine the
operator's commands, and folds what it holds back into a RunHistory when a run resumes.

The engine never calls the journal's writing methods itself; it emits events (core.run.events) and this
module is where each one becomes rows.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from core.run.events import (
    BlockEnded,
    BlockStarted,
    CommandDone,
    Decided,
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

if TYPE_CHECKING:
    from core.journal.writer import Journal


def _plan(p: Any) -> tuple[int, str, dict[str, Any], Any] | None:
    return None if p is None else (p.block_id, p.point, p.state, p.settings)


def _waiting(j: Any, e: Waiting) -> None:
    """What the instrument wait says is logged by the engine (Logged events); the wait itself is the state."""


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
}


def write_event(journal: Journal, event: RunEvent) -> None:
    """One event, in one transaction, with the journal's clock set to the event's instrument time."""
    journal.note_clock(event.t_s)
    _WRITERS[type(event)](journal, event)


def fold_history(journal: Journal) -> RunHistory | None:
    """The run so far, folded from the journal's tables (None: no engine has run on it yet)."""
    if not journal.has_history():
        return None
    q = journal.q
    row = q.engine_row()
    open_blk = q.open_block()
    pending = q.pending_decision()
    last_decision = journal.conn.execute("SELECT COALESCE(MAX(decision_id), 0) FROM decisions").fetchone()
    return RunHistory(
        completed=bool(row.get("completed")),
        stop_reason=str(row.get("stop_reason") or ""),
        last_state=str(row.get("state", "idle")),
        plan=q.latest_campaign_state(),
        observed=q.observed_blocks(),
        driver=q.latest_driver_state(),
        recovery_s=q.recovery_seconds(),
        open_block=None if open_blk is None else (open_blk[0], q.results(open_blk[0].block_id)),
        pending=None
        if pending is None
        else (pending.decision_id, pending.decision, pending.needs_approval_reason or "awaiting approval"),
        queued_commands=len(q.unprocessed_commands()),
        last_decision_id=int(last_decision[0]),
        last_snapshot_id=journal.next_snapshot_id() - 1,
    )

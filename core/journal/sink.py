"""The journal as a run's record: it writes each engine event in one transaction, hands the engine the
operator's commands, and, when a run resumes, feeds its rows back through the one fold of a run's events
(core.run.history) into the RunHistory the engine starts from.

The engine never calls the journal's writing methods itself; it emits events (core.run.events) and this
module is where each one becomes rows.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from core.journal.codec import (
    APPROVAL_CATEGORY,
    INDENT_COLS,
    block_from_dict,
    decision_from_dict,
    result_from_row,
)
from core.plan import StepRecord
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

if TYPE_CHECKING:
    from core.journal.writer import Journal


def _plan(p: Any) -> tuple[int, str, dict[str, Any], Any] | None:
    return None if p is None else (p.block_id, p.point, p.state, p.settings)


def _waiting(j: Any, e: Waiting) -> None:
    """What the instrument wait says is logged by the engine (Logged events); the wait itself is the state."""


def _approval_asked(j: Any, e: ApprovalAsked) -> None:
    """A log row the console counts down from: its wall time plus ``timeout_s`` is the deadline."""
    detail = {"decision_id": e.decision_id, "timeout_s": e.timeout_s, "on_timeout": e.on_timeout}
    j.log(
        "info",
        f"decision {e.decision_id} waits {e.timeout_s:g} s for an answer, then: {e.on_timeout}",
        category=APPROVAL_CATEGORY,
        block_id=e.block_id,
        detail=json.dumps(detail),
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


def write_event(journal: Journal, event: RunEvent) -> None:
    """One event, in one transaction, with the journal's clock set to the event's instrument time."""
    journal.note_clock(event.t_s)
    _WRITERS[type(event)](journal, event)


def fold_history(journal: Journal) -> RunHistory | None:
    """The run so far: the journal's rows fed, kind by kind in the order written, through the fold the
    engine's events go through (core.run.history). None: no engine has run on it yet."""
    if not journal.has_history():
        return None
    c = journal.conn
    fold = HistoryFold()
    fold.session()
    row = journal.q.engine_row()
    fold.state_changed(
        str(row.get("state", "idle")), bool(row.get("completed")), str(row.get("stop_reason") or "")
    )
    # Decided (auto or pending), then what answered it: BlockStarted (approved) or Resolved
    for did, decision_json, status, why in c.execute(
        "SELECT decision_id, decision_json, status, needs_approval_reason FROM decisions ORDER BY decision_id"
    ):
        fold.decided(
            int(did),
            decision_from_dict(json.loads(decision_json)),
            status if status == "auto" else "pending",
            why,
        )
        if status not in ("auto", "pending"):
            fold.resolved(int(did))
    blocks = [
        (block_from_dict(json.loads(j)), status)
        for j, status in c.execute("SELECT block_json, status FROM blocks ORDER BY block_id")
    ]
    for block, _ in blocks:  # BlockStarted, or the block of an auto decision
        fold.block_planned(block)
    for r in c.execute(f"SELECT {INDENT_COLS} FROM indents ORDER BY block_id, indent_index"):  # Indent
        fold.indent(result_from_row(r))
    for block, status in blocks:  # BlockEnded; an observed block is Observed's below
        if status not in ("planned", "running", "observed"):
            fold.block_status(block.block_id, status)
    for sid, bid in c.execute(
        "SELECT snapshot_id, block_id FROM gp_snapshots ORDER BY snapshot_id"
    ):  # Observed
        fold.observed(int(bid), int(sid))
    fold.steps(  # the steps of Indent and Steps
        StepRecord(cat, sec, bid, idx)
        for bid, idx, cat, sec in c.execute(
            "SELECT block_id, indent_index, category, seconds FROM steps ORDER BY step_id"
        )
    )
    driver = journal.q.latest_driver_state()  # the instrument state of the last Indent or Steps
    if driver is not None:
        fold.instrument(driver)
    plan = journal.q.latest_campaign_state()  # the plan of the last event that carried one
    if plan is not None:
        fold.planner(*plan)
    return fold.history(queued_commands=len(journal.q.unprocessed_commands()))

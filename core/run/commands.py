"""What the engine does with each operator command (one handler per kind, looked up by the engine after the
owner and the state machine have allowed it). Each handler answers (outcome, reason) for the journal."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from datetime import datetime
from typing import TYPE_CHECKING, Any

from core.errors import InputError
from core.operator import OperatorAvailability, OperatorHours
from core.run.events import PlanChanged, StateChanged
from core.run.machine import CommandKind, EngineState, Trigger
from core.settings import check_veto, coerce_supervision

if TYPE_CHECKING:
    from core.run.engine import Engine

Handler = Callable[["Engine", str, dict[str, Any], int], tuple[str, str]]


def pause(engine: Engine, author: str, payload: dict[str, Any], cid: int) -> tuple[str, str]:
    engine._fire(Trigger.PAUSE)
    return "accepted", "pausing after the current indent" if engine._current else ""


def resume(engine: Engine, author: str, payload: dict[str, Any], cid: int) -> tuple[str, str]:
    engine._fire(Trigger.RESUME)
    return "accepted", ""


def stop_after_block(engine: Engine, author: str, payload: dict[str, Any], cid: int) -> tuple[str, str]:
    if engine._stop_requested:
        return "rejected", "already stopping after this block"
    engine._stop_requested = "stopped after the block by the operator"
    return (
        "accepted",
        "stopping after the current block" if engine._current else "stopping now (between blocks)",
    )


def abort(engine: Engine, author: str, payload: dict[str, Any], cid: int) -> tuple[str, str]:
    engine.stop_reason = f"aborted by {author}"
    engine._fire(Trigger.STOP)
    return "accepted", "finishing the current indent, lifting, stopping"


def confirm(engine: Engine, author: str, payload: dict[str, Any], cid: int) -> tuple[str, str]:
    return instrument_report(engine, "started", str(payload.get("token", "")), author)


def report(engine: Engine, author: str, payload: dict[str, Any], cid: int) -> tuple[str, str]:
    return instrument_report(engine, str(payload.get("kind", "")), str(payload.get("token", "")), author)


def skip(engine: Engine, author: str, payload: dict[str, Any], cid: int) -> tuple[str, str]:
    return instrument_report(engine, "skip", str(payload.get("site", "")), author)


def away_until(engine: Engine, author: str, payload: dict[str, Any], cid: int) -> tuple[str, str]:
    """The operator is away until a local time: nobody answers before it, so the planner plans for nobody."""

    text = str(payload.get("until", ""))
    try:
        until = datetime.fromisoformat(text)
    except ValueError:
        return "rejected", f"until {text!r} is not an ISO local date-time"
    base = engine.operator or OperatorAvailability(OperatorHours.parse("always"))
    engine.operator = replace(base, away_until=until)
    engine._plan_for_operator()
    block_id = engine._next_block_id if engine._current is None else engine._current[0].block_id
    engine._emit(PlanChanged(engine._clock(), engine._plan_state(block_id, "away")))
    when = until.strftime("%a %Y-%m-%d %H:%M")
    engine._log("info", f"{author} is away until {when}: blocks are planned for nobody until then")
    return "accepted", f"away until {when}"


def instrument_report(engine: Engine, what: str, value: str, author: str) -> tuple[str, str]:
    """The operator's word on the instrument (started with the token, aborted, surface, skip a site)."""
    if engine._operator is None:
        return "rejected", "this run's driver takes no instrument reports"
    ok, why = engine._operator.operator_report(what, value, author)
    return ("accepted" if ok else "rejected"), why


def check_stale(engine: Engine, payload: dict[str, Any]) -> str:
    assert engine._pending is not None
    want = payload.get("decision_id")
    if want is not None and want != engine._pending[0]:
        return f"stale: decision {engine._pending[0]} is pending, not {want}"
    return ""


def approve(engine: Engine, author: str, payload: dict[str, Any], cid: int) -> tuple[str, str]:
    assert engine._pending is not None  # the machine takes approve only while a decision waits
    stale = check_stale(engine, payload)
    if stale:
        return "rejected", stale
    did, decision, why = engine._pending
    refusal = engine._interlock_refusal(decision.block)
    if refusal:
        return "rejected", f"{refusal}; veto it to let the planner offer another block"
    if why.startswith("length-scale collapse") and engine._last_collapse is not None:
        engine._collapse_ack_snapshot = engine._last_collapse[0]
    engine._release(did, decision, ("approved", author, cid))
    return "accepted", f"block {decision.block.block_id} approved"


def veto(engine: Engine, author: str, payload: dict[str, Any], cid: int) -> tuple[str, str]:
    assert engine._pending is not None  # the machine takes veto only while a decision waits
    stale = check_stale(engine, payload)
    if stale:
        return "rejected", stale
    try:
        hold = check_veto(payload)
    except InputError as exc:
        return "rejected", str(exc)
    block_id = engine._pending[1].block.block_id
    if not engine._offer(engine._veto_pending(author, cid, hold)):
        engine._fire(Trigger.STOP)
        return "accepted", f"vetoed; stopping: {engine.stop_reason}"
    if engine._pending is None:
        engine._fire(Trigger.GO)
    return "accepted", f"vetoed block {block_id}; the next best is offered"


def adjust(engine: Engine, author: str, payload: dict[str, Any], cid: int) -> tuple[str, str]:
    changes = dict(payload)
    if not changes:
        return "rejected", "nothing to adjust"
    supervision = changes.pop("supervision", None)
    if supervision is not None:
        supervision = coerce_supervision(supervision)  # InputError: rejected with its message
    if changes:
        try:
            engine.campaign.adjust(**changes)
        except (InputError, TypeError) as exc:
            return "rejected", str(exc)
        block_id = engine._next_block_id if engine._current is None else engine._current[0].block_id
        engine._emit(PlanChanged(engine._clock(), engine._plan_state(block_id, "adjust")))
    if supervision is not None and supervision != engine.supervision:
        engine.supervision = supervision
        engine._emit(StateChanged(engine._clock(), engine.state, supervision=supervision))
        if (
            engine._pending is not None
            and engine.state is EngineState.AWAITING_APPROVAL
            and not engine._approval_reason(engine._pending[1])
        ):
            did, decision, _ = engine._pending
            engine._release(did, decision, ("auto", "engine", None))
    shown = ", ".join(f"{k}={v!r}" for k, v in payload.items())
    return "accepted", shown


HANDLERS: dict[CommandKind, Handler] = {
    CommandKind.PAUSE: pause,
    CommandKind.RESUME: resume,
    CommandKind.APPROVE: approve,
    CommandKind.STEP: approve,
    CommandKind.VETO: veto,
    CommandKind.ADJUST: adjust,
    CommandKind.STOP_AFTER_BLOCK: stop_after_block,
    CommandKind.ABORT: abort,
    CommandKind.CONFIRM: confirm,
    CommandKind.REPORT: report,
    CommandKind.SKIP: skip,
    CommandKind.AWAY_UNTIL: away_until,
}

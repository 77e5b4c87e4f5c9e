"""The journal's event log: every engine event, typed, in the order it happened (table ``run_events``).

Each event is one row (its kind, its instrument time, its fields as JSON) written in the same transaction
as the rows the console and the exports read (core.journal.sink), so the two never disagree. A resume
folds the log in order (core.run.history); nothing is decoded from log text by category.

A journal written before the log existed (schema 3 or 4) gets one when an engine reopens it (a reader
rebuilds it in memory until then): the events are rebuilt from its tables (``events_from_tables``), each
table in the order it was written, merged by instrument time, so both folds read them as they happened.
"""

from __future__ import annotations

import dataclasses
import heapq
import json
import sqlite3
from collections.abc import Callable, Iterator
from typing import Any

from core.driver import InstrumentWait
from core.errors import InputError
from core.journal.codec import (
    block_from_dict,
    decision_from_dict,
    indent_cols,
    result_from_row,
    result_to_row,
    to_json,
    utc_now,
)
from core.plan import StepRecord
from core.run.events import (
    ApprovalAsked,
    BlockEnded,
    BlockStarted,
    CommandDone,
    Decided,
    EngineDied,
    FitSummary,
    Indent,
    Logged,
    Observed,
    PlanChanged,
    PlanState,
    Resolved,
    RunEvent,
    SessionBegan,
    SessionEnded,
    StateChanged,
    Steps,
    TimedSteps,
    Waiting,
)
from core.run.machine import EngineState
from core.run.records import DriverState
from core.settings import settings_from_dict, settings_to_dict


# -- one serialisation per field type ----------------------------------------------------------------
def _plan(p: PlanState | None) -> dict[str, Any] | None:
    if p is None:
        return None
    return {
        "block_id": p.block_id,
        "point": p.point,
        "state": p.state,
        "settings": settings_to_dict(p.settings),
    }


def _plan_from(d: dict[str, Any] | None) -> PlanState | None:
    if d is None:
        return None
    return PlanState(int(d["block_id"]), str(d["point"]), d["state"], settings_from_dict(d["settings"]))


def _driver(ds: DriverState) -> dict[str, Any]:
    return dataclasses.asdict(ds)


def _driver_from(d: dict[str, Any]) -> DriverState:
    x, y = d["position_um"]
    return DriverState(d["clock_s"], d["physics_clock_s"], (x, y), bool(d["program_open"]), d["reason"])


def _steps(steps: TimedSteps) -> list[list[Any]]:
    return [[s.category, s.seconds, s.block_id, s.indent_index, t] for s, t in steps]


def _steps_from(rows: list[list[Any]]) -> TimedSteps:
    return tuple((StepRecord(cat, sec, int(bid), int(idx)), t) for cat, sec, bid, idx, t in rows)


def _fit_from(d: dict[str, Any]) -> FitSummary:
    tuples = ("lengthscales_um", "noise_lengthscales_um", "lengthscales_uv")
    fields: dict[str, Any] = {k: tuple(v) if k in tuples else v for k, v in d.items()}
    return FitSummary(**fields)


def _wait_from(d: dict[str, Any]) -> InstrumentWait:
    return InstrumentWait(**{**d, "notes": tuple(d["notes"]), "panel": tuple(d["panel"])})


_ENCODE: dict[type, Callable[[Any], dict[str, Any]]] = {
    SessionBegan: lambda e: {"kind": e.kind},
    EngineDied: lambda e: {
        "cause": e.cause,
        "pid": e.pid,
        "exit_code": e.exit_code,
        "signal": e.signal,
        "action": e.action,
    },
    SessionEnded: lambda e: {"state": e.state.value},
    StateChanged: lambda e: {
        "state": e.state.value,
        "supervision": e.supervision,
        "completed": e.completed,
        "stop_reason": e.stop_reason,
    },
    Logged: lambda e: {
        "level": e.level,
        "text": e.text,
        "category": e.category,
        "block_id": e.block_id,
        "detail": e.detail,
    },
    Decided: lambda e: {
        "decision_id": e.decision_id,
        "decision": e.decision,
        "status": e.status,
        "why": e.why,
        "text": e.text,
        "plan": _plan(e.plan),
    },
    Resolved: lambda e: {
        "decision_id": e.decision_id,
        "status": e.status,
        "by": e.by,
        "command_id": e.command_id,
        "plan": _plan(e.plan),
    },
    BlockStarted: lambda e: {
        "block": e.block,
        "decision_id": e.decision_id,
        "plan": _plan(e.plan),
        "resolution": list(e.resolution),
    },
    BlockEnded: lambda e: {"block_id": e.block_id, "status": e.status, "finished": e.finished},
    Indent: lambda e: {
        "result": list(result_to_row(e.result)),
        "steps": _steps(e.steps),
        "driver": _driver(e.driver),
    },
    Steps: lambda e: {
        "steps": _steps(e.steps),
        "driver": _driver(e.driver),
        "text": e.text,
        "category": e.category,
        "block_id": e.block_id,
    },
    Waiting: lambda e: {"wait": dataclasses.asdict(e.wait)},
    ApprovalAsked: lambda e: {
        "decision_id": e.decision_id,
        "block_id": e.block_id,
        "timeout_s": e.timeout_s,
        "on_timeout": e.on_timeout,
    },
    PlanChanged: lambda e: {"plan": _plan(e.plan)},
    # the map fields stay in gp_snapshots (one blob per refit): the log names the snapshot
    Observed: lambda e: {
        "block_id": e.block_id,
        "snapshot_id": e.snapshot_id,
        "hyper": e.hyper,
        "fit": dataclasses.asdict(e.fit),
        "plan": _plan(e.plan),
        "text": e.text,
    },
    CommandDone: lambda e: {
        "command_id": e.command_id,
        "outcome": e.outcome,
        "reason": e.reason,
        "state_before": e.state_before.value,
        "text": e.text,
    },
}

_DECODE: dict[str, Callable[[float, dict[str, Any]], RunEvent]] = {
    "SessionBegan": lambda t, d: SessionBegan(t, d["kind"]),
    "EngineDied": lambda t, d: EngineDied(t, d["cause"], d["pid"], d["exit_code"], d["signal"], d["action"]),
    "SessionEnded": lambda t, d: SessionEnded(t, EngineState(d["state"])),
    "StateChanged": lambda t, d: StateChanged(
        t, EngineState(d["state"]), d["supervision"], d["completed"], d["stop_reason"]
    ),
    "Logged": lambda t, d: Logged(t, d["level"], d["text"], d["category"], d["block_id"], d["detail"]),
    "Decided": lambda t, d: Decided(
        t,
        d["decision_id"],
        decision_from_dict(d["decision"]),
        d["status"],
        d["why"],
        d["text"],
        _plan_from(d["plan"]),
    ),
    "Resolved": lambda t, d: Resolved(
        t, d["decision_id"], d["status"], d["by"], d["command_id"], _plan_from(d["plan"])
    ),
    "BlockStarted": lambda t, d: BlockStarted(
        t,
        block_from_dict(d["block"]),
        d["decision_id"],
        _plan_from(d["plan"]) or _no_plan(),
        (d["resolution"][0], d["resolution"][1], d["resolution"][2]),
    ),
    "BlockEnded": lambda t, d: BlockEnded(t, d["block_id"], d["status"], d["finished"]),
    "Indent": lambda t, d: Indent(
        t, result_from_row(d["result"]), _steps_from(d["steps"]), _driver_from(d["driver"])
    ),
    "Steps": lambda t, d: Steps(
        t, _steps_from(d["steps"]), _driver_from(d["driver"]), d["text"], d["category"], d["block_id"]
    ),
    "Waiting": lambda t, d: Waiting(t, _wait_from(d["wait"])),
    "ApprovalAsked": lambda t, d: ApprovalAsked(
        t, d["decision_id"], d["block_id"], d["timeout_s"], d["on_timeout"]
    ),
    "PlanChanged": lambda t, d: PlanChanged(t, _plan_from(d["plan"]) or _no_plan()),
    "Observed": lambda t, d: Observed(
        t,
        d["block_id"],
        d["snapshot_id"],
        d["hyper"],
        _fit_from(d["fit"]),
        None,
        _plan_from(d["plan"]) or _no_plan(),
        d["text"],
    ),
    "CommandDone": lambda t, d: CommandDone(
        t, d["command_id"], d["outcome"], d["reason"], EngineState(d["state_before"]), d["text"]
    ),
}


def _no_plan() -> PlanState:
    raise ValueError("an event that always carries the planner state has none")


def encode(event: RunEvent) -> tuple[str, float, str]:
    """(kind, t_s, body JSON) of one event."""
    return type(event).__name__, float(event.t_s), to_json(_ENCODE[type(event)](event))


def decode(kind: str, t_s: float, body: str) -> RunEvent:
    return _DECODE[kind](t_s, json.loads(body))


def append(conn: sqlite3.Connection, event: RunEvent, wall_utc: str, rebuilt: bool = False) -> None:
    """One event row (inside the caller's transaction), stamped with the writer's wall clock."""
    kind, t_s, body = encode(event)
    conn.execute(
        "INSERT INTO run_events (kind, t_s, wall_utc, body_json, rebuilt) VALUES (?, ?, ?, ?, ?)",
        (kind, t_s, wall_utc, body, int(rebuilt)),
    )


def read_events(conn: sqlite3.Connection, until_seq: int | None = None) -> Iterator[RunEvent]:
    """The log in the order it was written (up to ``until_seq``, inclusive)."""
    sql = "SELECT kind, t_s, body_json FROM run_events"
    args: tuple[Any, ...] = ()
    if until_seq is not None:
        sql += " WHERE seq <= ?"
        args = (until_seq,)
    for kind, t_s, body in conn.execute(sql + " ORDER BY seq", args):
        yield decode(kind, t_s, body)


# -- a journal made before the log: its events rebuilt from its tables ----------------------------------
# where an event falls among others at the same instrument time and block: a block is decided, planned,
# its steps lead to its indents, it ends, it is observed (the next block's decision follows at that time)
_RANK = {Decided: 0, Resolved: 0, BlockStarted: 1, Steps: 2, Indent: 3, BlockEnded: 4, Observed: 5}
_Keyed = tuple[tuple[float, int, int], RunEvent]


def events_from_tables(conn: sqlite3.Connection) -> Iterator[RunEvent]:
    """What an engine emitted on a journal made before the event log, as far as its tables hold it, in the
    order it happened: each table in the order it was written, merged by instrument time (then block, then
    the order above). The resume fold reads each kind in its own order; the console's fold and its replay
    read them in this one. The instrument's state is known only after the last row: every event carries it."""
    if conn.execute("SELECT COUNT(*) FROM sessions").fetchone()[0] == 0:
        return
    yield SessionBegan(0.0, "start")
    plans = _plans_by_block(conn)
    # a block or a refit with no planner state of its own carries the last one (the log ends with it)
    last_plan = next(reversed(plans.values()), None)
    driver_row = conn.execute(
        "SELECT clock_s, physics_clock_s, x_um, y_um, program_open, reason FROM driver_states "
        "ORDER BY id DESC LIMIT 1"
    ).fetchone()
    driver = (
        None
        if driver_row is None
        else DriverState(
            driver_row[0], driver_row[1], (driver_row[2], driver_row[3]), bool(driver_row[4]), driver_row[5]
        )
    )

    def keyed(event: RunEvent, block_id: int) -> _Keyed:
        return (float(event.t_s), block_id, _RANK[type(event)]), event

    def decisions() -> Iterator[_Keyed]:
        for did, t_s, decision_json, status, why, by, cid in conn.execute(
            "SELECT decision_id, t_s, decision_json, status, needs_approval_reason, resolved_by, command_id "
            "FROM decisions ORDER BY decision_id"
        ).fetchall():
            decision = decision_from_dict(json.loads(decision_json))
            bid = decision.block.block_id
            yield keyed(
                Decided(t_s, int(did), decision, "auto" if status == "auto" else "pending", why, ""), bid
            )
            if status not in ("auto", "pending"):
                yield keyed(Resolved(t_s, int(did), status, by or "", cid), bid)

    ended: list[_Keyed] = []

    def blocks() -> Iterator[_Keyed]:
        for block_json, status, did, t_s, finished_t_s in conn.execute(
            "SELECT block_json, status, decision_id, planned_t_s, finished_t_s FROM blocks ORDER BY block_id"
        ).fetchall():
            block = block_from_dict(json.loads(block_json))
            plan = plans.get((block.block_id, "planned")) or plans.get((block.block_id, None)) or last_plan
            if plan is not None:
                started = BlockStarted(
                    t_s, block, -1 if did is None else int(did), plan, ("approved", "", None)
                )
                yield keyed(started, block.block_id)
            if status not in ("planned", "running", "observed"):
                end = BlockEnded(finished_t_s or t_s, block.block_id, status, finished_t_s is not None)
                ended.append(keyed(end, block.block_id))

    def indents() -> Iterator[_Keyed]:
        for r in conn.execute(
            f"SELECT {indent_cols(conn)} FROM indents ORDER BY block_id, indent_index"
        ).fetchall():
            result = result_from_row(r)
            if driver is None:  # every indent is written with the instrument state after it
                raise InputError(
                    "journal", f"indent {result.block_id}/{result.indent_index} has no instrument state"
                )
            yield keyed(Indent(result.t_s, result, (), driver), result.block_id)

    def steps() -> Iterator[_Keyed]:
        if driver is None:
            return
        for bid, idx, cat, sec, t_end in conn.execute(
            "SELECT block_id, indent_index, category, seconds, t_end_s FROM steps ORDER BY step_id"
        ).fetchall():
            yield keyed(Steps(t_end, ((StepRecord(cat, sec, int(bid), int(idx)), t_end),), driver), int(bid))

    def observed() -> Iterator[_Keyed]:
        for sid, bid, t_s, hyper_json, summary_json in conn.execute(
            "SELECT snapshot_id, block_id, t_s, hyper_json, summary_json FROM gp_snapshots ORDER BY snapshot_id"
        ).fetchall():
            plan = plans.get((int(bid), "observed")) or plans.get((int(bid), None)) or last_plan
            if plan is None:
                continue
            summary = json.loads(summary_json)
            known = {f.name for f in dataclasses.fields(FitSummary)}
            fit = _fit_from(
                {k: v for k, v in summary.items() if k in known} | {"fitted": "lengthscales_um" in summary}
            )
            yield keyed(
                Observed(t_s, int(bid), int(sid), json.loads(hyper_json), fit, None, plan, ""), int(bid)
            )

    started = list(blocks())  # fills ``ended`` too
    streams = (decisions(), iter(started), indents(), steps(), iter(ended), observed())
    for _, event in heapq.merge(*streams, key=lambda k: k[0]):
        yield event
    row = conn.execute("SELECT state, completed, stop_reason FROM engine_state").fetchone()
    latest = conn.execute(
        "SELECT block_id, point, state_json, settings_json FROM campaign_states ORDER BY id DESC LIMIT 1"
    ).fetchone()
    if latest is not None:
        plan = PlanState(
            int(latest[0]), latest[1], json.loads(latest[2]), settings_from_dict(json.loads(latest[3]))
        )
        yield PlanChanged(0.0, plan)
    if row is not None:
        yield StateChanged(0.0, EngineState(row[0]), None, bool(row[1]), str(row[2] or ""))


def _plans_by_block(conn: sqlite3.Connection) -> dict[tuple[int, str | None], PlanState]:
    """The last planner state recorded at each (block, point), and at each block whatever the point."""
    out: dict[tuple[int, str | None], PlanState] = {}
    for bid, point, state_json, settings_json in conn.execute(
        "SELECT block_id, point, state_json, settings_json FROM campaign_states ORDER BY id"
    ):
        plan = PlanState(
            int(bid), point, json.loads(state_json), settings_from_dict(json.loads(settings_json))
        )
        out[(int(bid), point)] = plan
        out[(int(bid), None)] = plan
    return out


def rebuild(conn: sqlite3.Connection) -> None:
    """Fill an empty event log from the tables of a journal made before it (inside the caller's transaction)."""
    for event in events_from_tables(conn):
        append(conn, event, utc_now(), rebuilt=True)

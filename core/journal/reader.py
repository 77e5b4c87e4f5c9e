"""Reading a journal: the shared queries (the engine resumes with them) and the consoles' read-only view."""

from __future__ import annotations

import contextlib
import json
import math
import os
import pwd
import sqlite3
import statistics
import time
from collections.abc import Iterator, Sequence
from datetime import datetime
from pathlib import Path
from typing import Any

from core.cost import indent_steps
from core.drift import AREA_ERROR_THRESHOLD_PCT, area_error_pct
from core.driver import InstrumentWait
from core.journal.codec import (
    BlockRecord,
    DriverState,
    StoredCommand,
    StoredDecision,
    block_from_dict,
    decision_from_dict,
    indent_cols,
    map_fields_from_bytes,
    result_from_row,
)
from core.journal.eventlog import decode
from core.journal.schema import (
    LOG_TAIL,
    TABLES,
    TERMINAL_STATES,
    check_journal_file,
    connect_ro,
    engine_running,
    user_name,
)
from core.plan import LEDGER_CATEGORIES, Block, Decision, IndentResult, PlannerSettings, StepRecord
from core.profile import profile_from_dict
from core.run.events import Waiting
from core.runview import (
    ApprovalDeadline,
    DriftStatus,
    EngineState,
    GpStatus,
    LogEvent,
    MapFields,
    QueueItem,
    RunSnapshot,
    TestedCenter,
)
from core.settings import settings_from_dict

_ALL = 2**62  # a block id above every block: no cut-off


class Queries:
    """Reads over one connection; both the reader and the writer use them."""

    def __init__(self, conn: sqlite3.Connection, path: Path) -> None:
        self.conn = conn
        self.path = path

    def meta(self) -> dict[str, Any]:
        return {k: json.loads(v) for k, v in self.conn.execute("SELECT key, value FROM meta")}

    def engine_row(self) -> dict[str, Any]:
        row = self.conn.execute(
            "SELECT state, supervision, session_id, pid, updated_utc, completed, stop_reason FROM engine_state"
        ).fetchone()
        if row is None:
            return {"state": "idle", "supervision": "auto", "completed": 0, "stop_reason": "", "pid": None}
        keys = ("state", "supervision", "session_id", "pid", "updated_utc", "completed", "stop_reason")
        return dict(zip(keys, row, strict=True))

    def unprocessed_commands(self) -> list[StoredCommand]:
        out = []
        for cid, kind, author, uid, payload, shown, wall in self.conn.execute(
            "SELECT command_id, kind, author, uid, payload_json, shown_scores_json, wall_utc FROM commands "
            "WHERE processed = 0 ORDER BY command_id"
        ):
            out.append(
                StoredCommand(int(cid), kind, author, int(uid), json.loads(payload), json.loads(shown), wall)
            )
        return out

    def latest_driver_state(self) -> DriverState | None:
        row = self.conn.execute(
            "SELECT clock_s, physics_clock_s, x_um, y_um, program_open, reason FROM driver_states "
            "ORDER BY id DESC LIMIT 1"
        ).fetchone()
        if row is None:
            return None
        return DriverState(row[0], row[1], (row[2], row[3]), bool(row[4]), row[5])

    def latest_campaign_state(self) -> tuple[dict[str, Any], PlannerSettings] | None:
        row = self.conn.execute(
            "SELECT state_json, settings_json FROM campaign_states ORDER BY id DESC LIMIT 1"
        ).fetchone()
        if row is None:
            return None
        return json.loads(row[0]), settings_from_dict(json.loads(row[1]))

    def results(self, block_id: int) -> list[IndentResult]:
        rows = self.conn.execute(
            f"SELECT {indent_cols(self.conn)} FROM indents WHERE block_id = ? ORDER BY indent_index",
            (block_id,),
        )
        return [result_from_row(r) for r in rows]

    def all_results(self) -> list[IndentResult]:
        rows = self.conn.execute(
            f"SELECT {indent_cols(self.conn)} FROM indents ORDER BY block_id, indent_index"
        )
        return [result_from_row(r) for r in rows]

    def block_rows(self, where: str = "", args: tuple[Any, ...] = ()) -> list[tuple[Block, str, int | None]]:
        rows = self.conn.execute(
            f"SELECT block_json, status, decision_id FROM blocks {where} ORDER BY block_id", args
        )
        return [(block_from_dict(json.loads(j)), s, d) for j, s, d in rows]

    def observed_blocks(self) -> list[tuple[Block, list[IndentResult]]]:
        return [(b, self.results(b.block_id)) for b, _, _ in self.block_rows("WHERE status = 'observed'")]

    def open_block(self) -> tuple[Block, str, int] | None:
        """The latest block that was planned but not yet observed, with its status and indents done."""
        rows = self.block_rows("WHERE status != 'observed'")
        if not rows:
            return None
        block, status, _ = rows[-1]
        done = self.conn.execute(
            "SELECT COUNT(*) FROM indents WHERE block_id = ?", (block.block_id,)
        ).fetchone()
        return block, status, int(done[0])

    def decision(self, decision_id: int) -> StoredDecision | None:
        row = self.conn.execute(
            "SELECT decision_id, decision_json, status, needs_approval_reason, t_s FROM decisions "
            "WHERE decision_id = ?",
            (decision_id,),
        ).fetchone()
        return self._stored_decision(row)

    def _stored_decision(self, row: Sequence[Any] | None) -> StoredDecision | None:
        if row is None:
            return None
        return StoredDecision(int(row[0]), decision_from_dict(json.loads(row[1])), row[2], row[3], row[4])

    def pending_decision(self) -> StoredDecision | None:
        row = self.conn.execute(
            "SELECT decision_id, decision_json, status, needs_approval_reason, t_s FROM decisions "
            "WHERE status = 'pending' ORDER BY decision_id DESC LIMIT 1"
        ).fetchone()
        return self._stored_decision(row)

    def last_accepted_decision(self) -> StoredDecision | None:
        row = self.conn.execute(
            "SELECT decision_id, decision_json, status, needs_approval_reason, t_s FROM decisions "
            "WHERE status IN ('approved', 'auto') ORDER BY decision_id DESC LIMIT 1"
        ).fetchone()
        return self._stored_decision(row)

    def recovery_seconds(self) -> float:
        row = self.conn.execute(
            "SELECT COALESCE(SUM(seconds), 0) FROM steps WHERE category = 'recovery'"
        ).fetchone()
        return float(row[0])

    def max_block_id(self) -> int:
        row = self.conn.execute(
            "SELECT MAX(m) FROM (SELECT MAX(block_id) AS m FROM blocks UNION ALL SELECT MAX(block_id) FROM decisions)"
        ).fetchone()
        return -1 if row[0] is None else int(row[0])


def drift_status(
    rate_nm_s: float | None, last: Decision | None, events: tuple[tuple[float, float], ...]
) -> DriftStatus:
    """The drift panel's view: the last measured rate, the hold the last decision chose, the events."""
    hold_mode = "fixed"
    err = None if rate_nm_s is None else area_error_pct(rate_nm_s)
    if last is not None:
        hold_mode = (
            last.hold_mode
            if f"{last.block.hold_s:g} s" in last.hold_mode
            else f"{last.hold_mode} {last.block.hold_s:g} s"
        )
        if last.area_error_pct is not None:
            err = last.area_error_pct
    return DriftStatus(
        last_rate_nm_s=rate_nm_s,
        hold_mode=hold_mode,
        area_error_pct=err,
        threshold_pct=AREA_ERROR_THRESHOLD_PCT,
        events=events[-100:],
    )


class JournalReader:
    """Read-only view of a journal, safe while the engine writes; what consoles, replay and export use."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        check_journal_file(self.path)
        self.conn = connect_ro(self.path)
        self.q = Queries(self.conn, self.path)
        self._meta = self.q.meta()
        self._has_event_log = bool(
            self.conn.execute(
                "SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = 'run_events'"
            ).fetchone()
        )  # a journal of schema 3 or 4 not yet reopened by an engine has none
        self.profile = profile_from_dict(self._meta["profile"])
        self.owner_uid = self.path.stat().st_uid
        self._tested: dict[int, TestedCenter] = {}
        self._drift_seen_rowid = 0
        self._drift_events: list[tuple[float, float]] = []

    def close(self) -> None:
        self.conn.close()

    def __enter__(self) -> JournalReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def meta(self) -> dict[str, Any]:
        return dict(self._meta)

    @property
    def name(self) -> str:
        return str(self._meta.get("name", "run"))

    @contextlib.contextmanager
    def _read(self) -> Iterator[sqlite3.Connection]:
        """One consistent read transaction (the writer may commit in between two of them)."""
        self.conn.execute("BEGIN")
        try:
            yield self.conn
        finally:
            self.conn.execute("COMMIT")

    # -- simple reads --------------------------------------------------------------------------
    def latest_campaign_state(self) -> tuple[dict[str, Any], PlannerSettings] | None:
        """The planner's last journaled state (a tray's progress per sample, core.run.tray_view)."""
        with self._read():
            return self.q.latest_campaign_state()

    def results(self) -> list[IndentResult]:
        with self._read():
            return self.q.all_results()

    def state(self) -> tuple[EngineState, bool]:
        """The engine state and whether the engine process has ended."""
        with self._read():
            row = self.q.engine_row()
        return self._effective_state(row)

    def _effective_state(self, row: dict[str, Any]) -> tuple[EngineState, bool]:
        # 'pausing': what an engine watcher of before the state machine wrote while a pause was queued
        state = EngineState("paused" if row["state"] == "pausing" else row["state"])
        running = engine_running(self.path)
        if running:
            return state, False
        if state in TERMINAL_STATES or state == EngineState.IDLE:
            return state, True
        return EngineState.FAILED, True  # the engine died without saying so (crash, kill -9)

    def map_fields(self, snapshot_id: int) -> MapFields:
        row = self.conn.execute(
            "SELECT fields_npz FROM gp_snapshots WHERE snapshot_id = ?", (snapshot_id,)
        ).fetchone()
        if row is None or row[0] is None:
            raise KeyError(f"no map fields stored for snapshot {snapshot_id}")
        return map_fields_from_bytes(snapshot_id, row[0])

    def commands(self) -> list[dict[str, Any]]:
        cols = (
            "command_id",
            "kind",
            "author",
            "uid",
            "payload_json",
            "shown_scores_json",
            "wall_utc",
            "processed",
            "outcome",
            "reason",
            "processed_utc",
            "processed_t_s",
            "state_before",
        )
        rows = self.conn.execute(f"SELECT {', '.join(cols)} FROM commands ORDER BY command_id").fetchall()
        return [dict(zip(cols, r, strict=True)) for r in rows]

    def decisions(self) -> list[StoredDecision]:
        rows = self.conn.execute(
            "SELECT decision_id, decision_json, status, needs_approval_reason, t_s FROM decisions ORDER BY decision_id"
        ).fetchall()
        return [d for d in (self.q._stored_decision(r) for r in rows) if d is not None]

    def events(self, limit: int | None = None) -> list[LogEvent]:
        sql = "SELECT wall_utc, t_s, level, text FROM events ORDER BY event_id DESC"
        rows = self.conn.execute(sql + (f" LIMIT {int(limit)}" if limit else "")).fetchall()
        return [LogEvent(w, t, lv, tx) for w, t, lv, tx in reversed(rows)]

    def table(self, name: str) -> tuple[list[str], list[tuple[Any, ...]]]:
        if name not in TABLES:
            raise KeyError(name)
        cur = self.conn.execute(f"SELECT * FROM {name}")
        return [d[0] for d in cur.description], cur.fetchall()

    def blocks(self) -> list[BlockRecord]:
        """Every planned block in order with its decision, indents, steps and fit: what replay walks."""
        with self._read() as c:
            decisions = {d.decision_id: d.decision for d in self.decisions()}
            results: dict[int, list[IndentResult]] = {}
            for r in self.q.all_results():
                results.setdefault(r.block_id, []).append(r)
            steps: dict[int, list[StepRecord]] = {}
            for bid, idx, cat, sec in c.execute(
                "SELECT block_id, indent_index, category, seconds FROM steps ORDER BY step_id"
            ):
                steps.setdefault(bid, []).append(StepRecord(cat, sec, bid, idx))
            snaps = {
                bid: (sid, json.loads(summ))
                for sid, bid, summ in c.execute(
                    "SELECT snapshot_id, block_id, summary_json FROM gp_snapshots"
                )
            }
            rows = c.execute(
                "SELECT block_json, status, decision_id, planned_t_s, finished_t_s FROM blocks ORDER BY block_id"
            ).fetchall()
        out = []
        for bj, status, did, t0, t1 in rows:
            block = block_from_dict(json.loads(bj))
            sid, summary = snaps.get(block.block_id, (None, {}))
            out.append(
                BlockRecord(
                    block=block,
                    status=status,
                    decision=decisions.get(did) if did is not None else None,
                    results=tuple(results.get(block.block_id, ())),
                    steps=tuple(steps.get(block.block_id, ())),
                    snapshot_id=sid,
                    fit_summary=summary,
                    planned_t_s=t0,
                    finished_t_s=t1,
                )
            )
        return out

    # -- the console's whole view ----------------------------------------------------------------
    def _owner_view(self, reader_user: str | int | None) -> tuple[str, bool]:
        owner = user_name(self.owner_uid)
        if reader_user is None:
            reader_uid: int | None = os.getuid()
        elif isinstance(reader_user, int):
            reader_uid = reader_user
        else:
            try:
                reader_uid = pwd.getpwnam(reader_user).pw_uid
            except KeyError:
                reader_uid = None
        return owner, reader_uid == self.owner_uid

    def _tested_centres(self, c: sqlite3.Connection, upto: int | None) -> tuple[TestedCenter, ...]:
        new = c.execute(
            "SELECT b.block_id, b.center_x_um, b.center_y_um FROM blocks b WHERE b.status = 'observed' "
            "AND b.block_id > ?",
            (max(self._tested, default=-1),),
        ).fetchall()
        for bid, cx, cy in new:
            hs = [
                r[0]
                for r in c.execute(
                    "SELECT hardness_gpa FROM indents WHERE block_id = ? AND status = 'measured'", (bid,)
                )
            ]
            if hs:
                self._tested[bid] = TestedCenter(cx, cy, bid, float(statistics.median(hs)))
        return tuple(self._tested[k] for k in sorted(self._tested) if upto is None or k <= upto)

    def _drift(
        self, c: sqlite3.Connection, last: Decision | None, upto: int | None, t_end: float
    ) -> DriftStatus:
        for rowid, t_s, rate in c.execute(
            "SELECT rowid, t_s, drift_rate_nm_s FROM indents WHERE rowid > ? ORDER BY rowid",
            (self._drift_seen_rowid,),
        ):
            self._drift_seen_rowid = rowid
            if rate is not None and area_error_pct(rate) >= AREA_ERROR_THRESHOLD_PCT:
                self._drift_events.append((t_s, rate))
        row = c.execute(
            "SELECT drift_rate_nm_s FROM indents WHERE drift_rate_nm_s IS NOT NULL AND block_id <= ? "
            "ORDER BY block_id DESC, indent_index DESC LIMIT 1",
            (_ALL if upto is None else upto,),
        ).fetchone()
        rate = None if row is None else float(row[0])
        events = tuple(e for e in self._drift_events if upto is None or e[0] <= t_end + 1e-6)
        return drift_status(rate, last, events)

    def _queue(
        self, current: Block | None, done: int, nxt: Block | None, pos: tuple[float, float], is_open: bool
    ) -> tuple[QueueItem, ...]:
        items: list[QueueItem] = []
        eta = 0.0
        for block, start in ((current, done), (nxt, 0)):
            if block is None:
                continue
            for i in range(start, block.n_indents):
                eta += sum(s.seconds for s in indent_steps(self.profile, block, i, pos, is_open))
                spec = block.indents[i]
                pos, is_open = (spec.x_um, spec.y_um), True
                items.append(QueueItem(block.block_id, i, spec, block.grid_g, eta))
        return tuple(items)

    def replay_blocks(self) -> list[int]:
        """The blocks a replay steps through: every observed block with indents, in order."""
        rows = self.conn.execute(
            "SELECT block_id FROM blocks b WHERE status = 'observed' "
            "AND EXISTS (SELECT 1 FROM indents i WHERE i.block_id = b.block_id) ORDER BY block_id"
        ).fetchall()
        return [int(r[0]) for r in rows]

    def snapshot(self, reader_user: str | int | None = None, upto: int | None = None) -> RunSnapshot:
        """The console's whole view, read in one consistent transaction: the run now, or (``upto``, a block
        of :meth:`replay_blocks`) the run as it was just after that block was observed (replay).

        One set of rules for both: a replay is the same view with every row after its block left out.
        """
        owner, can_command = self._owner_view(reader_user)
        cut = _ALL if upto is None else upto  # the last block whose rows count
        with self._read() as c:
            eng = self.q.engine_row()
            ds = self.q.latest_driver_state()
            ledger = dict.fromkeys(LEDGER_CATEGORIES, 0.0)
            n_reconf = 0
            for cat, total, n in c.execute(
                "SELECT category, SUM(seconds), COUNT(*) FROM steps "
                + (
                    ""
                    if upto is None
                    else "WHERE block_id IN (SELECT block_id FROM blocks WHERE block_id <= ?) "
                )
                + "GROUP BY category",
                () if upto is None else (upto,),
            ):
                ledger[cat] = round(float(total), 6)
                if cat == "reconfigure":
                    n_reconf = int(n)
            n_indents, n_blocks = c.execute(
                "SELECT COUNT(*), COUNT(DISTINCT block_id) FROM indents WHERE block_id <= ?", (cut,)
            ).fetchone()
            last_indent = c.execute(
                "SELECT t_s, commanded_x_um, commanded_y_um, actual_x_um, actual_y_um FROM indents "
                "WHERE block_id <= ? ORDER BY block_id DESC, indent_index DESC LIMIT 1",
                (cut,),
            ).fetchone()
            if upto is None:
                open_blk = self.q.open_block()
                pending = self.q.pending_decision()
                last = self.q.last_accepted_decision()
                t_end = ds.clock_s if ds else 0.0
            else:  # replay: no block open; the decision that came next waits; the block's own was the last
                open_blk = None
                nxt = c.execute(
                    "SELECT decision_id FROM blocks WHERE block_id > ? ORDER BY block_id LIMIT 1", (upto,)
                ).fetchone()
                pending = None if nxt is None or nxt[0] is None else self.q.decision(int(nxt[0]))
                own = c.execute(
                    "SELECT decision_id, finished_t_s FROM blocks WHERE block_id = ?", (upto,)
                ).fetchone()
                last = None if own is None or own[0] is None else self.q.decision(int(own[0]))
                t_end = float(own[1]) if own is not None and own[1] is not None else float(last_indent[0])
            gp_row = c.execute(
                "SELECT snapshot_id, summary_json FROM gp_snapshots WHERE block_id <= ? "
                "ORDER BY snapshot_id DESC LIMIT 1",
                (cut,),
            ).fetchone()
            cs = c.execute("SELECT settings_json FROM campaign_states ORDER BY id DESC LIMIT 1").fetchone()
            sessions = c.execute("SELECT started_unix, ended_unix FROM sessions").fetchall()
            tested = self._tested_centres(c, upto)
            drift = self._drift(c, last.decision if last else None, upto, t_end)
            log_rows = c.execute(
                "SELECT wall_utc, t_s, level, text FROM events "
                + ("" if upto is None else "WHERE t_s <= ? ")
                + "ORDER BY event_id DESC LIMIT ?",
                (LOG_TAIL,) if upto is None else (t_end + 1e-6, LOG_TAIL),
            ).fetchall()
            first_wall = c.execute("SELECT wall_utc FROM events ORDER BY event_id LIMIT 1").fetchone()
            # the instrument's wait and the approval's deadline, as the typed events the engine emitted
            wait_row, asked_row = None, None
            if self._has_event_log:
                wait_row = c.execute(
                    "SELECT t_s, body_json FROM run_events WHERE kind = 'Waiting' ORDER BY seq DESC LIMIT 1"
                ).fetchone()
                asked_row = c.execute(
                    "SELECT wall_utc, body_json FROM run_events WHERE kind = 'ApprovalAsked' "
                    "ORDER BY seq DESC LIMIT 1"
                ).fetchone()
        state, finished = self._effective_state(eng)
        live = upto is None and not finished
        waiting = live and state is EngineState.WAITING_FOR_INSTRUMENT and wait_row is not None
        deadline = None
        if live and state is EngineState.AWAITING_APPROVAL and pending is not None and asked_row:
            deadline = ApprovalDeadline.from_record(asked_row[0], asked_row[1])
            if deadline.decision_id != pending.decision_id:
                deadline = None  # the deadline of an earlier wait (this one has none)
        current = open_blk[0] if open_blk and open_blk[1] in ("planned", "running", "aborted") else None
        done = open_blk[2] if open_blk and current is not None else 0
        if upto is None:
            pos = ds.position_um if ds else (0.0, 0.0)
            is_open = ds.program_open if ds else False
            at = ds.position_um if ds else None
        else:  # just after the block's last indent
            pos, is_open = (float(last_indent[1]), float(last_indent[2])), True
            ax, ay = last_indent[3], last_indent[4]
            seen = ax is not None and ay is not None and math.isfinite(ax) and math.isfinite(ay)
            at = (float(ax), float(ay)) if seen else pos  # where the tip went, else where it was sent
        queue = (
            ()
            if finished and upto is None
            else self._queue(current, done, pending.decision.block if pending else None, pos, is_open)
        )
        summary: dict[str, Any] = json.loads(gp_row[1]) if gp_row else {}
        gp = GpStatus(
            lengthscales_um=tuple(summary.get("lengthscales_um", ()) or ()),
            noise_lengthscales_um=tuple(summary.get("noise_lengthscales_um", ()) or ()),
            collapse_alarm=bool(summary.get("collapse_alarm", False)),
            collapse_reason=str(summary.get("collapse_reason", "")),
            refit_s=summary.get("refit_s"),
            snapshot_id=int(gp_row[0]) if gp_row else None,
        )
        settings = (
            settings_from_dict(json.loads(cs[0]))
            if cs
            else settings_from_dict(dict(self._meta.get("config", {}).get("settings", {})))
        )
        if upto is None:
            now = time.time()
            wall_s = float(sum((e if e is not None else now) - s for s, e in sessions))
        else:  # from the run's first event to this block's last
            wall_s = _wall_seconds(first_wall[0], log_rows[0][0]) if log_rows and first_wall else 0.0
        cfg = self._meta.get("config") or {}
        bounds = self._meta.get("stage_bounds_um") or [0.0, 0.0, 0.0, 0.0]
        return RunSnapshot(
            run_name=self.name,
            journal_path=str(self.path),
            state=state,
            supervision=str(eng["supervision"]),
            policy=str(cfg.get("policy", "")),
            profile_name=self.profile.name,
            owner=owner,
            can_command=can_command and live,
            instrument_s=float(t_end),
            wall_s=wall_s,
            n_indents=int(n_indents),
            n_blocks=int(n_blocks),
            reconfigurations=n_reconf,
            ledger=ledger,
            grid_baseline_s=float(self._meta.get("grid_baseline_s", 0.0)),
            queue=queue,
            current_block=current,
            pending=pending.decision if pending else None,
            last_decision=last.decision if last else None,
            drift=drift,
            gp=gp,
            mape_pct=summary.get("mape_pct"),
            max_found_gpa=summary.get("max_found_gpa"),
            tested=tested,
            settings=settings,
            log=tuple(LogEvent(w, t, lv, tx) for w, t, lv, tx in reversed(log_rows)),
            stage_bounds_um=(float(bounds[0]), float(bounds[1]), float(bounds[2]), float(bounds[3])),
            reverse_x=self.profile.reverse_x,
            finished=finished,
            allowed_holds_s=self.profile.allowed_holds_s,
            instrument_wait=_wait(wait_row) if waiting and wait_row is not None else None,
            reconfig_threshold_um=self.profile.reconfig_threshold_um,
            position_um=at,
            approval_deadline=deadline,
        )


def _wall_seconds(a: str, b: str) -> float:
    try:
        start = datetime.fromisoformat(a.replace("Z", "+00:00"))
        end = datetime.fromisoformat(b.replace("Z", "+00:00"))
    except ValueError:
        return 0.0
    return max((end - start).total_seconds(), 0.0)


def _wait(row: tuple[float, str]) -> InstrumentWait:
    event = decode("Waiting", row[0], row[1])
    assert isinstance(event, Waiting)
    return event.wait

"""Reading a journal: the shared queries (the engine resumes with them) and the consoles' read-only view."""

from __future__ import annotations

import contextlib
import json
import math
import os
import pwd
import sqlite3
import time
from collections.abc import Iterator, Sequence
from datetime import datetime
from pathlib import Path
from typing import Any

from core.cost import indent_steps
from core.drift import AREA_ERROR_THRESHOLD_PCT, area_error_pct
from core.journal.codec import (
    BlockRecord,
    StoredCommand,
    StoredDecision,
    block_from_dict,
    decision_from_dict,
    indent_cols,
    map_fields_from_bytes,
    result_from_row,
)
from core.journal.eventlog import decode, events_from_tables
from core.journal.schema import (
    LOG_TAIL,
    TABLES,
    TERMINAL_STATES,
    check_journal_file,
    connect_ro,
    engine_running,
    user_name,
)
from core.journal.snapshot import SnapshotFold
from core.plan import Block, Decision, IndentResult, PlannerSettings
from core.profile import profile_from_dict
from core.run.events import RunEvent, RunHistory
from core.run.history import HistoryFold
from core.runview import (
    ApprovalDeadline,
    DriftStatus,
    EngineState,
    GpStatus,
    LogEvent,
    MapFields,
    QueueItem,
    RunSnapshot,
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
        self._live = SnapshotFold()  # the run so far, advanced by each read
        self._replay: SnapshotFold | None = None  # the run up to a replay's block
        self._rebuilt: list[tuple[int, str, RunEvent]] | None = None  # a log-less journal's events

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
        """The planner's last state in the run's events (a tray's progress per sample, core.run.tray_view)."""
        with self._read():
            plan = self._fold().plan
        return None if plan is None else (plan.state, plan.settings)

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

    def events(self, limit: int | None = None) -> list[LogEvent]:
        sql = "SELECT wall_utc, t_s, level, text FROM events ORDER BY event_id DESC"
        rows = self.conn.execute(sql + (f" LIMIT {int(limit)}" if limit else "")).fetchall()
        return [LogEvent(w, t, lv, tx) for w, t, lv, tx in reversed(rows)]

    def table(self, name: str) -> tuple[list[str], list[tuple[Any, ...]]]:
        if name not in TABLES:
            raise KeyError(name)
        cur = self.conn.execute(f"SELECT * FROM {name}")
        return [d[0] for d in cur.description], cur.fetchall()

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

    # -- the run's events, folded (core.journal.snapshot) ------------------------------------------
    def _rows(self, after: int, until: int | None = None) -> Iterator[tuple[int, str, RunEvent]]:
        """The log's events after seq ``after`` (up to ``until``), each with its seq and wall time. A
        journal of schema 3 or 4 no engine has reopened has no log: its events are rebuilt from its
        tables in memory, as the engine's migration writes them (core.journal.eventlog)."""
        if not self._has_event_log:
            self._has_event_log = bool(
                self.conn.execute(
                    "SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = 'run_events'"
                ).fetchone()
            )
            if self._has_event_log:  # an engine migrated it meanwhile: fold its log from the start
                self._live = SnapshotFold()
                if after > 0:
                    return
        if not self._has_event_log:
            if self._rebuilt is None:
                self._rebuilt = [(i, "", e) for i, e in enumerate(events_from_tables(self.conn), start=1)]
            yield from (r for r in self._rebuilt if r[0] > after and (until is None or r[0] <= until))
            return
        sql = "SELECT seq, wall_utc, kind, t_s, body_json FROM run_events WHERE seq > ?"
        args: tuple[Any, ...] = (after,)
        if until is not None:
            sql += " AND seq <= ?"
            args = (after, until)
        for seq, wall, kind, t_s, body in self.conn.execute(sql + " ORDER BY seq", args).fetchall():
            yield int(seq), str(wall), decode(kind, t_s, body)

    def _fold(self) -> SnapshotFold:
        """The run so far: the live fold, advanced by the events written since the last read (call inside
        a read transaction)."""
        for seq, wall, event in self._rows(self._live.seq):
            self._live.emit(event, seq, wall)
        return self._live

    def _fold_until(self, seq: int) -> SnapshotFold:
        """The run as it was at event ``seq`` (a replay steps forward through one fold, else starts again)."""
        if self._replay is None or self._replay.seq > seq:
            self._replay = SnapshotFold()
        for s, wall, event in self._rows(self._replay.seq, seq):
            self._replay.emit(event, s, wall)
        return self._replay

    def history(self) -> RunHistory | None:
        """The run so far as a resume folds it (core.run.history), from the same events; None: no engine
        has run on it yet. The report rebuilds the final maps from it."""
        fold = HistoryFold()
        with self._read():
            for _, _, event in self._rows(0):
                fold.emit(event)
        return fold.history()

    def replay_blocks(self) -> list[int]:
        """The blocks a replay steps through: every observed block with indents, in order."""
        with self._read():
            return self._fold().replay_blocks()

    def blocks(self) -> list[BlockRecord]:
        """Every planned block in order with its decision, indents, steps and fit: what replay walks."""
        with self._read():
            return self._fold().block_records()

    def decisions(self) -> list[StoredDecision]:
        with self._read():
            fold = self._fold()
        return [fold.decisions[k] for k in sorted(fold.decisions)]

    def results(self) -> list[IndentResult]:
        """Every indent row of the run (the measurements as recorded, in block and indent order)."""
        with self._read():
            return self.q.all_results()

    def snapshot(self, reader_user: str | int | None = None, upto: int | None = None) -> RunSnapshot:
        """The console's whole view, read in one consistent transaction: the run now, or (``upto``, a block
        of :meth:`replay_blocks`) the run as it was just after that block was observed (replay).

        Both are the fold of the run's events (core.journal.snapshot): a replay is the fold stopped at the
        block's ``Observed`` event. Only what is not an engine event is read beside it: the engine row's
        state while no event has said one, the sessions' wall time and the log panel's lines.
        """
        owner, can_command = self._owner_view(reader_user)
        with self._read() as c:
            live_fold = self._fold()
            eng = self.q.engine_row()
            if upto is None:
                fold = live_fold
            elif upto in live_fold.observed_at:
                fold = self._fold_until(live_fold.observed_at[upto])
            else:
                raise KeyError(f"block {upto} was not observed: no replay step ends there")
            sessions = c.execute("SELECT started_unix, ended_unix FROM sessions").fetchall()
            first_wall = c.execute("SELECT wall_utc FROM events ORDER BY event_id LIMIT 1").fetchone()
            if upto is None:
                t_end = fold.driver.clock_s if fold.driver else 0.0
            else:
                own_block = fold.blocks[upto]
                last_r = fold.last_indent
                t_end = (
                    float(own_block.finished_t_s)
                    if own_block.finished_t_s is not None
                    else float(last_r.t_s if last_r else 0.0)
                )
            log_rows = c.execute(
                "SELECT wall_utc, t_s, level, text FROM events "
                + ("" if upto is None else "WHERE t_s <= ? ")
                + "ORDER BY event_id DESC LIMIT ?",
                (LOG_TAIL,) if upto is None else (t_end + 1e-6, LOG_TAIL),
            ).fetchall()
        # the state the events say (a replay shows the run's, as it ended or is now); the command watcher
        # marks 'stopping' on the engine row at once, before the engine says so
        said = live_fold.state
        if said is None or (eng["state"] == "stopping" and said is EngineState.RUNNING):
            eng_state = dict(eng)
        else:
            eng_state = {**eng, "state": said.value}
        state, finished = self._effective_state(eng_state)
        live = upto is None and not finished
        open_blk = fold.open_block() if upto is None else None
        if upto is None:
            pending, last = fold.pending(), fold.last_accepted()
        else:  # replay: no block open; the decision that came next waits; the block's own was the last
            later = [k for k in live_fold.blocks if k > upto]
            pending = live_fold.decision_of(min(later)) if later else None
            last = fold.decision_of(upto)
        waiting = live and state is EngineState.WAITING_FOR_INSTRUMENT and fold.wait is not None
        deadline = None
        asked = fold.asked
        if (
            live
            and state is EngineState.AWAITING_APPROVAL
            and pending is not None
            and asked is not None
            and asked.decision_id == pending.decision_id  # else the deadline of an earlier wait
        ):
            began = datetime.fromisoformat(asked.wall_utc.replace("Z", "+00:00")).timestamp()
            deadline = ApprovalDeadline(asked.decision_id, began + asked.timeout_s, asked.on_timeout)
        current = open_blk[0] if open_blk and open_blk[1] in ("planned", "running", "aborted") else None
        done = open_blk[2] if open_blk and current is not None else 0
        ds = fold.driver
        if upto is None:
            pos = ds.position_um if ds else (0.0, 0.0)
            is_open = ds.program_open if ds else False
            at = ds.position_um if ds else None
        else:  # just after the block's last indent
            r = fold.last_indent
            assert r is not None  # a replay step is an observed block with indents
            pos, is_open = (float(r.commanded_x_um), float(r.commanded_y_um)), True
            seen = math.isfinite(r.actual_x_um) and math.isfinite(r.actual_y_um)
            at = (float(r.actual_x_um), float(r.actual_y_um)) if seen else pos
        queue = (
            ()
            if finished and upto is None
            else self._queue(current, done, pending.decision.block if pending else None, pos, is_open)
        )
        sid, summary = fold.fit if fold.fit is not None else (None, {})
        gp = GpStatus(
            lengthscales_um=tuple(summary.get("lengthscales_um", ()) or ()),  # type: ignore[arg-type]
            noise_lengthscales_um=tuple(summary.get("noise_lengthscales_um", ()) or ()),  # type: ignore[arg-type]
            collapse_alarm=bool(summary.get("collapse_alarm", False)),
            collapse_reason=str(summary.get("collapse_reason", "")),
            refit_s=summary.get("refit_s"),  # type: ignore[arg-type]
            snapshot_id=sid,
        )
        settings = fold.settings or settings_from_dict(dict(self._meta.get("config", {}).get("settings", {})))
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
            supervision=str(fold.supervision or eng["supervision"]),
            policy=str(cfg.get("policy", "")),
            profile_name=self.profile.name,
            owner=owner,
            can_command=can_command and live,
            instrument_s=float(t_end),
            wall_s=wall_s,
            n_indents=fold.n_indents,
            n_blocks=fold.n_blocks,
            reconfigurations=fold.reconfigurations,
            ledger=fold.rounded_ledger(),
            grid_baseline_s=float(self._meta.get("grid_baseline_s", 0.0)),
            queue=queue,
            current_block=current,
            pending=pending.decision if pending else None,
            last_decision=last.decision if last else None,
            drift=drift_status(
                fold.last_drift_rate_nm_s, last.decision if last else None, tuple(fold.drift_events)
            ),
            gp=gp,
            mape_pct=summary.get("mape_pct"),  # type: ignore[arg-type]
            max_found_gpa=summary.get("max_found_gpa"),  # type: ignore[arg-type]
            tested=tuple(fold.tested),
            settings=settings,
            log=tuple(LogEvent(w, t, lv, tx) for w, t, lv, tx in reversed(log_rows)),
            stage_bounds_um=(float(bounds[0]), float(bounds[1]), float(bounds[2]), float(bounds[3])),
            reverse_x=self.profile.reverse_x,
            finished=finished,
            allowed_holds_s=self.profile.allowed_holds_s,
            instrument_wait=fold.wait if waiting else None,
            reconfig_threshold_um=self.profile.reconfig_threshold_um,
            position_um=at,
            approval_deadline=deadline,
            indents=fold.indents_upto(upto),
        )


def _wall_seconds(a: str, b: str) -> float:
    try:
        start = datetime.fromisoformat(a.replace("Z", "+00:00"))
        end = datetime.fromisoformat(b.replace("Z", "+00:00"))
    except ValueError:
        return 0.0
    return max((end - start).total_seconds(), 0.0)

"""Writing a journal: the engine's transactions, and the one row a console may add (a command)."""

from __future__ import annotations

import contextlib
import fcntl
import os
import socket
import sqlite3
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any, Self

from core.access import JOURNAL_MODE, command_channel_problem, protect, protect_side_files
from core.errors import InputError
from core.journal.codec import (
    INDENT_COLS,
    DriverState,
    StoredCommand,
    map_fields_to_bytes,
    result_to_row,
    to_json,
    utc_now,
)
from core.journal.eventlog import append, rebuild
from core.journal.reader import Queries
from core.journal.schema import (
    BUSY_TIMEOUT_MS,
    SCHEMA_SQL,
    SCHEMA_VERSION,
    check_journal_file,
    engine_running,
    lock_path_for,
    migrate,
    user_name,
)
from core.plan import Block, Decision, IndentResult, PlannerSettings, StepRecord
from core.profile import InstrumentProfile, profile_to_dict
from core.run.events import EngineDied, RunEvent
from core.runview import Command, CommandKind, EngineState, MapFields
from core.settings import settings_to_dict


class JournalLockedError(InputError):
    """Another engine holds this journal."""


class CommandWatch:
    """Sees the owner's abort while a slow driver step runs (the engine only reads commands between
    indents): it marks the state ``stopping`` at once, so a console shows it. A pause waits for the
    checkpoint (the console shows it queued)."""

    def __init__(self, path: Path, owner_uid: int) -> None:
        self.conn = sqlite3.connect(str(path), isolation_level=None, timeout=BUSY_TIMEOUT_MS / 1000)
        self.conn.execute(f"PRAGMA busy_timeout = {BUSY_TIMEOUT_MS}")
        self.owner_uid = owner_uid
        self._aborted = False

    def poll(self) -> bool:
        """True once, the first time an abort from the owner is waiting (the caller aborts the driver)."""
        try:
            if self._aborted:
                return False
            row = self.conn.execute(
                "SELECT 1 FROM commands WHERE processed = 0 AND kind = 'abort' AND uid = ? LIMIT 1",
                (self.owner_uid,),
            ).fetchone()
            if row is None:
                return False
            self.conn.execute("UPDATE engine_state SET state = 'stopping' WHERE state = 'running'")
        except sqlite3.Error:
            return False  # busy or gone: the next poll tries again
        self._aborted = True
        return True

    def close(self) -> None:
        self.conn.close()


class JournalWriter:
    """The engine's write side. Create a run with :meth:`create`, reopen it with :meth:`open_writer`."""

    def __init__(self, path: Path, conn: sqlite3.Connection, lock_fd: int) -> None:
        self.path = path
        self.conn = conn
        self._lock_fd: int | None = lock_fd
        self.q = Queries(conn, path)
        self.session_id: int | None = None
        self._t_s = 0.0
        self._in_tx = False

    # -- opening ---------------------------------------------------------------------------------
    @staticmethod
    def _take_lock(path: Path, retries: int = 10, gid: int | None = None) -> int:
        lp = lock_path_for(path)
        fd = os.open(lp, os.O_RDWR | os.O_CREAT, JOURNAL_MODE)
        with contextlib.suppress(OSError):  # the journal's watchers probe the lock: same group and mode
            protect(lp, gid)
        for attempt in range(retries):
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except OSError:
                if attempt == retries - 1:
                    try:
                        holder = os.pread(fd, 64, 0).decode(errors="replace").strip() or "unknown"
                    finally:
                        os.close(fd)
                    raise JournalLockedError(
                        str(path),
                        f"another engine (PID {holder}) is running this journal; refusing to start a second",
                    ) from None
                time.sleep(0.1)  # a console may be probing the lock for a moment
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        return fd

    @staticmethod
    def _connect_rw(path: Path) -> sqlite3.Connection:
        conn = sqlite3.connect(str(path), isolation_level=None, timeout=BUSY_TIMEOUT_MS / 1000)
        conn.execute(f"PRAGMA busy_timeout = {BUSY_TIMEOUT_MS}")
        conn.execute("PRAGMA journal_mode = WAL")
        conn.execute("PRAGMA synchronous = FULL")
        protect_side_files(path)
        return conn

    @classmethod
    def create(
        cls,
        path: str | Path,
        config: Any,
        profile: InstrumentProfile,
        calibration: Any = None,
        *,
        supervision: str = "auto",
        driver: str = "sim",
        speed: float | None = None,
        grid_baseline_s: float = 0.0,
        stage_bounds_um: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0),
        name: str | None = None,
        extra: dict[str, Any] | None = None,
        group_gid: int | None = None,
    ) -> Self:
        """A new journal holding the run's configuration; returns the writer (lock held).

        The file is created ``0640`` and given ``group_gid`` when set (see core.access): only its owner
        can write it, so only the owner can command the run.
        """
        p = Path(path)
        if p.exists():
            raise InputError(str(p), "journal already exists; use `aeni resume` to continue it")
        p.parent.mkdir(parents=True, exist_ok=True)
        lock_fd = cls._take_lock(p, gid=group_gid)
        tmp = p.with_name(p.name + ".creating")
        try:
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()
            conn = cls._connect_rw(tmp)
            conn.execute("BEGIN")
            for stmt in SCHEMA_SQL.split(";"):
                if stmt.strip():
                    conn.execute(stmt)
            conn.execute("INSERT INTO schema_version (version) VALUES (?)", (SCHEMA_VERSION,))
            run_name = name or getattr(config, "name", None) or "run"
            meta: dict[str, Any] = {
                "name": run_name,
                "created_utc": utc_now(),
                "config": config,
                "profile": profile_to_dict(profile),
                "calibration": calibration,
                "driver": driver,
                "speed": speed,
                "grid_baseline_s": float(grid_baseline_s),
                "stage_bounds_um": list(stage_bounds_um),
                "created_by": user_name(os.getuid()),
                "host": socket.gethostname(),
            }
            meta.update(extra or {})
            conn.executemany(
                "INSERT INTO meta (key, value) VALUES (?, ?)", [(k, to_json(v)) for k, v in meta.items()]
            )
            conn.execute(
                "INSERT INTO engine_state (id, state, supervision, updated_utc) VALUES (1, ?, ?, ?)",
                (EngineState.IDLE.value, supervision, utc_now()),
            )
            conn.execute("COMMIT")
            conn.close()
            protect(tmp, group_gid)
            os.replace(tmp, p)  # a journal either exists whole or not at all
            for suffix in ("-wal", "-shm"):
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(str(tmp) + suffix)
        except BaseException:
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()
            os.close(lock_fd)
            raise
        return cls(p, cls._connect_rw(p), lock_fd)

    @classmethod
    def open_writer(cls, path: str | Path) -> Self:
        """Reopen a journal for writing (resume). Checks it read-only first and takes the engine lock."""
        p = Path(path)
        check_journal_file(p)
        lock_fd = cls._take_lock(p, gid=p.stat().st_gid)
        try:
            conn = cls._connect_rw(p)
            migrate(conn, rebuild)
        except BaseException:
            os.close(lock_fd)
            raise
        return cls(p, conn, lock_fd)

    def close(self, compact: bool = True) -> None:
        """Release the lock; a finished journal is folded back into one file when nobody is reading it."""
        if self._lock_fd is None:
            return
        if compact:
            with contextlib.suppress(sqlite3.Error):
                self.conn.execute("PRAGMA wal_checkpoint(TRUNCATE)")
                self.conn.execute("PRAGMA journal_mode = DELETE")
        self.conn.close()
        os.close(self._lock_fd)
        self._lock_fd = None

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- writing ---------------------------------------------------------------------------------
    @contextlib.contextmanager
    def _tx(self) -> Iterator[sqlite3.Connection]:
        """One transaction; inside another (an event and the rows it becomes), part of that one."""
        if self._in_tx:
            yield self.conn
            return
        self.conn.execute("BEGIN IMMEDIATE")
        self._in_tx = True
        try:
            yield self.conn
        except BaseException:
            self._in_tx = False
            self.conn.execute("ROLLBACK")
            raise
        self._in_tx = False
        self.conn.execute("COMMIT")

    def transaction(self) -> contextlib.AbstractContextManager[sqlite3.Connection]:
        """The writer's transaction, for a caller that writes several rows as one (core.journal.sink)."""
        return self._tx()

    def record_event(self, event: RunEvent) -> None:
        """The event's row in the event log (core.journal.eventlog)."""
        with self._tx() as c:
            append(c, event, utc_now())

    def has_history(self) -> bool:
        """Whether an engine has run on this journal before (then the next one resumes it)."""
        row = self.conn.execute("SELECT COUNT(*) FROM sessions").fetchone()
        return int(row[0]) > 0

    def command_watch(self, owner_uid: int) -> CommandWatch | None:
        """A second connection for the engine's watcher thread; None when it cannot be opened."""
        try:
            return CommandWatch(self.path, owner_uid)
        except sqlite3.Error:
            return None

    def note_clock(self, t_s: float) -> None:
        self._t_s = t_s

    # -- the engine's record (core.run.events.RunRecord): a sink, a command source, a history ----------
    @property
    def name(self) -> str:
        return str(self.path)

    def owner_uid(self) -> int:
        return os.stat(self.path).st_uid

    def pending_commands(self) -> list[StoredCommand]:
        return self.q.unprocessed_commands()

    def command_channel_problem(self, owner_uid: int) -> str:
        return command_channel_problem(self.path, owner_uid)

    def begin_session(self, kind: str) -> int:
        now = time.time()
        with self._tx() as c:
            cur = c.execute(
                "INSERT INTO sessions (kind, pid, host, os_user, started_utc, started_unix) VALUES (?, ?, ?, ?, ?, ?)",
                (kind, os.getpid(), socket.gethostname(), user_name(os.getuid()), utc_now(), now),
            )
            self.session_id = int(cur.lastrowid or 0)
            c.execute("UPDATE engine_state SET session_id = ?, pid = ?", (self.session_id, os.getpid()))
        return self.session_id

    def end_session(self, state: EngineState) -> None:
        with self._tx() as c:
            c.execute(
                "UPDATE sessions SET ended_utc = ?, ended_unix = ?, end_state = ? WHERE session_id = ?",
                (utc_now(), time.time(), state.value, self.session_id),
            )

    def set_state(
        self,
        state: EngineState,
        *,
        supervision: str | None = None,
        completed: bool | None = None,
        stop_reason: str | None = None,
    ) -> None:
        sets = ["state = ?", "updated_utc = ?"]
        args: list[Any] = [state.value, utc_now()]
        if supervision is not None:
            sets.append("supervision = ?")
            args.append(supervision)
        if completed is not None:
            sets.append("completed = ?")
            args.append(int(completed))
        if stop_reason is not None:
            sets.append("stop_reason = ?")
            args.append(stop_reason)
        with self._tx() as c:
            c.execute(f"UPDATE engine_state SET {', '.join(sets)}", args)

    def _event(
        self,
        c: sqlite3.Connection,
        level: str,
        text: str,
        category: str,
        block_id: int | None,
        detail: str | None,
    ) -> None:
        c.execute(
            "INSERT INTO events (wall_utc, t_s, level, category, block_id, text, detail) VALUES (?, ?, ?, ?, ?, ?, ?)",
            (utc_now(), self._t_s, level, category, block_id, text, detail),
        )

    def log(
        self,
        level: str,
        text: str,
        *,
        category: str = "engine",
        block_id: int | None = None,
        detail: str | None = None,
    ) -> None:
        with self._tx() as c:
            self._event(c, level, text, category, block_id, detail)

    def record_engine_death(self, e: EngineDied) -> None:
        """The supervisor's record of an engine that died without ending its run: the dead engine's
        session ends ``failed``, the run is FAILED (unless it had ended; an engine that failed on an
        exception keeps its own reason), and one ``supervisor`` row says the cause and what comes next."""
        detail = {"pid": e.pid, "exit_code": e.exit_code, "signal": e.signal, "action": e.action}
        with self._tx() as c:
            row = c.execute("SELECT state, completed, session_id FROM engine_state").fetchone()
            state, completed, session_id = (str(row[0]), bool(row[1]), row[2]) if row else ("", False, None)
            if not completed and state not in (EngineState.STOPPED.value, EngineState.FAILED.value):
                c.execute(
                    "UPDATE engine_state SET state = ?, stop_reason = ?, updated_utc = ?",
                    (EngineState.FAILED.value, e.cause, utc_now()),
                )
            if session_id is not None:
                c.execute(
                    "UPDATE sessions SET ended_utc = ?, ended_unix = ?, end_state = ? "
                    "WHERE session_id = ? AND ended_utc IS NULL",
                    (utc_now(), time.time(), EngineState.FAILED.value, session_id),
                )
            text = f"{e.cause}; {e.action}" if e.action else e.cause
            self._event(c, "error", text, "supervisor", None, to_json(detail))

    def _driver_state(self, c: sqlite3.Connection, ds: DriverState) -> None:
        c.execute(
            "INSERT INTO driver_states (wall_utc, clock_s, physics_clock_s, x_um, y_um, program_open, reason) "
            "VALUES (?, ?, ?, ?, ?, ?, ?)",
            (
                utc_now(),
                ds.clock_s,
                ds.physics_clock_s,
                ds.position_um[0],
                ds.position_um[1],
                int(ds.program_open),
                ds.reason,
            ),
        )

    def _steps(self, c: sqlite3.Connection, steps: Sequence[tuple[StepRecord, float]]) -> None:
        now = utc_now()
        c.executemany(
            "INSERT INTO steps (block_id, indent_index, category, seconds, t_end_s, wall_utc, session_id) "
            "VALUES (?, ?, ?, ?, ?, ?, ?)",
            [(s.block_id, s.indent_index, s.category, s.seconds, t, now, self.session_id) for s, t in steps],
        )

    def _insert_block(self, c: sqlite3.Connection, block: Block, decision_id: int | None, t_s: float) -> None:
        c.execute(
            "INSERT INTO blocks (block_id, decision_id, kind, center_x_um, center_y_um, grid_g, pitch_um, hold_s, "
            "n_indents, block_json, status, planned_utc, planned_t_s) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
            (
                block.block_id,
                decision_id,
                block.kind,
                block.center_x_um,
                block.center_y_um,
                block.grid_g,
                block.pitch_um,
                block.hold_s,
                block.n_indents,
                to_json(block),
                "planned",
                utc_now(),
                t_s,
            ),
        )

    def _resolve(
        self, c: sqlite3.Connection, decision_id: int, status: str, by: str, command_id: int | None
    ) -> None:
        c.execute(
            "UPDATE decisions SET status = ?, resolved_by = ?, resolved_utc = ?, command_id = ? WHERE decision_id = ?",
            (status, by, utc_now(), command_id, decision_id),
        )

    def record_decision(
        self,
        decision: Decision,
        t_s: float,
        status: str,
        needs_approval_reason: str = "",
        text: str = "",
        plan: tuple[dict[str, Any], PlannerSettings] | None = None,
        decision_id: int | None = None,
    ) -> int:
        """A planner proposal with its scores and alternatives; with ``plan`` (an auto decision) also the
        block plan and the planner state, in the same transaction. ``decision_id``: the engine's number
        for it (None: the next free one)."""
        b = decision.block
        with self._tx() as c:
            cur = c.execute(
                "INSERT INTO decisions (decision_id, block_id, wall_utc, t_s, policy, phase, kind, center_x_um, center_y_um, "
                "score, acquisition, predicted_cost_s, decision_json, status, needs_approval_reason) "
                "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (
                    decision_id,
                    b.block_id,
                    utc_now(),
                    t_s,
                    decision.policy,
                    decision.phase,
                    b.kind,
                    b.center_x_um,
                    b.center_y_um,
                    decision.score,
                    decision.acquisition,
                    decision.predicted_cost_s,
                    to_json(decision),
                    status,
                    needs_approval_reason,
                ),
            )
            did = int(cur.lastrowid or 0)
            if plan is not None:
                self._insert_block(c, b, did, t_s)
                self._campaign_state(c, b.block_id, "planned", plan[0], plan[1])
            if text:
                self._event(c, "decision", text, "decision", b.block_id, None)
            return did

    def resolve_decision(
        self,
        decision_id: int,
        status: str,
        by: str,
        command_id: int | None = None,
        campaign_state: tuple[int, str, dict[str, Any], PlannerSettings] | None = None,
    ) -> None:
        """Close a decision (vetoed, dropped), with the planner state that results, in one transaction."""
        with self._tx() as c:
            self._resolve(c, decision_id, status, by, command_id)
            if campaign_state is not None:
                self._campaign_state(c, *campaign_state)

    def record_block_planned(
        self,
        block: Block,
        decision_id: int | None,
        t_s: float,
        campaign_state: dict[str, Any] | None = None,
        settings: PlannerSettings | None = None,
        resolve: tuple[str, str, int | None] | None = None,
    ) -> None:
        """The approved plan of one block (with the planner state and the approval), in one transaction."""
        with self._tx() as c:
            if resolve is not None and decision_id is not None:
                self._resolve(c, decision_id, *resolve)
            self._insert_block(c, block, decision_id, t_s)
            if campaign_state is not None and settings is not None:
                self._campaign_state(c, block.block_id, "planned", campaign_state, settings)

    def set_block_status(self, block_id: int, status: str, finished_t_s: float | None = None) -> None:
        with self._tx() as c:
            if finished_t_s is None:
                c.execute("UPDATE blocks SET status = ? WHERE block_id = ?", (status, block_id))
            else:
                c.execute(
                    "UPDATE blocks SET status = ?, finished_t_s = ? WHERE block_id = ?",
                    (status, finished_t_s, block_id),
                )

    def record_indent(
        self, result: IndentResult, steps: Sequence[tuple[StepRecord, float]], driver_state: DriverState
    ) -> None:
        """One finished indent with the steps that led to it: its own transaction, synced to disk."""
        with self._tx() as c:
            self._steps(c, steps)
            last = c.execute("SELECT MAX(step_id) FROM steps").fetchone()[0]
            c.execute(
                f"INSERT INTO indents ({INDENT_COLS}, wall_utc, session_id, last_step_id) "
                "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (*result_to_row(result), utc_now(), self.session_id, last),
            )
            self._driver_state(c, driver_state)
            c.execute(
                "UPDATE blocks SET status = 'running' WHERE block_id = ? AND status = 'planned'",
                (result.block_id,),
            )

    def record_steps(
        self,
        steps: Sequence[tuple[StepRecord, float]],
        driver_state: DriverState,
        text: str = "",
        category: str = "engine",
        block_id: int | None = None,
    ) -> None:
        """Steps that end no indent (the comeback, crash recovery), with the instrument state after them."""
        with self._tx() as c:
            self._steps(c, steps)
            self._driver_state(c, driver_state)
            if text:
                self._event(c, "info", text, category, block_id, None)

    def _campaign_state(
        self,
        c: sqlite3.Connection,
        block_id: int,
        point: str,
        state: dict[str, Any],
        settings: PlannerSettings,
    ) -> None:
        c.execute(
            "INSERT INTO campaign_states (block_id, point, wall_utc, state_json, settings_json) VALUES (?, ?, ?, ?, ?)",
            (block_id, point, utc_now(), to_json(state), to_json(settings_to_dict(settings))),
        )

    def record_campaign_state(
        self, block_id: int, point: str, state: dict[str, Any], settings: PlannerSettings
    ) -> None:
        with self._tx() as c:
            self._campaign_state(c, block_id, point, state, settings)

    def next_snapshot_id(self) -> int:
        row = self.conn.execute("SELECT COALESCE(MAX(snapshot_id), 0) FROM gp_snapshots").fetchone()
        return int(row[0]) + 1

    def record_observation(
        self,
        block_id: int,
        t_s: float,
        snapshot_id: int,
        hyper: dict[str, Any],
        summary: dict[str, Any],
        fields: MapFields | None,
        campaign_state: dict[str, Any],
        settings: PlannerSettings,
        text: str = "",
    ) -> None:
        """A block folded into the model: GP snapshot, planner state and block status, atomically."""
        with self._tx() as c:
            c.execute(
                "INSERT INTO gp_snapshots (snapshot_id, block_id, wall_utc, t_s, hyper_json, summary_json, fields_npz) "
                "VALUES (?, ?, ?, ?, ?, ?, ?)",
                (
                    snapshot_id,
                    block_id,
                    utc_now(),
                    t_s,
                    to_json(hyper),
                    to_json(summary),
                    map_fields_to_bytes(fields) if fields is not None else None,
                ),
            )
            self._campaign_state(c, block_id, "observed", campaign_state, settings)
            c.execute(
                "UPDATE blocks SET status = 'observed', observed_utc = ?, "
                "finished_t_s = COALESCE(finished_t_s, ?) WHERE block_id = ?",
                (utc_now(), t_s, block_id),
            )
            if text:
                self._event(c, "info", text, "block", block_id, None)

    def mark_command(
        self, command_id: int, outcome: str, reason: str, t_s: float, state_before: EngineState, text: str
    ) -> None:
        with self._tx() as c:
            c.execute(
                "UPDATE commands SET processed = 1, outcome = ?, reason = ?, processed_utc = ?, processed_t_s = ?, "
                "state_before = ? WHERE command_id = ?",
                (outcome, reason, utc_now(), t_s, state_before.value, command_id),
            )
            self._event(c, "command", text, "command", None, None)


# --------------------------------------------------------------------------------------------------
# commands from consoles


class NotOwnerError(PermissionError):
    """Only the run's owner (the journal file's owner) may command it; everyone else may watch."""


def append_event(journal_path: str | Path, level: str, text: str, category: str) -> None:
    """One log row from beside the engine (its alert sender, in a thread of the engine's process), on a
    connection of its own; at the instrument time of the latest row."""
    conn = sqlite3.connect(str(journal_path), isolation_level=None, timeout=BUSY_TIMEOUT_MS / 1000)
    try:
        conn.execute(f"PRAGMA busy_timeout = {BUSY_TIMEOUT_MS}")
        (t_s,) = conn.execute("SELECT COALESCE(MAX(t_s), 0.0) FROM events").fetchone()
        conn.execute(
            "INSERT INTO events (wall_utc, t_s, level, category, block_id, text, detail) VALUES (?, ?, ?, ?, ?, ?, ?)",
            (utc_now(), float(t_s), level, category, None, text, None),
        )
    finally:
        conn.close()


def _why_no_engine(p: Path) -> str:
    """What `aeni resume` would do with this journal, so `aeni send` and `aeni resume` say the same."""
    try:
        conn = sqlite3.connect(f"file:{p}?mode=ro", uri=True, timeout=BUSY_TIMEOUT_MS / 1000)
        try:
            row = conn.execute("SELECT state, stop_reason, completed FROM engine_state").fetchone()
        finally:
            conn.close()
    except sqlite3.Error:
        row = None
    if row is not None and row[2]:
        return f"the run is finished ({row[1] or 'done'}), so it takes no more commands and there is nothing to resume"
    if row is not None and row[0] == "stopped":
        return f"the run was stopped ({row[1] or 'by the operator'}); `aeni resume --continue {p}` resumes it"
    return "start it again with `aeni resume`"


def send_command(journal_path: str | Path, command: Command, *, uid: int | None = None) -> int:
    """Queue an operator command for the engine running this journal; returns the command id.

    Refused with :class:`NotOwnerError` when ``uid`` (default: this process's) does not own the journal
    file, and with InputError when no engine is running it (a stale command must not fire on a later
    resume).
    """
    p = Path(journal_path)
    if not p.is_file():
        raise InputError(str(p), "no such journal file")
    me = os.getuid() if uid is None else uid
    owner = p.stat().st_uid
    if me != owner:
        raise NotOwnerError(
            f"{p}: only the run's owner {user_name(owner)} may command it; {user_name(me)} may watch"
        )
    if not engine_running(p):
        raise InputError(str(p), f"no engine is running this journal: {_why_no_engine(p)}")
    kind = CommandKind(command.kind)
    conn = sqlite3.connect(str(p), isolation_level=None, timeout=BUSY_TIMEOUT_MS / 1000)
    try:
        conn.execute(f"PRAGMA busy_timeout = {BUSY_TIMEOUT_MS}")
        cur = conn.execute(
            "INSERT INTO commands (kind, author, uid, payload_json, shown_scores_json, wall_utc) "
            "VALUES (?, ?, ?, ?, ?, ?)",
            (
                kind.value,
                command.author,
                me,
                to_json(dict(command.payload)),
                to_json(dict(command.shown_scores)),
                utc_now(),
            ),
        )
        return int(cur.lastrowid or 0)
    except sqlite3.OperationalError as exc:
        raise NotOwnerError(
            f"{p}: cannot write the journal ({exc}); only its owner may command the run"
        ) from None
    finally:
        conn.close()

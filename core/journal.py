"""The run journal: one SQLite file per run that survives a crash and that any console can read.

The engine is the only writer (an exclusive lock file, held for the engine's life); consoles read it
read-only while it is written (WAL) and send operator commands by inserting rows into its ``commands``
table, so no network port is ever opened. Every finished indent is committed in its own transaction,
so a crash loses at most the indent in flight. See docs/journal.md for the schema.
"""

from __future__ import annotations

import contextlib
import dataclasses
import enum
import fcntl
import io
import json
import os
import pwd
import socket
import sqlite3
import statistics
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from core.cost import indent_steps
from core.drift import AREA_ERROR_THRESHOLD_PCT, area_error_pct
from core.errors import InputError
from core.plan import (
    LEDGER_CATEGORIES,
    Alternative,
    Block,
    Decision,
    IndentResult,
    IndentSpec,
    PlannerSettings,
    StepRecord,
)
from core.profile import InstrumentProfile, profile_from_dict, profile_to_dict
from core.runview import (
    Command,
    CommandKind,
    DriftStatus,
    EngineState,
    GpStatus,
    LogEvent,
    MapFields,
    QueueItem,
    RunSnapshot,
    TestedCenter,
)

SCHEMA_VERSION = 1
SQLITE_MAGIC = b"SQLite format 3\x00"
LOG_TAIL = 200
_BUSY_TIMEOUT_MS = 10_000
TERMINAL_STATES = (EngineState.STOPPED, EngineState.FAILED)

_SCHEMA = """
CREATE TABLE schema_version (version INTEGER NOT NULL);
CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE sessions (
    session_id INTEGER PRIMARY KEY, kind TEXT NOT NULL, pid INTEGER NOT NULL, host TEXT NOT NULL,
    os_user TEXT NOT NULL, started_utc TEXT NOT NULL, started_unix REAL NOT NULL,
    ended_utc TEXT, ended_unix REAL, end_state TEXT);
CREATE TABLE engine_state (
    id INTEGER PRIMARY KEY CHECK (id = 1), state TEXT NOT NULL, supervision TEXT NOT NULL,
    session_id INTEGER, pid INTEGER, updated_utc TEXT NOT NULL, completed INTEGER NOT NULL DEFAULT 0,
    stop_reason TEXT NOT NULL DEFAULT '');
CREATE TABLE blocks (
    block_id INTEGER PRIMARY KEY, decision_id INTEGER, kind TEXT NOT NULL,
    center_x_um REAL NOT NULL, center_y_um REAL NOT NULL, grid_g INTEGER NOT NULL, pitch_um REAL NOT NULL,
    hold_s REAL NOT NULL, n_indents INTEGER NOT NULL, block_json TEXT NOT NULL,
    status TEXT NOT NULL CHECK (status IN ('planned', 'running', 'executed', 'observed', 'aborted')),
    planned_utc TEXT NOT NULL, planned_t_s REAL NOT NULL, finished_t_s REAL, observed_utc TEXT);
CREATE TABLE indents (
    block_id INTEGER NOT NULL, indent_index INTEGER NOT NULL,
    commanded_x_um REAL NOT NULL, commanded_y_um REAL NOT NULL, actual_x_um REAL NOT NULL,
    actual_y_um REAL NOT NULL, hold_s REAL NOT NULL, hardness_gpa REAL NOT NULL, modulus_gpa REAL NOT NULL,
    drift_rate_nm_s REAL NOT NULL, t_s REAL NOT NULL, wall_utc TEXT NOT NULL, session_id INTEGER,
    last_step_id INTEGER, PRIMARY KEY (block_id, indent_index));
CREATE TABLE steps (
    step_id INTEGER PRIMARY KEY, block_id INTEGER NOT NULL, indent_index INTEGER NOT NULL,
    category TEXT NOT NULL, seconds REAL NOT NULL, t_end_s REAL NOT NULL, wall_utc TEXT NOT NULL,
    session_id INTEGER);
CREATE INDEX steps_block ON steps (block_id);
CREATE TABLE driver_states (
    id INTEGER PRIMARY KEY, wall_utc TEXT NOT NULL, clock_s REAL NOT NULL, physics_clock_s REAL,
    x_um REAL NOT NULL, y_um REAL NOT NULL, program_open INTEGER NOT NULL, reason TEXT NOT NULL);
CREATE TABLE decisions (
    decision_id INTEGER PRIMARY KEY, block_id INTEGER NOT NULL, wall_utc TEXT NOT NULL, t_s REAL NOT NULL,
    policy TEXT NOT NULL, phase TEXT NOT NULL, kind TEXT NOT NULL, center_x_um REAL NOT NULL,
    center_y_um REAL NOT NULL, score REAL, acquisition REAL, predicted_cost_s REAL,
    decision_json TEXT NOT NULL,
    status TEXT NOT NULL CHECK (status IN ('pending', 'approved', 'auto', 'vetoed', 'dropped')),
    needs_approval_reason TEXT NOT NULL DEFAULT '', resolved_by TEXT, resolved_utc TEXT, command_id INTEGER);
CREATE TABLE commands (
    command_id INTEGER PRIMARY KEY, kind TEXT NOT NULL, author TEXT NOT NULL, uid INTEGER NOT NULL,
    payload_json TEXT NOT NULL, shown_scores_json TEXT NOT NULL, wall_utc TEXT NOT NULL,
    processed INTEGER NOT NULL DEFAULT 0, outcome TEXT, reason TEXT, processed_utc TEXT,
    processed_t_s REAL, state_before TEXT);
CREATE INDEX commands_open ON commands (processed);
CREATE TABLE gp_snapshots (
    snapshot_id INTEGER PRIMARY KEY, block_id INTEGER NOT NULL, wall_utc TEXT NOT NULL, t_s REAL NOT NULL,
    hyper_json TEXT NOT NULL, summary_json TEXT NOT NULL, fields_npz BLOB);
CREATE TABLE campaign_states (
    id INTEGER PRIMARY KEY, block_id INTEGER NOT NULL, point TEXT NOT NULL, wall_utc TEXT NOT NULL,
    state_json TEXT NOT NULL, settings_json TEXT NOT NULL);
CREATE TABLE events (
    event_id INTEGER PRIMARY KEY, wall_utc TEXT NOT NULL, t_s REAL NOT NULL, level TEXT NOT NULL,
    category TEXT NOT NULL, block_id INTEGER, text TEXT NOT NULL, detail TEXT);
"""

_TABLES = (
    "schema_version",
    "meta",
    "sessions",
    "engine_state",
    "blocks",
    "indents",
    "steps",
    "driver_states",
    "decisions",
    "commands",
    "gp_snapshots",
    "campaign_states",
    "events",
)


# --------------------------------------------------------------------------------------------------
# plain-data codecs: dataclasses go in as JSON, come back as the same frozen records


def _default(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, enum.Enum):
        return obj.value
    if isinstance(obj, Path):
        return str(obj)
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return dataclasses.asdict(obj)
    if isinstance(obj, set | frozenset):
        return sorted(obj)
    raise TypeError(f"cannot store {type(obj).__name__} in the journal")


def to_json(obj: Any) -> str:
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        obj = dataclasses.asdict(obj)
    return json.dumps(obj, default=_default, separators=(",", ":"))


def block_from_dict(d: dict[str, Any]) -> Block:
    return Block(
        block_id=int(d["block_id"]),
        kind=d["kind"],
        center_x_um=float(d["center_x_um"]),
        center_y_um=float(d["center_y_um"]),
        grid_g=int(d["grid_g"]),
        pitch_um=float(d["pitch_um"]),
        hold_s=float(d["hold_s"]),
        indents=tuple(
            IndentSpec(float(s["x_um"]), float(s["y_um"]), float(s["hold_s"])) for s in d["indents"]
        ),
    )


def decision_from_dict(d: dict[str, Any]) -> Decision:
    kw = dict(d)
    kw["block"] = block_from_dict(d["block"])
    kw["alternatives"] = tuple(Alternative(**a) for a in d.get("alternatives", ()))
    known = {f.name for f in dataclasses.fields(Decision)}
    return Decision(**{k: v for k, v in kw.items() if k in known})


def settings_from_dict(d: dict[str, Any]) -> PlannerSettings:
    known = {f.name for f in dataclasses.fields(PlannerSettings)}
    kw = {k: v for k, v in d.items() if k in known}
    if "avoid_centers_um" in kw:
        kw["avoid_centers_um"] = tuple(tuple(float(c) for c in p) for p in kw["avoid_centers_um"])
    return PlannerSettings(**kw)


def map_fields_to_bytes(fields: MapFields) -> bytes:
    buf = io.BytesIO()
    nxt = np.asarray(fields.next_candidate_um if fields.next_candidate_um is not None else [], dtype=float)
    np.savez_compressed(
        buf,
        x_um=fields.x_um,
        y_um=fields.y_um,
        mean_gpa=fields.mean_gpa,
        epistemic_sd_gpa=fields.epistemic_sd_gpa,
        noise_sd_gpa=fields.noise_sd_gpa,
        total_sd_gpa=fields.total_sd_gpa,
        next_candidate_um=nxt,
    )
    return buf.getvalue()


def map_fields_from_bytes(snapshot_id: int, blob: bytes) -> MapFields:
    with np.load(io.BytesIO(blob)) as z:
        nxt = z["next_candidate_um"]
        return MapFields(
            snapshot_id=snapshot_id,
            x_um=z["x_um"],
            y_um=z["y_um"],
            mean_gpa=z["mean_gpa"],
            epistemic_sd_gpa=z["epistemic_sd_gpa"],
            noise_sd_gpa=z["noise_sd_gpa"],
            total_sd_gpa=z["total_sd_gpa"],
            next_candidate_um=(float(nxt[0]), float(nxt[1])) if nxt.size == 2 else None,
        )


def utc_now() -> str:
    return datetime.now(UTC).isoformat(timespec="milliseconds").replace("+00:00", "Z")


def default_journal_path(name: str, runs_dir: str | Path = "runs") -> Path:
    """``./runs/<UTC time>-<name>.sqlite``; the name is reduced to file-safe characters."""
    safe = "".join(c if c.isalnum() or c in "-_." else "-" for c in name).strip("-.") or "run"
    stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%SZ")
    return Path(runs_dir) / f"{stamp}-{safe}.sqlite"


def user_name(uid: int) -> str:
    try:
        return pwd.getpwuid(uid).pw_name
    except KeyError:
        return str(uid)


def lock_path_for(path: str | Path) -> Path:
    p = Path(path)
    return p.with_name(p.name + ".lock")


def engine_running(path: str | Path) -> bool:
    """Whether an engine holds the journal's lock right now (probed without blocking it for long)."""
    lp = lock_path_for(path)
    try:
        fd = os.open(lp, os.O_RDONLY)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except OSError:
        return True
    else:
        fcntl.flock(fd, fcntl.LOCK_UN)
        return False
    finally:
        os.close(fd)


# --------------------------------------------------------------------------------------------------
# opening and validating


def check_journal_file(path: str | Path) -> None:
    """Refuse a file that is missing, not SQLite, truncated, corrupt or of an unknown schema version.

    Opens read-only: a journal that cannot be read is never modified.
    """
    p = Path(path)
    src = str(p)
    if not p.is_file():
        raise InputError(src, "no such journal file")
    try:
        with open(p, "rb") as fh:
            head = fh.read(100)
    except OSError as exc:
        raise InputError(src, f"cannot read journal ({exc.strerror})") from None
    if len(head) < 100 or not head.startswith(SQLITE_MAGIC):
        raise InputError(src, "not a journal: the file is not an SQLite database (truncated or another file)")
    page_size = int.from_bytes(head[16:18], "big")
    page_size = 65536 if page_size == 1 else page_size
    n_pages = int.from_bytes(head[28:32], "big")
    size = p.stat().st_size
    if page_size and n_pages and size < page_size * n_pages:
        raise InputError(
            src,
            f"journal is truncated: {size} bytes on disk but the header says {n_pages} pages of {page_size} "
            "bytes; nothing was changed",
        )
    # a WAL-mode file without its -wal has nothing pending: read it immutable, so checking creates no sidecars
    immutable = head[18] == 2 and not Path(str(p) + "-wal").exists()
    conn = _connect_ro(p, immutable=immutable)
    try:
        try:
            rows = conn.execute("PRAGMA quick_check").fetchall()
        except sqlite3.DatabaseError as exc:
            raise InputError(src, f"journal is corrupt ({exc}); nothing was changed") from None
        if [r[0] for r in rows] != ["ok"]:
            first = "; ".join(str(r[0]) for r in rows[:3])
            raise InputError(src, f"journal is corrupt ({first}); nothing was changed")
        _check_schema(conn, src)
    finally:
        conn.close()


def _connect_ro(path: Path, immutable: bool = False) -> sqlite3.Connection:
    uri = f"file:{path.resolve()}?mode=ro" + ("&immutable=1" if immutable else "")
    try:
        conn = sqlite3.connect(uri, uri=True, timeout=_BUSY_TIMEOUT_MS / 1000, check_same_thread=False)
    except sqlite3.Error as exc:
        raise InputError(str(path), f"cannot open journal read-only ({exc})") from None
    conn.execute(f"PRAGMA busy_timeout = {_BUSY_TIMEOUT_MS}")
    return conn


def _check_schema(conn: sqlite3.Connection, src: str) -> None:
    try:
        names = {r[0] for r in conn.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        if "schema_version" not in names:
            raise InputError(src, "not an AE-NI journal (no schema_version table)")
        row = conn.execute("SELECT version FROM schema_version").fetchone()
    except sqlite3.DatabaseError as exc:
        raise InputError(src, f"journal is corrupt ({exc}); nothing was changed") from None
    if row is None:
        raise InputError(src, "journal has no schema version (it was never fully created)")
    if int(row[0]) != SCHEMA_VERSION:
        raise InputError(
            src,
            f"journal schema version {row[0]} is not supported (this program reads version {SCHEMA_VERSION})",
        )
    missing = [t for t in _TABLES if t not in names]
    if missing:
        raise InputError(src, f"journal is missing tables {', '.join(missing)}")


# --------------------------------------------------------------------------------------------------
# shared reads (used by the reader and by the engine when it resumes)


@dataclass(frozen=True)
class StoredCommand:
    """A command row as the engine sees it (``kind`` stays a string: a bad row must be rejected, not crash)."""

    command_id: int
    kind: str
    author: str
    uid: int
    payload: dict[str, Any]
    shown_scores: dict[str, Any]
    wall_utc: str


@dataclass(frozen=True)
class StoredDecision:
    decision_id: int
    decision: Decision
    status: str
    needs_approval_reason: str
    t_s: float


@dataclass(frozen=True)
class DriverState:
    clock_s: float
    physics_clock_s: float | None
    position_um: tuple[float, float]
    program_open: bool
    reason: str


@dataclass(frozen=True)
class BlockRecord:
    """One planned block with what became of it: the unit the replay walks."""

    block: Block
    status: str  # planned | running | executed | observed | aborted
    decision: Decision | None
    results: tuple[IndentResult, ...]
    steps: tuple[StepRecord, ...]
    snapshot_id: int | None
    fit_summary: dict[str, Any]
    planned_t_s: float
    finished_t_s: float | None

    @property
    def median_gpa(self) -> float | None:
        return statistics.median(r.hardness_gpa for r in self.results) if self.results else None

    @property
    def seconds(self) -> float:
        return float(sum(s.seconds for s in self.steps))


def _result_from_row(r: Sequence[Any]) -> IndentResult:
    return IndentResult(
        block_id=int(r[0]),
        indent_index=int(r[1]),
        commanded_x_um=r[2],
        commanded_y_um=r[3],
        actual_x_um=r[4],
        actual_y_um=r[5],
        hold_s=r[6],
        hardness_gpa=r[7],
        modulus_gpa=r[8],
        drift_rate_nm_s=r[9],
        t_s=r[10],
    )


_INDENT_COLS = (
    "block_id, indent_index, commanded_x_um, commanded_y_um, actual_x_um, actual_y_um, hold_s, "
    "hardness_gpa, modulus_gpa, drift_rate_nm_s, t_s"
)


class _Queries:
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
            f"SELECT {_INDENT_COLS} FROM indents WHERE block_id = ? ORDER BY indent_index", (block_id,)
        )
        return [_result_from_row(r) for r in rows]

    def all_results(self) -> list[IndentResult]:
        rows = self.conn.execute(f"SELECT {_INDENT_COLS} FROM indents ORDER BY block_id, indent_index")
        return [_result_from_row(r) for r in rows]

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


# --------------------------------------------------------------------------------------------------
# the writer


class JournalLockedError(InputError):
    """Another engine holds this journal."""


class Journal:
    """The engine's write side. Create a run with :meth:`create`, reopen it with :meth:`open_writer`."""

    def __init__(self, path: Path, conn: sqlite3.Connection, lock_fd: int) -> None:
        self.path = path
        self.conn = conn
        self._lock_fd: int | None = lock_fd
        self.q = _Queries(conn, path)
        self.session_id: int | None = None
        self._t_s = 0.0

    # -- opening ---------------------------------------------------------------------------------
    @staticmethod
    def _take_lock(path: Path, retries: int = 10) -> int:
        lp = lock_path_for(path)
        fd = os.open(lp, os.O_RDWR | os.O_CREAT, 0o644)
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
        conn = sqlite3.connect(str(path), isolation_level=None, timeout=_BUSY_TIMEOUT_MS / 1000)
        conn.execute(f"PRAGMA busy_timeout = {_BUSY_TIMEOUT_MS}")
        conn.execute("PRAGMA journal_mode = WAL")
        conn.execute("PRAGMA synchronous = FULL")
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
    ) -> Journal:
        """A new journal holding the run's configuration; returns the writer (lock held)."""
        p = Path(path)
        if p.exists():
            raise InputError(str(p), "journal already exists; use `aeni resume` to continue it")
        p.parent.mkdir(parents=True, exist_ok=True)
        lock_fd = cls._take_lock(p)
        tmp = p.with_name(p.name + ".creating")
        try:
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()
            conn = cls._connect_rw(tmp)
            conn.execute("BEGIN")
            for stmt in _SCHEMA.split(";"):
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
    def open_writer(cls, path: str | Path) -> Journal:
        """Reopen a journal for writing (resume). Checks it read-only first and takes the engine lock."""
        p = Path(path)
        check_journal_file(p)
        lock_fd = cls._take_lock(p)
        try:
            conn = cls._connect_rw(p)
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

    def __enter__(self) -> Journal:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- writing ---------------------------------------------------------------------------------
    @contextlib.contextmanager
    def _tx(self) -> Iterator[sqlite3.Connection]:
        self.conn.execute("BEGIN IMMEDIATE")
        try:
            yield self.conn
        except BaseException:
            self.conn.execute("ROLLBACK")
            raise
        self.conn.execute("COMMIT")

    def note_clock(self, t_s: float) -> None:
        self._t_s = t_s

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
    ) -> int:
        """A planner proposal with its scores and alternatives; with ``plan`` (an auto decision) also the
        block plan and the planner state, in the same transaction."""
        b = decision.block
        with self._tx() as c:
            cur = c.execute(
                "INSERT INTO decisions (block_id, wall_utc, t_s, policy, phase, kind, center_x_um, center_y_um, "
                "score, acquisition, predicted_cost_s, decision_json, status, needs_approval_reason) "
                "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (
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
                f"INSERT INTO indents ({_INDENT_COLS}, wall_utc, session_id, last_step_id) "
                "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (
                    result.block_id,
                    result.indent_index,
                    result.commanded_x_um,
                    result.commanded_y_um,
                    result.actual_x_um,
                    result.actual_y_um,
                    result.hold_s,
                    result.hardness_gpa,
                    result.modulus_gpa,
                    result.drift_rate_nm_s,
                    result.t_s,
                    utc_now(),
                    self.session_id,
                    last,
                ),
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
            (block_id, point, utc_now(), to_json(state), to_json(settings)),
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
        raise InputError(str(p), "no engine is running this journal (start it with `aeni resume`)")
    kind = CommandKind(command.kind)
    conn = sqlite3.connect(str(p), isolation_level=None, timeout=_BUSY_TIMEOUT_MS / 1000)
    try:
        conn.execute(f"PRAGMA busy_timeout = {_BUSY_TIMEOUT_MS}")
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


# --------------------------------------------------------------------------------------------------
# the reader


class JournalReader:
    """Read-only view of a journal, safe while the engine writes; what consoles, replay and export use."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        check_journal_file(self.path)
        self.conn = _connect_ro(self.path)
        self.q = _Queries(self.conn, self.path)
        self._meta = self.q.meta()
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
    def results(self) -> list[IndentResult]:
        with self._read():
            return self.q.all_results()

    def state(self) -> tuple[EngineState, bool]:
        """The engine state and whether the engine process has ended."""
        with self._read():
            row = self.q.engine_row()
        return self._effective_state(row)

    def _effective_state(self, row: dict[str, Any]) -> tuple[EngineState, bool]:
        state = EngineState(row["state"])
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
        if name not in _TABLES:
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

    def _tested_centres(self, c: sqlite3.Connection) -> tuple[TestedCenter, ...]:
        new = c.execute(
            "SELECT b.block_id, b.center_x_um, b.center_y_um FROM blocks b WHERE b.status = 'observed' "
            "AND b.block_id > ?",
            (max(self._tested, default=-1),),
        ).fetchall()
        for bid, cx, cy in new:
            hs = [r[0] for r in c.execute("SELECT hardness_gpa FROM indents WHERE block_id = ?", (bid,))]
            if hs:
                self._tested[bid] = TestedCenter(cx, cy, bid, float(statistics.median(hs)))
        return tuple(self._tested[k] for k in sorted(self._tested))

    def _drift(self, c: sqlite3.Connection, last: Decision | None) -> DriftStatus:
        for rowid, t_s, rate in c.execute(
            "SELECT rowid, t_s, drift_rate_nm_s FROM indents WHERE rowid > ? ORDER BY rowid",
            (self._drift_seen_rowid,),
        ):
            self._drift_seen_rowid = rowid
            if area_error_pct(rate) >= AREA_ERROR_THRESHOLD_PCT:
                self._drift_events.append((t_s, rate))
        row = c.execute("SELECT drift_rate_nm_s FROM indents ORDER BY rowid DESC LIMIT 1").fetchone()
        rate = None if row is None else float(row[0])
        hold_mode = "fixed"
        err = None if rate is None else area_error_pct(rate)
        if last is not None:
            hold_mode = (
                last.hold_mode
                if f"{last.block.hold_s:g} s" in last.hold_mode
                else f"{last.hold_mode} {last.block.hold_s:g} s"
            )
            if last.area_error_pct is not None:
                err = last.area_error_pct
        return DriftStatus(
            last_rate_nm_s=rate,
            hold_mode=hold_mode,
            area_error_pct=err,
            threshold_pct=AREA_ERROR_THRESHOLD_PCT,
            events=tuple(self._drift_events[-100:]),
        )

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

    def snapshot(self, reader_user: str | int | None = None) -> RunSnapshot:
        """The console's whole view, read in one consistent transaction."""
        owner, can_command = self._owner_view(reader_user)
        with self._read() as c:
            eng = self.q.engine_row()
            ds = self.q.latest_driver_state()
            ledger = dict.fromkeys(LEDGER_CATEGORIES, 0.0)
            n_reconf = 0
            for cat, total, n in c.execute(
                "SELECT category, SUM(seconds), COUNT(*) FROM steps GROUP BY category"
            ):
                ledger[cat] = round(float(total), 6)
                if cat == "reconfigure":
                    n_reconf = int(n)
            n_indents = int(c.execute("SELECT COUNT(*) FROM indents").fetchone()[0])
            n_blocks = int(c.execute("SELECT COUNT(DISTINCT block_id) FROM indents").fetchone()[0])
            open_blk = self.q.open_block()
            pending = self.q.pending_decision()
            last = self.q.last_accepted_decision()
            gp_row = c.execute(
                "SELECT snapshot_id, summary_json FROM gp_snapshots ORDER BY snapshot_id DESC LIMIT 1"
            ).fetchone()
            cs = c.execute("SELECT settings_json FROM campaign_states ORDER BY id DESC LIMIT 1").fetchone()
            sessions = c.execute("SELECT started_unix, ended_unix FROM sessions").fetchall()
            tested = self._tested_centres(c)
            drift = self._drift(c, last.decision if last else None)
            log_rows = c.execute(
                "SELECT wall_utc, t_s, level, text FROM events ORDER BY event_id DESC LIMIT ?", (LOG_TAIL,)
            ).fetchall()
        state, finished = self._effective_state(eng)
        current = open_blk[0] if open_blk and open_blk[1] in ("planned", "running", "aborted") else None
        done = open_blk[2] if open_blk and current is not None else 0
        pos = ds.position_um if ds else (0.0, 0.0)
        is_open = ds.program_open if ds else False
        queue = (
            ()
            if finished
            else self._queue(current, done, pending.decision.block if pending else None, pos, is_open)
        )
        summary: dict[str, Any] = json.loads(gp_row[1]) if gp_row else {}
        gp = GpStatus(
            lengthscales_um=tuple(summary.get("lengthscales_um", ())),
            noise_lengthscales_um=tuple(summary.get("noise_lengthscales_um", ())),
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
        now = time.time()
        wall_s = float(sum((e if e is not None else now) - s for s, e in sessions))
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
            can_command=can_command and not finished,
            instrument_s=ds.clock_s if ds else 0.0,
            wall_s=wall_s,
            n_indents=n_indents,
            n_blocks=n_blocks,
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
        )

"""The journal file itself: its tables, its version, how it is opened, checked and locked.

One SQLite file per run. The engine holds ``<journal>.lock`` for its life (one writer); readers open the
file read-only. A file that is missing, truncated, corrupt or of another schema version is refused
before anything opens it for writing.
"""

from __future__ import annotations

import fcntl
import os
import sqlite3
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path

from core.access import user_name as user_name
from core.errors import InputError
from core.runview import EngineState

# 2: indents carry a status (measured / failed / not_run) and NULL values when not measured
# 4: the status may also be 'unverified' (made, but its export was refused); 3 is migrated on resume
# 6: each indent's channel ('csm' or 'fast', issue 36); earlier journals read as all CSM, migrated on resume
SCHEMA_VERSION = 6
READABLE_VERSIONS = (3, 4, 5, 6)
SQLITE_MAGIC = b"SQLite format 3\x00"
LOG_TAIL = 200
BUSY_TIMEOUT_MS = 10_000
TERMINAL_STATES = (EngineState.STOPPED, EngineState.FAILED)

SCHEMA_SQL = """
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
    commanded_x_um REAL NOT NULL, commanded_y_um REAL NOT NULL, actual_x_um REAL,
    actual_y_um REAL, hold_s REAL NOT NULL, hardness_gpa REAL, modulus_gpa REAL,
    drift_rate_nm_s REAL, t_s REAL NOT NULL,
    status TEXT NOT NULL CHECK (status IN ('measured', 'failed', 'not_run', 'unverified')), note TEXT NOT NULL,
    depth_at_max_load_nm REAL, wall_utc TEXT NOT NULL, session_id INTEGER,
    last_step_id INTEGER, channel TEXT NOT NULL DEFAULT 'csm' CHECK (channel IN ('csm', 'fast')),
    PRIMARY KEY (block_id, indent_index));
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
CREATE TABLE run_events (
    seq INTEGER PRIMARY KEY, kind TEXT NOT NULL, t_s REAL NOT NULL, wall_utc TEXT NOT NULL,
    body_json TEXT NOT NULL, rebuilt INTEGER NOT NULL DEFAULT 0);
"""

TABLES = (
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


def default_journal_path(name: str, runs_dir: str | Path = "runs") -> Path:
    """``./runs/<UTC time>-<name>.sqlite``; the name is reduced to file-safe characters."""
    safe = "".join(c if c.isalnum() or c in "-_." else "-" for c in name).strip("-.") or "run"
    stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%SZ")
    return Path(runs_dir) / f"{stamp}-{safe}.sqlite"


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

    Opens read-only: a journal that cannot be read is never modified. The file is opened through SQLite
    only: closing a plain handle on it would drop every POSIX lock this process holds on it (a console's
    open reader, the engine's own connection), after which another process closing its connection takes
    itself for the last one and deletes the ``-shm`` under them: this process would read that stale index
    ever after (a console would never see the engine its supervisor resumed). Only a file SQLite refuses
    is read by hand, to say why.
    """
    p = Path(path)
    src = str(p)
    if not p.is_file():
        raise InputError(src, "no such journal file")
    if not os.access(p, os.R_OK):
        raise InputError(src, "cannot read journal (Permission denied)")
    # shorter than SQLite's header: not a journal (SQLite would take an empty file for a new database)
    if p.stat().st_size < 100:
        raise InputError(src, "not a journal: the file is not an SQLite database (truncated or another file)")
    wal = Path(f"{p}-wal")
    # a file without its -wal has nothing pending: read it immutable, so checking creates no sidecars
    conn = connect_ro(p, immutable=not wal.exists())
    try:
        try:
            rows = conn.execute("PRAGMA quick_check").fetchall()
        except sqlite3.DatabaseError as exc:
            raise _refusal(p, wal, exc) from None
        if [r[0] for r in rows] != ["ok"]:
            first = "; ".join(str(r[0]) for r in rows[:3])
            raise InputError(src, f"journal is corrupt ({first}); nothing was changed")
        _check_schema(conn, src)
    finally:
        conn.close()


def _refusal(p: Path, wal: Path, exc: sqlite3.DatabaseError) -> InputError:
    """Why SQLite refused the file, read from its header (only for a file SQLite cannot read)."""
    src = str(p)
    try:
        with open(p, "rb") as fh:
            head = fh.read(100)
    except OSError as err:
        return InputError(src, f"cannot read journal ({err.strerror})")
    if len(head) < 100 or not head.startswith(SQLITE_MAGIC):
        return InputError(
            src, "not a journal: the file is not an SQLite database (truncated or another file)"
        )
    page_size = int.from_bytes(head[16:18], "big")
    page_size = 65536 if page_size == 1 else page_size
    n_pages = int.from_bytes(head[28:32], "big")
    size = p.stat().st_size
    # with a -wal, pages beyond the file's end may be there: a checkpoint cut short by a full disk writes the
    # header first and leaves every page in the WAL (SQLite reads them there; then it is corrupt otherwise)
    pending = wal.is_file() and wal.stat().st_size > 0
    if page_size and n_pages and size < page_size * n_pages and not pending:
        return InputError(
            src,
            f"journal is truncated: {size} bytes on disk but the header says {n_pages} pages of {page_size} "
            "bytes; nothing was changed",
        )
    return InputError(src, f"journal is corrupt ({exc}); nothing was changed")


def migrate(conn: sqlite3.Connection, rebuild_events: Callable[[sqlite3.Connection], None]) -> None:
    """Bring a journal of an earlier version to this one, in one transaction.

    3 -> 4: the indents table's status check gains 'unverified' (SQLite cannot alter a CHECK, so the table
    is rebuilt from the new definition). 4 -> 5: the event log (``run_events``), rebuilt from the tables by
    ``rebuild_events`` (core.journal.eventlog). 5 -> 6: the indents' channel, every earlier indent a CSM one."""
    row = conn.execute("SELECT version FROM schema_version").fetchone()
    if row is None or int(row[0]) not in (3, 4, 5):
        return
    conn.execute("BEGIN IMMEDIATE")
    try:
        if int(row[0]) == 3:
            start = SCHEMA_SQL.index("CREATE TABLE indents")
            create = SCHEMA_SQL[start : SCHEMA_SQL.index(";", start)]
            conn.execute(create.replace("CREATE TABLE indents", "CREATE TABLE indents_v4", 1))
            cols = ", ".join(r[1] for r in conn.execute("PRAGMA table_info(indents)"))
            conn.execute(f"INSERT INTO indents_v4 ({cols}) SELECT {cols} FROM indents")
            conn.execute("DROP TABLE indents")
            conn.execute("ALTER TABLE indents_v4 RENAME TO indents")
        if "channel" not in {r[1] for r in conn.execute("PRAGMA table_info(indents)")}:
            conn.execute(
                "ALTER TABLE indents ADD COLUMN channel TEXT NOT NULL DEFAULT 'csm' "
                "CHECK (channel IN ('csm', 'fast'))"
            )
        if int(row[0]) in (3, 4):
            start = SCHEMA_SQL.index("CREATE TABLE run_events")
            conn.execute(SCHEMA_SQL[start : SCHEMA_SQL.index(";", start)])
            rebuild_events(conn)
        conn.execute("UPDATE schema_version SET version = ?", (SCHEMA_VERSION,))
        conn.execute("COMMIT")
    except BaseException:
        conn.execute("ROLLBACK")
        raise


def connect_ro(path: Path, immutable: bool = False) -> sqlite3.Connection:
    uri = f"file:{path.resolve()}?mode=ro" + ("&immutable=1" if immutable else "")
    try:
        conn = sqlite3.connect(uri, uri=True, timeout=BUSY_TIMEOUT_MS / 1000, check_same_thread=False)
    except sqlite3.Error as exc:
        raise InputError(str(path), f"cannot open journal read-only ({exc})") from None
    conn.execute(f"PRAGMA busy_timeout = {BUSY_TIMEOUT_MS}")
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
    if int(row[0]) > SCHEMA_VERSION:
        raise InputError(
            src,
            f"journal schema version {row[0]} is not supported: it was written by a newer release (schema "
            f"{row[0]} > {SCHEMA_VERSION}, the newest this program reads); open it with that release or a later one",
        )
    if int(row[0]) not in READABLE_VERSIONS:
        raise InputError(
            src,
            f"journal schema version {row[0]} is not supported (this program reads version {SCHEMA_VERSION}; "
            "journals written by an earlier version are not converted, see docs/journal.md)",
        )
    missing = [t for t in TABLES if t not in names]
    if int(row[0]) >= 5 and "run_events" not in names:
        missing.append("run_events")
    if missing:
        raise InputError(src, f"journal is missing tables {', '.join(missing)}")

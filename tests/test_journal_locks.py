"""A process that watches a journal (a console, `aeni runs`, the test probing a supervised run) keeps seeing it
after another process writes and closes it. Checking a journal used to open and close a plain handle on its
file, which drops every POSIX lock this process holds on it (SQLite's readers hold one): the next writer to
close took itself for the last connection and deleted the ``-shm``, and this process went on reading the old,
unlinked index: a console never saw the engine a supervisor resumed (issue 38's lost probe)."""

from __future__ import annotations

import sqlite3
import subprocess
import sys
from pathlib import Path

from core.journal import check_journal_file
from core.journal.schema import SCHEMA_SQL, SCHEMA_VERSION, connect_ro

WRITE = """
import sqlite3, sys
c = sqlite3.connect(sys.argv[1], isolation_level=None)
c.execute("INSERT INTO events (wall_utc, t_s, level, category, text) VALUES ('', 0, 'info', 'e', ?)", (sys.argv[2],))
c.close()
"""


def _write(path: Path, text: str) -> None:
    """One row from another process (its connection closed after), as the supervisor journals a death."""
    subprocess.run([sys.executable, "-c", WRITE, str(path), text], check=True, timeout=60)


def test_checking_a_journal_keeps_the_locks_of_this_process_readers(tmp_path: Path) -> None:
    path = tmp_path / "j.sqlite"
    with sqlite3.connect(path, isolation_level=None) as c:
        c.execute("PRAGMA journal_mode = WAL")
        c.executescript(SCHEMA_SQL)
        c.execute("INSERT INTO schema_version VALUES (?)", (SCHEMA_VERSION,))
    c.close()
    _write(path, "before")
    watcher = connect_ro(path)  # a console's reader, held open
    try:
        assert watcher.execute("SELECT COUNT(*) FROM events").fetchone() == (1,)
        check_journal_file(path)  # as JournalReader, `aeni runs` or the supervisor do, in the same process
        _write(path, "a death")  # the other process must not take itself for the last connection
        assert Path(f"{path}-shm").exists() and Path(f"{path}-wal").exists()
        _write(path, "resumed")
        check_journal_file(path)
        fresh = connect_ro(path)  # a new look from this process sees every row
        try:
            assert [r[0] for r in fresh.execute("SELECT text FROM events")] == [
                "before",
                "a death",
                "resumed",
            ]
        finally:
            fresh.close()
        assert watcher.execute("SELECT COUNT(*) FROM events").fetchone() == (3,)
    finally:
        watcher.close()

"""The run journal: one SQLite file per run that survives a crash and that any console can read.

The engine is the only writer (an exclusive lock file, held for the engine's life); consoles read it
read-only while it is written (WAL) and send operator commands by inserting rows into its ``commands``
table, so no network port is ever opened. Every finished indent is committed in its own transaction,
so a crash loses at most the indent in flight. See docs/journal.md for the schema.

The package follows the file's seams: ``schema`` (tables, version, opening, the lock), ``codec`` (records
in and out), ``reader`` (queries and the consoles' view), ``writer`` (the engine's transactions and
the console's command row), ``eventlog`` (every event, typed, in order), ``snapshot`` (the console's fold over
it) and ``sink`` (the journal as the engine's run record: events in, the resume fold out).
"""

from core.journal.codec import (
    BlockRecord,
    DriverState,
    StoredCommand,
    StoredDecision,
    block_from_dict,
    decision_from_dict,
    map_fields_from_bytes,
    map_fields_to_bytes,
    to_json,
    utc_now,
)
from core.journal.reader import JournalReader, Queries
from core.journal.schema import (
    SCHEMA_VERSION,
    TERMINAL_STATES,
    check_journal_file,
    default_journal_path,
    engine_running,
    lock_path_for,
    user_name,
)
from core.journal.sink import Journal
from core.journal.writer import JournalLockedError, NotOwnerError, append_event, send_command

__all__ = [
    "SCHEMA_VERSION",
    "TERMINAL_STATES",
    "BlockRecord",
    "DriverState",
    "Journal",
    "JournalLockedError",
    "JournalReader",
    "NotOwnerError",
    "Queries",
    "StoredCommand",
    "StoredDecision",
    "append_event",
    "block_from_dict",
    "check_journal_file",
    "decision_from_dict",
    "default_journal_path",
    "engine_running",
    "lock_path_for",
    "map_fields_from_bytes",
    "map_fields_to_bytes",
    "send_command",
    "to_json",
    "user_name",
    "utc_now",
]

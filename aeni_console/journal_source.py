"""The console's sources backed by a real run journal: a live run, and a finished run to step through.

``JournalSource`` is a thin, lock-guarded wrapper over ``core.journal.JournalReader`` (one reader per
console, used from the feed thread). ``JournalReplay`` walks ``core.journal.ReplayView``: the snapshot
the console would have shown just after each block finished, rebuilt by the reader's own rules, so an
operator can walk a run block by block and see the map, the ledger and the decision that came next.
"""

from __future__ import annotations

import threading
from pathlib import Path

from core.journal import JournalReader, ReplayView, engine_running, send_command
from core.runview import Command, MapFields, RunSnapshot


class JournalSource:
    """A live (or finished) run read from its journal; commands go into the journal's command table."""

    def __init__(self, path: str | Path, reader_user: str | int | None = None) -> None:
        self.path = Path(path)
        self.reader_user = reader_user
        self._lock = threading.Lock()
        self._reader = JournalReader(self.path)
        self._seen: tuple[int, bool] | None = None

    def changed(self) -> bool:
        """Whether the journal may read differently since the last call: another connection committed
        (SQLite's ``data_version``) or the engine process started or ended. Costs one pragma and one lock
        probe, so the feed can ask often and read a whole snapshot only when something happened."""
        with self._lock:
            version = int(self._reader.conn.execute("PRAGMA data_version").fetchone()[0])
        now = (version, engine_running(self.path))
        if now == self._seen:
            return False
        self._seen = now
        return True

    def snapshot(self) -> RunSnapshot:
        with self._lock:
            return self._reader.snapshot(self.reader_user)

    def map_fields(self, snapshot_id: int) -> MapFields | None:
        with self._lock:
            try:
                return self._reader.map_fields(snapshot_id)
            except KeyError:
                return None

    def send(self, command: Command) -> None:
        send_command(self.path, command)

    def close(self) -> None:
        with self._lock:
            self._reader.close()


class JournalReplay(JournalSource):
    """Step through a run: ``snapshot_at(i)`` is the view just after the i-th observed block."""

    def __init__(self, path: str | Path, reader_user: str | int | None = None) -> None:
        super().__init__(path, reader_user)
        self._view: ReplayView | None = None

    def _load(self) -> ReplayView:
        with self._lock:
            self._view = ReplayView(self._reader, self.reader_user)
        return self._view

    def n_blocks(self) -> int:
        return len(self._load().observed)

    def send(self, command: Command) -> None:
        raise PermissionError("a replay cannot command the run; attach with `aeni console RUN` instead")

    def snapshot_at(self, block_index: int) -> RunSnapshot:
        view = self._view if self._view is not None else self._load()
        return view.snapshot_at(block_index)

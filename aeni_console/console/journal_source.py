"""The console's sources backed by a real run journal: a live run, and a finished run to step through.

``JournalSource`` is a thin, lock-guarded wrapper over ``core.journal.JournalReader`` (one reader per
console, used from the feed thread), whose view is the fold of the run's events (core.journal.snapshot).
``JournalReplay`` steps through the same fold stopped just after each observed block
(``JournalReader.snapshot(upto=...)``): one set of rules for the live console and replay, so an operator can walk a run block by block and see the map, the ledger and the decision that
came next as the console showed them.
"""

from __future__ import annotations

import threading
from dataclasses import replace
from pathlib import Path

from core.errors import InputError
from core.journal import JournalReader, engine_running, send_command
from core.run.tray_view import SampleProgress, journal_tray, tray_progress
from core.runview import Command, MapFields, RunSnapshot
from core.sample import Sample, sample_from_dict


def journal_sample(reader: JournalReader) -> Sample | None:
    """The sample the run was planned on (the journal holds it in its campaign config), None if it has none."""
    data = (reader.meta.get("config") or {}).get("sample")
    if not data:
        return None
    try:
        return sample_from_dict(data, f"{reader.path} sample")
    except InputError:
        return None  # the map draws no outline rather than refuse to show the run


class JournalSource:
    """A live (or finished) run read from its journal; commands go into the journal's command table."""

    def __init__(self, path: str | Path, reader_user: str | int | None = None) -> None:
        self.path = Path(path)
        self.reader_user = reader_user
        self._lock = threading.Lock()
        self._reader = JournalReader(self.path)
        self._seen: tuple[int, bool] | None = None
        self._sample = journal_sample(self._reader)
        self._tray = journal_tray(self._reader.meta)  # a tray run's samples, None for one sample

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

    def snapshot(self, upto: int | None = None) -> RunSnapshot:
        """The run now, or (``upto``) just after that observed block, with the sample it was planned on."""
        with self._lock:
            snap = self._reader.snapshot(self.reader_user, upto)
            tray: tuple[SampleProgress, ...] = ()
            if self._tray is not None and upto is None:  # (a replay's past block: its state then is not kept)
                latest = self._reader.latest_campaign_state()
                tray = tuple(tray_progress(self._tray, None if latest is None else latest[0]))
            return replace(snap, sample=self._sample, tray=tray)

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
        self._blocks: list[int] | None = None

    def _steps(self) -> list[int]:
        if self._blocks is None:
            with self._lock:
                self._blocks = self._reader.replay_blocks()
        return self._blocks

    def n_blocks(self) -> int:
        self._blocks = None  # a running run may have observed more since
        return len(self._steps())

    def send(self, command: Command) -> None:
        raise PermissionError("a replay cannot command the run; attach with `aeni console RUN` instead")

    def snapshot_at(self, block_index: int) -> RunSnapshot:
        blocks = self._steps()
        if not 0 <= block_index < len(blocks):
            raise IndexError(f"block index {block_index} is outside 0–{len(blocks) - 1}")
        return self.snapshot(blocks[block_index])

"""Where the console's data comes from, and the thread that brings it without blocking the UI.

The console only knows the small ``RunSource`` protocol: a live journal, a finished journal (replay)
and a canned snapshot (rendering tests) all look the same. A ``Feed`` thread asks the source whether
anything changed (a source that can tell, like a journal's ``changed()``, answers for the price of one
pragma), reads a snapshot only then, loads the map fields when the GP refits, and posts *replaceable*
messages at a capped rate (the memray/Toolong pattern): if the UI is busy, a newer snapshot replaces the
queued one instead of piling up. A console at rest (no new journal rows) therefore does no work.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Protocol, runtime_checkable

from textual.message import Message

from core.runview import Command, MapFields, RunSnapshot


@runtime_checkable
class RunSource(Protocol):
    """A run the console can show and command."""

    def snapshot(self) -> RunSnapshot: ...

    def map_fields(self, snapshot_id: int) -> MapFields | None: ...

    def send(self, command: Command) -> None:
        """Record an operator command (raises for a reader that does not own the run)."""
        ...


@runtime_checkable
class ChangeAwareSource(RunSource, Protocol):
    """A source that can say cheaply whether a new snapshot could differ from the last one."""

    def changed(self) -> bool: ...


@runtime_checkable
class ReplaySource(RunSource, Protocol):
    """A finished run, stepped through block by block."""

    def n_blocks(self) -> int: ...

    def snapshot_at(self, block_index: int) -> RunSnapshot:
        """The run as it was just after block ``block_index`` (0-based) finished."""
        ...


class SnapshotArrived(Message):
    """A newer view of the run; a queued older one is dropped in its favour."""

    def __init__(self, snapshot: RunSnapshot) -> None:
        super().__init__()
        self.snapshot = snapshot

    def can_replace(self, message: Message) -> bool:
        return isinstance(message, SnapshotArrived)


class MapArrived(Message):
    """New GP map fields (after a refit)."""

    def __init__(self, fields: MapFields) -> None:
        super().__init__()
        self.fields = fields

    def can_replace(self, message: Message) -> bool:
        return isinstance(message, MapArrived)


class FeedProblem(Message):
    """The source could not be read (journal locked, file gone ...); the console shows it and keeps polling."""

    def __init__(self, text: str) -> None:
        super().__init__()
        self.text = text

    def can_replace(self, message: Message) -> bool:
        return isinstance(message, FeedProblem)


class Feed(threading.Thread):
    """Polls a source every ``poll_s`` and posts what changed to ``target``, at most ``max_rate_hz``.

    ``poke()`` asks for an immediate poll (after the operator sent a command). The thread is a daemon
    and never touches widgets; it only posts messages, which Textual makes thread-safe.
    """

    def __init__(
        self,
        source: RunSource,
        post: Callable[[Message], object],
        poll_s: float = 0.25,
        max_rate_hz: float = 8.0,
    ) -> None:
        super().__init__(name="aeni-feed", daemon=True)
        self.source = source
        self._post = post
        self.poll_s = poll_s
        self.min_gap_s = 1.0 / max_rate_hz if max_rate_hz > 0 else 0.0
        self._wake = threading.Event()
        self._stop_event = threading.Event()
        self._last: RunSnapshot | None = None
        self._last_map_id: int | None = None
        self._last_post = 0.0
        self.posted = 0  # snapshots posted (for tests and the benchmark)
        self.polls = 0
        self.reads = 0  # snapshots read (a poll with nothing changed reads none)
        self._retry = False  # the last read failed: read again even if the source saw no change

    def poke(self) -> None:
        self._wake.set()

    def stop(self) -> None:
        self._stop_event.set()
        self._wake.set()

    @property
    def map_checked_id(self) -> int | None:
        """The last fit whose map fields were looked up (found or not)."""
        return self._last_map_id

    @property
    def stopped(self) -> bool:
        return self._stop_event.is_set()

    def poll_once(self) -> None:
        """One poll: read, compare, post. Public so a test can drive the feed without the thread."""
        self.polls += 1
        try:
            if (
                self._last is not None
                and not self._retry
                and isinstance(self.source, ChangeAwareSource)
                and not self.source.changed()
            ):
                return
            self.reads += 1
            self._retry = False
            snap = self.source.snapshot()
        except Exception as exc:  # a feed must survive a bad read; the console shows why
            self._retry = True
            self._post(FeedProblem(f"cannot read the run: {exc}"))
            return
        if snap != self._last:
            self._last = snap
            self.posted += 1
            self._post(SnapshotArrived(snap))
        sid = snap.gp.snapshot_id
        if sid is not None and sid != self._last_map_id:
            try:
                fields = self.source.map_fields(sid)
            except Exception as exc:
                self._retry = True
                self._post(FeedProblem(f"cannot read the map fields: {exc}"))
                return
            self._last_map_id = sid  # a fit without stored fields (too few points) is not asked for again
            if fields is not None:
                self._post(MapArrived(fields))

    def run(self) -> None:
        while not self._stop_event.is_set():
            gap = self.min_gap_s - (time.monotonic() - self._last_post)
            if gap > 0:
                self._stop_event.wait(gap)  # the rate cap: never post faster than max_rate_hz
                if self._stop_event.is_set():
                    break
            self._last_post = time.monotonic()
            self.poll_once()
            self._wake.wait(self.poll_s)
            self._wake.clear()

"""A thread that sees pause and abort while a slow driver step runs (the main loop only reads commands
between indents): on the owner's abort it aborts the driver at once."""

from __future__ import annotations

import threading

from core.driver import Driver
from core.run.events import RunRecord


class AbortWatcher:
    def __init__(self, record: RunRecord, owner_uid: int, driver: Driver, watch_s: float | None) -> None:
        self.record = record
        self.owner_uid = owner_uid
        self.driver = driver
        self.watch_s = watch_s  # None: no watcher (a headless run)
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()

    def start(self) -> None:
        if self.watch_s is None:
            return
        self._stop.clear()
        self._thread = threading.Thread(target=self._watch, name="engine-watch", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        if self._thread is not None:
            self._stop.set()
            self._thread.join(timeout=5)
            self._thread = None

    def _watch(self) -> None:
        assert self.watch_s is not None
        watch = self.record.command_watch(self.owner_uid)
        if watch is None:
            return
        try:
            while not self._stop.wait(self.watch_s):
                if self.record.command_channel_problem(self.owner_uid):
                    continue  # the checkpoint rejects them, with the reason
                if watch.poll():
                    self.driver.abort()
        finally:
            watch.close()

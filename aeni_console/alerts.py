"""Alerts: a short message through apprise (email, Slack, Teams, Matrix, ntfy, ...) when a run needs someone.

An ``AlertWatcher`` reads the journal's new rows, as a console does, in a background thread of the engine's
process: sending never blocks or fails the engine. It alerts when a decision waits for approval, a timeout
was taken, the instrument has not answered for ``instrument_silence_s``, the interlock refused a block, a
deadline passed, the exchange folder went missing, the run ended or failed. The same kind of alert is sent at
most once per ``repeat_s``. A send that fails is journaled, without the URL (it may hold a token); apprise's
own log, which could name the service, is kept quiet.
"""

from __future__ import annotations

import contextlib
import logging
import sqlite3
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

from core.notifyconfig import NotifyConfig
from core.runview import LogEvent

TITLE = "AE-NI"
# what in a log row is worth an alert, by kind (the engine's and the drivers' words)
EVENT_KINDS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("interlock", ("safety interlock refused",)),
    ("timeout", ("timed out", "timeout")),
    ("deadline", ("deadline",)),
    ("folder", ("exchange folder",)),
)
ONCE_KINDS = ("ended", "failed")  # said once, never held back by the rate limit


def event_kind(text: str) -> str | None:
    """The alert kind of a log row's text, or None."""
    low = text.lower()
    if low.startswith("alert"):
        return None  # our own rows
    return next((kind for kind, needles in EVENT_KINDS if any(n in low for n in needles)), None)


def alert_worthy(events: Iterable[LogEvent]) -> bool:
    """Whether any of these log rows is one an alert is sent for (the console rings its bell)."""
    return any(event_kind(e.text) is not None for e in events)


def send(urls: tuple[str, ...], body: str, title: str = TITLE, severity: str = "info") -> tuple[bool, str]:
    """(sent, what happened in words without any URL); ``severity``: apprise's info, warning or failure."""
    import apprise

    logging.getLogger("apprise").setLevel(logging.CRITICAL + 1)  # its messages may name the service
    ap = apprise.Apprise()
    bad = sum(1 for u in urls if not ap.add(u))
    if len(ap) == 0:
        return False, f"none of the {len(urls)} alert URL(s) is one apprise knows"
    ok = bool(ap.notify(title=title, body=body, notify_type=apprise.NotifyType(severity)))
    if not ok:
        return False, f"a service did not accept the alert ({len(ap)} tried)"
    return True, f"sent to {len(ap)} service(s)" + (f"; {bad} URL(s) not understood" if bad else "")


@dataclass
class _Seen:
    state: str = ""
    event_id: int = 0
    progress_at: float = 0.0  # monotonic time of the last sign of life while waiting for the instrument
    results: int = 0


class AlertWatcher:
    """Reads the journal every ``poll_s`` and sends what needs someone (see the module docstring)."""

    def __init__(
        self,
        journal: str | Path,
        config: NotifyConfig,
        *,
        poll_s: float = 1.0,
        sender: Callable[[tuple[str, ...], str], tuple[bool, str]] = send,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.journal = Path(journal)
        self.config = config
        self.poll_s = poll_s
        self.sender = sender
        self.clock = clock
        self.sent: list[tuple[str, str]] = []  # (kind, text) of every alert sent, for the report and tests
        self._last: dict[str, float] = {}
        self._seen = _Seen(progress_at=clock())
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._started = False

    # -- the thread ----------------------------------------------------------------------------------
    def start(self) -> AlertWatcher:
        self._thread = threading.Thread(target=self._run, name="aeni-alerts", daemon=True)
        self._thread.start()
        return self

    def stop(self, timeout_s: float = 30.0) -> None:
        """A last look (the run's end), then stop."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout_s)

    def _run(self) -> None:
        while True:
            stopping = self._stop.is_set()
            try:
                self.check()
            except Exception as exc:  # an alert never fails the engine; say so once in its log
                self._journal(f"alerts: could not read the journal ({type(exc).__name__})")
            if stopping:
                return
            self._stop.wait(self.poll_s)

    # -- one look -------------------------------------------------------------------------------------
    def check(self) -> None:
        conn = sqlite3.connect(f"file:{self.journal}?mode=ro", uri=True, timeout=5.0)
        try:
            state, reason = conn.execute("SELECT state, stop_reason FROM engine_state").fetchone() or ("", "")
            rows = conn.execute(
                "SELECT event_id, text FROM events WHERE event_id > ? ORDER BY event_id",
                (self._seen.event_id,),
            ).fetchall()
            (results,) = conn.execute("SELECT COUNT(*) FROM indents").fetchone()
        finally:
            conn.close()
        now = self.clock()
        seen = self._seen
        if not self._started:
            # a resumed run: what was journaled before this engine started is not news
            self._started = True
            seen.state, seen.results = state, results
            seen.event_id = rows[-1][0] if rows else 0
            seen.progress_at = now
            return
        if rows or results != seen.results or state != seen.state:
            seen.progress_at = now
        for event_id, text in rows:
            seen.event_id = event_id
            kind = event_kind(text)
            if kind is not None:
                self._alert(kind, text)
        if state != seen.state:
            if state == "awaiting-approval":
                self._alert("approval", f"{self.journal.name}: a decision waits for approval")
            elif state == "stopped":
                self._alert("ended", f"{self.journal.name}: run ended: {reason or 'stopped'}")
            elif state == "failed":
                self._alert("failed", f"{self.journal.name}: run failed: {reason or 'failed'}")
        seen.state, seen.results = state, results
        silent = now - seen.progress_at
        if state == "waiting-for-instrument" and silent >= self.config.instrument_silence_s:
            self._alert(
                "silence", f"{self.journal.name}: the instrument has not answered for {silent:,.0f} s"
            )
            seen.progress_at = now  # the next one after another silence as long (and the rate limit)

    def _alert(self, kind: str, text: str) -> None:
        now = self.clock()
        last = self._last.get(kind)
        if kind in ONCE_KINDS:
            if last is not None:
                return
        elif last is not None and now - last < self.config.repeat_s:
            return
        self._last[kind] = now
        body = text if text.startswith(self.journal.name) else f"{self.journal.name}: {text}"
        try:
            ok, how = self.sender(self.config.urls, body)
        except Exception as exc:  # a sender that raises is a failed send, never the engine's problem
            ok, how = False, type(exc).__name__
        if ok:
            self.sent.append((kind, body))
        else:
            self._journal(f"alert not sent ({kind}): {how}")

    def _journal(self, text: str) -> None:
        from core.journal import append_event

        with contextlib.suppress(sqlite3.Error):  # the journal busy or gone: nothing more an alert can do
            append_event(self.journal, "warn", text, "alerts")

"""Alerts: a short message through apprise (email, Slack, Teams, Matrix, ntfy, ...) when a run needs someone.

An ``AlertWatcher`` reads the journal's new rows, as a console does, in a background thread of the engine's
process: sending never blocks or fails the engine. It alerts when a decision waits for approval, a timeout
was taken, the instrument has not answered for ``instrument_silence_s``, the interlock refused a block, a
deadline passed, the exchange folder went missing, an export was refused (once, with its reason: no silence
alerts follow it while the corrected export is awaited), the run ended or failed. Each alert carries apprise's
severity (``Severity``: failure, warning, info) and a title naming its cause. The same kind of alert is sent at
most once per ``repeat_s``. A send that fails is journaled, without the URL (it may hold a token); apprise's
own log, which could name the service, is kept quiet.
"""

from __future__ import annotations

import contextlib
import logging
import sqlite3
import threading
import time
import warnings
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path

from core.journal import append_event
from core.notifyconfig import NotifyConfig, import_apprise
from core.runview import LogEvent

TITLE = "AE-NI"


class Severity(StrEnum):
    """How bad it is, in apprise's own words (its ``NotifyType`` values): a service shows them as a colour or
    an icon. A stable API: the supervisor sends ``Severity.FAILURE`` when the engine dies."""

    FAILURE = (
        "failure"  # the run cannot go on by itself: it failed, the engine died, the exchange folder went
    )
    WARNING = "warning"  # the run goes on, but someone should look: a decision waits, a refusal, a silence
    INFO = "info"  # news only: the run ended as planned


@dataclass(frozen=True)
class AlertKind:
    """What happened (the cause an alert names in its title) and how bad it is."""

    cause: str
    severity: Severity


# every alert the watcher sends, by kind; the title is "AE-NI <severity>: <cause>"
KINDS: dict[str, AlertKind] = {
    "interlock": AlertKind("the safety interlock refused a block", Severity.WARNING),
    "refused": AlertKind("an export was refused", Severity.WARNING),
    "timeout": AlertKind("an approval timed out", Severity.WARNING),
    "deadline": AlertKind("a block's deadline passed", Severity.WARNING),
    "folder": AlertKind("the exchange folder is gone", Severity.FAILURE),
    "approval": AlertKind("a decision waits for approval", Severity.WARNING),
    "silence": AlertKind("the instrument is silent", Severity.WARNING),
    "ended": AlertKind("the run ended", Severity.INFO),
    "failed": AlertKind("the run failed", Severity.FAILURE),
    "tip": AlertKind("the tip check on the reference failed", Severity.FAILURE),
}
# what in a log row is worth an alert, by kind (the engine's and the drivers' words), first match wins
EVENT_KINDS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("tip", ("tip check failed",)),  # core.tipcheck's words: the run paused on a worn or dirty tip
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
    if low.startswith("export ") and " refused: " in low:  # the inbox's words (drivers.kla.array_run)
        return "refused"
    return next((kind for kind, needles in EVENT_KINDS if any(n in low for n in needles)), None)


def alert_worthy(events: Iterable[LogEvent]) -> bool:
    """Whether any of these log rows is one an alert is sent for (the console rings its bell)."""
    return any(event_kind(e.text) is not None for e in events)


def alert_title(severity: Severity, cause: str) -> str:
    return f"{TITLE} {severity.value}: {cause}"


def send(
    urls: tuple[str, ...],
    body: str,
    severity: Severity = Severity.INFO,
    cause: str = "",
) -> tuple[bool, str]:
    """Send one alert with apprise's severity (its NotifyType) and a title naming the cause; returns
    (sent, what happened in words without any URL). Never raises for a service that fails."""
    apprise = import_apprise()
    logging.getLogger("apprise").setLevel(logging.CRITICAL + 1)  # its messages may name the service
    with warnings.catch_warnings():  # its plugins load on first use (one imports the deprecated imghdr)
        warnings.simplefilter("ignore", DeprecationWarning)
        ap = apprise.Apprise()
        bad = sum(1 for u in urls if not ap.add(u))
        if len(ap) == 0:
            return False, f"none of the {len(urls)} alert URL(s) is one apprise knows"
        title = alert_title(severity, cause) if cause else TITLE
        ok = bool(ap.notify(title=title, body=body, notify_type=apprise.NotifyType(severity.value)))
    if not ok:
        return False, f"a service did not accept the alert ({len(ap)} tried)"
    return True, f"sent to {len(ap)} service(s)" + (f"; {bad} URL(s) not understood" if bad else "")


Sender = Callable[[tuple[str, ...], str, Severity, str], tuple[bool, str]]


@dataclass
class _Seen:
    state: str = ""
    event_id: int = 0
    progress_at: float = 0.0  # monotonic time of the last sign of life while waiting for the instrument
    results: int = 0
    refused: bool = False  # the last news is a refused export, and nothing has moved since
    asked_id: int = 0  # the last decision that needed approval and has been told (or was never asked)


class AlertWatcher:
    """Reads the journal every ``poll_s`` and sends what needs someone (see the module docstring)."""

    def __init__(
        self,
        journal: str | Path,
        config: NotifyConfig,
        *,
        poll_s: float = 1.0,
        sender: Sender = send,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.journal = Path(journal)
        self.config = config
        self.poll_s = poll_s
        self.sender = sender
        self.clock = clock
        self.sent: list[tuple[str, str]] = []  # (kind, text) of every alert sent, for the report and tests
        self.severities: list[Severity] = []  # the severity each of them was sent with
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
    def _asked(self, asks: list[tuple[int, str]], state: str) -> bool:
        """Whether a decision was put to someone since the last look: read from the decisions table, not from
        the engine's state, so an approval that timed out between two looks (a 1 s timeout, a slow poll) is
        told too. A decision the engine refused itself (auto supervision) was never put to anyone."""
        told = False
        for decision_id, by in asks:
            if not by and state != "awaiting-approval":
                break  # still open, and nobody is asked yet: look again next time
            self._seen.asked_id = decision_id
            told |= by != "engine"
        return told

    def check(self) -> None:
        conn = sqlite3.connect(f"file:{self.journal}?mode=ro", uri=True, timeout=5.0)
        try:
            state, reason = conn.execute("SELECT state, stop_reason FROM engine_state").fetchone() or ("", "")
            rows = conn.execute(
                "SELECT event_id, text FROM events WHERE event_id > ? ORDER BY event_id",
                (self._seen.event_id,),
            ).fetchall()
            (results,) = conn.execute("SELECT COUNT(*) FROM indents").fetchone()
            asks = conn.execute(
                "SELECT decision_id, COALESCE(resolved_by, '') FROM decisions "
                "WHERE needs_approval_reason != '' AND decision_id > ? ORDER BY decision_id",
                (self._seen.asked_id,),
            ).fetchall()
        finally:
            conn.close()
        now = self.clock()
        seen = self._seen
        if not self._started:
            # a resumed run: what was journaled before this engine started is not news
            self._started = True
            seen.state, seen.results = state, results
            seen.event_id = rows[-1][0] if rows else 0
            seen.asked_id = asks[-1][0] if asks else 0
            seen.progress_at = now
            return
        if rows or results != seen.results or state != seen.state:
            seen.progress_at = now
        if results != seen.results or state != seen.state:
            seen.refused = False  # the instrument went on: a later silence is news again
        for event_id, text in rows:
            seen.event_id = event_id
            kind = event_kind(text)
            if kind is not None:
                self._alert(kind, text)
            if kind == "refused":
                # the refusal says why nothing moves: no "has not answered" on top while the corrected export
                # is awaited (it would repeat every silence, and say less)
                seen.refused = True
        if self._asked(asks, state):
            self._alert("approval", f"{self.journal.name}: a decision waits for approval")
        if state != seen.state:
            if state == "stopped":
                # a run that ended on refusals or a timeout is news someone must act on, not just news
                bad_end = any(w in (reason or "").lower() for w in ("refus", "timed out", "interlock"))
                self._alert(
                    "ended",
                    f"{self.journal.name}: run ended: {reason or 'stopped'}",
                    Severity.WARNING if bad_end else None,
                )
            elif state == "failed":
                self._alert("failed", f"{self.journal.name}: run failed: {reason or 'failed'}")
        seen.state, seen.results = state, results
        silent = now - seen.progress_at
        if (
            state == "waiting-for-instrument"
            and silent >= self.config.instrument_silence_s
            and not seen.refused
        ):
            self._alert(
                "silence", f"{self.journal.name}: the instrument has not answered for {silent:,.0f} s"
            )
            seen.progress_at = now  # the next one after another silence as long (and the rate limit)

    def _alert(self, kind: str, text: str, severity: Severity | None = None) -> None:
        now = self.clock()
        last = self._last.get(kind)
        if kind in ONCE_KINDS:
            if last is not None:
                return
        elif last is not None and now - last < self.config.repeat_s:
            return
        self._last[kind] = now
        body = text if text.startswith(self.journal.name) else f"{self.journal.name}: {text}"
        what = KINDS[kind]
        severity = severity or what.severity
        try:
            ok, how = self.sender(self.config.urls, body, severity, what.cause)
        except Exception as exc:  # a sender that raises is a failed send, never the engine's problem
            ok, how = False, type(exc).__name__
        if ok:
            self.sent.append((kind, body))
            self.severities.append(severity)
        else:
            self._journal(f"alert not sent ({kind}): {how}")

    def _journal(self, text: str) -> None:

        with contextlib.suppress(sqlite3.Error):  # the journal busy or gone: nothing more an alert can do
            append_event(self.journal, "warn", text, "alerts")

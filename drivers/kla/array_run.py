"""One block's array on InView, from its published ticket to one outcome per site.

The operator (or a helper on the instrument PC) reports what happened, each report counting only with
the ticket's token: started, aborted (the rows present are kept), surface not found (nothing ran). The
operator may also take a site out of the array. The block ends when an export is accepted, when the
surface was not found, or at the deadline (a stable partial export is then taken as it is; otherwise the
sites a refused export placed, or, after a confirmed start, every site, are "unverified", the rest "not
run"). Every report and every refusal is kept in ``events`` for the journal.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from datetime import UTC, datetime, timedelta
from pathlib import Path

from drivers.kla.exchange import REPORT_KINDS, ExchangeFolder, ReportKind, Ticket, same_token
from drivers.kla.inbox import InboxWatcher, Refusal, SiteOutcome


def utc_now() -> datetime:
    return datetime.now(UTC)


@dataclass(frozen=True)
class ArrayEnd:
    """How a block's array ended and what each of its sites became."""

    outcomes: tuple[SiteOutcome, ...]
    how: str
    sha256: str | None = None
    archived: Path | None = None
    notes: tuple[str, ...] = ()


@dataclass(frozen=True)
class ArrayEvent:
    """Something the journal must record: a report (accepted or refused) or a refused export."""

    kind: str  # "started", "aborted", "surface-not-found", "skip", "refused", "note"
    text: str
    accepted: bool = True
    by: str = ""


@dataclass
class ArrayRun:
    folder: ExchangeFolder
    watcher: InboxWatcher
    ticket: Ticket
    now: Callable[[], datetime] = utc_now
    reported: set[str] = field(default_factory=set)  # the accepted reports (REPORT_KINDS)
    skipped: set[int] = field(default_factory=set)
    waiting: str = "no export yet"
    events: list[ArrayEvent] = field(default_factory=list)
    # the indents a refused export says were made (where the tip went): kept if no export is accepted
    made: tuple[SiteOutcome, ...] = ()
    _ignored_files: set[tuple[str, str]] = field(default_factory=set)
    _aborted_at: datetime | None = None

    def __post_init__(self) -> None:
        # a resumed block: what a refusal before the restart said was made (the archive kept it)
        t = self.ticket
        if not self.made:
            self.made = tuple(
                o
                for o in self.watcher.archive.refused_made(t.run, t.block_id)
                if t.first_index <= o.indent_index < t.first_index + t.n_sites
            )

    @property
    def started(self) -> bool:
        return "started" in self.reported

    @property
    def aborted(self) -> bool:
        return "aborted" in self.reported

    @property
    def surface_not_found(self) -> bool:
        return "surface-not-found" in self.reported

    # -- reports ---------------------------------------------------------------------------------
    def report(self, kind: ReportKind, token: str, by: str) -> tuple[bool, str]:
        """An operator's (or helper's) report; refused without this block's token."""
        if kind not in REPORT_KINDS:
            return self._event(kind, f"unknown report {kind!r}", False, by)
        if not same_token(token, self.ticket.token):
            return self._event(
                kind,
                f"{kind} refused: {token.strip()!r} is not block {self.ticket.block_id}'s token",
                False,
                by,
            )
        if kind in self.reported:
            return self._event(kind, f"{kind} already reported for block {self.ticket.block_id}", False, by)
        self.reported.add(kind)
        if kind == "aborted":
            self._aborted_at = self.now()
        text = {
            "started": f"block {self.ticket.block_id}: array started (token confirmed)",
            "aborted": f"block {self.ticket.block_id}: array aborted; the rows exported are kept, the rest not run",
            "surface-not-found": f"block {self.ticket.block_id}: surface not found; no site ran",
        }[kind]
        return self._event(kind, text, True, by)

    def skip(self, indent_index: int, by: str) -> tuple[bool, str]:
        """Take one site out of the array (its row is not expected; the site is 'not run')."""
        first, n = self.ticket.first_index, self.ticket.n_sites
        if not first <= indent_index < first + n:
            return self._event(
                "skip",
                f"skip refused: block {self.ticket.block_id} has sites {first + 1}-{first + n}",
                False,
                by,
            )
        if indent_index in self.skipped:
            return self._event("skip", f"site {indent_index + 1} is already skipped", False, by)
        self.skipped.add(indent_index)
        return self._event("skip", f"block {self.ticket.block_id}: site {indent_index + 1} skipped", True, by)

    def _event(self, kind: str, text: str, accepted: bool = True, by: str = "") -> tuple[bool, str]:
        self.events.append(ArrayEvent(kind, text, accepted, by))
        return accepted, text

    def _read_report_files(self) -> None:
        for kind in REPORT_KINDS:
            token = self.folder.report(self.ticket, kind)
            if token is None:
                continue
            if kind in self.reported:
                continue
            if same_token(token, self.ticket.token):
                self.report(kind, token, f"file {self.folder.report_path(self.ticket.block_id, kind).name}")
            elif (kind, token) not in self._ignored_files:
                self._ignored_files.add((kind, token))
                name = self.folder.report_path(self.ticket.block_id, kind).name
                self._event(
                    kind,
                    f"{name} ignored: {token[:20]!r} is not block {self.ticket.block_id}'s token",
                    False,
                    name,
                )

    # -- waiting ---------------------------------------------------------------------------------
    def extend(self, wall_s: float, why: str) -> None:
        """At least ``wall_s`` more to wait from now (the exchange folder was unusable: time nobody could
        write an export or a report does not count against the deadline)."""
        if self.seconds_left() >= wall_s:
            return
        until = (self.now() + timedelta(seconds=wall_s)).replace(microsecond=0)
        self.ticket = replace(self.ticket, deadline_utc=until.isoformat())
        self._event(
            "note", f"block {self.ticket.block_id}: {why}; the deadline moves to {until:%H:%M:%S} UTC"
        )

    def seconds_left(self) -> float:
        return (self.ticket.deadline() - self.now()).total_seconds()

    def poll(self) -> ArrayEnd | None:
        """Look once at the inbox and the reports; the end of the block, or None while it waits."""
        self._read_report_files()
        t = self.ticket
        if self.surface_not_found:
            return self._close("surface not found")
        final = self.seconds_left() <= 0
        result = self.watcher.poll(t, partial_ok=self.aborted, final=final, skipped=frozenset(self.skipped))
        for r in result.refused:
            self._refused(r)
            if r.made:
                self.made = r.made
        self.waiting = result.waiting
        if result.accepted is not None:
            a = result.accepted
            how = f"export {a.original} accepted (SHA-256 {a.sha256[:12]}…)"
            if not self.started:
                self._event("note", f"block {t.block_id}: export arrived without a start confirmation")
            return ArrayEnd(a.outcomes, how, a.sha256, a.archived, a.notes)
        if final:
            return self._close(f"no export by the deadline ({t.deadline():%H:%M:%S} UTC)")
        if self.aborted and self.made:  # the operator ended it, and the refused rows say what ran
            return self._close("array aborted; the refused export's rows are what ran")
        if self.aborted and result.waiting == "no export yet" and self._grace_over():
            return self._close("array aborted; no export came")
        return None

    def _grace_over(self) -> bool:
        """An aborted array's export may follow the report by a few polls; no longer than that."""
        if self._aborted_at is None:
            return False
        s = self.folder.settings
        return (self.now() - self._aborted_at).total_seconds() >= (s.stable_polls + 2) * s.poll_s

    def _refused(self, r: Refusal) -> None:
        self._event("refused", f"export {r.file} refused: {r.reason}", False, "inbox")

    def _close(self, why: str) -> ArrayEnd:
        """Every site not run, except those a refused export said were made, and, when the array was
        confirmed started but no export said what ran, every site not skipped: both ``unverified``.

        Without an export nothing tells which sites the tip went down on. Counting them taken (at the
        planned place, with no value) costs a few sites; counting them free could put a new indent on an
        old one, whose value the model would then learn as if it were clean.
        """
        t = self.ticket
        made = {o.indent_index: o for o in self.made}
        maybe = self.started and not self.surface_not_found and not made
        for k in range(t.n_sites):
            i = t.first_index + k
            if maybe and i not in self.skipped:
                made[i] = SiteOutcome(
                    i,
                    "unverified",
                    reason=f"{why}: the array was confirmed started, so the tip may have indented here "
                    "(taken, no value)",
                )
        outcomes = tuple(
            made.get(t.first_index + k)
            or SiteOutcome(
                t.first_index + k,
                "not_run",
                reason="skipped by the operator" if t.first_index + k in self.skipped else why,
            )
            for k in range(t.n_sites)
        )
        self.watcher.archive.close(t.run, t.block_id, why, tuple(made.values()))
        notes: tuple[str, ...]
        if maybe:
            notes = (f"{len(made)} site(s) held as taken: the array started and no export came",)
        elif made:
            notes = (f"{len(made)} indent(s) made but unverified (the export was refused)",)
        else:
            notes = ()
        return ArrayEnd(outcomes, why, notes=notes)

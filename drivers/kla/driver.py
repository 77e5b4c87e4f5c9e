"""The KLA iMicro driver: the Driver contract through the InView file exchange, with the operator in the loop.

For each block it publishes the array and the ticket, then waits (yielding ``InstrumentWait`` so the engine
can show WAITING FOR INSTRUMENT, take the operator's reports and keep its checkpoints) until the block's
array ends: an accepted export, a surface not found, or the deadline. It then reports, in indent order, the
cost model's steps and one ``IndentResult`` per site: measured, failed (no number) or not run.

A fast array (``Block.channel == "fast"``) goes out the same way as its own ticket: the profile's NanoBlitz
method (``fast.method``), its peak load and its grid (``drivers.kla.fast_ticket``); its NanoBlitz CSV is matched
to the sites by position and every result carries the channel "fast". A profile without a fast mode refuses
one: a fast array is never sent as a CSM ticket.

The clock is the cost model's, as for the simulated instrument, so budgets and the ledger mean the same with
either driver; the time actually spent waiting is in the journal's wall-clock times.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Generator, Iterator, Sequence
from dataclasses import replace
from datetime import datetime, timedelta
from pathlib import Path
from typing import TypeVar, cast

from core.cost import comeback_step, indent_steps
from core.driver import DriverAborted, DriverEvent, InstrumentState, InstrumentWait
from core.errors import InputError
from core.plan import Block, IndentResult, StepRecord
from core.profile import InstrumentProfile
from drivers.kla.array_run import ArrayEnd, ArrayRun, utc_now
from drivers.kla.exchange import (
    REPORT_KINDS,
    ExchangeFolder,
    ReportKind,
    Ticket,
    check_exchange_dir,
    make_ticket,
    margin_s,
    stretch_line,
    ticket_panel,
    ticket_text,
    write_atomic,
)
from drivers.kla.inbox import ExportArchive, InboxWatcher, SiteOutcome
from drivers.kla.tray import KlaTray

_T = TypeVar("_T")


def archive_dir_for(journal_path: str | Path) -> Path:
    """Accepted exports live next to the journal: ``runs/x.sqlite`` -> ``runs/x.sqlite.exports/``."""
    p = Path(journal_path)
    return p.with_name(p.name + ".exports")


def make_kla_driver(
    profile: InstrumentProfile,
    journal: str | Path,
    exchange: str | Path | None,
    *,
    start_um: tuple[float, float] = (0.0, 0.0),
    speed: float | None = None,
    tray: KlaTray | None = None,
) -> KlaDriver:
    """The driver for a run's journal. A new run names its exchange folder, which is kept beside the
    journal (``<journal>.exports/exchange.json``) so ``aeni resume`` finds it again. ``tray``: a tray run's
    samples (drivers.kla.tray)."""
    archive = archive_dir_for(journal)
    where = archive / "exchange.json"
    if exchange is None:
        try:
            exchange = str(json.loads(where.read_text(encoding="utf-8"))["exchange"])
        except (OSError, ValueError, KeyError) as exc:
            raise InputError(str(where), f"cannot tell this run's exchange folder ({exc})") from None
    folder = check_exchange_dir(exchange).resolve()
    run = Path(journal).name.removesuffix(".sqlite")
    driver = KlaDriver(profile, folder, run, archive, start_um=start_um, speed=speed, tray=tray)
    if not where.exists():
        write_atomic(where, json.dumps({"exchange": str(folder), "run": run}) + "\n")
    return driver


class KlaDriver(InstrumentState):
    """Runs blocks on an iMicro through an exchange folder (see docs/kla.md)."""

    def __init__(
        self,
        profile: InstrumentProfile,
        exchange: str | Path,
        run: str,
        archive: str | Path,
        *,
        start_um: tuple[float, float] = (0.0, 0.0),
        clock_s: float = 0.0,
        now: Callable[[], datetime] = utc_now,
        speed: float | None = None,
        tray: KlaTray | None = None,
    ) -> None:
        self.profile = profile
        # a tray: each block is on one of its samples, priced with that sample's profile; the first block on
        # a sample after a block on another one pays the sample change (drivers.kla.tray)
        self.tray = tray
        self._on: str | None = None  # the sample the tip last indented (a tray)
        self.folder = ExchangeFolder(exchange, run, profile.inview)
        self.archive = ExportArchive(archive)
        self.watcher = InboxWatcher(self.folder, self.archive)
        self.now = now
        self.speed = speed  # a fake InView's speed-up: deadlines shrink with it
        super().__init__(start_um, clock_s)
        self._array: ArrayRun | None = None
        self._stretch: tuple[Block, ...] = ()  # a stretch handed to the operator: its arrays in load order
        self._answer_delay_s: Callable[[], float] = lambda: 0.0  # until someone can answer a ticket

    # -- state -----------------------------------------------------------------------------------

    def set_state(
        self,
        clock_s: float,
        position_um: tuple[float, float],
        program_open: bool,
        physics_clock_s: float | None = None,
    ) -> None:
        super().set_state(clock_s, position_um, program_open, physics_clock_s)
        if self.tray is not None:  # a resumed tray: the tip is on the sample under its last indent
            self._on = self.tray.on_after_restore(clock_s, position_um)

    def _sample(self, block: Block) -> str:
        return "" if self.tray is None else self.tray.sample_of(block)

    def _profile_for(self, block: Block) -> InstrumentProfile:
        return self.profile if self.tray is None else self.tray.profiles[self.tray.sample_of(block)]

    def _change(self, block: Block, on: str | None) -> list[StepRecord]:
        return [] if self.tray is None else self.tray.change(block, on)

    def end_program(self) -> Iterator[StepRecord]:
        if self._open:
            yield self._advance(comeback_step(self.profile))
            self._open = False

    def _advance(self, step: StepRecord) -> StepRecord:
        self._clock_s += step.seconds
        return step

    # -- the operator ------------------------------------------------------------------------------
    def operator_report(self, kind: str, value: str, author: str) -> tuple[bool, str]:
        """A report from the console or ``aeni send``: started/aborted/surface-not-found with the token,
        or skip with a 1-based site number. (False, why) when nothing waits or it does not fit."""
        array = self._array
        if array is None:
            return False, "no block is waiting for the instrument"
        if kind == "skip":
            try:
                site = int(value)
            except ValueError:
                return False, f"skip needs a site number, got {value!r}"
            return array.skip(array.ticket.first_index + site - 1, author)
        if kind not in REPORT_KINDS:
            return False, f"unknown report {kind!r} (expected {', '.join(REPORT_KINDS)} or skip)"
        return array.report(cast(ReportKind, kind), value, author)

    def wait_from_answer(self, delay_s: Callable[[], float]) -> None:
        """A ticket's deadline counts from when the operator can answer it (core.driver.WaitsFromAnswer)."""
        self._answer_delay_s = delay_s

    # -- a stretch ---------------------------------------------------------------------------------
    def load_stretch(self, arrays: Sequence[Block]) -> None:
        """Nobody comes between a stretch's arrays: the first array's ticket goes out with all the others
        (each with its own sites file, method and token, its deadline after the arrays before it)."""
        self._stretch = tuple(arrays)

    def _stretch_tickets(self, start_index: int) -> list[Ticket]:
        """The tickets of the loaded stretch, in load order (the first from ``start_index``), priced one
        after another by the cost model from where the instrument is now."""
        pos, is_open, clock, before, on = self._pos, self._open, self._clock_s, 0.0, self._on
        delay_s = self._answer_delay_s()
        tickets = []
        for k, block in enumerate(self._stretch):
            first = start_index if k == 0 else 0
            expected = self._expected_s(block, first, pos, is_open, on)
            tickets.append(
                make_ticket(
                    self.folder.run,
                    block,
                    self.profile.inview,
                    expected_s=expected,
                    first_index=first,
                    now=self.now(),
                    clock_s=clock,
                    from_um=pos,
                    program_open=is_open,
                    speed=self.speed,
                    runs_after_s=before,
                    answer_delay_s=delay_s,
                    fast=self.profile.fast,
                    sample=self._sample(block),
                )
            )
            before, clock = before + expected, clock + expected
            pos, is_open = (block.indents[-1].x_um, block.indents[-1].y_um), True
            on = self._sample(block) or None
        lines = tuple(stretch_line(t, k) for k, t in enumerate(tickets, start=1))
        return [
            replace(t, stretch_index=k, stretch_arrays=lines, stretch_s=before)
            for k, t in enumerate(tickets, start=1)
        ]

    # -- a block -----------------------------------------------------------------------------------
    def _expected_s(
        self, block: Block, start_index: int, pos: tuple[float, float], is_open: bool, on: str | None = None
    ) -> float:
        """The instrument seconds the array runs, as the results will charge them (``on``: the tray sample
        the tip is on before it)."""
        profile = self._profile_for(block)
        expected = sum(s.seconds for s in self._change(block, on))
        for i in range(start_index, block.n_indents):
            expected += sum(s.seconds for s in indent_steps(profile, block, i, pos, is_open))
            pos, is_open = (block.indents[i].x_um, block.indents[i].y_um), True
        return expected

    def _ticket(self, block: Block, start_index: int) -> Ticket:
        """This block's ticket: the one already out (a resumed run, a stretch's later array keeps its
        token), or a new one (the first array of a stretch: with every other array of it)."""
        existing = self.folder.read_ticket(block.block_id)
        wanted = tuple((s.x_um, s.y_um) for s in block.indents[start_index:])
        if existing is not None and existing.first_index == start_index and existing.sites_um == wanted:
            if existing.deadline() <= self.now():  # the engine was down past it: a fresh wait, same token
                wait = timedelta(seconds=self._answer_delay_s() + margin_s(self.profile.inview, self.speed))
                existing = replace(
                    existing, deadline_utc=(self.now() + wait).replace(microsecond=0).isoformat()
                )
                self.folder.publish(existing)
            return existing
        if self._stretch and self._stretch[0].block_id == block.block_id:
            tickets = self._stretch_tickets(start_index)
            self.folder.publish(tickets[0])
            for t in tickets[1:]:  # in load order; one already out (a resumed run) stays as it is
                if self.folder.read_ticket(t.block_id) is None:
                    self.folder.publish(t)
            return tickets[0]
        ticket = make_ticket(
            self.folder.run,
            block,
            self.profile.inview,
            expected_s=self._expected_s(block, start_index, self._pos, self._open, self._on),
            first_index=start_index,
            now=self.now(),
            clock_s=self._clock_s,
            from_um=self._pos,
            program_open=self._open,
            speed=self.speed,
            answer_delay_s=self._answer_delay_s(),
            fast=self.profile.fast,
            sample=self._sample(block),
        )
        self.folder.publish(ticket)
        return ticket

    def _recorded_end(self, block: Block, start_index: int) -> ArrayEnd | None:
        """A block the archive already closed (the engine died after that, before journaling all of it):
        the outcomes of its sites from ``start_index`` on (those before are in the journal already)."""
        run, rest = self.folder.run, range(start_index, block.n_indents)
        accepted = self.archive.accepted_export(run, block.block_id)
        if accepted is not None:
            return ArrayEnd(
                tuple(o for o in accepted.outcomes if o.indent_index >= start_index),
                "export accepted before the restart",
                accepted.sha256,
                accepted.archived,
            )
        closed = self.archive.closed(run, block.block_id)
        if closed is not None:
            why = str(closed["reason"])
            made = {o["indent_index"]: SiteOutcome(**o) for o in closed.get("outcomes", [])}
            outcomes = tuple(made.get(i) or SiteOutcome(i, "not_run", reason=why) for i in rest)
            return ArrayEnd(outcomes, why)
        return None

    def execute_block(self, block: Block, start_index: int = 0) -> Generator[DriverEvent, None, None]:
        if self._abort.is_set():
            raise DriverAborted("driver was aborted")
        if block.channel == "fast" and self.profile.fast is None:
            # never as a CSM ticket: a fast array runs the profile's own NanoBlitz method
            raise ValueError(
                f"block {block.block_id} is a fast array but profile {self.profile.name} has no fast mode"
            )
        if start_index >= block.n_indents:
            return  # every indent is in the journal (a crash before the block was observed): nothing to run
        self.profile = self._profile_for(block)  # a tray: the profile of the sample the block is on
        end = self._recorded_end(block, start_index)  # closed before a restart: no new ticket goes out
        if end is None:
            ticket = yield from self._with_folder(block.block_id, lambda: self._ticket(block, start_index))
            array = ArrayRun(self.folder, self.watcher, ticket, now=self.now)
            self._array = array
            shown = 0
            try:
                margin = margin_s(self.profile.inview, self.speed)
                back = "the exchange folder was unusable"
                while True:
                    end = yield from self._with_folder(
                        block.block_id, array.poll, on_back=lambda: array.extend(margin, back)
                    )
                    notes = tuple(e.text for e in array.events[shown:])
                    shown = len(array.events)
                    if end is not None:  # the run log keeps what the export was and how it was matched
                        notes += tuple(f"block {block.block_id}: {n}" for n in end.notes)
                    yield InstrumentWait(
                        block_id=block.block_id,
                        ticket=ticket_text(ticket).replace(ticket.token, "·····"),
                        deadline_utc=array.ticket.deadline_utc,
                        seconds_left=max(array.seconds_left(), 0.0),
                        waiting=array.waiting if end is None else end.how,
                        started=array.started,
                        notes=notes,
                        panel=ticket_panel(ticket) + (end.notes if end is not None else ()),
                    )
                    if end is not None:
                        break
                    if self._abort.wait(self.profile.inview.poll_s):
                        raise DriverAborted(f"aborted while block {block.block_id} waited for the instrument")
            finally:
                self._array = None
        yield from self._results(block, end)

    def _with_folder(
        self, block_id: int, action: Callable[[], _T], on_back: Callable[[], None] | None = None
    ) -> Generator[DriverEvent, None, _T]:
        """``action`` on the exchange folder; while the folder is missing or unreadable the block waits
        (an InstrumentWait with the reason, journaled once) and tries again when it is back (``on_back``
        first: nobody could answer meanwhile)."""
        told = False
        while True:
            problem = self.folder.problem()
            if problem is None:
                if told and on_back is not None:
                    on_back()
                    told = False
                try:
                    return action()
                except (OSError, InputError):
                    problem = self.folder.problem()
                    if problem is None:
                        raise
            yield InstrumentWait(
                block_id=block_id,
                ticket="",
                deadline_utc="",
                seconds_left=0.0,
                waiting=f"{problem}; the run goes on when it is back",
                started=False,
                notes=() if told else (f"block {block_id}: {problem}; waiting for it to come back",),
            )
            told = True
            if self._abort.wait(self.profile.inview.poll_s):
                raise DriverAborted(f"aborted while block {block_id} waited for the exchange folder")

    def _results(self, block: Block, end: ArrayEnd) -> Iterator[DriverEvent]:
        """The cost model's steps for the sites that ran, and one result per site in indent order."""
        for outcome in sorted(end.outcomes, key=lambda o: o.indent_index):
            i = outcome.indent_index
            spec = block.indents[i]
            if outcome.status == "not_run":
                yield IndentResult.unmeasured(
                    block.block_id, i, spec, self._clock_s, "not_run", outcome.reason, block.channel
                )
                continue
            for step in self._change(block, self._on):  # the block's first indent made on another sample
                yield self._advance(step)
            for step in indent_steps(self.profile, block, i, self._pos, self._open):
                yield self._advance(step)  # made, so priced on the instrument clock (unverified too)
            self._pos, self._open = (spec.x_um, spec.y_um), True
            self._on = self._sample(block) or None
            if outcome.status == "unverified":  # where the export says the tip went; no value
                made = IndentResult.unmeasured(
                    block.block_id, i, spec, self._clock_s, "unverified", outcome.reason, block.channel
                )
                yield replace(
                    made,
                    actual_x_um=_nan(outcome.x_um),
                    actual_y_um=_nan(outcome.y_um),
                    depth_at_max_load_nm=outcome.max_depth_nm,
                )
                continue
            yield IndentResult(
                block_id=block.block_id,
                indent_index=i,
                commanded_x_um=spec.x_um,
                commanded_y_um=spec.y_um,
                actual_x_um=spec.x_um if outcome.x_um is None else outcome.x_um,
                actual_y_um=spec.y_um if outcome.y_um is None else outcome.y_um,
                hold_s=spec.hold_s,
                hardness_gpa=_nan(outcome.hardness_gpa),
                modulus_gpa=_nan(outcome.modulus_gpa),
                drift_rate_nm_s=_nan(outcome.drift_rate_nm_s),
                t_s=self._clock_s,
                status=outcome.status,
                note=outcome.reason,
                depth_at_max_load_nm=outcome.max_depth_nm,
                channel=block.channel,
            )


def _nan(value: float | None) -> float:
    return math.nan if value is None else float(value)

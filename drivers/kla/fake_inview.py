"""A fake InView: watches the outbox, runs each array on the emulator, and writes exports as InView does.

It exists so the KLA driver can be tested (and demonstrated) end to end without an instrument, and it
misbehaves the ways the real one does: exports appear slowly or by a rename, Excel-style ``~$`` lock
files sit beside them, there is a units row and three summary rows, NanoBlitz column names, and
1.797e308 where a value is invalid. Faults on demand (``--fault NAME[@BLOCK]``):

    aborted            the array stops half way; a partial export and an ``aborted`` report
    surface-not-found  no indent at all; a ``surface-not-found`` report, no export
    missing-export     the array runs but nothing is exported (the engine's deadline passes)
    duplicate-export   the same export is written again after the first was taken
    mm-um              positions written in mm under a µm units row
    flipped-y          the array's Y offsets are applied with the other sign (a wrong convention)

The measurements come from the simulated instrument (``drivers.sim``): the same emulator, cost model and
clock as the sim driver, synced to the engine's model of the instrument carried by each ticket, so a run
through the fake InView measures what a sim run on the same seed measures. A fast array's ticket (NanoBlitz)
is read from the emulator's fast channel at the ticket's peak load, takes the fast array's time, and is
exported as the NanoBlitz CSV (``drivers.kla.fake_nanoblitz``) whatever ``--format`` says: blank cells
where an indent failed.

Over a tray (``--tray``) it is the simulated tray (``drivers.sim.tray``): every sample's truth on one stage
with one tip, the sample changes and the tip's wear charged as the simulated tray charges them. Each ticket
runs on the sample it names; a ticket that names none, or whose array does not start on the sample it names
(or on any sample), is not started: the operator reports the surface not found.
"""

from __future__ import annotations

import errno
import io
import json
import math
import os
import random
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import openpyxl

from core.errors import InputError
from core.plan import Block, IndentResult, IndentSpec
from core.profile import InstrumentProfile
from drivers.kla.exchange import ExchangeFolder, Ticket, block_tag, from_array_offset, parse_name, parse_sites
from drivers.kla.fake_nanoblitz import nanoblitz_csv
from drivers.kla.fake_records import record_csv
from drivers.sim.driver import SimulatedDriver
from drivers.sim.fast_channel import FastPhysics
from drivers.sim.tray import TraySimDriver

FAULTS: tuple[str, ...] = (
    "aborted",
    "surface-not-found",
    "missing-export",
    "duplicate-export",
    "mm-um",
    "flipped-y",
)
INVALID = 1.797e308  # what InView/NanoSuite write for "no value"
HEADER = [
    "Test",
    "X Position",
    "Y Position",
    "MODULUS",
    "HARDNESS",
    "Drift Rate",
    "Displacement at Max Load",
    "Load at Max Load",
    "Hold Time",
]
BERKOVICH_C0 = 24.5


@dataclass(frozen=True)
class Fault:
    name: str
    block_id: int | None  # None: every block

    def hits(self, block_id: int) -> bool:
        return self.block_id is None or self.block_id == block_id


def parse_fault(text: str) -> Fault:
    """``NAME`` or ``NAME@BLOCK``."""
    name, _, block = text.partition("@")
    if name not in FAULTS:
        raise InputError("--fault", f"{name!r} is not a fault (known: {', '.join(FAULTS)})")
    if block:
        if not block.isdigit():
            raise InputError("--fault", f"block in {text!r} must be a whole number")
        return Fault(name, int(block))
    return Fault(name, None)


@dataclass
class FakeInView:
    """One fake instrument PC serving one exchange folder (every run that writes tickets there)."""

    exchange: Path
    profile: InstrumentProfile
    make_emulator: Callable[[], Any] | None  # None over a tray (``tray_driver``: its stations measure)
    speed: float | None = None
    faults: tuple[Fault, ...] = ()
    fmt: str = "xlsx"  # or "csv", or "records" (a folder of per-test record CSVs, one per test)
    invalid_rate: float = 0.03  # share of indents InView marks invalid (1.797e308)
    write_s: float = 0.6  # wall seconds a slow export write takes
    positions: bool = True  # False: a lab template without X/Y Test Position columns
    log: Callable[[str], None] = print
    # the instrument's own record of every indent it made (JSON lines), kept outside the exchange folder:
    # the soak checks the journal against it
    ledger: Path | None = None
    # a tray (``--tray``): the simulated tray's instrument over every sample (drivers.sim.tray.make_tray_driver)
    tray_driver: Callable[[], TraySimDriver] | None = None
    _done: set[tuple[str, int]] = field(default_factory=set)
    _sim: SimulatedDriver | None = None
    _tray_sim: TraySimDriver | None = None

    def __post_init__(self) -> None:
        if self.fmt not in ("xlsx", "csv", "records"):
            raise InputError("--format", f"{self.fmt!r} is not allowed: expected xlsx, csv or records")
        (self.exchange / "outbox").mkdir(parents=True, exist_ok=True)
        (self.exchange / "inbox").mkdir(exist_ok=True)

    def _fault(self, name: str, block_id: int) -> bool:
        return any(f.name == name and f.hits(block_id) for f in self.faults)

    def pending(self) -> list[Path]:
        """Tickets not yet served, oldest block first."""
        out = []
        for path in sorted((self.exchange / "outbox").glob("*-ticket.json")):
            parsed = parse_name(path.name.removesuffix(".json"))
            if parsed is None or (parsed.run, parsed.block_id) in self._done:
                continue
            if any((self.exchange / "inbox").glob(f"{parsed.run}-{block_tag(parsed.block_id)}-started.txt")):
                self._done.add((parsed.run, parsed.block_id))  # served before this process started
                continue
            out.append(path)
        return out

    def serve_forever(self, poll_s: float = 0.2, stop: Callable[[], bool] = lambda: False) -> None:
        gone = False
        while not stop():
            if not (self.exchange / "outbox").is_dir():  # the stick was carried away: wait for it
                if not gone:
                    self.log(f"exchange folder {self.exchange} is gone: waiting for it")
                gone = True
                time.sleep(poll_s)
                continue
            if gone:
                self.log(f"exchange folder {self.exchange} is back")
                gone = False
            try:
                for path in self.pending():
                    self.serve(path)
            except FileNotFoundError as exc:  # taken away mid-ticket: what was not written is retried
                self.log(f"exchange folder went away while serving: {exc}")
            time.sleep(poll_s)

    def _deliver(self, write: Callable[[], None], poll_s: float = 0.2) -> None:
        """Write into the exchange folder; while it is gone, wait and write again once it is back.

        InView cannot write to a share that is not there, or that turned read-only: the operator exports
        again when it is back (writable).
        """
        told = False
        while True:
            while not (self.exchange / "inbox").is_dir():
                time.sleep(poll_s)
            try:
                write()
                return
            except FileNotFoundError:
                self.log("exchange folder went away while writing: writing again when it is back")
            except OSError as exc:
                if exc.errno not in (errno.EROFS, errno.EACCES, errno.EPERM):
                    raise
                if not told:
                    self.log(f"exchange folder is not writable ({exc.strerror}): writing again when it is")
                told = True
                time.sleep(poll_s)

    def _record(self, ticket: Ticket, results: list[IndentResult], exported: bool) -> None:
        if self.ledger is None:
            return
        lines = []
        for r in results:
            invalid = self._invalid(ticket, r.indent_index) or not r.measured
            lines.append(
                json.dumps(
                    {
                        "run": ticket.run,
                        "block_id": ticket.block_id,
                        "indent_index": r.indent_index,
                        "token": ticket.token,
                        "x_um": r.commanded_x_um,  # where this instrument sent the tip
                        "y_um": r.commanded_y_um,
                        "hardness_gpa": None if invalid else r.hardness_gpa,
                        **(
                            {}
                            if self._tray_sim is None
                            else {"sample": self._sample_at(r.commanded_x_um, r.commanded_y_um)}
                        ),
                        "invalid": invalid,
                        "exported": exported,
                    }
                )
            )
        with self.ledger.open("a", encoding="utf-8") as fh:
            fh.write("".join(line + "\n" for line in lines))
            fh.flush()
            os.fsync(fh.fileno())

    def _invalid(self, ticket: Ticket, indent_index: int) -> bool:
        """InView marks this indent invalid (1.797e308): the same draw for the export and the ledger."""
        return random.Random(f"{ticket.run}/{ticket.block_id}/{indent_index}").random() < self.invalid_rate

    # -- one ticket ------------------------------------------------------------------------------
    def serve(self, ticket_path: Path) -> None:
        data = json.loads(ticket_path.read_text(encoding="utf-8"))
        ticket = Ticket.from_dict(data, str(ticket_path))
        folder = ExchangeFolder(self.exchange, ticket.run, self.profile.inview)
        tag = f"{ticket.run} block {ticket.block_id}"
        block = self._block(ticket, folder)  # a folder gone before this: the ticket is served when it is back
        self._done.add((ticket.run, ticket.block_id))
        wrong = self._off_sample(ticket, block)
        if wrong is not None:  # the operator does not start an array on another sample than its ticket's
            report = folder.report_path(ticket.block_id, "surface-not-found")
            self._deliver(lambda: _write_atomic(report, ticket.token + "\n"))
            self.log(f"{tag}: not started: {wrong}; reported surface not found")
            return
        started = folder.report_path(ticket.block_id, "started")
        self._deliver(lambda: _write_atomic(started, ticket.token + "\n"))
        self.log(f"{tag}: started ({ticket.n_sites} sites, token {ticket.token})")
        if self._fault("surface-not-found", ticket.block_id):
            report = folder.report_path(ticket.block_id, "surface-not-found")
            self._deliver(lambda: _write_atomic(report, ticket.token + "\n"))
            self.log(f"{tag}: surface not found (fault)")
            return
        stop_after = ticket.n_sites // 2 if self._fault("aborted", ticket.block_id) else ticket.n_sites
        results = self._run(block, ticket, stop_after)
        if stop_after < ticket.n_sites:
            report = folder.report_path(ticket.block_id, "aborted")
            self._deliver(lambda: _write_atomic(report, ticket.token + "\n"))
            self.log(f"{tag}: aborted after {stop_after} of {ticket.n_sites} indents (fault)")
        if self._fault("missing-export", ticket.block_id):
            self._record(ticket, results, exported=False)
            self.log(f"{tag}: no export (fault)")
            return
        if self.fmt == "records" and ticket.fast is None:
            target = folder.inbox / ticket.export_stem
            self._record(ticket, results, exported=True)
            self._deliver(lambda: self._write_records(target, results, ticket))
            self.log(f"{tag}: exported {target.name}/ ({len(results)} per-test records)")
            return
        if ticket.fast is not None:  # NanoBlitz exports its map as one CSV, whatever the format asked
            scale = 1e-3 if self._fault("mm-um", ticket.block_id) else 1.0
            payload = nanoblitz_csv(
                results, ticket.fast.peak_load_mn, lambda r: self._invalid(ticket, r.indent_index), scale
            )
            target = folder.inbox / f"{ticket.export_stem}.csv"
        else:
            payload = self._export_bytes(results, ticket)
            target = folder.inbox / f"{ticket.export_stem}.{self.fmt}"
        self._record(ticket, results, exported=True)
        if ticket.block_id % 2:
            self._deliver(lambda: self._write_slowly(target, payload))
        else:
            self._deliver(lambda: _write_bytes_atomic(target, payload))
        self.log(f"{tag}: exported {target.name} ({len(results)} rows)")
        if self._fault("duplicate-export", ticket.block_id):
            self._write_again(target, payload, tag)

    def _write_again(self, target: Path, payload: bytes, tag: str) -> None:
        deadline = time.monotonic() + 30
        while target.exists() and time.monotonic() < deadline:
            time.sleep(0.1)  # the engine takes the first copy
        _write_bytes_atomic(target, payload)
        self.log(f"{tag}: exported {target.name} again (fault)")

    def _block(self, ticket: Ticket, folder: ExchangeFolder) -> Block:
        """What the instrument will actually do: the sites file read with this PC's array convention."""
        sites_path = folder.outbox / ticket.sites_file
        offsets = parse_sites(sites_path.read_text(encoding="utf-8"), str(sites_path))
        settings = self.profile.inview
        specs = []
        for k, (ax, ay) in enumerate(offsets):
            dx, dy = from_array_offset(settings, ax, ay)
            if self._fault("flipped-y", ticket.block_id):
                dy = -dy
            hold = ticket.holds_s[k] if k < len(ticket.holds_s) else ticket.holds_s[-1]
            specs.append(IndentSpec(ticket.origin_x_um + dx, ticket.origin_y_um + dy, hold))
        # a resumed block keeps its indent numbering: the indents before first_index are never run again
        indents = tuple([specs[0]] * ticket.first_index + specs)
        return Block(
            ticket.block_id,
            "global" if ticket.kind == "global" else "local",
            ticket.origin_x_um,
            ticket.origin_y_um,
            ticket.grid_g,
            ticket.pitch_um,
            ticket.holds_s[0],
            indents,
            channel="fast" if ticket.fast is not None else "csm",
        )

    def _tray(self) -> TraySimDriver | None:
        if self.tray_driver is not None and self._tray_sim is None:
            self._tray_sim = self._sim = self.tray_driver()
        return self._tray_sim

    def _sample_at(self, x_um: float, y_um: float) -> str | None:
        tray = self._tray()
        here = None if tray is None else tray.tray.sample_at(x_um, y_um)
        return None if here is None else here.name

    def _off_sample(self, ticket: Ticket, block: Block) -> str | None:
        """Why a tray's ticket cannot run on the sample it names (None: it can; always None without a tray)."""
        if self._tray() is None:
            return None
        if not ticket.sample:
            return "the ticket names no sample of the tray"
        first = block.indents[ticket.first_index]
        here = self._sample_at(first.x_um, first.y_um)
        if here is None:
            return f"no sample of the tray under its first site ({first.x_um:.1f}, {first.y_um:.1f}) µm"
        if here != ticket.sample:
            return f"the ticket names sample {ticket.sample!r} but its array starts on {here!r}"
        return None

    def _run(self, block: Block, ticket: Ticket, stop_after: int) -> list[IndentResult]:
        if self._sim is None:
            tray = self._tray()
            if tray is None:
                assert self.make_emulator is not None, "a fake InView needs an emulator or a tray"
                self._sim = SimulatedDriver(self.make_emulator(), self.profile, speed=self.speed)
            else:
                self._sim = tray
        sim = self._sim
        if ticket.fast is not None:  # the load the operator set in the NanoBlitz method
            if self.profile.fast is None:
                raise InputError(f"profile {self.profile.name}", "has no fast mode: cannot run a fast array")
            sim.fast_physics = FastPhysics(ticket.fast.peak_load_mn)
        sim.set_state(ticket.clock_s, ticket.from_um, ticket.program_open)
        results: list[IndentResult] = []
        if ticket.first_index > 0 or (block.kind == "local" and not sim.program_open()):
            for _ in sim.recover(block.block_id):
                pass
        for ev in sim.execute_block(block, ticket.first_index):
            if isinstance(ev, IndentResult):
                results.append(ev)
                if len(results) >= stop_after:
                    break
        return results

    # -- the export ------------------------------------------------------------------------------
    def _rows(self, results: Iterable[IndentResult], ticket: Ticket) -> list[list[Any]]:
        mm = self._fault("mm-um", ticket.block_id)
        rows: list[list[Any]] = [HEADER, ["", "µm", "µm", "GPa", "GPa", "nm/s", "nm", "mN", "s"]]
        valid: list[list[float]] = []
        for n, r in enumerate(results, start=1):
            scale = 1e-3 if mm else 1.0
            depth_nm = 100.0 if r.depth_at_max_load_nm is None else r.depth_at_max_load_nm
            load_mn = r.hardness_gpa * BERKOVICH_C0 * depth_nm**2 * 1e-6
            values = [r.modulus_gpa, r.hardness_gpa, r.drift_rate_nm_s, depth_nm, load_mn]
            if self._invalid(
                ticket, r.indent_index
            ):  # the surface find or the unload failed for this indent: InView writes DBL_MAX
                values = [INVALID, INVALID, r.drift_rate_nm_s, INVALID, INVALID]
            else:
                valid.append(values)
            rows.append([n, r.commanded_x_um * scale, r.commanded_y_um * scale, *values, r.hold_s])
        rows.append([])
        for label, fn in (("Mean", _mean), ("Std. Dev.", _sd), ("% COV", _cov)):
            stats = [fn([v[k] for v in valid]) if valid else None for k in range(5)]
            rows.append([label, None, None, *stats, None])
        if not self.positions:  # the template has no X/Y Test Position columns
            rows = [[c for k, c in enumerate(row) if k not in (1, 2)] for row in rows]
        return rows

    def _write_records(self, target: Path, results: list[IndentResult], ticket: Ticket) -> None:
        """InView's one CSV per test, 'Test N.csv', in the block's export folder. Written in a hidden
        folder first and renamed whole: the inbox never sees a folder with some of its tests."""
        staging = target.with_name(f".{target.name}.{os.getpid()}.tmp")
        staging.mkdir(parents=True, exist_ok=True)
        scale = 1e-3 if self._fault("mm-um", ticket.block_id) else 1.0
        for n, r in enumerate(results, start=1):
            depth_nm = 100.0 if r.depth_at_max_load_nm is None else r.depth_at_max_load_nm
            failed = self._invalid(ticket, r.indent_index)
            payload = record_csv(
                r.commanded_x_um * scale,
                r.commanded_y_um * scale,
                None if failed else r.hardness_gpa,
                None if failed else r.modulus_gpa,
                r.drift_rate_nm_s,
                depth_nm,
                r.hardness_gpa * BERKOVICH_C0 * depth_nm**2 * 1e-6,
                INVALID,
            )
            (staging / f"Test {n}.csv").write_bytes(payload)
        os.replace(staging, target)

    def _export_bytes(self, results: list[IndentResult], ticket: Ticket) -> bytes:
        rows = self._rows(results, ticket)
        if self.fmt == "csv":
            lines = [
                ",".join("" if v is None else (repr(v) if isinstance(v, float) else str(v)) for v in r)
                for r in rows
            ]
            return ("\r\n".join(lines) + "\r\n").encode("utf-8-sig")
        book = openpyxl.Workbook()
        sheet = book.active
        assert sheet is not None
        sheet.title = "Results"
        for r in rows:
            sheet.append(r)
        info = book.create_sheet("Sample Information")
        info.append(["Sample", ticket.run])
        info.append(["Block", ticket.block_id])
        info.append(["Method", ticket.methods[0].method])
        buf = io.BytesIO()
        book.save(buf)
        return buf.getvalue()

    def _write_slowly(self, target: Path, payload: bytes) -> None:
        """InView writing a big workbook over a share: a lock file, then the file growing in chunks."""
        lock = target.with_name("~$" + target.name)
        lock.write_bytes(b"fake-inview")
        try:
            chunks = 6
            step = math.ceil(len(payload) / chunks)
            with target.open("wb") as fh:
                for k in range(chunks):
                    fh.write(payload[k * step : (k + 1) * step])
                    fh.flush()
                    time.sleep(self.write_s / chunks)
        finally:
            lock.unlink(missing_ok=True)


def _mean(v: list[float]) -> float:
    return sum(v) / len(v)


def _sd(v: list[float]) -> float:
    m = _mean(v)
    return math.sqrt(sum((x - m) ** 2 for x in v) / max(len(v) - 1, 1))


def _cov(v: list[float]) -> float:
    m = _mean(v)
    return 100.0 * _sd(v) / m if m else 0.0


def _write_bytes_atomic(path: Path, payload: bytes) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_bytes(payload)
    os.replace(tmp, path)


def _write_atomic(path: Path, text: str) -> None:
    _write_bytes_atomic(path, text.encode("utf-8"))

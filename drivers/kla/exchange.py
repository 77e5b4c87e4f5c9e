"""The file contract between the engine and InView: the array file, the ticket, and the operator's reports.

InView has no API, but every lab can import an array of sites, run a saved test method and export the
results. So each block becomes files in an exchange folder (typically a share with the instrument PC):

    outbox/<run>-<block>-sites.txt     one ``x, y`` line per site, µm offsets from the block origin
    outbox/<run>-<block>-ticket.json   what to load, where to move, which method, the deadline, a token
    outbox/<run>-<block>-ticket.txt    the same for a person
    inbox/<run>-<block>-started.txt    the token: the array started (the operator, a helper or fake InView)
    inbox/<run>-<block>-aborted.txt    the token: the array was aborted (rows present are kept)
    inbox/<run>-<block>-surface-not-found.txt   the token: InView did not find the surface
    inbox/<run>-<block>-export.(csv|xlsx|xls)   InView's export of the array

``<block>`` is the block id with three digits. Everything here is plain data and file names; the
inbox's acceptance rules live in ``drivers.kla.inbox``.
"""

from __future__ import annotations

import json
import math
import os
import re
import secrets
import tempfile
from dataclasses import asdict, dataclass
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any, Literal

from core.describe import sites_words
from core.errors import InputError
from core.plan import Block, IndentSpec
from core.profile import FastMode, InViewSettings
from drivers.kla.fast_ticket import FastArrayTicket, fast_array_ticket, fast_panel, fast_steps

TOKEN_ALPHABET = "ACDEFHJKMNPRTUVWXY34679"  # no look-alikes (0/O, 1/I/L, 2/Z, 5/S, 8/B)
TOKEN_LENGTH = 5
EXPORT_SUFFIXES = (".csv", ".txt", ".tsv", ".xlsx", ".xls")
ReportKind = Literal["started", "aborted", "surface-not-found"]
REPORT_KINDS: tuple[ReportKind, ...] = ("started", "aborted", "surface-not-found")
_NAME = re.compile(
    r"^(?P<run>.+)-(?P<block>\d{3,})-(?P<kind>sites|ticket|started|aborted|surface-not-found|export)"
    r"(?P<suffix>\.[A-Za-z]+)?$"
)
_RUN_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._+-]*$")


def new_token() -> str:
    return "".join(secrets.choice(TOKEN_ALPHABET) for _ in range(TOKEN_LENGTH))


def same_token(given: str, token: str) -> bool:
    """Tokens compare without case and surrounding blanks (typed over SSH, written by a helper)."""
    return secrets.compare_digest(given.strip().upper().encode(), token.strip().upper().encode())


def block_tag(block_id: int) -> str:
    return f"{block_id:03d}"


@dataclass(frozen=True)
class ParsedName:
    run: str
    block_id: int
    kind: str
    suffix: str


def parse_name(name: str) -> ParsedName | None:
    """``run-007-export.xlsx`` -> (run, 7, 'export', '.xlsx'); None for any other file."""
    m = _NAME.match(name)
    if m is None:
        return None
    return ParsedName(m["run"], int(m["block"]), m["kind"], (m["suffix"] or "").lower())


# ----------------------------------------------------------------------------------- array convention


def to_array_offset(settings: InViewSettings, dx_um: float, dy_um: float) -> tuple[float, float]:
    """Stage offset from the origin -> the array dialog's (x, y): signs, then an optional swap."""
    ax, ay = settings.array_x_sign * dx_um, settings.array_y_sign * dy_um
    return (ay, ax) if settings.array_swap_xy else (ax, ay)


def from_array_offset(settings: InViewSettings, ax: float, ay: float) -> tuple[float, float]:
    """The inverse of :func:`to_array_offset` (what the fake InView does with a sites file)."""
    if settings.array_swap_xy:
        ax, ay = ay, ax
    return settings.array_x_sign * ax, settings.array_y_sign * ay


def format_sites(offsets: list[tuple[float, float]]) -> str:
    """InView's array-import text: ``x, y`` per line, comma and space, no header, µm."""
    return "".join(f"{_fmt(x)}, {_fmt(y)}\n" for x, y in offsets)


def _fmt(v: float) -> str:
    text = f"{v:.3f}".rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


def parse_sites(text: str, source: str) -> list[tuple[float, float]]:
    out = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        parts = [p.strip() for p in line.split(",")]
        try:
            x, y = (float(p) for p in parts)
        except ValueError:
            raise InputError(source, f"line {lineno}: expected 'x, y' in µm, got {line!r}") from None
        if not (math.isfinite(x) and math.isfinite(y)):
            raise InputError(source, f"line {lineno}: offsets must be finite")
        out.append((x, y))
    if not out:
        raise InputError(source, "no sites")
    return out


# ------------------------------------------------------------------------------------------- ticket


@dataclass(frozen=True)
class MethodStep:
    hold_s: float
    method: str
    first_site: int  # 1-based lines of the sites file
    last_site: int


@dataclass(frozen=True)
class Ticket:
    """Everything the operator (or a helper) needs for one block, and what the inbox checks against."""

    run: str
    block_id: int
    kind: str  # "global": move and engage; "local": the tip stays on the surface
    grid_g: int
    pitch_um: float
    origin_x_um: float
    origin_y_um: float
    first_index: int  # the block's first indent in this array (> 0 when a block resumes)
    sites_um: tuple[tuple[float, float], ...]  # planned absolute stage positions, in array order
    holds_s: tuple[float, ...]
    methods: tuple[MethodStep, ...]
    array_x_sign: int
    array_y_sign: int
    array_swap_xy: bool
    sites_file: str
    export_stem: str
    expected_s: float
    deadline_s: float
    created_utc: str
    deadline_utc: str
    token: str
    # the engine's model of the instrument before this block (cost-model clock s, stage µm, tip engaged):
    # for the record, and what the fake InView syncs its emulator to
    clock_s: float = 0.0
    from_um: tuple[float, float] = (0.0, 0.0)
    program_open: bool = False
    # a stretch (arrays loaded in one visit before an absence): this array's place in it (1-based; 0: not
    # a stretch), one line per array in load order, and the instrument seconds the whole stretch runs
    stretch_index: int = 0
    stretch_arrays: tuple[str, ...] = ()
    stretch_s: float = 0.0
    # a fast (NanoBlitz-class) array: its method, peak load and grid (None: a CSM array)
    fast: FastArrayTicket | None = None
    # the tray sample the block is on (a tray run; "" for the run's one sample, and in older tickets)
    sample: str = ""

    @property
    def n_sites(self) -> int:
        return len(self.sites_um)

    @property
    def origin_mm(self) -> tuple[float, float]:
        return self.origin_x_um / 1000.0, self.origin_y_um / 1000.0

    def created(self) -> datetime:
        return datetime.fromisoformat(self.created_utc)

    def deadline(self) -> datetime:
        return datetime.fromisoformat(self.deadline_utc)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["origin_mm"] = list(self.origin_mm)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any], source: str) -> Ticket:
        try:
            return cls(
                run=str(d["run"]),
                block_id=int(d["block_id"]),
                kind=str(d["kind"]),
                grid_g=int(d["grid_g"]),
                pitch_um=float(d["pitch_um"]),
                origin_x_um=float(d["origin_x_um"]),
                origin_y_um=float(d["origin_y_um"]),
                first_index=int(d["first_index"]),
                sites_um=tuple((float(x), float(y)) for x, y in d["sites_um"]),
                holds_s=tuple(float(h) for h in d["holds_s"]),
                methods=tuple(MethodStep(**m) for m in d["methods"]),
                array_x_sign=int(d["array_x_sign"]),
                array_y_sign=int(d["array_y_sign"]),
                array_swap_xy=bool(d["array_swap_xy"]),
                sites_file=str(d["sites_file"]),
                export_stem=str(d["export_stem"]),
                expected_s=float(d["expected_s"]),
                deadline_s=float(d["deadline_s"]),
                created_utc=str(d["created_utc"]),
                deadline_utc=str(d["deadline_utc"]),
                token=str(d["token"]),
                clock_s=float(d.get("clock_s", 0.0)),
                from_um=(float(d.get("from_um", (0, 0))[0]), float(d.get("from_um", (0, 0))[1])),
                program_open=bool(d.get("program_open", False)),
                stretch_index=int(d.get("stretch_index", 0)),
                stretch_arrays=tuple(str(line) for line in d.get("stretch_arrays", ())),
                stretch_s=float(d.get("stretch_s", 0.0)),
                fast=None if d.get("fast") is None else FastArrayTicket.from_dict(d["fast"]),
                sample=str(d.get("sample", "")),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(source, f"not a valid ticket ({type(exc).__name__}: {exc})") from None


# Wall seconds the file exchange itself may take whatever the speed-up: a fake InView's poll (0.2 s), its
# emulator run and slow write (0.6 s) on a loaded PC, a share's latency. An assumption with room (no
# instrument measured it), added to the inbox's own stability polls.
EXCHANGE_LATENCY_S = 30.0


def margin_s(settings: InViewSettings, speed: float | None = None) -> float:
    """The deadline's margin: ``deadline_margin_s`` of the real instrument, ``speed`` times shorter for a
    fake InView at ``--speed`` (docs/kla.md: the deadlines shrink with it), but never shorter than the
    exchange needs to see an export land (its stability polls and EXCHANGE_LATENCY_S), nor than the margin
    the profile asks for when that is shorter still."""
    margin = settings.deadline_margin_s
    if not speed or speed <= 1.0:
        return margin
    floor = (settings.stable_polls + 2) * settings.poll_s + EXCHANGE_LATENCY_S
    return max(margin / speed, min(margin, floor))


def deadline_s(settings: InViewSettings, expected_s: float, speed: float | None = None) -> float:
    """How long the engine waits for the export: estimate × factor + margin (1.5 × + 180 s by default);
    at a fake InView's ``speed`` the instrument's estimate and the margin both shrink (see margin_s)."""
    return expected_s / (speed or 1.0) * settings.deadline_factor + margin_s(settings, speed)


def make_ticket(
    run: str,
    block: Block,
    settings: InViewSettings,
    *,
    expected_s: float,
    first_index: int = 0,
    now: datetime | None = None,
    token: str | None = None,
    clock_s: float = 0.0,
    from_um: tuple[float, float] = (0.0, 0.0),
    program_open: bool = False,
    speed: float | None = None,
    runs_after_s: float = 0.0,
    answer_delay_s: float = 0.0,
    fast: FastMode | None = None,
    sample: str = "",
) -> Ticket:
    """The ticket for ``block`` from indent ``first_index`` on; the origin is the block's centre.

    ``speed``: the instrument runs that many times faster than the cost model (a fake InView at ``--speed``),
    so the deadline is (the estimate × factor + margin) ÷ speed of wall time (the margin with a floor). ``runs_after_s``: instrument
    seconds of the arrays loaded before it that run first (a stretch), counted into the deadline.
    ``answer_delay_s``: wall seconds until the operator can answer at all (nobody there): the wait counts
    from then, so a block written at night does not run out unrun before anyone could load it.
    ``fast``: the profile's fast mode, for a fast array (``block.channel == "fast"``): one NanoBlitz method.
    ``sample``: the tray sample the block is on ("" for a single-sample run).
    """
    if not _RUN_NAME.match(run):
        raise InputError("run", f"{run!r} cannot name exchange files (letters, digits, . _ + - only)")
    if not 0 <= first_index < block.n_indents:
        raise ValueError(f"first_index {first_index} outside block {block.block_id}")
    specs = block.indents[first_index:]
    holds = tuple(s.hold_s for s in specs)
    methods: list[MethodStep] = []
    fast_part = None
    if block.channel == "fast":
        if fast is None:
            raise ValueError(
                f"block {block.block_id} is a fast array: its ticket needs the profile's fast mode"
            )
        fast_part = fast_array_ticket(tuple((s.x_um, s.y_um) for s in specs), block.pitch_um, fast)
        methods.append(MethodStep(0.0, fast.method, 1, len(specs)))
    for i, hold in enumerate(() if fast_part else holds, start=1):  # a fast array has its one method
        if methods and math.isclose(methods[-1].hold_s, hold):
            last = methods[-1]
            methods[-1] = MethodStep(last.hold_s, last.method, last.first_site, i)
        else:
            methods.append(MethodStep(hold, settings.method_for(hold), i, i))
    created = (now or datetime.now(UTC)).replace(microsecond=0)
    wait_s = deadline_s(settings, runs_after_s + expected_s, speed)
    tag = block_tag(block.block_id)
    return Ticket(
        run=run,
        block_id=block.block_id,
        kind=block.kind,
        grid_g=block.grid_g,
        pitch_um=block.pitch_um,
        origin_x_um=block.center_x_um,
        origin_y_um=block.center_y_um,
        first_index=first_index,
        sites_um=tuple((s.x_um, s.y_um) for s in specs),
        holds_s=holds,
        methods=tuple(methods),
        array_x_sign=settings.array_x_sign,
        array_y_sign=settings.array_y_sign,
        array_swap_xy=settings.array_swap_xy,
        sites_file=f"{run}-{tag}-sites.txt",
        export_stem=f"{run}-{tag}-export",
        expected_s=float(expected_s),
        deadline_s=wait_s,
        created_utc=created.isoformat(),
        deadline_utc=(created + timedelta(seconds=math.ceil(answer_delay_s + wait_s))).isoformat(),
        token=token or new_token(),
        clock_s=float(clock_s),
        from_um=(float(from_um[0]), float(from_um[1])),
        program_open=program_open,
        fast=fast_part,
        sample=sample,
    )


# an L of three sites, 100 µm along x and 50 µm along y: no flip or swap of the axes maps it onto itself
TEST_BLOCK_OFFSETS_UM: tuple[tuple[float, float], ...] = ((0.0, 0.0), (100.0, 0.0), (0.0, 50.0))


def check_block(origin_x_um: float, origin_y_um: float, hold_s: float, block_id: int = 0) -> Block:
    """The 3-site block of the first-run check (docs/kla.md): shows the signs, swap and origin at once."""
    indents = tuple(
        IndentSpec(origin_x_um + dx, origin_y_um + dy, hold_s) for dx, dy in TEST_BLOCK_OFFSETS_UM
    )
    return Block(block_id, "global", origin_x_um, origin_y_um, 1, 50.0, hold_s, indents)


def array_offsets(ticket: Ticket, settings: InViewSettings) -> list[tuple[float, float]]:
    return [
        to_array_offset(settings, x - ticket.origin_x_um, y - ticket.origin_y_um) for x, y in ticket.sites_um
    ]


def _ranges(m: MethodStep) -> str:
    return f"site {m.first_site}" if m.first_site == m.last_site else f"sites {m.first_site}-{m.last_site}"


def stretch_line(ticket: Ticket, k: int) -> str:
    """One array of a stretch in its load order, for every ticket of the stretch."""
    xmm, ymm = ticket.origin_mm
    methods = ", ".join(f'"{m.method}" (hold {m.hold_s:g} s, {_ranges(m)})' for m in ticket.methods)
    on = f" on {ticket.sample}" if ticket.sample else ""  # a tray's stretch may go from sample to sample
    return (
        f"{k}. block {ticket.block_id}{on}: outbox/{ticket.sites_file}, {ticket.n_sites} sites at X {xmm:.4f} mm, "
        f"Y {ymm:.4f} mm; {methods}; ~{ticket.expected_s / 60:.0f} min; export inbox/{ticket.export_stem}.xlsx"
    )


def _stretch_words(t: Ticket) -> str:
    if not t.stretch_index:
        return ""
    n = len(t.stretch_arrays)
    loaded = (
        "load all of them now, in this order"
        if t.stretch_index == 1
        else ("loaded with array 1 in one visit: nothing to do for it unless it was not loaded")
    )
    return (
        f"STRETCH: array {t.stretch_index} of {n}, run unattended one after another; the stretch runs "
        f"~{t.stretch_s / 3600:.1f} h of instrument time ({loaded}):\n"
        + "".join(f"   {line}\n" for line in t.stretch_arrays)
        + "\n"
    )


def _sample_words(t: Ticket) -> str:
    if not t.sample:
        return "Sample: the run's sample, as calibrated (same mounting, same crosshair reference)."
    return f"Sample: {t.sample} on the tray, as calibrated (its own corners, same crosshair reference)."


def ticket_text(ticket: Ticket) -> str:
    """The ticket for a person at the instrument PC (also shown in the console's ticket panel)."""
    t = ticket
    xmm, ymm = t.origin_mm
    sign = f"x sign {t.array_x_sign:+d}, y sign {t.array_y_sign:+d}" + (
        ", x/y swapped" if t.array_swap_xy else ""
    )
    deadline = t.deadline().strftime("%H:%M:%S UTC")
    resumed = f" (resumes at indent {t.first_index + 1})" if t.first_index else ""
    if t.kind == "global":
        move = (
            f"2. Lift, then move the stage (XY Control) to the block origin:\n"
            f"   X {xmm:.4f} mm, Y {ymm:.4f} mm   ({t.origin_x_um:.1f}, {t.origin_y_um:.1f} µm)\n"
            f"   and find the surface there."
        )
    else:
        move = (
            f"2. The tip stays on the surface: move (XY Control) to the block origin\n"
            f"   X {xmm:.4f} mm, Y {ymm:.4f} mm   ({t.origin_x_um:.1f}, {t.origin_y_um:.1f} µm)."
        )
    methods = "\n".join(f'   hold {m.hold_s:g} s: "{m.method}" ({_ranges(m)})' for m in t.methods)
    grid = f" ({t.grid_g}×{t.grid_g} at {t.pitch_um:g} µm)" if t.grid_g > 1 else ""
    words = sites_words(t.kind, t.sites_um, t.grid_g, t.pitch_um, None)
    array_words = f"{words.program}: {words.layout} {words.extent}".rstrip()
    array = (
        f"3. Array dialog: import outbox/{t.sites_file}\n"
        f"   {t.n_sites} sites{grid}, µm offsets from the crosshair, {sign}.\n"
        f"   ({array_words})\n"
    )
    method = f"4. Test method:\n{methods}\n"
    export = f"6. Export (Sample File → Export, CSV or Excel) as inbox/{t.export_stem}.xlsx (or .csv).\n"
    kind = ""
    if t.fast is not None:
        array, method, export = fast_steps(t.fast, t.n_sites, t.sites_file, sign, t.export_stem)
        kind = f"NANOBLITZ FAST ARRAY (not CSM): {t.n_sites} load-controlled indents, no hold\n"
    return (
        f"AE-NI ticket  run {t.run}  block {t.block_id}{resumed}\n"
        f"{kind}"
        f"TOKEN {t.token}  (confirm the start with it: console key c, or `aeni send RUN confirm {t.token}`)\n"
        f"\n"
        f"{_stretch_words(t)}"
        f"1. {_sample_words(t)}\n"
        f"{move}\n"
        f"{array}"
        f"{method}"
        f"5. Start the array. Expected {t.expected_s:,.0f} s; deadline {deadline}.\n"
        f"{export}"
        f"If the array aborts or the surface is not found, report it (console keys a / f) with the token.\n"
    )


def ticket_panel(ticket: Ticket) -> tuple[str, ...]:
    """The ticket in short lines (≤ 40 characters where it can) for the console at 80×24."""
    t = ticket
    xmm, ymm = t.origin_mm
    how = "find the surface" if t.kind == "global" else "tip on the surface"
    words = sites_words(t.kind, t.sites_um, t.grid_g, t.pitch_um, None)
    lines = [
        *([f"sample {t.sample} (tray)"] if t.sample else []),
        *(
            [f"STRETCH array {t.stretch_index} of {len(t.stretch_arrays)}, ~{t.stretch_s / 3600:.1f} h"]
            if t.stretch_index
            else []
        ),
        f"move to X {xmm:.4f} mm  Y {ymm:.4f} mm",
        f"  = ({t.origin_x_um:.1f}, {t.origin_y_um:.1f}) µm; {how}",
        f"{words.program}: {words.layout} {words.extent}".rstrip(),
        f"array: {t.n_sites} sites, x{t.array_x_sign:+d} y{t.array_y_sign:+d}"
        + (" swap" if t.array_swap_xy else ""),
        f"  outbox/{t.sites_file}",
    ]
    if t.fast is not None:
        lines += [*fast_panel(t.fast, t.n_sites), f"export: inbox/{t.export_stem}.csv"]
    else:
        lines += [f"method {m.hold_s:g} s: {m.method}" for m in t.methods]
        lines += [f"export: inbox/{t.export_stem}.xlsx"]
    lines += [f"expected {t.expected_s:,.0f} s of instrument time"]
    return tuple(lines)


# --------------------------------------------------------------------------------------- the folder


def write_atomic(path: Path, text: str) -> None:
    """Temp file beside the target, then rename: InView or the operator never sees half a file."""
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="\n") as fh:
            fh.write(text)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def check_exchange_dir(root: str | Path) -> Path:
    """The exchange folder as a run starts: it exists, is a folder, and this process can write in it (and in
    its outbox and inbox). Written to, not asked: a share mounted read-only passes ``os.access`` for root and
    some network filesystems answer it wrongly, so a probe file is made and removed."""
    p = Path(root)
    if p.is_file():
        raise InputError(
            str(root), "is a file, not a folder (the exchange folder is a folder shared with InView)"
        )
    if not p.is_dir():
        raise InputError(str(root), "exchange folder does not exist")
    for sub in (p, p / "outbox", p / "inbox"):
        if sub is not p and not sub.is_dir():
            continue
        try:
            fd, probe = tempfile.mkstemp(prefix=".aeni-write-check-", dir=sub)
            os.close(fd)
            os.unlink(probe)
        except OSError as exc:
            raise InputError(
                str(sub),
                f"exchange folder is not writable ({exc.strerror or exc}): the run could not publish a block; "
                "mount the share read-write",
            ) from None
    return p


class ExchangeFolder:
    """The outbox and inbox of one run in an exchange folder shared with the instrument PC."""

    def __init__(self, root: str | Path, run: str, settings: InViewSettings) -> None:
        self.root = check_exchange_dir(root)
        if not _RUN_NAME.match(run):
            raise InputError("run", f"{run!r} cannot name exchange files (letters, digits, . _ + - only)")
        self.run = run
        self.settings = settings
        self.outbox = self.root / "outbox"
        self.inbox = self.root / "inbox"
        self.outbox.mkdir(exist_ok=True)
        self.inbox.mkdir(exist_ok=True)

    def problem(self) -> str | None:
        """Why the folder cannot be used right now (a USB stick carried to the other PC, a share gone), or
        None; when it is back, its outbox and inbox are made again if they went with it."""
        try:
            if not self.root.is_dir():
                return f"exchange folder {self.root} is missing"
            if not os.access(self.root, os.R_OK | os.W_OK | os.X_OK):
                return f"exchange folder {self.root} is not readable and writable"
            self.outbox.mkdir(exist_ok=True)
            self.inbox.mkdir(exist_ok=True)
            for sub in (self.outbox, self.inbox):
                if not os.access(sub, os.R_OK | os.W_OK | os.X_OK):
                    return f"exchange folder {sub} is not readable and writable"
        except OSError as exc:
            return f"exchange folder {self.root} is unreadable ({exc.strerror or exc})"
        return None

    def ticket_path(self, block_id: int) -> Path:
        return self.outbox / f"{self.run}-{block_tag(block_id)}-ticket.json"

    def report_path(self, block_id: int, kind: ReportKind) -> Path:
        return self.inbox / f"{self.run}-{block_tag(block_id)}-{kind}.txt"

    def publish(self, ticket: Ticket) -> None:
        """Sites file first, then the readable ticket, then the JSON ticket (the fake InView's trigger)."""
        write_atomic(self.outbox / ticket.sites_file, format_sites(array_offsets(ticket, self.settings)))
        write_atomic(self.ticket_path(ticket.block_id).with_suffix(".txt"), ticket_text(ticket))
        write_atomic(self.ticket_path(ticket.block_id), json.dumps(ticket.to_dict(), indent=2) + "\n")

    def read_ticket(self, block_id: int) -> Ticket | None:
        path = self.ticket_path(block_id)
        if not path.is_file():
            return None
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError) as exc:
            raise InputError(str(path), f"unreadable ticket ({exc})") from None
        return Ticket.from_dict(data, str(path))

    def report(self, ticket: Ticket, kind: ReportKind) -> str | None:
        """The token in a report file, if the file exists (checked by the caller)."""
        path = self.report_path(ticket.block_id, kind)
        try:
            return path.read_text(encoding="utf-8", errors="replace").strip()
        except FileNotFoundError:
            return None

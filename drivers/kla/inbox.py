"""The inbox watcher: when an InView export counts as this block's results, and what its rows mean.

An export is accepted only when it is complete (size and mtime stable over N polls, no ``~$`` lock file
beside it, and it opens cleanly), when its row count fits the plan, and when its X/Y positions lie on the
planned sites (mm written as µm is detected and converted). What it then says becomes one outcome per
planned site: measured, failed (blank, ``--``, 1.797e308, impossible values) or not run (a partial or
aborted array). Every accepted export is archived with its SHA-256 next to the journal and never parsed
again; stale and duplicate exports are refused with a reason and kept in the archive's ``refused/``.
"""

from __future__ import annotations

import itertools
import json
import math
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Literal

import numpy as np
from scipy.spatial import cKDTree

from core.errors import InputError
from drivers.kla.exchange import EXPORT_SUFFIXES, ExchangeFolder, Ticket, parse_name
from drivers.kla.export import KlaExport, KlaIndent, read_kla_export
from drivers.kla.export_folder import copy_export, lock_names, remove_export, sha256_tree, tree_stat

# the same words as core.plan.IndentResult.status
SiteStatus = Literal["measured", "failed", "not_run", "unverified"]
MATCHED_BY_ORDER = (
    "no positions in the export: matched by test order "
    "(add X/Y Test Position to the export template to let the driver check them)"
)
FAST_ORDER = "NanoBlitz rows in the instrument's own order: each matched to the planned site it lies on"
STALE_SLACK_S = 5.0  # clocks of the instrument PC and this one may differ a little on a share


def _empty(path: Path) -> bool:
    try:
        return path.stat().st_size == 0
    except FileNotFoundError:
        return False


def sha256_of(path: Path) -> str:
    return sha256_tree(path)  # a file, or a folder of per-test files (one export)


@dataclass(frozen=True)
class SiteOutcome:
    """One planned site of the array after its export was read."""

    indent_index: int  # within the block
    status: SiteStatus
    x_um: float | None = None  # as the export reports it (µm, converted where mm was detected)
    y_um: float | None = None
    hardness_gpa: float | None = None  # None unless measured
    modulus_gpa: float | None = None
    drift_rate_nm_s: float | None = None
    max_depth_nm: float | None = None
    reason: str = ""


@dataclass(frozen=True)
class AcceptedExport:
    block_id: int
    archived: Path
    sha256: str
    outcomes: tuple[SiteOutcome, ...]
    notes: tuple[str, ...]
    original: str = ""  # the file's name in the inbox
    fmt: str = ""  # the format the reader recognised (InView, NanoSuite, TestWorks, Hysitron ...)

    @property
    def partial(self) -> bool:
        return any(o.status == "not_run" for o in self.outcomes)


@dataclass(frozen=True)
class Refusal:
    file: str
    reason: str
    sha256: str | None
    # a refused export whose rows say where the tip went: those indents were made ("unverified")
    made: tuple[SiteOutcome, ...] = ()


@dataclass(frozen=True)
class PollResult:
    accepted: AcceptedExport | None = None
    refused: tuple[Refusal, ...] = ()
    waiting: str = "no export yet"  # what the watcher waits for, for the ticket panel


# ------------------------------------------------------------------------------------------ archive


class ExportArchive:
    """Accepted exports (and refused files) with their SHA-256, in a folder next to the journal."""

    def __init__(self, folder: str | Path) -> None:
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self.manifest = self.folder / "manifest.jsonl"

    def entries(self) -> list[dict[str, Any]]:
        if not self.manifest.is_file():
            return []
        out = []
        for line in self.manifest.read_text(encoding="utf-8").splitlines():
            if line.strip():
                try:
                    out.append(json.loads(line))
                except json.JSONDecodeError:
                    continue  # a line cut by a crash; the file it names is still in the folder
        return out

    def by_sha(self, sha: str) -> dict[str, Any] | None:
        return next((e for e in self.entries() if e["sha256"] == sha), None)

    def accepted(self, run: str, block_id: int) -> dict[str, Any] | None:
        return next(
            (
                e
                for e in self.entries()
                if e["status"] == "accepted" and e["run"] == run and e["block_id"] == block_id
            ),
            None,
        )

    def closed(self, run: str, block_id: int) -> dict[str, Any] | None:
        """The entry that closed a block: an accepted export or a 'not run' closure (timeout, skip)."""
        return next(
            (
                e
                for e in self.entries()
                if e["status"] in ("accepted", "closed") and e["run"] == run and e["block_id"] == block_id
            ),
            None,
        )

    def export_files(self) -> dict[tuple[int, str], str]:
        """(block, indent status) -> the archived export the indent's record came from: the block's accepted
        export for a measured or failed indent, the last refused one for an unverified one."""
        out: dict[tuple[int, str], str] = {}
        for e in self.entries():
            if e["status"] == "accepted":
                out[(e["block_id"], "measured")] = out[(e["block_id"], "failed")] = str(e["file"])
            elif e["status"] == "refused":
                out[(e["block_id"], "unverified")] = str(e["file"])
        return out

    def _append(self, entry: dict[str, Any]) -> None:
        """One line; after a line a crash or a full disk cut short, on a line of its own (else the cut line
        would swallow this entry too)."""
        with self.manifest.open("a+b") as fh:
            fh.seek(0, 2)
            cut = False
            if fh.tell() > 0:
                fh.seek(-1, 2)
                cut = fh.read(1) != b"\n"
            fh.write((("\n" if cut else "") + json.dumps(entry) + "\n").encode("utf-8"))
            fh.flush()

    def _keep(self, src: Path, sha: str, entry: dict[str, Any], sub: str = "") -> Path:
        """Copy the file into the archive, record ``entry``, then take the file out of the inbox.

        In that order a kill at any point loses nothing: before the record the file is still in the inbox
        (read again on resume), after it the record holds what the file said (a copy left in the inbox is
        then refused as a duplicate). A copy, not a rename: the inbox may be a share on another file system.
        """
        folder = self.folder / sub if sub else self.folder
        folder.mkdir(exist_ok=True)
        dst = folder / f"{sha[:12]}-{src.name}"
        copy_export(src, dst)
        entry["file"] = f"{sub}/{dst.name}" if sub else dst.name
        self._append(entry)
        remove_export(src)
        return dst

    def accept(self, src: Path, sha: str, run: str, block_id: int, export: AcceptedExport) -> AcceptedExport:
        """Archive the file and record what it said, so a resumed run never parses it again."""
        entry = _entry("accepted", run, block_id, sha, src.name, "", "")
        if export.fmt:
            entry["format"] = export.fmt
        entry["outcomes"] = [asdict(o) for o in export.outcomes]
        entry["notes"] = list(export.notes)
        dst = self._keep(src, sha, entry)
        return AcceptedExport(block_id, dst, sha, export.outcomes, export.notes, src.name, export.fmt)

    def accepted_export(self, run: str, block_id: int) -> AcceptedExport | None:
        """A block's accepted export as recorded when it was accepted (for a resumed run)."""
        e = self.accepted(run, block_id)
        if e is None:
            return None
        outcomes = tuple(SiteOutcome(**o) for o in e.get("outcomes", []))
        notes = tuple(e.get("notes", []))
        return AcceptedExport(
            block_id,
            self.folder / e["file"],
            e["sha256"],
            outcomes,
            notes,
            e["original"],
            e.get("format", ""),
        )

    def refuse(
        self,
        src: Path,
        sha: str | None,
        run: str,
        block_id: int,
        reason: str,
        fmt: str = "",
        made: tuple[SiteOutcome, ...] = (),
    ) -> None:
        """Keep a refused file in ``refused/``; ``made``: the indents its rows say were made (``unverified``),
        recorded with the refusal so a run killed before the block closes still journals them."""
        if sha is None:
            sha = sha256_of(src)
        entry = _entry("refused", run, block_id, sha, src.name, "", reason)
        if fmt:
            entry["format"] = fmt
        if made:
            entry["outcomes"] = [asdict(o) for o in made]
        self._keep(src, sha, entry, "refused")

    def refused_made(self, run: str, block_id: int) -> tuple[SiteOutcome, ...]:
        """The indents the block's last refused export said were made (nothing when none said so)."""
        found: tuple[SiteOutcome, ...] = ()
        for e in self.entries():
            if (
                e["status"] == "refused"
                and e["run"] == run
                and e["block_id"] == block_id
                and e.get("outcomes")
            ):
                found = tuple(SiteOutcome(**o) for o in e["outcomes"])
        return found

    def close(self, run: str, block_id: int, reason: str, outcomes: tuple[SiteOutcome, ...] = ()) -> None:
        """A block ended without an accepted export (deadline, skip, surface not found); ``outcomes``
        when a refused export said which indents were made (``unverified``), so a resume keeps them."""
        entry = _entry("closed", run, block_id, "", "", "", reason)
        if outcomes:
            entry["outcomes"] = [asdict(o) for o in outcomes]
        self._append(entry)


def _entry(
    status: str, run: str, block_id: int, sha: str, original: str, stored: str, reason: str
) -> dict[str, Any]:
    return {
        "status": status,
        "run": run,
        "block_id": block_id,
        "sha256": sha,
        "original": original,
        "file": stored,
        "reason": reason,
        "utc": datetime.now(UTC).isoformat(timespec="seconds"),
    }


# ----------------------------------------------------------------------------------------- matching


@dataclass(frozen=True)
class Match:
    """Which site each export row belongs to, or why none fits."""

    site_of_row: tuple[int | None, ...] = ()
    notes: tuple[str, ...] = ()
    refusal: str = ""
    scale: float = 1.0


def _tolerance_um(ticket: Ticket, tolerance_um: float) -> float:
    """The settings' tolerance, but below half the closest spacing, so no row can fit two sites (a fast
    array's pitch may be 5 µm: 2.25 µm then). A k-d tree: a fast array has thousands of sites."""
    sites = np.asarray(ticket.sites_um, dtype=float).reshape(-1, 2)
    if len(sites) < 2:
        return tolerance_um
    closest = float(cKDTree(sites).query(sites, k=2)[0][:, 1].min())
    return min(tolerance_um, 0.45 * closest)


def _assign(
    rows: list[tuple[float, float] | None], sites: tuple[tuple[float, float], ...], tol: float
) -> tuple[int | None, ...] | None:
    """Each positioned row to its nearest site within ``tol``, one to one; None when a row fits none."""
    placed = [k for k, pos in enumerate(rows) if pos is not None]
    out: list[int | None] = [None] * len(rows)
    if not placed:
        return tuple(out)
    dist, best = cKDTree(np.asarray(sites, dtype=float).reshape(-1, 2)).query(
        np.asarray([rows[k] for k in placed], dtype=float)
    )
    if bool((dist > tol).any()) or len(set(best.tolist())) < len(placed):
        return None
    for k, site in zip(placed, best.tolist(), strict=True):
        out[k] = int(site)
    return tuple(out)


def _diagnose(rows: list[tuple[float, float]], ticket: Ticket, tol: float) -> str:
    """Why the rows are not on the plan, in the operator's terms."""
    ox, oy = ticket.origin_x_um, ticket.origin_y_um
    planned = ticket.sites_um[: len(rows)]
    candidates = {
        "the Y axis is flipped (set inview.array_y_sign to the other sign)": [
            (x, 2 * oy - y) for x, y in planned
        ],
        "the X axis is flipped (set inview.array_x_sign to the other sign)": [
            (2 * ox - x, y) for x, y in planned
        ],
        "X and Y are swapped (inview.array_swap_xy)": [(ox + (y - oy), oy + (x - ox)) for x, y in planned],
    }
    for why, expect in candidates.items():
        if all(math.dist(r, e) <= tol for r, e in zip(rows, expect, strict=False)):
            return f"the rows lie where the array would put them if {why}"
    shift = (
        sum(r[0] - p[0] for r, p in zip(rows, planned, strict=False)) / len(rows),
        sum(r[1] - p[1] for r, p in zip(rows, planned, strict=False)) / len(rows),
    )
    spread = max(math.dist((r[0] - p[0], r[1] - p[1]), shift) for r, p in zip(rows, planned, strict=False))
    if spread <= tol:
        return (
            f"the array ran from another origin: every row is off by ({shift[0]:+.1f}, {shift[1]:+.1f}) µm "
            f"(move to X {ox / 1000:.4f} mm, Y {oy / 1000:.4f} mm before importing the array)"
        )
    worst = max(math.dist(r, p) for r, p in zip(rows, planned, strict=False))
    return f"the rows do not lie on the planned sites (up to {worst:.1f} µm off, tolerance {tol:.1f} µm)"


def match_rows(
    export: KlaExport,
    ticket: Ticket,
    tolerance_um: float,
    skipped: frozenset[int] = frozenset(),
    partial: bool = False,
) -> Match:
    """Rows to planned sites: in array order when they agree, else one-to-one by position.

    InView runs the array in file order, so row k is site k. A row list that is a permutation of the
    sites (a flipped axis on a grid symmetric about its origin) still puts every measurement where it was
    made; it is accepted with a warning that names the likely convention error. Positions that are 1000×
    too small are mm labelled µm: converted, with a note.
    """
    tol = _tolerance_um(ticket, tolerance_um)
    raw = [(i.x_um, i.y_um) if i.x_um is not None and i.y_um is not None else None for i in export.indents]
    positioned = [p for p in raw if p is not None]
    if not positioned:
        return _by_order(len(raw), ticket, skipped, partial)
    ox, oy = ticket.origin_x_um, ticket.origin_y_um
    readings: list[tuple[float, str, list[tuple[float, float] | None]]] = [
        (1.0, "", raw),
        (1000.0, "X/Y positions were mm labelled as µm: read ×1000", _scaled(raw, 1000.0)),
        (
            1.0,
            "X/Y positions were relative to the block origin: the origin was added",
            [None if p is None else (p[0] + ox, p[1] + oy) for p in raw],
        ),
    ]
    for scale, note, rows in readings:
        if len(rows) > ticket.n_sites:
            break
        if any(p is None for p in rows):  # rows without X/Y: only array order can place them
            if all(p is None or math.dist(p, ticket.sites_um[k]) <= tol for k, p in enumerate(rows)):
                extra = "rows without X/Y were taken in array order"
                return Match(tuple(range(len(rows))), tuple(filter(None, [note, extra])), scale=scale)
            continue
        assigned = _assign(rows, ticket.sites_um, tol)
        if assigned is None:
            continue
        sites = [a for a in assigned if a is not None]
        if all(a < b for a, b in itertools.pairwise(sites)):
            return Match(assigned, (note,) if note else (), scale=scale)  # array order (sites may be skipped)
        if ticket.fast is not None:  # NanoBlitz may make its grid in its own order (a raster, a snake)
            return Match(assigned, tuple(filter(None, [note, FAST_ORDER])), scale=scale)
        why = _diagnose([p for p in rows if p is not None], ticket, tol)
        warn = f"rows are not in the array's order but each lies on a planned site: {why}"
        return Match(assigned, tuple(filter(None, [note, warn])), scale=scale)
    return Match(refusal=_diagnose(positioned, ticket, tol))


def _by_order(n_rows: int, ticket: Ticket, skipped: frozenset[int], partial: bool) -> Match:
    """An export without positions: InView runs the array in the sites file's order, so row k is the k-th
    site that ran, when the count says so (all sites, or all but the skipped ones; the first ones of an
    array that stopped early)."""
    ran = [k for k in range(ticket.n_sites) if ticket.first_index + k not in skipped]
    if n_rows == len(ran):
        return Match(tuple(ran), (MATCHED_BY_ORDER,))
    if partial and 0 < n_rows < len(ran):
        stopped = f"the array stopped after {n_rows} of {len(ran)} sites: the rows are its first sites"
        return Match(tuple(ran[:n_rows]), (MATCHED_BY_ORDER, stopped))
    return Match(
        refusal=(
            f"no positions in the export and {n_rows} rows for {len(ran)} sites: cannot tell which row is "
            "which site (add X/Y Test Position to the export template)"
        )
    )


def _scaled(rows: list[tuple[float, float] | None], factor: float) -> list[tuple[float, float] | None]:
    return [None if p is None else (p[0] * factor, p[1] * factor) for p in rows]


def made_where_reported(export: KlaExport, ticket: Ticket, why: str) -> tuple[SiteOutcome, ...]:
    """The indents a refused export says were made, row k being the array's k-th site (InView runs it in
    order), at the export's positions: ``unverified``, with no value, so they are priced and kept away from
    but never learnt from. Nothing when a row has no position or there are more rows than sites."""
    rows = export.indents
    if not rows or len(rows) > ticket.n_sites or any(i.x_um is None or i.y_um is None for i in rows):
        return ()
    note = f"{why}: made at the export's position, not checked against the plan, not learnt from"
    return tuple(
        SiteOutcome(
            ticket.first_index + k,
            "unverified",
            row.x_um,
            row.y_um,
            max_depth_nm=row.max_depth_nm,
            reason=note
            if row.hardness_gpa is None
            else f"{note} (the export read {row.hardness_gpa:.3g} GPa)",
        )
        for k, row in enumerate(rows)
    )


def outcomes_for(
    export: KlaExport,
    ticket: Ticket,
    match: Match,
    not_run_reason: str,
    skipped: frozenset[int] = frozenset(),
) -> tuple[SiteOutcome, ...]:
    """One outcome per planned site: measured, failed (with the reader's reason) or not run."""
    by_site: dict[int, KlaIndent] = {}
    for indent, site in zip(export.indents, match.site_of_row, strict=True):
        assert site is not None
        by_site[site] = indent
    out = []
    for k in range(ticket.n_sites):
        index = ticket.first_index + k
        row = by_site.get(k)
        if row is None:
            why = "skipped by the operator" if index in skipped else not_run_reason
            out.append(SiteOutcome(index, "not_run", reason=why))
            continue
        x = None if row.x_um is None else row.x_um * match.scale
        y = None if row.y_um is None else row.y_um * match.scale
        if row.failed:
            out.append(
                SiteOutcome(
                    index,
                    "failed",
                    x,
                    y,
                    None,
                    row.modulus_gpa,
                    row.drift_rate_nm_s,
                    row.max_depth_nm,
                    reason=str(row.failure),
                )
            )
        else:
            out.append(
                SiteOutcome(
                    index,
                    "measured",
                    x,
                    y,
                    row.hardness_gpa,
                    row.modulus_gpa,
                    row.drift_rate_nm_s,
                    row.max_depth_nm,
                )
            )
    return tuple(out)


# ------------------------------------------------------------------------------------------ watcher


@dataclass
class _Seen:
    size: int
    mtime_ns: int
    stable: int = 0


@dataclass
class InboxWatcher:
    """Polls the inbox for one run; call :meth:`poll` every ``settings.poll_s`` while a block waits."""

    folder: ExchangeFolder
    archive: ExportArchive
    _seen: dict[str, _Seen] = field(default_factory=dict)

    def _candidates(self) -> list[tuple[Path, int]]:
        out = []
        for path in sorted(self.folder.inbox.iterdir()):
            name = path.name
            if name.startswith((".", "~")) or not (path.is_file() or path.is_dir()):
                continue  # temp files, lock files
            parsed = parse_name(name)
            if parsed is None or parsed.run != self.folder.run or parsed.kind != "export":
                continue
            if parsed.suffix in EXPORT_SUFFIXES or (
                path.is_dir() and not parsed.suffix
            ):  # a folder: per-test files
                out.append((path, parsed.block_id))
        return out

    def _locked(self, path: Path) -> bool:
        """Excel/InView keep ``~$<name>`` (sometimes with the first letters cut) while the file is open."""
        folder = path if path.is_dir() else self.folder.inbox
        for lock in folder.glob("~$*"):
            rest = lock.name[2:]
            if rest and any(name.endswith(rest) for name in lock_names(path)):
                return True
        return False

    def _stable(self, path: Path) -> bool:
        try:
            size, mtime_ns = tree_stat(path)
        except FileNotFoundError:
            self._seen.pop(path.name, None)
            return False
        seen = self._seen.get(path.name)
        if seen is None or (seen.size, seen.mtime_ns) != (size, mtime_ns):
            self._seen[path.name] = _Seen(size, mtime_ns)
            return False
        seen.stable += 1
        return seen.stable >= self.folder.settings.stable_polls

    def _refuse(
        self,
        path: Path,
        sha: str | None,
        block_id: int,
        reason: str,
        fmt: str = "",
        made: tuple[SiteOutcome, ...] = (),
    ) -> Refusal:
        """Keep the file in the archive's refused/ and say why (the manifest names the reader's format and
        the indents the rows say were made)."""
        self.archive.refuse(path, sha, self.folder.run, block_id, reason, fmt, made)
        self._seen.pop(path.name, None)
        return Refusal(path.name, reason, sha, made)

    def poll(
        self,
        ticket: Ticket,
        *,
        partial_ok: bool = False,
        final: bool = False,
        skipped: frozenset[int] = frozenset(),
    ) -> PollResult:
        """Look once. ``partial_ok``: the array was reported aborted (fewer rows are expected);
        ``final``: the deadline passed, so a complete-looking export is judged as it is; ``skipped``:
        indent indices the operator took out of the array (their rows are not expected)."""
        refused: list[Refusal] = []
        waiting = "no export yet"
        for path, block_id in self._candidates():
            ours = block_id == ticket.block_id  # only this block's files make the status it shows
            if not self._stable(path):
                if ours:
                    waiting = f"{path.name} is still being written"
                continue
            if self._locked(path):
                if ours:
                    waiting = f"{path.name} is open in InView (lock file ~$…)"
                continue
            if _empty(path):  # every empty file has one SHA-256: judged before the duplicate check
                if ours and not final:
                    waiting = f"{path.name} is empty (0 bytes): export the array again"
                elif ours or self.archive.closed(self.folder.run, block_id) is not None:
                    why = "cannot be read: the file is empty (0 bytes)"
                    refused.append(self._refuse(path, None, block_id, why))
                continue
            sha = sha256_of(path)
            known = self.archive.by_sha(sha)
            if known is not None:
                what = "accepted" if known["status"] == "accepted" else "refused"
                refused.append(
                    self._refuse(
                        path,
                        sha,
                        block_id,
                        f"duplicate: same SHA-256 as the export {what} for block {known['block_id']}",
                    )
                )
                continue
            closed = self.archive.closed(self.folder.run, block_id)
            if closed is not None:
                how = (
                    "has an accepted export"
                    if closed["status"] == "accepted"
                    else f"was closed ({closed['reason']})"
                )
                refused.append(self._refuse(path, sha, block_id, f"stale: block {block_id} {how}"))
                continue
            if not ours:
                continue  # another open block's export (not expected; left for that block)
            mtime = datetime.fromtimestamp(path.stat().st_mtime, UTC)
            if (ticket.created() - mtime).total_seconds() > STALE_SLACK_S:
                refused.append(
                    self._refuse(
                        path,
                        sha,
                        block_id,
                        f"stale: written {mtime:%H:%M:%S} UTC, before this block's ticket",
                    )
                )
                continue
            try:
                export = read_kla_export(path)
            except InputError as exc:
                if final:
                    refused.append(self._refuse(path, sha, block_id, f"cannot be read: {exc.problem}"))
                else:
                    waiting = f"{path.name} does not open cleanly yet ({exc.problem})"
                continue
            result = self._judge(
                path, sha, export, ticket, partial_ok=partial_ok, final=final, skipped=skipped
            )
            if isinstance(result, Refusal):
                refused.append(result)
            elif isinstance(result, str):
                waiting = result
            else:
                return PollResult(result, tuple(refused))
        return PollResult(None, tuple(refused), waiting)

    def _judge(
        self,
        path: Path,
        sha: str,
        export: KlaExport,
        ticket: Ticket,
        *,
        partial_ok: bool,
        final: bool,
        skipped: frozenset[int],
    ) -> AcceptedExport | Refusal | str:
        n_rows, n_sites = len(export.indents), ticket.n_sites
        n_expected = n_sites - len({k for k in skipped if k >= ticket.first_index})
        if n_rows > n_sites:
            return self._refuse(
                path, sha, ticket.block_id, f"has {n_rows} rows, the block planned {n_sites} (another array?)"
            )
        if not export.has_positions and n_rows < n_expected and not (partial_ok or final):
            return (
                f"{path.name} has {n_rows} of {n_expected} rows and no positions: waiting for an "
                "'aborted' report (then its rows are the array's first sites)"
            )
        tolerance = self.folder.settings.position_tolerance_um
        match = match_rows(export, ticket, tolerance, skipped, partial=partial_ok or final)
        if match.refusal:
            reason = f"positions do not match the plan: {match.refusal} ({export.summary})"
            made = made_where_reported(export, ticket, f"export {path.name} refused")
            return self._refuse(path, sha, ticket.block_id, reason, export.software, made)
        if n_rows < n_expected and not (partial_ok or final):
            return (
                f"{path.name} has {n_rows} of {n_expected} rows: waiting for an 'aborted' report "
                "(then the rows present are kept and the rest marked not run)"
            )
        why = "array aborted" if partial_ok else "no row in the export (deadline passed)"
        outcomes = outcomes_for(export, ticket, match, why, skipped)
        found = AcceptedExport(
            ticket.block_id,
            path,
            sha,
            outcomes,
            (*match.notes, *export.warnings, export.summary),
            fmt=export.software,
        )
        self._seen.pop(path.name, None)
        return self.archive.accept(path, sha, self.folder.run, ticket.block_id, found)

"""Reading and validating ``sample.toml``: one-line errors that name the file and the field.

The checks are the ones an operator gets wrong at the instrument: a corner left out, corners typed in the
wrong order, a z read off the wrong place, millimetres typed where micrometres belong, an exclusion that
swallows the sample. Every one is refused here, before a run starts.
"""

from __future__ import annotations

import csv
import math
import sqlite3
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from core.errors import InputError
from core.geometry import (
    CORNER_NAMES,
    PARALLELOGRAM_WARN_FRACTION,
    Calibration,
    CandidateLattice,
    Corner,
    _validate_corners,
    distance_to_polygon_um,
    mm_typed,
    polygon_meets_polygon,
    polygon_self_crossing,
)
from core.profile import InstrumentProfile, load_profile
from core.sample.model import (
    UNLIMITED_STAGE_UM,
    CircleExclusion,
    Exclusion,
    PolygonExclusion,
    Sample,
    check_positive,
)

_TOP = ("name", "profile", "lattice_n", "corners", "safety", "exclusions", "earlier", "source")
_SAFETY = ("dz_safe_um", "r_excl_um", "edge_band_um", "stage_rect_um")
_EARLIER = ("indents_csv", "journals", "indents_um")
# a sample narrower than this is not a sample: the corners were typed in mm
_MIN_SPAN_UM = 50.0
# distances below these are mm typed as µm (an indent alone is a few µm wide)
_MIN_R_EXCL_UM = 1.0
_MIN_DZ_SAFE_UM = 0.05


def _table(source: str, data: Mapping[str, Any], key: str, allowed: Sequence[str]) -> dict[str, Any]:
    value = data.get(key, {})
    if not isinstance(value, Mapping):
        raise InputError(source, f"[{key}] must be a table, got {value!r}")
    for k in value:
        if k not in allowed:
            raise InputError(source, f"unknown field {key}.{k} (allowed: {', '.join(allowed)})")
    return dict(value)


def _point(source: str, name: str, value: Any, n: int) -> tuple[float, ...]:
    if not isinstance(value, Sequence) or isinstance(value, str) or len(value) != n:
        raise InputError(source, f"field {name} must be a list of {n} numbers, got {value!r}")
    out = []
    for v in value:
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise InputError(source, f"field {name} must hold finite numbers, got {value!r}")
        out.append(float(v))
    return tuple(out)


def _corners(source: str, data: Mapping[str, Any]) -> tuple[Corner, Corner, Corner, Corner]:
    table = _table(source, data, "corners", [n.lower() for n in CORNER_NAMES])
    out = []
    for name in (n.lower() for n in CORNER_NAMES):
        if name not in table:
            raise InputError(
                source, f"field corners.{name} is missing (give all four corners: tl, tr, br, bl)"
            )
        c = table[name]
        if not isinstance(c, Mapping):
            raise InputError(source, f"field corners.{name} must be {{ x_um = …, y_um = …, z_um = … }}")
        for axis in c:
            if axis not in ("x_um", "y_um", "z_um"):
                raise InputError(source, f"unknown field corners.{name}.{axis} (allowed: x_um, y_um, z_um)")
        vals = []
        for axis in ("x_um", "y_um", "z_um"):
            if axis not in c:
                raise InputError(source, f"field corners.{name}.{axis} is missing")
            v = c[axis]
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                raise InputError(source, f"field corners.{name}.{axis} must be a finite number, got {v!r}")
            vals.append(float(v))
        out.append(Corner(*vals))
    tl, tr, br, bl = out
    return tl, tr, br, bl


def _check_units(source: str, xy: np.ndarray) -> None:
    span = max(float(np.ptp(xy[:, 0])), float(np.ptp(xy[:, 1])))
    if span < _MIN_SPAN_UM:
        raise InputError(
            source,
            f"field corners: the corners span only {span:g} µm; these look like mm, "
            f"but stage coordinates are µm (multiply by 1000)",
        )


def _parallelogram_defect(xy: np.ndarray) -> np.ndarray:
    """TL − TR + BR − BL: zero for a parallelogram; a quarter of its length is the affine fit's miss per corner."""
    return np.asarray(xy[0] - xy[1] + xy[2] - xy[3], dtype=float)


def _completed_corner(xy: np.ndarray, k: int) -> np.ndarray:
    """Where corner k would be if the other three, as typed, were corners of a parallelogram."""
    sign = 1.0 if k in (0, 2) else -1.0
    return np.asarray(xy[k] - sign * _parallelogram_defect(xy), dtype=float)


def _fits_parallelogram(xy: np.ndarray) -> bool:
    """The four corners make a parallelogram within 2 % of its shortest side."""
    side = min(float(np.linalg.norm(xy[k] - xy[(k + 1) % 4])) for k in range(4))
    return float(np.linalg.norm(_parallelogram_defect(xy))) / 4.0 <= PARALLELOGRAM_WARN_FRACTION * side


def _check_corner_scale(source: str, xy: np.ndarray) -> None:
    """One corner typed in mm (or nm) among corners in µm: that corner ×1000 (÷1000) makes a parallelogram."""
    if _fits_parallelogram(xy):
        return
    for k, name in enumerate(CORNER_NAMES):
        for factor, unit, size in ((1000.0, "mm", "smaller"), (0.001, "nm", "larger")):
            fixed = xy.copy()
            fixed[k] = xy[k] * factor
            # the corner itself is about 1000× off where the other three put it (not just near the origin)
            where = float(np.linalg.norm(_completed_corner(xy, k)))
            ratio = float(np.linalg.norm(xy[k])) * factor / where if where > 0 else math.inf
            if 0.5 <= ratio <= 2.0 and _fits_parallelogram(fixed):
                raise InputError(
                    source,
                    f"field corners.{name.lower()} = ({xy[k, 0]:g}, {xy[k, 1]:g}) is about 1000× {size} than "
                    f"the other corners: it looks like {unit}, but stage coordinates are µm "
                    f"(({fixed[k, 0]:g}, {fixed[k, 1]:g}) µm would fit)",
                )


def _check_affine(source: str, cal: Calibration, xy: np.ndarray) -> None:
    """Corners that miss a parallelogram by more than 2 % of the diagonal are a typo, not a sample."""
    limit = PARALLELOGRAM_WARN_FRACTION * cal.diagonal_um
    miss = cal.parallelogram_residual_um
    if miss <= limit:
        return
    # the corners to check: those whose angle is furthest from a right angle (samples are cut square)
    angles = []
    for k in range(4):
        a, b = xy[k - 1] - xy[k], xy[(k + 1) % 4] - xy[k]
        cos = float(np.dot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b)))
        angles.append(abs(math.degrees(math.acos(max(-1.0, min(1.0, cos)))) - 90.0))
    worst = max(angles)
    suspects = [k for k in range(4) if angles[k] >= worst - 0.1]
    where = ", ".join(
        f"{CORNER_NAMES[k].lower()} at ({x:.0f}, {y:.0f}) µm"
        for k in suspects
        for x, y in [_completed_corner(xy, k)]
    )
    names = " or ".join(f"corners.{CORNER_NAMES[k].lower()}" for k in suspects)
    raise InputError(
        source,
        f"field corners: the affine fit misses the corners by {miss:.1f} µm ({100 * miss / cal.diagonal_um:.1f} % "
        f"of the {cal.diagonal_um:.0f} µm diagonal; at most {100 * PARALLELOGRAM_WARN_FRACTION:.0f} % is "
        f"accepted): check {names} (a parallelogram through the other three puts {where})",
    )


def _tilt_um_per_mm(cal: Calibration) -> float:
    return 1000.0 * cal.plane.slope


def _exclusion(source: str, i: int, item: Any, cal: Calibration) -> Exclusion:
    name = f"exclusions[{i}]"
    if not isinstance(item, Mapping) or len(item) != 1 or next(iter(item)) not in ("circle_um", "polygon_um"):
        raise InputError(source, f"field {name} must have exactly one of circle_um or polygon_um")
    key, value = next(iter(item.items()))
    area = cal.corners_xy_um
    if key == "circle_um":
        x, y, r = _point(source, f"{name}.circle_um", value, 3)
        if not r > 0:
            raise InputError(source, f"field {name}.circle_um: the radius must be > 0, got {r:g}")
        if mm_typed([[x, y]], cal.bounds_um):
            raise InputError(
                source,
                f"field {name}.circle_um = {list(value)!r} looks like mm, but stage coordinates are µm",
            )
        gap = distance_to_polygon_um(x, y, area) - r
        if gap > 0:
            raise InputError(
                source,
                f"field {name}.circle_um = {list(value)!r} lies entirely off the sample ({gap:,.0f} µm from its "
                "edge), so it protects nothing: check its centre and radius (stage µm)",
            )
        return CircleExclusion(x, y, r)
    if not isinstance(value, Sequence) or isinstance(value, str) or len(value) < 3:
        raise InputError(source, f"field {name}.polygon_um must list at least 3 [x_um, y_um] vertices")
    verts = tuple(_point(source, f"{name}.polygon_um[{k}]", v, 2) for k, v in enumerate(value))
    pts = np.array(verts)
    crossing = polygon_self_crossing(pts)
    if crossing is not None:
        a, b = crossing
        n = len(verts)
        raise InputError(
            source,
            f"field {name}.polygon_um crosses itself (its edge from vertex {a} to {(a + 1) % n} meets the edge "
            f"from vertex {b} to {(b + 1) % n}): list the vertices in order around the outline",
        )
    signed = 0.5 * float(np.sum(pts[:, 0] * np.roll(pts[:, 1], -1) - np.roll(pts[:, 0], -1) * pts[:, 1]))
    if abs(signed) <= 1e-9 * max(float(np.ptp(pts)), 1.0) ** 2:
        raise InputError(source, f"field {name}.polygon_um has no area (its vertices lie on one line)")
    if mm_typed(pts, cal.bounds_um):
        raise InputError(source, f"field {name}.polygon_um looks like mm, but stage coordinates are µm")
    if not polygon_meets_polygon(pts, area):
        raise InputError(
            source,
            f"field {name}.polygon_um lies entirely off the sample, so it protects nothing: check its "
            "vertices (stage µm)",
        )
    return PolygonExclusion(tuple((float(a), float(b)) for a, b in verts))


def _read_indents_csv(source: str, path: Path) -> list[tuple[float, float]]:
    name = f"earlier.indents_csv ({path})"
    try:
        # utf-8-sig: Excel's "CSV UTF-8" starts with a byte-order mark; newline="" reads CRLF lines too
        with path.open(newline="", encoding="utf-8-sig") as fh:
            rows = list(csv.reader(fh))
    except FileNotFoundError:
        raise InputError(source, f"field {name}: no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(source, f"field {name}: cannot read ({exc})") from None
    rows = [r for r in rows if r and any(c.strip() for c in r)]
    if not rows:
        return []
    header = [c.strip().lower() for c in rows[0]]
    if "x_um" not in header or "y_um" not in header:
        if len(rows[0]) == 1 and ";" in rows[0][0]:
            # Excel in a decimal-comma locale: its "1,5" cannot be told from two columns, so ask, never guess
            raise InputError(
                source,
                f"field {name}: uses ';' as the separator (Excel in a decimal-comma locale); save it as "
                "comma-separated with '.' decimals",
            )
        raise InputError(source, f"field {name}: the header must name the columns x_um and y_um")
    ix, iy = header.index("x_um"), header.index("y_um")
    out = []
    for k, r in enumerate(rows[1:], start=2):
        try:
            x, y = float(r[ix]), float(r[iy])
        except (IndexError, ValueError):
            raise InputError(source, f"field {name}: line {k} has no numeric x_um, y_um ({r!r})") from None
        if not (math.isfinite(x) and math.isfinite(y)):
            raise InputError(source, f"field {name}: line {k} has a non-finite coordinate")
        out.append((x, y))
    return out


def _read_journal_indents(source: str, path: Path) -> list[tuple[float, float]]:
    """Where an earlier run indented, read-only from its journal's indents table (docs/journal.md: the
    table is the journal's public format, so the sample needs nothing of the journal's code); an indent
    whose position was not measured counts where it was commanded."""
    where = f"field earlier.journals: {path}"
    if not path.is_file():
        raise InputError(source, f"{where}: no such journal file")
    try:
        conn = sqlite3.connect(f"file:{path.resolve()}?mode=ro", uri=True)
        try:
            rows = conn.execute(
                "SELECT COALESCE(actual_x_um, commanded_x_um), COALESCE(actual_y_um, commanded_y_um) FROM indents"
            ).fetchall()
        finally:
            conn.close()
    except sqlite3.Error as exc:
        raise InputError(source, f"{where}: not a readable journal ({exc})") from None
    return [(float(x), float(y)) for x, y in rows]


def _earlier(source: str, table: Mapping[str, Any], base_dir: Path | None) -> list[tuple[float, float]]:
    out: list[tuple[float, float]] = []
    inline = table.get("indents_um", [])
    if not isinstance(inline, Sequence) or isinstance(inline, str):
        raise InputError(source, "field earlier.indents_um must be a list of [x_um, y_um]")
    for k, p in enumerate(inline):
        x, y = _point(source, f"earlier.indents_um[{k}]", p, 2)
        out.append((x, y))

    def resolve(p: str) -> Path:
        path = Path(p)
        return path if path.is_absolute() or base_dir is None else base_dir / path

    csv_path = table.get("indents_csv")
    if csv_path is not None:
        if not isinstance(csv_path, str) or not csv_path:
            raise InputError(source, "field earlier.indents_csv must be a file name")
        out.extend(_read_indents_csv(source, resolve(csv_path)))
    journals = table.get("journals", [])
    if not isinstance(journals, list) or not all(isinstance(j, str) for j in journals):
        raise InputError(source, "field earlier.journals must be a list of journal paths")
    for j in journals:
        out.extend(_read_journal_indents(source, resolve(j)))
    return out


def parse_sample(data: Mapping[str, Any], source: str = "sample", base_dir: Path | None = None) -> Sample:
    """Validate a parsed sample table; every failure is an InputError naming ``source`` and the field."""
    for key in data:
        if key not in _TOP:
            raise InputError(source, f"unknown field {key!r} (allowed: {', '.join(_TOP[:-1])})")
    name = data.get("name")
    if not isinstance(name, str) or not name.strip():
        raise InputError(source, "field name is missing or empty (give the sample a name)")
    profile_name = data.get("profile", "kla-imicro")
    if not isinstance(profile_name, str):
        raise InputError(source, f"field profile must be a profile name, got {profile_name!r}")
    try:
        profile: InstrumentProfile = load_profile(profile_name)
    except InputError as exc:
        raise InputError(source, f"field profile = {profile_name!r}: {exc.problem}") from None
    lattice_n = data.get("lattice_n", 50)
    if isinstance(lattice_n, bool) or not isinstance(lattice_n, int) or not 5 <= lattice_n <= 400:
        raise InputError(source, f"field lattice_n = {lattice_n!r} must be a whole number from 5 to 400")

    corners = _corners(source, data)
    xy = np.array([[c.x_um, c.y_um] for c in corners])
    _check_units(source, xy)
    _check_corner_scale(source, xy)
    try:
        _validate_corners(corners, f"{source}: field corners")
    except InputError as exc:
        raise InputError(source, f"field corners: {exc.problem}") from None
    cal = Calibration(*corners)
    _check_affine(source, cal, xy)

    safety = _table(source, data, "safety", _SAFETY)
    dz = check_positive(source, "safety.dz_safe_um", safety.get("dz_safe_um", 5.0))
    r_excl = check_positive(source, "safety.r_excl_um", safety.get("r_excl_um", 20.0), allow_zero=True)
    band = check_positive(source, "safety.edge_band_um", safety.get("edge_band_um", 25.0), allow_zero=True)
    if dz < _MIN_DZ_SAFE_UM:
        raise InputError(source, f"field safety.dz_safe_um = {dz:g} looks like mm, but it is in µm")
    if 0 < r_excl < _MIN_R_EXCL_UM:
        raise InputError(source, f"field safety.r_excl_um = {r_excl:g} looks like mm, but it is in µm")
    rect_raw = safety.get("stage_rect_um", list(UNLIMITED_STAGE_UM))
    x_min, y_min, x_max, y_max = _point(source, "safety.stage_rect_um", rect_raw, 4)
    if not (x_min < x_max and y_min < y_max):
        raise InputError(
            source, "field safety.stage_rect_um must be [x_min, y_min, x_max, y_max] with min < max"
        )
    outside = [
        n
        for n, (x, y) in zip(CORNER_NAMES, xy, strict=True)
        if not (x_min <= x <= x_max and y_min <= y <= y_max)
    ]
    if outside:
        scaled = all(x_min * 1000 <= x <= x_max * 1000 and y_min * 1000 <= y <= y_max * 1000 for x, y in xy)
        hint = " (the rectangle looks like mm; it is in µm)" if scaled else ""
        raise InputError(
            source,
            f"field safety.stage_rect_um: corner(s) {', '.join(outside)} lie outside the stage's safe travel{hint}",
        )
    bx0, bx1, by0, by1 = cal.bounds_um
    if band > 0 and band < 1.0 and max(bx1 - bx0, by1 - by0) > 100 * _MIN_SPAN_UM:
        raise InputError(source, f"field safety.edge_band_um = {band:g} looks like mm, but it is in µm")

    tilt = _tilt_um_per_mm(cal)
    if tilt > profile.max_tilt_um_per_mm:
        raise InputError(
            source,
            f"field corners: the z values imply a tilt of {tilt:.1f} µm/mm, more than profile {profile.name} "
            f"allows ({profile.max_tilt_um_per_mm:g} µm/mm); check the z readings (µm) or remount the sample",
        )

    raw_excl = data.get("exclusions", [])
    if not isinstance(raw_excl, list):
        raise InputError(source, "field exclusions must be a list of [[exclusions]] tables")
    exclusions = tuple(_exclusion(source, i, e, cal) for i, e in enumerate(raw_excl))

    earlier_table = _table(source, data, "earlier", _EARLIER)
    earlier = _earlier(source, earlier_table, base_dir)
    if mm_typed(earlier, cal.bounds_um):
        raise InputError(
            source, "field earlier: the earlier indents look like mm, but stage coordinates are µm"
        )

    sample = Sample(
        name=name.strip(),
        profile=profile_name,
        calibration=cal,
        lattice_n=int(lattice_n),
        dz_safe_um=dz,
        r_excl_um=r_excl,
        edge_band_um=band,
        stage_rect_um=(x_min, y_min, x_max, y_max),
        exclusions=exclusions,
        earlier_indents_um=tuple(earlier),
        source=str(data.get("source", source)),
    )
    _check_room(source, sample)
    return sample


def _check_room(source: str, sample: Sample) -> None:
    """Refuse a sample where nothing can be indented: exclusions, edge band or earlier indents cover it all."""
    try:
        lattice = CandidateLattice.build(sample.calibration, sample.lattice_n, grid_halfwidth_um=0.0)
    except InputError as exc:
        raise InputError(source, f"field corners: {exc.problem}") from None
    if sample.allowed(lattice.xy_um).any():
        return
    if len(sample.earlier_indents_um) and replace(sample, earlier_indents_um=()).allowed(lattice.xy_um).any():
        raise InputError(source, "field earlier: earlier indents leave no candidate centre on the sample")
    raise InputError(
        source,
        "field exclusions: the exclusion regions and the edge band cover the whole area (no candidate "
        "centre is left)",
    )


def check_avoided_centres(sample: Sample, centres_um: Sequence[Sequence[float]], source: str = "") -> None:
    """``planner.avoid_centers_um`` typed in mm: refused by the rule the sample's own coordinates follow."""
    if mm_typed(centres_um, sample.calibration.bounds_um):
        shown = ", ".join(f"({x:g}, {y:g})" for x, y in list(centres_um)[:3])
        field = "field planner.avoid_centers_um"
        raise InputError(
            source or field,
            (f"{field} = " if source else "")
            + f"[{shown}{', ...' if len(centres_um) > 3 else ''}] lie far off sample {sample.name!r} but on it when "
            "read as mm: these look like mm, but stage coordinates are µm (multiply by 1000)",
        )


def load_sample(path: str | Path) -> Sample:
    """Read and validate a sample file; relative paths inside it are relative to the file."""
    p = Path(path)
    src = str(p)
    try:
        text = p.read_text(encoding="utf-8-sig")  # a byte-order mark (Windows editors) is not TOML's concern
    except FileNotFoundError:
        raise InputError(src, "no such sample file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(src, f"cannot read the sample file ({exc})") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(src, f"not valid TOML ({exc})") from None
    data.pop("source", None)
    data["source"] = str(p.resolve())
    return parse_sample(data, src, base_dir=p.parent)


def sample_from_dict(data: Mapping[str, Any], source: str = "sample") -> Sample:
    """Rebuild (and re-validate) a Sample from ``Sample.to_dict`` output or a parsed sample file."""
    return parse_sample(dict(data), source)

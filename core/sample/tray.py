"""A tray: several samples on the stage at once (libraries and a reference block), read from ``tray.toml``.

A lab loads the instrument's tray and leaves for the night; one run indents every sample. Each sample is a
sample file (``aeni sample new``) placed on the stage (``offset_um`` shifts the file's stage coordinates, so
one file serves a sample mounted anywhere), with a goal (``rel_sd_pct``, ``budget_s`` or ``indents``), a
priority and a role: a ``library`` to map, or a ``reference`` block whose known hardness checks the tip.

:func:`tray_problems` lists everything wrong with a tray, one line per problem (``aeni tray check`` prints
them and exits 2); :func:`parse_tray` refuses a tray with any. The sim driver's built-in samples (a library
that names a ``scenario`` and no file) are resolved by the application (core never sees a driver):
:meth:`Tray.resolved`.
"""

from __future__ import annotations

import itertools
import math
import tomllib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from core.errors import InputError
from core.geometry import Calibration, polygon_meets_polygon
from core.sample.load import load_sample, sample_from_dict
from core.sample.model import Sample

ROLES = ("library", "reference")
GOALS = ("rel_sd_pct", "budget_s", "indents")
# The stage's safe travel, x_min, y_min, x_max, y_max (µm): 100 mm × 100 mm, the usual XY range of an iMicro
# class stage. An assumption to check against the instrument's own limits (set [stage] rect_um).
DEFAULT_STAGE_RECT_UM = (0.0, 0.0, 100_000.0, 100_000.0)
DEFAULT_TOLERANCE_PCT = 5.0
DEFAULT_CHECK_EVERY_H = 4.0


@dataclass(frozen=True)
class ReferenceMaterial:
    """A reference block's nominal properties (what a good tip reads on it)."""

    hardness_gpa: float
    modulus_gpa: float
    source: str


# Fused silica, the customary tip-calibration block: E = 72 GPa (ν = 0.17), Oliver & Pharr, J. Mater. Res. 7
# (1992) 1564, Table I; H ≈ 9 GPa at the depths a Berkovich calibration uses (the same paper's fused-silica
# hardness, and the value ISO 14577-4 reference blocks are certified near). A block's own certificate wins:
# set hardness_gpa / modulus_gpa in the tray file.
REFERENCE_MATERIALS: dict[str, ReferenceMaterial] = {
    "fused-silica": ReferenceMaterial(9.0, 72.0, "Oliver & Pharr 1992 (J. Mater. Res. 7, 1564); ISO 14577-4"),
}


@dataclass(frozen=True)
class Goal:
    """When a library is done: its map's relative epistemic sd (p95) below ``value`` %, or ``value``
    instrument seconds spent on it, or ``value`` indents made on it."""

    kind: str  # rel_sd_pct | budget_s | indents
    value: float


@dataclass(frozen=True)
class Reference:
    """What a reference sample checks: its hardness must stay within ``tolerance_pct`` of the nominal."""

    material: str
    hardness_gpa: float
    modulus_gpa: float
    tolerance_pct: float = DEFAULT_TOLERANCE_PCT
    check_every_h: float = DEFAULT_CHECK_EVERY_H


@dataclass(frozen=True)
class TraySample:
    """One sample on the tray, placed (its coordinates are the stage's)."""

    name: str
    role: str  # library | reference
    sample: Sample | None  # None: the sim driver's built-in sample for ``sim`` (Tray.resolved places it)
    offset_um: tuple[float, float] = (0.0, 0.0)
    goal: Goal | None = None
    priority: float = 1.0
    reference: Reference | None = None
    sim: dict[str, Any] = field(default_factory=dict)  # the sim driver's options: scenario or truth_csv

    @property
    def placed(self) -> Sample:
        if self.sample is None:
            raise InputError(f"tray sample {self.name!r}", "not resolved (no sample file and no driver)")
        return self.sample

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "role": self.role,
            "sample": None if self.sample is None else self.sample.to_dict(),
            "offset_um": list(self.offset_um),
            "goal": None if self.goal is None else {self.goal.kind: self.goal.value},
            "priority": self.priority,
            "reference": None if self.reference is None else vars(self.reference).copy(),
            "sim": dict(self.sim),
        }


@dataclass(frozen=True)
class Tray:
    name: str
    samples: tuple[TraySample, ...]
    stage_rect_um: tuple[float, float, float, float] = DEFAULT_STAGE_RECT_UM
    source: str = "tray"

    @property
    def libraries(self) -> tuple[TraySample, ...]:
        return tuple(s for s in self.samples if s.role == "library")

    @property
    def reference(self) -> TraySample | None:
        return next((s for s in self.samples if s.role == "reference"), None)

    def by_name(self, name: str) -> TraySample:
        for s in self.samples:
            if s.name == name:
                return s
        raise KeyError(name)

    def resolved(self, builtin: Callable[[TraySample], Sample]) -> Tray:
        """The tray with every sample that has no file placed from ``builtin`` (the sim driver's own)."""
        out = []
        for s in self.samples:
            if s.sample is None:
                s = replace(s, sample=placed_sample(builtin(s), s.offset_um, self.stage_rect_um))
            out.append(s)
        return replace(self, samples=tuple(out))

    def sample_at(self, x_um: float, y_um: float) -> TraySample | None:
        """The sample whose outline holds the stage point (samples never overlap), or None."""
        for s in self.samples:
            if s.sample is not None and bool(s.sample.calibration.contains_stage(x_um, y_um)):
                return s
        return None

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "stage_rect_um": list(self.stage_rect_um),
            "samples": [s.to_dict() for s in self.samples],
            "source": self.source,
        }


def tray_from_dict(data: Mapping[str, Any], source: str = "journal tray") -> Tray:
    """Rebuild a Tray from :meth:`Tray.to_dict` (a run spec, a journal)."""
    samples = []
    for d in data["samples"]:
        ref = d.get("reference")
        goal = [(str(k), float(v)) for k, v in (d.get("goal") or {}).items()]
        samples.append(
            TraySample(
                name=str(d["name"]),
                role=str(d["role"]),
                sample=None if d.get("sample") is None else sample_from_dict(d["sample"], source),
                offset_um=(float(d["offset_um"][0]), float(d["offset_um"][1])),
                goal=Goal(*goal[0]) if goal else None,
                priority=float(d.get("priority", 1.0)),
                reference=None if ref is None else Reference(**ref),
                sim=dict(d.get("sim") or {}),
            )
        )
    x0, y0, x1, y1 = (float(v) for v in data["stage_rect_um"])
    return Tray(str(data["name"]), tuple(samples), (x0, y0, x1, y1), str(data.get("source", source)))


# -- placing a sample ----------------------------------------------------------------------------------
def placed_sample(
    sample: Sample, offset_um: tuple[float, float], stage_rect_um: tuple[float, float, float, float]
) -> Sample:
    """``sample`` moved by ``offset_um`` on the stage (corners, exclusions, earlier indents) within the tray's
    safe travel; re-validated as a sample file is."""
    dx, dy = offset_um
    d = sample.to_dict()
    for corner in d["corners"].values():
        corner["x_um"] += dx
        corner["y_um"] += dy
    for e in d["exclusions"]:
        if "circle_um" in e:
            x, y, r = e["circle_um"]
            e["circle_um"] = [x + dx, y + dy, r]
        else:
            e["polygon_um"] = [[x + dx, y + dy] for x, y in e["polygon_um"]]
    d["earlier"]["indents_um"] = [[x + dx, y + dy] for x, y in d["earlier"]["indents_um"]]
    # a sample off the tray's stage still reads (widened to hold it): layout_problems says it is off
    xs = [c["x_um"] for c in d["corners"].values()]
    ys = [c["y_um"] for c in d["corners"].values()]
    x0, y0, x1, y1 = stage_rect_um
    d["safety"]["stage_rect_um"] = [min(x0, *xs), min(y0, *ys), max(x1, *xs), max(y1, *ys)]
    return sample_from_dict(d, f"sample {sample.name!r} placed at offset ({dx:g}, {dy:g}) µm")


def block_sample(name: str, profile: str, x0_um: float, y0_um: float, w_um: float, h_um: float) -> Sample:
    """A flat rectangular sample (a reference block given by its size instead of a sample file)."""
    return Sample(name, profile, Calibration.rectangle(x0_um, y0_um, w_um, h_um), lattice_n=20)


# -- reading tray.toml ---------------------------------------------------------------------------------
_TOP = ("name", "profile", "stage", "samples")
_ENTRY = (
    "name", "role", "file", "size_um", "offset_um", "goal", "priority", "material", "hardness_gpa",
    "modulus_gpa", "tolerance_pct", "check_every_h", "scenario", "truth_csv",
)  # fmt: skip


def _number(where: str, key: str, value: Any, problems: list[str], *, positive: bool = True) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        problems.append(f"{where}: field {key} must be a number, got {value!r}")
        return None
    if positive and value <= 0:
        problems.append(f"{where}: field {key} must be > 0, got {value!r}")
        return None
    return float(value)


def _pair(where: str, key: str, value: Any, problems: list[str]) -> tuple[float, float] | None:
    if not isinstance(value, list) or len(value) != 2:
        problems.append(f"{where}: field {key} must be [x, y] in µm, got {value!r}")
        return None
    x, y = (_number(where, key, v, problems, positive=False) for v in value)
    return None if x is None or y is None else (x, y)


def _entry(
    i: int, d: Any, profile: str, stage: tuple[float, float, float, float], base: Path, problems: list[str]
) -> TraySample | None:
    if not isinstance(d, Mapping):
        problems.append(f"samples[{i}]: must be a [[samples]] table")
        return None
    name = d.get("name")
    where = f"sample {name!r}" if isinstance(name, str) and name.strip() else f"samples[{i}]"
    n0 = len(problems)
    if not isinstance(name, str) or not name.strip():
        problems.append(f"{where}: field name is missing (give every sample a name)")
    for key in d:
        if key not in _ENTRY:
            problems.append(f"{where}: unknown field {key!r} (allowed: {', '.join(_ENTRY)})")
    role = d.get("role", "library")
    if role not in ROLES:
        problems.append(f"{where}: field role = {role!r} is not allowed: library or reference")
    offset = _pair(where, "offset_um", d.get("offset_um", [0.0, 0.0]), problems) or (0.0, 0.0)
    priority = _number(where, "priority", d.get("priority", 1.0), problems) or 1.0
    sim = {k: str(d[k]) for k in ("scenario", "truth_csv") if k in d}
    if "truth_csv" in sim and not Path(sim["truth_csv"]).is_absolute():
        sim["truth_csv"] = str((base / sim["truth_csv"]).resolve())
    sample: Sample | None = None
    if "file" in d:
        try:
            sample = placed_sample(load_sample(base / str(d["file"])), offset, stage)
        except InputError as exc:
            problems.append(f"{where}: {exc}")
    elif "size_um" in d:
        size = _pair(where, "size_um", d["size_um"], problems)
        if size is not None and min(size) > 0:
            try:
                sample = placed_sample(block_sample(str(name), profile, 0.0, 0.0, *size), offset, stage)
            except InputError as exc:
                problems.append(f"{where}: {exc}")
    elif not sim:
        problems.append(
            f"{where}: no sample: give file = a sample file, size_um = [w, h] (a flat block) or, with the "
            "sim driver, scenario = a scenario name"
        )
    goal: Goal | None = None
    reference: Reference | None = None
    if role == "library":
        g = d.get("goal")
        if g is None:
            problems.append(
                f"{where}: no goal: give goal = {{ rel_sd_pct = 5 }}, {{ budget_s = ... }} or {{ indents = ... }}"
            )
        elif not isinstance(g, Mapping) or len(g) != 1 or next(iter(g)) not in GOALS:
            problems.append(f"{where}: field goal = {g!r} must name one of {', '.join(GOALS)}")
        else:
            (kind, value), *_ = g.items()
            v = _number(where, f"goal.{kind}", value, problems)
            if v is not None:
                goal = Goal(str(kind), v)
    elif role == "reference":
        material = str(d.get("material", "fused-silica"))
        nominal = REFERENCE_MATERIALS.get(material)
        h = d.get("hardness_gpa", nominal.hardness_gpa if nominal else None)
        e = d.get("modulus_gpa", nominal.modulus_gpa if nominal else None)
        if h is None or e is None:
            problems.append(
                f"{where}: material {material!r} has no nominal values here "
                f"(known: {', '.join(REFERENCE_MATERIALS)}): give hardness_gpa and modulus_gpa"
            )
        else:
            hv = _number(where, "hardness_gpa", h, problems)
            ev = _number(where, "modulus_gpa", e, problems)
            tol = _number(where, "tolerance_pct", d.get("tolerance_pct", DEFAULT_TOLERANCE_PCT), problems)
            every = _number(where, "check_every_h", d.get("check_every_h", DEFAULT_CHECK_EVERY_H), problems)
            if None not in (hv, ev, tol, every):
                reference = Reference(material, hv, ev, tol, every)  # type: ignore[arg-type]
    if len(problems) > n0:
        return None
    return TraySample(str(name).strip(), str(role), sample, offset, goal, priority, reference, sim)


def read_tray(path: str | Path) -> tuple[Tray | None, list[str]]:
    """The tray in ``path`` and every problem found reading it (one line each; an empty list: none)."""
    p = Path(path)
    src = str(p)
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8-sig"))
    except FileNotFoundError:
        return None, [f"{src}: no such tray file"]
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        return None, [f"{src}: cannot read the tray file ({exc})"]
    problems: list[str] = []
    for key in data:
        if key not in _TOP:
            problems.append(f"unknown field {key!r} (allowed: {', '.join(_TOP)})")
    profile = str(data.get("profile", "kla-imicro"))
    stage = DEFAULT_STAGE_RECT_UM
    rect = (data.get("stage") or {}).get("rect_um")
    if rect is not None:
        if not isinstance(rect, list) or len(rect) != 4 or not all(isinstance(v, int | float) for v in rect):
            problems.append(f"field stage.rect_um = {rect!r} must be [x_min, y_min, x_max, y_max] in µm")
        elif not (rect[0] < rect[2] and rect[1] < rect[3]):
            problems.append("field stage.rect_um must have min < max")
        else:
            stage = (float(rect[0]), float(rect[1]), float(rect[2]), float(rect[3]))
    raw = data.get("samples")
    if not isinstance(raw, list) or not raw:
        problems.append("no samples: add [[samples]] tables")
        raw = []
    entries = [e for i, d in enumerate(raw) if (e := _entry(i, d, profile, stage, p.parent, problems))]
    tray = Tray(str(data.get("name", p.stem)), tuple(entries), stage, str(p.resolve()))
    declared = tuple(str(d.get("role", "library")) for d in raw if isinstance(d, Mapping))
    problems.extend(layout_problems(tray, declared))
    return tray, [f"{src}: {x}" for x in problems]


def layout_problems(tray: Tray, declared: tuple[str, ...] = ()) -> list[str]:
    """What is wrong with the tray as a whole: repeated names, no library, more than one reference, a sample
    off the stage, samples that overlap (for the samples placed so far). ``declared``: the roles the file
    gives, entries with problems included (a library with a bad file is not "no library")."""
    out: list[str] = []
    names = [s.name for s in tray.samples]
    out += [f"sample {n!r}: the name is used twice" for n in sorted({n for n in names if names.count(n) > 1})]
    if not any(s.role == "library" for s in tray.samples) and not (set(declared) & {"library"}):
        out.append("no library: a tray needs at least one sample with role = library")
    if sum(s.role == "reference" for s in tray.samples) > 1:
        out.append("more than one reference: a tray checks its tip on one reference sample")
    placed = [s for s in tray.samples if s.sample is not None]
    x0, y0, x1, y1 = tray.stage_rect_um
    for s in placed:
        off = [
            n for n, c in zip(("TL", "TR", "BR", "BL"), s.placed.calibration.corners, strict=True)
            if not (x0 <= c.x_um <= x1 and y0 <= c.y_um <= y1)
        ]  # fmt: skip
        if off:
            out.append(f"sample {s.name!r}: off the stage (corner(s) {', '.join(off)} outside stage.rect_um)")
    for i, a in enumerate(placed):
        for b in placed[i + 1 :]:
            if polygon_meets_polygon(_outline(a.placed), _outline(b.placed)):
                out.append(f"samples {a.name!r} and {b.name!r} overlap (move one with offset_um)")
    return out


def _outline(sample: Sample) -> list[tuple[float, float]]:
    return [(c.x_um, c.y_um) for c in sample.calibration.corners]


def parse_tray(path: str | Path) -> Tray:
    """The tray in ``path``; any problem is an InputError (the first; ``aeni tray check`` lists them all)."""
    tray, problems = read_tray(path)
    if problems or tray is None:
        first = problems[0] if problems else f"{path}: not a tray"
        src, _, what = first.partition(": ")
        more = f" (and {len(problems) - 1} more: aeni tray check {path})" if len(problems) > 1 else ""
        raise InputError(src, what + more)
    return tray


TRAY_TEMPLATE = """\
# A tray: several samples on the stage, indented in one run (aeni tray check FILE validates and draws it;
# aeni run --tray FILE runs it). Every coordinate is in stage µm.
name = "overnight-tray"
profile = "kla-imicro"          # the profile of a reference given by its size (a sample file names its own)

[stage]
rect_um = [0.0, 0.0, 100000.0, 100000.0]   # the stage's safe travel: x_min, y_min, x_max, y_max

# One [[samples]] table per sample. A sample is a sample file (aeni sample new) placed with offset_um
# (added to the file's stage coordinates; [0, 0]: where the file says). With --driver sim a library may
# name a scenario (aeni scenarios) or a truth CSV instead of a file: the scenario's own sample, placed.
[[samples]]
name = "ternary-A"
role = "library"                # library: mapped to its goal
# file = "ternary-A.toml"       # the sample file (relative to this file): what a real run needs
scenario = "ternary"            # --driver sim: the truth it plays and its sample (or truth_csv = "truth.csv")
offset_um = [0.0, 0.0]
goal = { rel_sd_pct = 6.0 }     # one of: rel_sd_pct (map's p95 relative sd, %), budget_s, indents
priority = 1.0                  # > 1: this library's information counts more

[[samples]]
name = "film-B"
role = "library"
# file = "film-B.toml"
scenario = "film"               # the film scenario's sample sits at stage (10, 20) mm already
offset_um = [0.0, 0.0]
goal = { budget_s = 36000 }     # ten hours of instrument time on this sample
priority = 1.0

[[samples]]
name = "fused-silica"
role = "reference"              # indented before the first library, every check_every_h and after the last
material = "fused-silica"       # nominal H 9 GPa, E 72 GPa (Oliver & Pharr 1992); a certificate's values win:
# hardness_gpa = 9.0
# modulus_gpa = 72.0
size_um = [5000.0, 5000.0]      # a flat block given by its size (or file = "silica.toml")
offset_um = [30000.0, 30000.0]  # where its bottom-left corner sits
tolerance_pct = 5.0             # the tip is worn or dirty when the reference reads further off than this
check_every_h = 4.0             # hours of instrument time between two checks
"""


def visit_order(tray: Tray) -> list[TraySample]:
    """The order a tray's samples are first visited: the reference, the libraries by priority (highest first,
    then as listed), the reference again."""
    libs = sorted(tray.libraries, key=lambda s: -s.priority)
    ref = [tray.reference] if tray.reference is not None else []
    return [*ref, *libs, *ref]


def centre_um(sample: Sample) -> tuple[float, float]:
    x0, x1, y0, y1 = sample.calibration.bounds_um
    return ((x0 + x1) / 2.0, (y0 + y1) / 2.0)


def draw_tray(tray: Tray, width: int = 72, height: int = 24) -> str:
    """The tray as text, zoomed on its samples (within the stage's safe travel): each sample's outline as its
    letter (A, B, ... as listed), the moves between first visits as dots; y up."""
    placed = [s.sample for s in tray.samples if s.sample is not None]
    sx0, sy0, sx1, sy1 = tray.stage_rect_um
    if placed:
        xs = [v for p in placed for v in p.calibration.bounds_um[:2]]
        ys = [v for p in placed for v in p.calibration.bounds_um[2:]]
        pad = 0.08 * max(max(xs) - min(xs), max(ys) - min(ys), 1.0)
        sx0, sx1 = max(sx0, min(xs) - pad), min(sx1, max(xs) + pad)
        sy0, sy1 = max(sy0, min(ys) - pad), min(sy1, max(ys) + pad)
    grid = [[" "] * width for _ in range(height)]

    def cell(x: float, y: float) -> tuple[int, int]:
        col = min(width - 1, max(0, int((x - sx0) / (sx1 - sx0) * (width - 1) + 0.5)))
        row = min(height - 1, max(0, int((sy1 - y) / (sy1 - sy0) * (height - 1) + 0.5)))
        return row, col

    order = [s for s in visit_order(tray) if s.sample is not None]
    for a, b in itertools.pairwise(order):
        (ax, ay), (bx, by) = centre_um(a.placed), centre_um(b.placed)
        for t in np.linspace(0.0, 1.0, 2 * (width + height)):
            r, c = cell(ax + t * (bx - ax), ay + t * (by - ay))
            grid[r][c] = "."
    for k, s in enumerate(tray.samples):
        if s.sample is None:
            continue
        bx0, bx1, by0, by1 = s.sample.calibration.bounds_um
        r0, c0 = cell(bx0, by1)
        r1, c1 = cell(bx1, by0)
        for r in range(r0, r1 + 1):
            for c in range(c0, c1 + 1):
                if r in (r0, r1) or c in (c0, c1):
                    grid[r][c] = chr(ord("A") + k)
    frame = "+" + "-" * width + "+"
    rows = [frame, *("|" + "".join(r) + "|" for r in grid), frame]
    rows.append(f"stage x {sx0:,.0f} … {sx1:,.0f} µm (left to right), y {sy0:,.0f} … {sy1:,.0f} µm (up)")
    return "\n".join(rows)

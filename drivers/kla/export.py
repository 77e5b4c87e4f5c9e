"""Read KLA/Agilent nanoindenter exports (InView .xlsx, NanoSuite .xls) into tidy indent records.

Both programs write one workbook per sample: a ``Results`` sheet with one row per test (plus a units row
under the header and summary rows at the bottom) and one ``Test N`` sheet per test with the raw curve.
Column names drift between templates and versions, so every column is found through an alias table
(case-insensitive, whitespace- and underscore-normalised) and every value is converted with the units
row to µm / GPa / nm/s / mN / nm. NanoSuite marks invalid samples with 1.797e308; those become missing.

Where the hardness comes from (``KlaIndent.source``):

* ``"results"``: the Results sheet has a hardness column (Example.xls: "H Average Over Defined Range").
* ``"curve"``: it does not (the InView template of FusedSilica.xlsx has only Pmax, target load and
  position), so hardness is derived from the test's own sheet. If that sheet carries a CSM "Hardness"
  channel, its average over the file's "Minimum/Maximum Calculation Depth" is used; on Example.xls this
  reproduces NanoSuite's own Results values to 0.1 %. Otherwise (FusedSilica.xlsx: only Time, Load,
  Depth) the Oliver-Pharr method runs on the final unload; see ``_oliver_pharr`` for why the surface is
  re-found and how the frame compliance is obtained. On FusedSilica.xlsx this gives H ≈ 9.1 GPa and
  E ≈ 69 GPa (handbook: ~9 and 72); the instrument's own cycle analysis in that file reads 6.5 / 49.

Drift: ``drift_rate_nm_s`` comes from the Results sheet only. The curves are exported already drift-
corrected (InView's drift-hold segment is flat to 1e-14 nm/s), and what slope remains in a NanoSuite
drift hold is creep recovery, so neither is re-measured nor re-applied.
"""

from __future__ import annotations

import csv
import io
import math
import re
import warnings
from collections.abc import Iterable, Mapping
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any, cast

import numpy as np
import openpyxl
import pandas as pd
from openpyxl.worksheet._read_only import ReadOnlyWorksheet
from scipy.optimize import curve_fit

from core.errors import InputError

NO_POSITIONS = "no positions in the export"
INVALID_THRESHOLD = 1.0e307  # NanoSuite writes DBL_MAX (1.797e308) for "no value"
BERKOVICH_C0 = 24.5  # ideal Berkovich projected area A = 24.5 hc² (nm²)
EPSILON_BERKOVICH = 0.75  # Oliver-Pharr geometry factor for a paraboloid of revolution
DIAMOND_E_GPA = 1141.0
DIAMOND_NU = 0.07
DEFAULT_POISSON = 0.25  # only when the file does not state the sample's Poisson ratio

SOFTWARE_INVIEW = "InView"
SOFTWARE_NANOSUITE = "NanoSuite"
SOFTWARE_TESTWORKS = "TestWorks"
SOFTWARE_HYSITRON = "Hysitron"
SOFTWARE_ANTON_PAAR = "Anton Paar"
SOFTWARE_MICRO_MATERIALS = "Micro Materials"
SOFTWARE_FISCHERSCOPE = "Fischerscope"
SOFTWARE_UNKNOWN = "unknown"

_XLSX_MAGIC = b"PK\x03\x04"
_XLS_MAGIC = b"\xd0\xcf\x11\xe0\xa1\xb1\x1a\xe1"


@dataclass(frozen=True)
class KlaIndent:
    """One test of a KLA export; ``None`` where the file does not say (or says "invalid")."""

    test_id: str
    x_um: float | None
    y_um: float | None
    hardness_gpa: float | None
    modulus_gpa: float | None
    drift_rate_nm_s: float | None
    max_load_mn: float | None
    max_depth_nm: float | None
    source: str  # "results" or "curve"
    # why this indent has no usable hardness (blank, "--", 1.797e308, zero/negative/impossible value);
    # None for a measured indent. A failed indent never carries a hardness number.
    failure: str | None = None

    @property
    def failed(self) -> bool:
        return self.failure is not None


@dataclass(frozen=True)
class KlaExport:
    path: str
    software: str  # the format recognised: InView, NanoSuite, TestWorks, Hysitron, Anton Paar ... or unknown
    indents: tuple[KlaIndent, ...]
    warnings: tuple[str, ...] = ()
    # the depth range (nm) the hardness column says it was averaged over, e.g. "Avg Hardness [75-85 nm]"
    hardness_range_nm: tuple[float, float] | None = None
    hardness_column: str = ""  # the column the hardness came from ("load-depth curve" when derived)

    @property
    def has_positions(self) -> bool:
        return any(i.x_um is not None and i.y_um is not None for i in self.indents)

    @property
    def summary(self) -> str:
        """One line for logs and the manifest: the format, the tests, where hardness came from."""
        where = f", hardness from {self.hardness_column!r}" if self.hardness_column else ""
        xy = "" if self.has_positions else ", no positions"
        return f"{Path(self.path).name}: format {self.software}, {len(self.indents)} tests{where}{xy}"

    def to_frame(self) -> pd.DataFrame:
        columns = [f.name for f in fields(KlaIndent)]
        frame = pd.DataFrame([asdict(i) for i in self.indents], columns=columns)
        numeric = [c for c in columns if c not in ("test_id", "source", "failure")]
        frame[numeric] = frame[numeric].astype(float)
        return frame


# --------------------------------------------------------------------------------------------- aliases


def _norm(text: object) -> str:
    """Header key: lower case, underscores and runs of whitespace collapse to one space, no apostrophes."""
    s = str(text).replace("_", " ").replace("\u00a0", " ").replace("'", "").replace("\u2019", "")
    return " ".join(s.split()).lower()


_RESULT_ALIASES: dict[str, tuple[str, ...]] = {
    "test_id": (
        "test",
        "test #",
        "test number",
        "test no",
        "test no.",
        "test id",
        "test name",
        "indent",
        "indent #",
        "indent number",
        "indent no",
        "indent no.",
        "indent id",
        "indentation",
        "point",
        "point #",
        "#",
        "no.",
        "nr.",
        "nr",
    ),
    "x_um": ("x position", "x", "x test position", "x pos", "x axis position"),
    "y_um": ("y position", "y", "y test position", "y pos", "y axis position"),
    "hardness_gpa": (
        "hardness",
        "h-it",
        "hit",
        "h it",
        "h average over defined range",
        "hardness average over defined range",
        "avg hardness",
        "average hardness",
        "mean hardness",
        "hardness avg",
        "hardness average",
        "hardness mean",
        "hardness at max load",
        "h at max load",
        "avg h",
        "average h",
        "mean h",
        "h avg",
        "h average",
        "h mean",
        "h avg over defined range",
        "h average over range",
    ),
    "modulus_gpa": (
        "modulus",
        "e-it",
        "eit",
        "e it",
        "e average over defined range",
        "modulus average over defined range",
        "avg modulus",
        "average modulus",
        "mean modulus",
        "modulus avg",
        "modulus average",
        "modulus mean",
        "modulus at max load",
        "e at max load",
        "avg e",
        "average e",
        "mean e",
        "e avg",
        "e average",
        "e mean",
        "e avg over defined range",
        "e average over range",
    ),
    "drift_rate_nm_s": ("drift rate", "drift correction"),
    # "Maximum Displacement" and "Target Load" are the programmed limits, not measurements: not aliased.
    "max_load_mn": (
        "pmax",
        "p max",
        "max load",
        "maximum load",
        "load at max load",
        "peak load",
        "fmax",
        "f max",
        "max force",
        "maximum force",
    ),
    "max_depth_nm": (
        "hmax",
        "h max",
        "max depth",
        "maximum depth",
        "depth at max load",
        "displacement at max load",
    ),
}
_CURVE_ALIASES: dict[str, tuple[str, ...]] = {
    "depth": ("depth", "displacement into surface", "displacement"),
    "load": ("load", "load on sample", "force"),
    "time": ("time", "time on sample"),
    "hardness": _RESULT_ALIASES["hardness_gpa"],
    "modulus": _RESULT_ALIASES["modulus_gpa"],
    "marker": ("markers", "marker", "segment"),
}
_INPUT_ALIASES: dict[str, tuple[str, ...]] = {
    "x_um": _RESULT_ALIASES["x_um"],
    "y_um": _RESULT_ALIASES["y_um"],
    "poisson": ("poissons ratio of sample", "poissons ratio", "poisson ratio", "sample poissons ratio"),
    "min_calc_depth": ("minimum calculation depth", "min calculation depth"),
    "max_calc_depth": ("maximum calculation depth", "max calculation depth"),
}
_SUMMARY_LABELS = frozenset(
    {
        "average",
        "mean",
        "median",
        "standard deviation",
        "std dev",
        "std. dev.",
        "std",
        "stdev",
        "coefficient of variation",
        "cov",
        "% cov",
        "%cov",
        "cv",
        "minimum",
        "maximum",
        "min",
        "max",
        "min.",
        "max.",
        "range",
        "count",
        "sum",
        "total",
        "variance",
        "sd",
        "s.d.",
        "std. deviation",
        "std deviation",
        "standard dev",
        "standard dev.",
        "std. dev",
        "std dev.",
        "mean value",
        "average value",
        "avg",
        "avg.",
        "statistics",
        "summary",
        "valid tests",
    }
)
# a per-cycle row of a multi-cycle test: "1-1", "1:2", "3.5" written as text, "Test 1 Cycle 2"
_CYCLE_LABEL = re.compile(
    r"^\s*(?:test\s*)?#?\s*\d+\s*(?:[-:/_]\s*\d+|\.[1-9]\d*|\s+cycle\s*\d+)\s*$", re.IGNORECASE
)
_AREA_COEFF = re.compile(r"^area coefficient\s*(\d+)$")
# "Test 004", and curve sheets some InView templates suffix: "Test 004 Tagged", "Test 4 (2)"
_TEST_SHEET = re.compile(r"^\s*test\s*#?\s*(\d+)(?:[\s_\-(].*)?$", re.IGNORECASE)
_HEADER_UNIT = re.compile(r"^(.*?)\s*[\(\[]([^\)\]]*)[\)\]]\s*$")
# an averaging range carried in a header: "Avg Hardness [75-85 nm]", "H (100 to 200 nm) GPa"
_HEADER_RANGE = re.compile(
    r"[\(\[]?\s*(\d+(?:\.\d+)?)\s*(?:-|–|—|to|\.\.)\s*(\d+(?:\.\d+)?)\s*(nm|µm|μm|um)\s*[\)\]]?",
    re.IGNORECASE,
)
# values no material has: hardness above diamond's, modulus above diamond's (GPa)
MAX_HARDNESS_GPA = 200.0
MAX_MODULUS_GPA = 1500.0

# -------------------------------------------------------------------------------------------- units

_LENGTH_NM = {"nm": 1.0, "µm": 1e3, "mm": 1e6, "cm": 1e7, "m": 1e9, "a": 0.1, "å": 0.1}
_PRESSURE_GPA = {"gpa": 1.0, "mpa": 1e-3, "kpa": 1e-6, "pa": 1e-9, "n/mm²": 1e-3, "n/mm2": 1e-3}
_SPEED_NM_S = {"nm/s": 1.0, "µm/s": 1e3, "nm/min": 1.0 / 60.0, "a/s": 0.1}
_FORCE_MN = {"mn": 1.0, "µn": 1e-3, "nn": 1e-6, "n": 1e3, "gf": 9.80665}
_STIFFNESS_MN_NM = {"n/m": 1e-6, "kn/m": 1e-3, "mn/nm": 1.0, "mn/µm": 1e-3, "µn/nm": 1e-3}

# target unit name and factor table per quantity (factor converts to the *first* unit of the name)
_QUANTITY: dict[str, tuple[str, dict[str, float], float]] = {
    "x_um": ("µm", _LENGTH_NM, 1e-3),
    "y_um": ("µm", _LENGTH_NM, 1e-3),
    "hardness_gpa": ("GPa", _PRESSURE_GPA, 1.0),
    "modulus_gpa": ("GPa", _PRESSURE_GPA, 1.0),
    "drift_rate_nm_s": ("nm/s", _SPEED_NM_S, 1.0),
    "max_load_mn": ("mN", _FORCE_MN, 1.0),
    "max_depth_nm": ("nm", _LENGTH_NM, 1.0),
    "depth": ("nm", _LENGTH_NM, 1.0),
    "load": ("mN", _FORCE_MN, 1.0),
    "time": ("s", {"s": 1.0, "ms": 1e-3, "min": 60.0}, 1.0),
    "hardness": ("GPa", _PRESSURE_GPA, 1.0),
    "modulus": ("GPa", _PRESSURE_GPA, 1.0),
    "min_calc_depth": ("nm", _LENGTH_NM, 1.0),
    "max_calc_depth": ("nm", _LENGTH_NM, 1.0),
    "stiffness": ("mN/nm", _STIFFNESS_MN_NM, 1.0),
}


def _clean_unit(unit: object) -> str:
    """'Âµm' (UTF-8 read as Latin-1), 'μm' (Greek mu) and 'um' all mean µm."""
    if unit is None or (isinstance(unit, float) and math.isnan(unit)):
        return ""
    s = str(unit).strip().replace("Âµ", "µ").replace("\u03bc", "µ").replace("Â", "")
    if len(s) >= 2 and s[0] == "u" and s[1].isalpha():
        s = "µ" + s[1:]
    return s.lower()


def _unit_factor(quantity: str, unit: object, column: str, notes: list[str]) -> float:
    """Multiplier from the column's unit to the quantity's canonical unit; unknown units are kept as-is."""
    target, table, scale = _QUANTITY[quantity]
    u = _clean_unit(unit)
    if u in ("", "none", "integer", target.lower()):
        return 1.0
    if u in table:
        return table[u] * scale
    notes.append(f"column {column!r}: unknown unit {unit!r}, read as {target}")
    return 1.0


# ------------------------------------------------------------------------------------------- tables


@dataclass(frozen=True)
class _Table:
    """One sheet split into header, units and data rows (the data still raw objects)."""

    headers: tuple[str, ...]  # as written (for messages)
    keys: tuple[str, ...]  # normalised
    units: tuple[object, ...]
    data: pd.DataFrame  # positional columns 0..n-1, only the rows below header/units
    ranges_nm: tuple[tuple[float, float] | None, ...] = ()  # averaging range named in each header

    def column(self, aliases: Iterable[str]) -> int | None:
        wanted = set(aliases)
        for i, key in enumerate(self.keys):
            if key in wanted:
                return i
        return None


def _is_number(value: object) -> bool:
    return isinstance(value, int | float | np.integer | np.floating) and not isinstance(value, bool)


def _parse_header(text: str) -> tuple[str, str | None, tuple[float, float] | None]:
    """'Avg Hardness [75-85 nm] (GPa)' -> ('Avg Hardness', 'GPa', (75.0, 85.0)): name, unit, range in nm."""
    depth_range: tuple[float, float] | None = None
    m = _HEADER_RANGE.search(text)
    if m:
        factor = _LENGTH_NM[_clean_unit(m.group(3))]
        depth_range = (float(m.group(1)) * factor, float(m.group(2)) * factor)
        text = (text[: m.start()] + " " + text[m.end() :]).strip()
    u = _HEADER_UNIT.match(text)
    if u:
        return u.group(1).strip(), u.group(2), depth_range
    return text, None, depth_range


def _looks_like_units_row(cells: list[object]) -> bool:
    """A row of short unit labels ('µm', 'GPa', 'nm/s') and blanks: no numbers, no test labels, no '--'."""
    texts = [c.strip() for c in cells if isinstance(c, str) and c.strip()]
    if not texts or any(_is_number(c) and not math.isnan(float(cast(float, c))) for c in cells):
        return False
    return all(len(t) <= 16 and not _TEST_SHEET.match(t) and t.strip("-") for t in texts)


def _split_table(raw: pd.DataFrame, header_aliases: Iterable[str]) -> _Table | None:
    """Find the header row (first of the top 30 naming a known column) and an optional units row."""
    wanted = set(header_aliases)
    header_row = None
    for r in range(min(30, len(raw))):
        if any(_norm(_parse_header(v)[0]) in wanted for v in raw.iloc[r] if isinstance(v, str)):
            header_row = r
            break
    if header_row is None:
        return None
    headers: list[str] = []
    units: list[object] = []
    ranges: list[tuple[float, float] | None] = []
    for v in raw.iloc[header_row]:
        text = "" if v is None or (isinstance(v, float) and math.isnan(v)) else str(v)
        name, unit, depth_range = _parse_header(text)
        headers.append(name)
        units.append(unit)
        ranges.append(depth_range)
    start = header_row + 1
    if start < len(raw):
        cells = list(raw.iloc[start])
        if _looks_like_units_row(cells):
            units = [cells[i] if units[i] is None else units[i] for i in range(len(cells))]
            start += 1
    data = raw.iloc[start:].reset_index(drop=True)
    data.columns = range(data.shape[1])
    return _Table(tuple(headers), tuple(_norm(h) for h in headers), tuple(units), data, tuple(ranges))


def _numeric(series: pd.Series) -> np.ndarray:
    values = np.array(pd.to_numeric(series, errors="coerce"), dtype=float)
    values[np.abs(values) >= INVALID_THRESHOLD] = np.nan
    return values


def _test_key(label: object) -> str | None:
    """'1', 1, 1.0, 'Test 001' -> '1'; other labels as written; blanks -> None."""
    if label is None or (isinstance(label, float) and math.isnan(label)):
        return None
    if _is_number(label):
        f = float(cast(float, label))
        return str(int(f)) if f.is_integer() else str(f)
    s = str(label).strip()
    if not s:
        return None
    m = _TEST_SHEET.match(s)
    if m:
        return str(int(m.group(1)))
    try:
        f = float(s)
    except ValueError:
        return s
    return str(int(f)) if f.is_integer() else s


def _finite(value: float | None) -> float | None:
    return None if value is None or not math.isfinite(value) else float(value)


# ------------------------------------------------------------------------------------------- curves


@dataclass(frozen=True)
class _Curve:
    """One Test sheet: arrays in nm / mN / s / GPa (NaN where invalid); markers map label -> row."""

    depth_nm: np.ndarray
    load_mn: np.ndarray
    time_s: np.ndarray | None
    hardness_gpa: np.ndarray | None
    modulus_gpa: np.ndarray | None
    markers: Mapping[str, int] = field(default_factory=dict)


def _parse_curve(raw: pd.DataFrame, sheet: str, notes: list[str]) -> _Curve | None:
    table = _split_table(raw, _CURVE_ALIASES["load"] + _CURVE_ALIASES["depth"])
    if table is None:
        return None
    cols = {name: table.column(aliases) for name, aliases in _CURVE_ALIASES.items()}
    if cols["load"] is None or cols["depth"] is None:
        return None

    def channel(name: str) -> np.ndarray | None:
        col = cols[name]
        if col is None:
            return None
        where = f"{sheet}: {table.headers[col]}"
        return _numeric(table.data[col]) * _unit_factor(name, table.units[col], where, notes)

    markers: dict[str, int] = {}
    if cols["marker"] is not None:
        for row, label in enumerate(table.data[cols["marker"]]):
            if isinstance(label, str) and label.strip():
                markers.setdefault(_norm(label), row)
    depth, load = channel("depth"), channel("load")
    assert depth is not None and load is not None
    return _Curve(depth, load, channel("time"), channel("hardness"), channel("modulus"), markers)


def _marker(curve: _Curve, *words: str) -> int | None:
    """Row of the first marker whose label contains all the words."""
    for label, row in curve.markers.items():
        if all(w in label for w in words):
            return row
    return None


def _find_surface(load: np.ndarray, depth: np.ndarray, clock: np.ndarray, peak: int) -> float:
    """Depth where the load starts its sustained rise, extrapolated back to zero load.

    InView's "Surface Index" in FusedSilica.xlsx sits ~80-190 nm before contact: the depth runs up at the
    approach velocity while the load is still noise (±0.5 µN). Taking that depth as zero is what makes
    the instrument's own cycle analysis read 6.5 GPa on fused silica; re-zeroing gives 8.7-9 GPa.
    On a file whose depth is already surface-referenced this returns ~0.
    """
    window = 5
    head = load[: min(6, peak + 1)]
    noise = float(np.std(head)) if head.size > 1 else 0.0
    threshold = min(max(1e-3, 5.0 * noise), 0.02 * float(load[peak]))
    above = (load[: peak + 1] > threshold).astype(int)
    if above.size < window:
        return float(depth[0])
    runs = np.flatnonzero(np.convolve(above, np.ones(window, dtype=int), "valid") == window)
    if runs.size == 0:
        return float(depth[0])
    k = int(runs[0])
    slope, intercept = np.polyfit(clock[k : k + window], load[k : k + window], 1)
    if slope <= 0:
        return float(depth[k])
    t0 = -intercept / slope
    return float(np.interp(t0, clock[: k + 1], depth[: k + 1]))


@dataclass(frozen=True)
class _CurveResult:
    hardness_gpa: float | None
    modulus_gpa: float | None
    max_load_mn: float | None
    max_depth_nm: float | None


def _power_law(u: np.ndarray, a: float, uf: float, m: float) -> np.ndarray:
    return a * np.power(np.clip(u - uf, 1e-12, None), m)


def _oliver_pharr(
    curve: _Curve,
    *,
    test: str,
    frame_compliance_nm_mn: float,
    poisson: float,
    area_coeffs: tuple[float, ...] | None,
    notes: list[str],
) -> _CurveResult | None:
    """Oliver-Pharr (1992) on the last unload: P = a (h - hf)^m fitted to its top, S = dP/dh at hmax.

    Why the extra steps: the surface is re-found from the load signal (see ``_find_surface``); the
    instrument's frame compliance Cf (nm/mN) is removed from depth and stiffness (h -= P Cf,
    1/S -= Cf) because on a stiff sample it is ~15 % of the measured compliance. The fit spans the file's
    "Begin/End Stiffness Data" markers when present, otherwise 100 %-50 % of the peak load. Contact
    depth hc = h - 0.75 P/S, area from the file's area function or 24.5 hc², H = P/A,
    Er = sqrt(pi)/2 S/sqrt(A) (beta = 1, as InView/ISO 14577), E from Er with a diamond tip.
    """
    load, depth = curve.load_mn, curve.depth_nm
    ok = np.isfinite(load) & np.isfinite(depth)
    if ok.sum() < 20:
        notes.append(f"test {test}: too few valid load-depth points for Oliver-Pharr")
        return None
    clock = curve.time_s if curve.time_s is not None else np.arange(load.size, dtype=float)
    ok &= np.isfinite(clock)
    idx = np.flatnonzero(ok)
    load, depth, clock = load[idx], depth[idx], clock[idx]
    remap = {row: min(int(np.searchsorted(idx, row)), idx.size - 1) for row in curve.markers.values()}
    markers = {label: remap[row] for label, row in curve.markers.items()}
    sub = _Curve(depth, load, clock, None, None, markers)

    peak = int(np.argmax(load))
    depth = depth - _find_surface(load, depth, clock, peak)

    # unloading starts at the end of the hold: InView marks it, NanoSuite marks the first unload row
    start = _marker(sub, "end of hold")
    if start is None:
        start = _marker(sub, "unload")
    if start is None or load[start] < 0.98 * load[peak]:
        start = peak
        while start + 1 < load.size and load[start + 1] >= 0.998 * load[peak]:
            start += 1
    fit_lo = _marker(sub, "begin stiffness")
    fit_hi = _marker(sub, "end of stiffness")
    if fit_lo is None or fit_hi is None or not (start <= fit_lo < fit_hi):
        fit_lo = start
        below = np.flatnonzero(load[start:] < 0.5 * load[start])
        fit_hi = start + int(below[0]) if below.size else load.size - 1
    p_max, h_max = float(load[start]), float(depth[start])
    u = depth[fit_lo : fit_hi + 1] / h_max
    q = load[fit_lo : fit_hi + 1] / p_max
    if u.size < 5 or h_max <= 0 or p_max <= 0:
        notes.append(f"test {test}: no usable unloading segment")
        return None
    r = (q[-1] / q[0]) ** (1 / 1.5)
    uf0 = (u[-1] - r * u[0]) / (1 - r) if r < 1 else 0.5 * u.min()
    uf0 = float(np.clip(uf0, -0.9, u.min() - 1e-3))
    a0 = float(q[0] / (u[0] - uf0) ** 1.5)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            (a, uf, m), _ = curve_fit(
                _power_law, u, q, p0=(a0, uf0, 1.5), bounds=([0.0, -1.0, 1.0], [np.inf, u.min() - 1e-6, 3.0])
            )
    except (RuntimeError, ValueError):
        notes.append(f"test {test}: power-law fit to the unloading curve failed")
        return None
    stiffness = p_max / h_max * m * a * (1.0 - uf) ** (m - 1.0)  # mN/nm
    compliance = 1.0 / stiffness - frame_compliance_nm_mn
    if compliance <= 0:
        notes.append(f"test {test}: frame compliance exceeds the measured compliance; not removed")
        compliance = 1.0 / stiffness
        frame_compliance_nm_mn = 0.0
    stiffness = 1.0 / compliance
    h_max -= p_max * frame_compliance_nm_mn
    hc = h_max - EPSILON_BERKOVICH * p_max / stiffness
    if hc <= 0:
        notes.append(f"test {test}: contact depth {hc:.1f} nm is not positive")
        return None
    if area_coeffs:
        area = sum(c * hc ** (2.0 ** (1 - k)) for k, c in enumerate(area_coeffs))
    else:
        area = BERKOVICH_C0 * hc**2
    hardness = p_max / area * 1e6  # mN/nm² -> GPa
    er = math.sqrt(math.pi) / 2.0 * stiffness / math.sqrt(area) * 1e6
    inv = 1.0 / er - (1 - DIAMOND_NU**2) / DIAMOND_E_GPA
    modulus = (1 - poisson**2) / inv if inv > 0 else None
    return _CurveResult(hardness, modulus, p_max, h_max)


def _peak(curve: _Curve) -> tuple[float, float] | None:
    """Peak load and the deepest point before the unload (the end of the hold at peak load)."""
    load, depth = curve.load_mn, curve.depth_nm
    ok = np.isfinite(load) & np.isfinite(depth)
    if not ok.any():
        return None
    peak = int(np.nanargmax(np.where(ok, load, np.nan)))
    end = peak
    while end + 1 < load.size and ok[end + 1] and load[end + 1] >= 0.99 * load[peak]:
        end += 1
    return float(load[peak]), float(np.nanmax(np.where(ok, depth, np.nan)[: end + 1]))


def _csm_average(
    curve: _Curve, lo_nm: float | None, hi_nm: float | None, test: str, notes: list[str]
) -> _CurveResult | None:
    """Mean of the CSM Hardness/Modulus channels over [lo, hi] nm of the loading segment.

    Default band without file limits: 10-20 % of the maximum depth (the 10 % rule for films; bulk
    samples are flat there too), and the warnings say so.
    """
    assert curve.hardness_gpa is not None
    load, depth = curve.load_mn, curve.depth_nm
    peak_values = _peak(curve)
    if peak_values is None:
        return None
    p_peak, h_peak = peak_values
    peak = int(np.nanargmax(load))
    lo = lo_nm if lo_nm is not None else 0.1 * h_peak
    hi = hi_nm if hi_nm is not None else 0.2 * h_peak
    if lo_nm is None or hi_nm is None:
        notes.append(
            f"test {test}: the file names no calculation depth range; CSM hardness averaged over "
            f"{lo:.0f}-{hi:.0f} nm (10-20 % of the maximum depth)"
        )
    band = np.zeros(load.size, dtype=bool)
    band[: peak + 1] = (depth[: peak + 1] >= lo) & (depth[: peak + 1] <= hi)

    def mean(channel: np.ndarray | None) -> float | None:
        if channel is None:
            return None
        values = channel[band & np.isfinite(channel)]
        return float(values.mean()) if values.size else None

    return _CurveResult(mean(curve.hardness_gpa), mean(curve.modulus_gpa), p_peak, h_peak)


def _frame_compliance_from_cycles(sheets: Mapping[str, pd.DataFrame], notes: list[str]) -> float | None:
    """Frame compliance (nm/mN) from a multi-cycle test: 1/S = Cf + k/sqrt(P) per test, median intercept.

    Uses an InView "Cycles-*" sheet (Cycle Pmax, Cycle Su per "test:cycle" row) and only the cycles
    above 10 % of the test's peak load (the shallow ones suffer from tip rounding). Each test gets its own
    slope, so a map whose hardness varies between tests does not bias the intercept; the median shrugs off
    a bad indent.
    """
    label = re.compile(r"^\s*(\d+)\s*:\s*(\d+)\s*$")
    for name, raw in sheets.items():
        if not _norm(name).startswith("cycles"):
            continue
        table = _split_table(raw, ("cycle pmax", "cycle su"))
        if table is None:
            continue
        cp, cs = table.column(("cycle pmax",)), table.column(("cycle su",))
        if cp is None or cs is None:
            continue
        f_p = _unit_factor("load", table.units[cp], f"{name}: Cycle Pmax", notes)
        f_s = _unit_factor("stiffness", table.units[cs], f"{name}: Cycle Su", notes)
        rows: dict[str, list[tuple[float, float]]] = {}
        p_all, s_all = _numeric(table.data[cp]) * f_p, _numeric(table.data[cs]) * f_s
        for i, cell in enumerate(table.data[0]):
            m = label.match(str(cell))
            if m and p_all[i] > 0 and s_all[i] > 0:
                rows.setdefault(m.group(1), []).append((p_all[i], s_all[i]))
        intercepts = []
        for cycles in rows.values():
            p, s = np.array(cycles).T
            keep = p >= 0.1 * p.max()
            if keep.sum() >= 3 and np.unique(p[keep]).size >= 3:
                intercepts.append(float(np.polyfit(1 / np.sqrt(p[keep]), 1 / s[keep], 1)[1]))
        if not intercepts:
            continue
        cf = float(np.median(intercepts))
        if cf <= 0:
            notes.append(f"frame compliance from {name!r} came out {cf:.3g} nm/mN; not used")
            return None
        notes.append(f"frame compliance {cf:.3f} nm/mN estimated from {name!r} ({len(intercepts)} tests)")
        return cf
    return None


# ------------------------------------------------------------------------------------------- reader


def _check_file(path: Path) -> str:
    """Refuse early and clearly: missing, empty, or neither a workbook nor a text table.

    The content decides, never the extension: labs rename files, and InView's "Excel" export can be an
    .xlsx named .xls or a tab-separated text file. Returns "openpyxl", "xlrd" or "text".
    """
    if not path.is_file():
        raise InputError(str(path), "file not found")
    with path.open("rb") as fh:
        head = fh.read(4096)
    if not head:
        raise InputError(str(path), "empty file")
    if head.startswith(_XLSX_MAGIC):
        return "openpyxl"
    if head.startswith(_XLS_MAGIC):
        return "xlrd"
    text = _decode(head, path, partial=True).lstrip().lower()
    if text.startswith(("<html", "<!doctype", "<?xml", "<table")):
        raise InputError(str(path), "an HTML/XML page, not a workbook or CSV export (export as .xlsx or CSV)")
    return "text"


def _decode(data: bytes, path: Path, *, partial: bool = False) -> str:
    """UTF-16 (with BOM), UTF-8 or Windows-1252 text; binary junk is refused."""
    if data.startswith((b"\xff\xfe", b"\xfe\xff")):
        return data.decode("utf-16", errors="replace" if partial else "strict")
    if b"\x00" in data:
        raise InputError(str(path), "not an Excel workbook (.xlsx or .xls) or a text (CSV) export")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        if partial and exc.start >= len(data) - 3:  # a multi-byte character cut by the 4 kB sniff
            return data[: exc.start].decode("utf-8-sig")
        return data.decode("cp1252", errors="replace")


_DECIMAL_COMMA = re.compile(r"^[-+]?\d+,\d+(?:[eE][-+]?\d+)?$")


def _sniff_delimiter(lines: list[str]) -> str:
    """The separator that splits the most lines into the same number of fields (tab, ';' or ',')."""
    best, best_score = ",", -1
    for delim in ("\t", ";", ","):
        counts = [ln.count(delim) for ln in lines if ln.strip()]
        nonzero = [c for c in counts if c > 0]
        if not nonzero:
            continue
        mode = max(set(nonzero), key=nonzero.count)
        score = sum(c == mode for c in counts)
        if score > best_score:
            best, best_score = delim, score
    return best


def _text_cell(cell: str, decimal_comma: bool) -> object:
    text = cell.strip()
    if not text:
        return None
    if decimal_comma and _DECIMAL_COMMA.match(text):
        text = text.replace(",", ".")
    try:
        return float(text)
    except ValueError:
        return text


def _read_text(path: Path) -> dict[str, pd.DataFrame]:
    """A CSV/TSV export as one 'Results' sheet; ';'-separated files may use decimal commas."""
    lines = _decode(path.read_bytes(), path).splitlines()
    delimiter = _sniff_delimiter(lines)
    rows = list(csv.reader(lines, delimiter=delimiter))
    decimal_comma = delimiter != "," and any(_DECIMAL_COMMA.match(c.strip()) for r in rows for c in r)
    width = max((len(r) for r in rows), default=0)
    table = [[_text_cell(c, decimal_comma) for c in r] + [None] * (width - len(r)) for r in rows]
    return {"Results": pd.DataFrame(table, dtype=object)}


def _read_xlsx(path: Path) -> dict[str, pd.DataFrame]:
    """openpyxl directly, not pandas: an .xlsx stores DBL_MAX as text that parses to inf, and pandas'
    openpyxl reader then dies on int(inf). Here inf just becomes a missing value later. The file is
    passed open, so openpyxl does not refuse an .xlsx named .xls by its extension."""
    with path.open("rb") as fh:
        book = openpyxl.load_workbook(fh, read_only=True, data_only=True)
        try:
            out = {}
            for sheet in book.worksheets:
                if isinstance(sheet, ReadOnlyWorksheet):
                    sheet.reset_dimensions()  # exporters often write a wrong <dimension>
                out[sheet.title] = pd.DataFrame(list(sheet.iter_rows(values_only=True)))
            return out
        finally:
            book.close()


def _read_sheets(path: Path, engine: str) -> dict[str, pd.DataFrame]:
    log = io.StringIO()  # xlrd prints its file-format complaints to a log that is stdout by default
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # pandas deprecates xlrd; openpyxl warns on styles
            if engine == "text":
                sheets = _read_text(path)
            elif engine == "openpyxl":
                sheets = _read_xlsx(path)
            else:
                kwargs = {"logfile": log} if engine == "xlrd" else {}
                sheets = pd.read_excel(
                    path, sheet_name=None, header=None, engine=engine, engine_kwargs=kwargs
                )
    except InputError:
        raise
    except Exception as exc:  # the engines raise a zoo of types on corrupt files
        what = "text export" if engine == "text" else "Excel workbook"
        raise InputError(str(path), f"unreadable {what} ({type(exc).__name__}: {exc})") from exc
    for line in log.getvalue().splitlines():  # kept, as warnings (the CLI prints them on stderr)
        if line.strip():
            warnings.warn(f"{path.name}: {line.strip()}", UserWarning, stacklevel=2)
    if not sheets or all(df.empty for df in sheets.values()):
        raise InputError(str(path), "workbook has no data")
    return {str(name): df for name, df in sheets.items()}


def _sheet_words(sheets: Mapping[str, pd.DataFrame]) -> tuple[str, set[str]]:
    """Lower-case text of the sheets' top cells (vendor names live there) and every header-like key."""
    texts: list[str] = []
    keys: set[str] = set()
    for raw in sheets.values():
        top = raw.iloc[:40, :40]
        for row in top.itertuples(index=False):
            for cell in row:
                if isinstance(cell, str) and cell.strip():
                    texts.append(cell.lower())
                    keys.add(_norm(_parse_header(cell)[0]))
    return " | ".join(texts), keys


# vendor words in a file's own text, checked before any column-based guess
_VENDOR_WORDS: tuple[tuple[str, tuple[str, ...]], ...] = (
    (SOFTWARE_TESTWORKS, ("testworks",)),
    (SOFTWARE_NANOSUITE, ("nanosuite",)),
    (SOFTWARE_INVIEW, ("inview",)),
    (SOFTWARE_HYSITRON, ("hysitron", "triboscan", "triboview", "tribo indenter", "triboindenter", "xpm")),
    (SOFTWARE_ANTON_PAAR, ("anton paar", "csm instruments")),
    (SOFTWARE_MICRO_MATERIALS, ("micro materials", "micromaterials", "nanotest")),
    (SOFTWARE_FISCHERSCOPE, ("fischerscope", "helmut fischer", "winhcu")),
)


def _detect_software(sheets: Mapping[str, pd.DataFrame]) -> str:
    """The program that wrote the file: its sheet names, then its own words, then its column names."""
    names = {_norm(n) for n in sheets}
    if names & {"required inputs", "inputs editable post test"}:
        return SOFTWARE_NANOSUITE
    if names & {"pre-test inputs", "post-test inputs", "sample summary", "sample information"} or any(
        n.startswith("cycles-") for n in names
    ):
        return SOFTWARE_INVIEW
    text, keys = _sheet_words(sheets)
    for software, words in _VENDOR_WORDS:
        if any(re.search(rf"\b{re.escape(w)}\b", text) for w in words):
            return software
    if {"hit", "eit"} <= keys and keys & {"hvit", "fmax", "cit", "rit"}:  # ISO 14577 names, Anton Paar's
        return SOFTWARE_ANTON_PAAR
    # Hysitron's contact depth, peak force and reduced modulus (short or spelt out)
    if {"hc", "er"} <= keys or {"pmax", "er"} <= keys or {"contact depth", "reduced modulus"} <= keys:
        return SOFTWARE_HYSITRON
    test_sheets = [n for n in names if _TEST_SHEET.match(n)]
    if test_sheets and not any("result" in n for n in names):
        return SOFTWARE_TESTWORKS  # MTS TestWorks writes one sheet per test and no Results sheet
    if any(re.match(r"^test 0\d+$", n) for n in test_sheets):
        return SOFTWARE_NANOSUITE
    return SOFTWARE_UNKNOWN


def _results_sheet(sheets: Mapping[str, pd.DataFrame]) -> str | None:
    for name in sheets:
        if _norm(name) == "results":
            return name
    for name in sheets:
        if "result" in _norm(name):
            return name
    return None


def _table_sheet(path: Path, sheets: Mapping[str, pd.DataFrame]) -> str | None:
    """A sheet of another name that holds a per-test results table (a test column and a hardness column,
    no load-depth curve): a workbook without a Results sheet and without Test sheets. Two such sheets
    that differ are refused: which one is this run's cannot be told."""
    found: list[str] = []
    for name, raw in sheets.items():
        table = _split_table(raw, _RESULT_ALIASES["test_id"])
        if table is None or table.column(_RESULT_ALIASES["test_id"]) is None:
            continue
        if (
            table.column(_CURVE_ALIASES["load"]) is not None
            and table.column(_CURVE_ALIASES["depth"]) is not None
        ):
            continue
        if _value_columns(table, "hardness_gpa", "hardness", "h"):
            found.append(name)
    differing = [n for n in found[1:] if not sheets[n].equals(sheets[found[0]])]
    if differing:
        raise InputError(
            str(path),
            f"no 'Results' sheet, and sheets {found[0]!r} and {differing[0]!r} both hold a different results "
            "table: keep this run's one (or name it Results)",
        )
    return found[0] if found else None


def _key_of(text: str) -> str | None:
    """Which result a label names ('Hardness At Max Load (GPa)' -> hardness_gpa), or None."""
    key = _norm(_parse_header(text)[0])
    for name, aliases in _RESULT_ALIASES.items():
        if name != "test_id" and key in aliases:
            return name
    words = set(re.split(r"[^a-z%]+", key))
    if not words & _NOT_A_VALUE:
        if "hardness" in key:
            return "hardness_gpa"
        if "modulus" in key and "reduced" not in words:
            return "modulus_gpa"
    return None


def _as_number(cell: object) -> float | None:
    """A finite number from a cell (numeric text too, decimal comma allowed); None for anything else."""
    if _is_number(cell):
        value = float(cast(float, cell))
    elif isinstance(cell, str) and cell.strip():
        try:
            value = float(cell.strip().replace(",", "."))
        except ValueError:
            return None
    else:
        return None
    return value if math.isfinite(value) and abs(value) < INVALID_THRESHOLD else None


def _sheet_own_result(raw: pd.DataFrame, sheet: str, notes: list[str]) -> dict[str, float]:
    """A Test sheet's own result (TestWorks, some InView templates), as 'label | value | unit' rows or as a
    one-row table (labels, an optional units row, one row of values), converted to µm / GPa / nm/s / mN /
    nm. A curve's header row is not a result: its labels have a column of numbers below them."""
    grid = [list(r) for r in raw.iloc[:200, :60].itertuples(index=False)]
    load_words = set(_CURVE_ALIASES["load"])
    depth_words = set(_CURVE_ALIASES["depth"])

    def at(r: int, j: int) -> object:
        return grid[r][j] if r < len(grid) and j < len(grid[r]) else None

    out: dict[str, float] = {}
    for r, row in enumerate(grid):
        keys = {_norm(_parse_header(c)[0]) for c in row if isinstance(c, str)}
        curve_header = bool(keys & load_words) and bool(keys & depth_words)
        for j, cell in enumerate(row):
            if not isinstance(cell, str) or not cell.strip():
                continue
            key = _key_of(cell)
            if key is None or key in out:
                continue
            unit: object = _parse_header(cell)[1]
            right = [c for c in row[j + 1 : j + 4] if not _blank(c)]
            value = _as_number(right[0]) if right else None
            if value is not None:
                if unit is None and len(right) > 1 and isinstance(right[1], str):
                    unit = right[1]
            elif not curve_header:
                below = [at(r + k, j) for k in (1, 2, 3)]
                if _as_number(below[0]) is not None and _as_number(below[1]) is None:
                    value = _as_number(below[0])
                elif (
                    isinstance(below[0], str)
                    and _as_number(below[1]) is not None
                    and _as_number(below[2]) is None
                ):
                    value, unit = _as_number(below[1]), unit or below[0]
            if value is not None:
                out[key] = value * _unit_factor(key, unit, f"{sheet}: {cell.strip()}", notes)
    return out


_CANONICAL_HEADERS = {
    "x_um": ("X Position", "µm"),
    "y_um": ("Y Position", "µm"),
    "hardness_gpa": ("Hardness", "GPa"),
    "modulus_gpa": ("Modulus", "GPa"),
    "drift_rate_nm_s": ("Drift Rate", "nm/s"),
    "max_load_mn": ("Max Load", "mN"),
    "max_depth_nm": ("Max Depth", "nm"),
}


def _results_from_test_sheets(
    path: Path, sheets: Mapping[str, pd.DataFrame], notes: list[str]
) -> pd.DataFrame:
    """A Results table built from the Test sheets' own results, one row per sheet in test order (a test
    without a result there gets its hardness from its curve, as for a Results sheet without hardness)."""
    curve_sheets = _curve_sheet_names(sheets)
    per_test = {t: _sheet_own_result(sheets[n], n, notes) for t, n in curve_sheets.items()}
    keys = [k for k in _CANONICAL_HEADERS if any(k in v for v in per_test.values())]
    rows: list[list[object]] = [["Test", *(_CANONICAL_HEADERS[k][0] for k in keys)]]
    rows.append(["", *(_CANONICAL_HEADERS[k][1] for k in keys)])
    for test in sorted(per_test, key=int):
        rows.append([test, *(per_test[test].get(k) for k in keys)])
    if "hardness_gpa" in keys:
        notes.append(
            f"no Results sheet: each test's hardness is its own sheet's result ({len(per_test)} Test sheets)"
        )
    elif any(_parse_curve(sheets[n], n, []) is not None for n in curve_sheets.values()):
        notes.append("no Results sheet and no result on the Test sheets: hardness from each test's curve")
    else:
        raise InputError(
            str(path),
            f"no Results sheet, and its {len(curve_sheets)} Test sheets hold neither a hardness value nor "
            "Load/Depth columns",
        )
    return pd.DataFrame(rows, dtype=object)


_INPUT_SHEET_WORDS = ("input", "information", "sample", "parameter", "setup", "position", "method")


def _inputs_by_test(
    sheets: Mapping[str, pd.DataFrame], skip: set[str], notes: list[str], reads: frozenset[str] = frozenset()
) -> dict[str, dict[str, float]]:
    """Per-test values from the input sheets (positions, Poisson ratio, calculation depths, area function).

    Only the results sheet and sheets named as inputs or sample information are read: a copy of a sheet
    under an unrelated name ('Sheet2', 'Chart Data') may hold another run's numbers."""
    out: dict[str, dict[str, float]] = {}
    for name, raw in sheets.items():
        if name in skip or _TEST_SHEET.match(name) or _norm(name).startswith("cycles"):
            continue
        if not (name in reads or any(w in _norm(name) for w in _INPUT_SHEET_WORDS)):
            continue
        table = _split_table(raw, _RESULT_ALIASES["test_id"])
        if table is None:
            continue
        test_col = table.column(_RESULT_ALIASES["test_id"])
        assert test_col is not None
        wanted: dict[str, tuple[int, float]] = {}
        for key, aliases in _INPUT_ALIASES.items():
            col = table.column(aliases)
            if col is not None:
                factor = 1.0 if key == "poisson" else _unit_factor(key, table.units[col], name, notes)
                wanted[key] = (col, factor)
        for i, k in enumerate(table.keys):
            m = _AREA_COEFF.match(k)
            if m:
                wanted[f"area{int(m.group(1))}"] = (i, 1.0)
        if not wanted:
            continue
        columns = {key: _numeric(table.data[col]) * f for key, (col, f) in wanted.items()}
        for row, label in enumerate(table.data[test_col]):
            test = _test_key(label)
            if test is None or _norm(test) in _SUMMARY_LABELS:
                continue
            record = out.setdefault(test, {})
            for key, values in columns.items():
                if math.isfinite(values[row]):
                    record.setdefault(key, float(values[row]))
    return out


def _area_coeffs(values: Mapping[str, float]) -> tuple[float, ...] | None:
    """NanoSuite 'Area Coefficient k' -> (C0, C1, ...) for A = C0 hc² + C1 hc + C2 hc^½ + ..."""
    ks = sorted(int(k[4:]) for k in values if k.startswith("area") and k[4:].isdigit())
    if not ks or ks[0] != 1:
        return None
    coeffs = tuple(values[f"area{k}"] for k in range(1, ks[-1] + 1) if f"area{k}" in values)
    return coeffs if len(coeffs) == ks[-1] and coeffs[0] > 0 else None


def _robust_outliers(indents: list[KlaIndent], notes: list[str]) -> None:
    values = np.array([i.hardness_gpa for i in indents if i.hardness_gpa is not None], dtype=float)
    if values.size < 5:
        return
    median = float(np.median(values))
    mad = 1.4826 * float(np.median(np.abs(values - median)))
    for i in indents:
        h = i.hardness_gpa
        if h is not None and abs(h - median) > max(5 * mad, 0.25 * abs(median)):
            notes.append(
                f"test {i.test_id}: hardness {h:.2f} GPa is far from the file median {median:.2f} GPa "
                "(suspect indent: surface, contamination or a bad curve)"
            )


_NOT_A_VALUE = frozenset(
    {
        "vickers",
        "hv",
        "hvit",
        "martens",
        "hm",
        "std",
        "stdev",
        "dev",
        "deviation",
        "sd",
        "sigma",
        "error",
        "err",
        "cov",
        "cv",
        "uncertainty",
        "%",
        "range",
    }
)


def _value_columns(table: _Table, key: str, word: str, letter: str) -> list[int]:
    """Columns that hold a per-test value of ``word``: exact aliases first, then names that contain the
    word ('Avg Hardness', 'Hardness@CSM'), then a bare letter with a pressure unit ('H' in GPa).
    Spreads and errors ('Hardness Std Dev') are not values."""
    exact = [i for i, k in enumerate(table.keys) if k in _RESULT_ALIASES[key]]
    loose = []
    for i, k in enumerate(table.keys):
        named = word in k and not set(re.split(r"[^a-z%]+", k)) & _NOT_A_VALUE
        lettered = k == letter and _clean_unit(table.units[i]) in _PRESSURE_GPA
        if i not in exact and (named or lettered):
            loose.append(i)
    loose.sort(key=lambda i: not ({"avg", "average", "mean"} & set(table.keys[i].split())))
    return exact + loose


def _result_columns(table: _Table) -> dict[str, list[int]]:
    """Every candidate column per quantity, best first (hardness and modulus may have several)."""
    cols: dict[str, list[int]] = {}
    for key, aliases in _RESULT_ALIASES.items():
        col = table.column(aliases)
        cols[key] = [] if col is None else [col]
    cols["hardness_gpa"] = _value_columns(table, "hardness_gpa", "hardness", "h")
    cols["modulus_gpa"] = _value_columns(table, "modulus_gpa", "modulus", "e")
    return cols


def _missing_value(raw: object) -> str:
    """What a cell that gave no number held, for the failure reason."""
    if raw is None or (isinstance(raw, float) and math.isnan(raw)):
        return "blank"
    if _is_number(raw):
        v = float(cast(float, raw))
        if not math.isfinite(v) or abs(v) >= INVALID_THRESHOLD:
            return "1.797e308 (the instrument's 'invalid')"
        return f"{v:g}"
    text = str(raw).strip()
    return repr(text) if text else "blank"


def _physical(value: float | None, what: str, limit: float) -> str | None:
    """Why a hardness or modulus value cannot be real (zero, negative, above diamond's), or None."""
    if value is None:
        return None
    if value <= 0:
        return f"{what} {value:.4g} GPa is not physical (≤ 0)"
    if value > limit:
        return f"{what} {value:.4g} GPa is not physical (> {limit:g})"
    return None


def _summary_row(data: pd.DataFrame, row: int) -> bool:
    """'Average', 'Std Dev', '% COV' ... in any text cell of the row (the label column varies)."""
    for cell in data.iloc[row]:
        if isinstance(cell, str) and _norm(cell).rstrip(":") in _SUMMARY_LABELS:
            return True
    return False


def _curve_sheet_names(sheets: Mapping[str, pd.DataFrame]) -> dict[str, str]:
    """test key -> curve sheet; 'Test 004' wins over 'Test 004 Tagged' when both exist."""
    out: dict[str, str] = {}
    for name in sheets:
        m = _TEST_SHEET.match(name)
        if m is None:
            continue
        key = str(int(m.group(1)))
        exact = name.strip().lower().replace(" ", "") == f"test{m.group(1)}".lower()
        if key not in out or exact:
            out[key] = name
    return out


def read_kla_export(path: str | Path, *, frame_compliance_nm_mn: float | None = None) -> KlaExport:
    """Read one nanoindenter export; ``frame_compliance_nm_mn`` overrides the estimate from the file.

    Every per-test row of the file is one indent (per-cycle rows and summary rows are not tests). A row
    whose hardness is missing, marked invalid or impossible (≤ 0, or modulus ≤ 0) comes back as a failed
    indent with its reason and no hardness number. A file it cannot read is refused in one line that names
    the program that wrote it, when it can tell.
    """
    path = Path(path)
    engine = _check_file(path)
    sheets = _read_sheets(path, engine)
    software = _detect_software(sheets)
    try:
        return _read(path, sheets, software, frame_compliance_nm_mn)
    except InputError as exc:
        if software == SOFTWARE_UNKNOWN:
            raise
        hint = _VENDOR_HINTS.get(software, "")
        raise InputError(exc.source, f"{software} export: {exc.problem}{hint}") from None


# what to export instead, for programs whose usual files are one test's raw curve
_VENDOR_HINTS = {
    SOFTWARE_HYSITRON: " (export the analysed results table from TriboScan/TriboView, not a single .hld/.txt curve)",
    SOFTWARE_MICRO_MATERIALS: " (export the NanoTest results table with one row per indent)",
    SOFTWARE_FISCHERSCOPE: " (export the WIN-HCU results table with one row per indent, not a .hap file)",
    SOFTWARE_ANTON_PAAR: " (export the Indentation Software results table with one row per indent)",
}


_TEST_ID = re.compile(r"^\s*(?:test\s*)?#?\s*\d+\s*$", re.IGNORECASE)
_CYCLE_COLUMN = ("cycle", "cycle #", "cycle number", "cycle no", "cycle no.", "cycle id")


def _blank(cell: object) -> bool:
    return (
        cell is None
        or (isinstance(cell, float) and math.isnan(cell))
        or (isinstance(cell, str) and not cell.strip())
    )


def _test_rows(
    table: _Table, test_col: int | None, sheet: str, path: Path, notes: list[str]
) -> list[tuple[int, str]]:
    """(row, test id) for every per-test row. Not tests: summary rows, blank rows, a repeated header or
    units row, text lines without a number, and per-cycle rows ('1-1', or a filled 'Cycle' column beside
    per-test rows with it empty). A sheet of per-cycle rows only is refused (it has no per-test result)."""
    cycle_col = table.column(_CYCLE_COLUMN)
    cycle_filled = (
        [not _blank(v) for v in table.data[cycle_col]] if cycle_col is not None else [False] * len(table.data)
    )
    if all(cycle_filled):  # every row has a cycle: one cycle per test, or no per-test rows (duplicates show)
        cycle_filled = [False] * len(table.data)
    rows: list[tuple[int, str]] = []
    cycles: list[str] = []
    other = 0
    for row in range(len(table.data)):
        cells = list(table.data.iloc[row])
        label = cells[test_col] if test_col is not None else None
        if _summary_row(table.data, row):
            continue
        if all(_blank(c) for c in (cells[i] for i in range(len(cells)) if i != test_col)):
            continue
        texts = [_norm(_parse_header(c)[0]) for c in cells if isinstance(c, str) and c.strip()]
        if sum(t in table.keys for t in texts) >= 2 or (texts and _looks_like_units_row(cells)):
            other += 1  # a second header or units row (a table pasted below, a copy)
            continue
        if (isinstance(label, str) and _CYCLE_LABEL.match(label)) or cycle_filled[row]:
            cycles.append(
                str(label).strip() if not cycle_filled[row] else f"{label}/{cells[cast(int, cycle_col)]}"
            )
            continue
        id_like = _is_number(label) or (isinstance(label, str) and bool(_TEST_ID.match(label)))
        if not id_like and not any(_is_number(c) for c in cells):
            other += 1  # a note or a metadata line inside the table
            continue
        test_key = _test_key(label)
        rows.append((row, test_key if test_key is not None else str(len(rows) + 1)))
    if cycles and not rows:
        raise InputError(
            str(path),
            f"sheet {sheet!r} has per-cycle rows only ({cycles[0]!r} ...), no per-test rows: "
            "export the per-test results",
        )
    if cycles:
        notes.append(
            f"{sheet}: {len(cycles)} per-cycle row(s) ({cycles[0]!r} ...) are not tests: "
            f"read the {len(rows)} per-test row(s)"
        )
    if other:
        notes.append(f"{sheet}: {other} row(s) without test data (a repeated header, a note) skipped")
    seen: dict[str, int] = {}
    for _, test in rows:
        seen[test] = seen.get(test, 0) + 1
    repeated = [t for t, n in seen.items() if n > 1]
    if repeated and test_col is not None:
        raise InputError(
            str(path),
            f"sheet {sheet!r}: test {repeated[0]!r} is on {seen[repeated[0]]} rows (per-cycle rows without "
            "their per-test row?): export one row per test",
        )
    return rows


def _pick_value_column(
    table: _Table, candidates: list[int], key: str, rows: list[int], sheet: str, notes: list[str]
) -> int | None:
    """The first candidate with a number on a per-test row ('H' may be empty there while 'Avg H' holds
    the test's result); says which column was used when there was a choice."""
    word = "hardness" if key == "hardness_gpa" else "modulus"
    filled = [c for c in candidates if np.isfinite(_numeric(table.data[c].iloc[rows])).any()]
    if not candidates:
        return None
    chosen = filled[0] if filled else candidates[0]
    empty = [c for c in candidates if c not in filled and candidates.index(c) < candidates.index(chosen)]
    others = [c for c in candidates if c != chosen and c not in empty]
    if empty:
        names = ", ".join(repr(table.headers[c]) for c in empty)
        notes.append(f"{sheet}: {word} from {table.headers[chosen]!r} ({names} empty on the per-test rows)")
    elif others:
        names = ", ".join(repr(table.headers[c]) for c in others)
        notes.append(f"{sheet}: {word} from {table.headers[chosen]!r}; also present, not used: {names}")
    return chosen


def _read(
    path: Path, sheets: dict[str, pd.DataFrame], software: str, frame_compliance_nm_mn: float | None
) -> KlaExport:
    notes: list[str] = []
    res_name = _results_sheet(sheets)
    if res_name is None and _curve_sheet_names(sheets):
        res_name = "Test sheets"
        sheets = {**sheets, res_name: _results_from_test_sheets(path, sheets, notes)}
    elif res_name is None:
        res_name = _table_sheet(path, sheets)
        if res_name is None:
            raise InputError(
                str(path),
                f"no 'Results' sheet, no 'Test N' sheets and no sheet with a test and a hardness column "
                f"(sheets: {', '.join(sheets)})",
            )
        notes.append(f"no 'Results' sheet: results read from sheet {res_name!r}")
    table = _split_table(sheets[res_name], [a for aliases in _RESULT_ALIASES.values() for a in aliases])
    if table is None or table.data.empty:
        raise InputError(str(path), f"sheet {res_name!r} has no header row with known columns")
    candidates = _result_columns(table)
    test_col = candidates["test_id"][0] if candidates["test_id"] else None
    if test_col is None and table.keys and table.keys[0] == "":
        test_col = 0  # an unnamed first column holds the test labels (and 'Average', '1-1' ...)
    test_ids = _test_rows(table, test_col, res_name, path, notes)
    if not test_ids:
        raise InputError(str(path), f"sheet {res_name!r} has no test rows")
    row_index = [r for r, _ in test_ids]
    cols: dict[str, int | None] = {}
    for key, found in candidates.items():
        if key in ("hardness_gpa", "modulus_gpa"):
            cols[key] = _pick_value_column(table, found, key, row_index, res_name, notes)
        else:
            cols[key] = found[0] if found else None
    values: dict[str, np.ndarray] = {}
    for key, col in cols.items():
        if col is not None and key != "test_id":
            factor = _unit_factor(key, table.units[col], f"{res_name}: {table.headers[col]}", notes)
            values[key] = _numeric(table.data[col]) * factor
    hardness_column = table.headers[cols["hardness_gpa"]] if cols["hardness_gpa"] is not None else ""
    hardness_range = table.ranges_nm[cols["hardness_gpa"]] if cols["hardness_gpa"] is not None else None
    if hardness_range is not None:
        lo, hi = hardness_range
        notes.append(
            f"hardness is the file's own average over {lo:g}-{hi:g} nm "
            f"(column {table.headers[cast(int, cols['hardness_gpa'])]!r})"
        )
    area_cols = {int(m.group(1)): i for i, k in enumerate(table.keys) if (m := _AREA_COEFF.match(k))}

    inputs = _inputs_by_test(sheets, set(), notes, frozenset({res_name}))  # Results may carry depths too
    for row, test in test_ids:
        for k, col in area_cols.items():
            v = _numeric(table.data[col].iloc[[row]])[0]
            if math.isfinite(v):
                inputs.setdefault(test, {})[f"area{k}"] = float(v)

    has_xy = "x_um" in values and "y_um" in values
    if not has_xy and not any(
        "x_um" in inputs.get(t, {}) and "y_um" in inputs.get(t, {}) for _, t in test_ids
    ):
        notes.append(f"{NO_POSITIONS} (no X/Y column in {res_name!r} or any inputs sheet)")

    curve_sheets = _curve_sheet_names({n: df for n, df in sheets.items() if n != res_name})
    need_h = "hardness_gpa" not in values
    need_curve = need_h or "max_load_mn" not in values or "max_depth_nm" not in values
    if need_h and not curve_sheets:
        raise InputError(
            str(path), f"no hardness column in {res_name!r} and no 'Test N' sheets with load-depth data"
        )

    cf = frame_compliance_nm_mn
    cf_notes: list[str] = []
    if need_h and cf is None:
        cf = _frame_compliance_from_cycles(sheets, cf_notes)

    indents: list[KlaIndent] = []
    missing_curves: list[str] = []
    used_op = False
    parsed_curves = 0
    for row, test in test_ids:

        def get(key: str, r: int = row) -> float | None:
            return _finite(values[key][r]) if key in values else None

        extra = inputs.get(test, {})
        x = get("x_um") if get("x_um") is not None else extra.get("x_um")
        y = get("y_um") if get("y_um") is not None else extra.get("y_um")
        h, e, drift, p_max, h_max = (
            get("hardness_gpa"),
            get("modulus_gpa"),
            get("drift_rate_nm_s"),
            get("max_load_mn"),
            get("max_depth_nm"),
        )
        failure: str | None = None
        if not need_h and h is None:
            raw = table.data.iat[row, cast(int, cols["hardness_gpa"])]
            failure = f"hardness {_missing_value(raw)}"
        derived: _CurveResult | None = None
        if need_curve and test in curve_sheets:
            curve = _parse_curve(sheets[curve_sheets[test]], curve_sheets[test], notes)
            parsed_curves += curve is not None
            if curve is None:
                notes.append(f"test {test}: sheet {curve_sheets[test]!r} has no Load/Depth columns")
            elif need_h and curve.hardness_gpa is not None and np.isfinite(curve.hardness_gpa).any():
                derived = _csm_average(
                    curve, extra.get("min_calc_depth"), extra.get("max_calc_depth"), test, notes
                )
            elif need_h:
                poisson = extra.get("poisson")
                if poisson is None:
                    notes.append(f"test {test}: no Poisson ratio in the file, {DEFAULT_POISSON} assumed")
                    poisson = DEFAULT_POISSON
                used_op = True
                derived = _oliver_pharr(
                    curve,
                    test=test,
                    frame_compliance_nm_mn=cf or 0.0,
                    poisson=poisson,
                    area_coeffs=_area_coeffs(extra),
                    notes=notes,
                )
            else:  # hardness from Results; the curve only fills the peak load/depth
                peak_values = _peak(curve)
                if peak_values is not None:
                    derived = _CurveResult(None, None, peak_values[0], peak_values[1])
        elif need_h:
            missing_curves.append(test)
        if derived is not None:
            if need_h:
                h, e = _finite(derived.hardness_gpa), _finite(derived.modulus_gpa)
            p_max = p_max if p_max is not None else _finite(derived.max_load_mn)
            h_max = h_max if h_max is not None else _finite(derived.max_depth_nm)
        if need_h and h is None:
            failure = "no hardness from its curve" if test in curve_sheets else "no curve sheet"
        failure = failure or _physical(h, "hardness", MAX_HARDNESS_GPA)
        failure = failure or _physical(e, "modulus", MAX_MODULUS_GPA)
        if failure is not None:
            h = None
            e = e if _physical(e, "modulus", MAX_MODULUS_GPA) is None else None
        source = "curve" if need_h else "results"
        indents.append(KlaIndent(test, x, y, h, e, drift, p_max, h_max, source, failure))

    if need_h and parsed_curves == 0:
        raise InputError(
            str(path), f"no hardness in {res_name!r} and no Test sheet with Load/Depth columns to derive it"
        )
    if missing_curves:
        notes.append(f"no Test sheet for test(s) {', '.join(missing_curves)}: hardness missing")
    if used_op:
        notes.extend(cf_notes)
        if not cf:
            notes.append("modulus not corrected for frame compliance (none given or estimable): reads low")
    failed = [i for i in indents if i.failed]
    if failed:
        shown = "; ".join(f"test {i.test_id}: {i.failure}" for i in failed[:5])
        more = f" (and {len(failed) - 5} more)" if len(failed) > 5 else ""
        notes.append(f"{len(failed)} failed indent(s), no hardness recorded: {shown}{more}")
    _robust_outliers(indents, notes)
    return KlaExport(
        str(path),
        software,
        tuple(indents),
        tuple(dict.fromkeys(notes)),
        hardness_range,
        hardness_column if not need_h else "load-depth curve",
    )


def records(export: KlaExport) -> list[dict[str, Any]]:
    """JSON-ready dicts (None for missing), one per indent."""
    return [asdict(i) for i in export.indents]

"""Curve analysis: a Test sheet's load-depth record to hardness and modulus (Oliver-Pharr, CSM average).

Where a file states no hardness, it is derived from the test's own curve. If the curve carries a CSM
"Hardness" channel, its average over the file's "Minimum/Maximum Calculation Depth" is used; on Example.xls
this reproduces NanoSuite's own Results values to 0.1 %. Otherwise (FusedSilica.xlsx: only Time, Load,
Depth) the Oliver-Pharr method runs on the final unload; see ``oliver_pharr`` for why the surface is
re-found and how the frame compliance is obtained. On FusedSilica.xlsx this gives H ≈ 9.1 GPa and
E ≈ 69 GPa (handbook: ~9 and 72); the instrument's own cycle analysis in that file reads 6.5 / 49.
"""

from __future__ import annotations

import math
import re
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy.optimize import curve_fit

from drivers.kla.readers.columns import CURVE_ALIASES, norm_key, unit_factor
from drivers.kla.readers.tables import numeric, split_table

BERKOVICH_C0 = 24.5  # ideal Berkovich projected area A = 24.5 hc² (nm²)


EPSILON_BERKOVICH = 0.75  # Oliver-Pharr geometry factor for a paraboloid of revolution


DIAMOND_E_GPA = 1141.0


DIAMOND_NU = 0.07


DEFAULT_POISSON = 0.25  # only when the file does not state the sample's Poisson ratio


@dataclass(frozen=True)
class Curve:
    """One Test sheet: arrays in nm / mN / s / GPa (NaN where invalid); markers map label -> row."""

    depth_nm: np.ndarray
    load_mn: np.ndarray
    time_s: np.ndarray | None
    hardness_gpa: np.ndarray | None
    modulus_gpa: np.ndarray | None
    markers: Mapping[str, int] = field(default_factory=dict)


def parse_curve(raw: pd.DataFrame, sheet: str, notes: list[str]) -> Curve | None:
    table = split_table(raw, CURVE_ALIASES["load"] + CURVE_ALIASES["depth"])
    if table is None:
        return None
    cols = {name: table.column(aliases) for name, aliases in CURVE_ALIASES.items()}
    if cols["load"] is None or cols["depth"] is None:
        return None

    def channel(name: str) -> np.ndarray | None:
        col = cols[name]
        if col is None:
            return None
        where = f"{sheet}: {table.headers[col]}"
        return numeric(table.data[col]) * unit_factor(name, table.units[col], where, notes)

    markers: dict[str, int] = {}
    if cols["marker"] is not None:
        for row, label in enumerate(table.data[cols["marker"]]):
            if isinstance(label, str) and label.strip():
                markers.setdefault(norm_key(label), row)
    depth, load = channel("depth"), channel("load")
    assert depth is not None and load is not None
    return Curve(depth, load, channel("time"), channel("hardness"), channel("modulus"), markers)


def marker_row(curve: Curve, *words: str) -> int | None:
    """Row of the first marker whose label contains all the words."""
    for label, row in curve.markers.items():
        if all(w in label for w in words):
            return row
    return None


def find_surface(load: np.ndarray, depth: np.ndarray, clock: np.ndarray, peak: int) -> float:
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
class CurveResult:
    hardness_gpa: float | None
    modulus_gpa: float | None
    max_load_mn: float | None
    max_depth_nm: float | None
    # Oliver-Pharr only: what the file's own analysis can be checked against
    raw_depth_nm: float | None = None  # depth at the analysed peak on the file's own zero
    stiffness_mn_nm: float | None = None  # the unloading stiffness as measured (frame included)
    contact_depth_nm: float | None = None


def area_of(coeffs: tuple[float, ...] | None, hc_nm: float) -> float:
    """Projected contact area (nm²): the file's area function, or the ideal Berkovich 24.5 hc²."""
    if coeffs:
        return float(sum(c * hc_nm ** (2.0 ** (1 - k)) for k, c in enumerate(coeffs)))
    return BERKOVICH_C0 * hc_nm**2


def describe_area(coeffs: tuple[float, ...] | None) -> str:
    """The area function in one phrase, for the notes and ``aeni kla read``."""
    if not coeffs:
        return "A = 24.5 hc² (ideal Berkovich, assumed: the file states no area function)"
    terms = " + ".join(f"{c:g} hc^{2.0 ** (1 - k):g}" for k, c in enumerate(coeffs))
    return f"A = {terms} (the file's area function)"


def _power_law(u: np.ndarray, a: float, uf: float, m: float) -> np.ndarray:
    return a * np.power(np.clip(u - uf, 1e-12, None), m)


def oliver_pharr(
    curve: Curve,
    *,
    test: str,
    frame_compliance_nm_mn: float,
    poisson: float,
    area_coeffs: tuple[float, ...] | None,
    notes: list[str],
) -> CurveResult | None:
    """Oliver-Pharr (1992) on the last unload: P = a (h - hf)^m fitted to its top, S = dP/dh at hmax.

    Why the extra steps: the surface is re-found from the load signal (see ``find_surface``); the
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
    sub = Curve(depth, load, clock, None, None, markers)

    peak = int(np.argmax(load))
    surface = find_surface(load, depth, clock, peak)
    depth = depth - surface

    # unloading starts at the end of the hold: InView marks it, NanoSuite marks the first unload row
    start = marker_row(sub, "end of hold")
    if start is None:
        start = marker_row(sub, "unload")
    if start is None or load[start] < 0.98 * load[peak]:
        start = peak
        while start + 1 < load.size and load[start + 1] >= 0.998 * load[peak]:
            start += 1
    fit_lo = marker_row(sub, "begin stiffness")
    fit_hi = marker_row(sub, "end of stiffness")
    if fit_lo is None or fit_hi is None or not (start <= fit_lo < fit_hi):
        fit_lo = start
        below = np.flatnonzero(load[start:] < 0.5 * load[start])
        fit_hi = start + int(below[0]) if below.size else load.size - 1
    p_max, h_max = float(load[start]), float(depth[start])
    raw_depth = h_max + surface
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
    measured_stiffness = stiffness
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
    area = area_of(area_coeffs, hc)
    hardness = p_max / area * 1e6  # mN/nm² -> GPa
    er = math.sqrt(math.pi) / 2.0 * stiffness / math.sqrt(area) * 1e6
    inv = 1.0 / er - (1 - DIAMOND_NU**2) / DIAMOND_E_GPA
    modulus = (1 - poisson**2) / inv if inv > 0 else None
    return CurveResult(hardness, modulus, p_max, h_max, raw_depth, measured_stiffness, hc)


def peak_of(curve: Curve) -> tuple[float, float] | None:
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


def csm_average(
    curve: Curve, lo_nm: float | None, hi_nm: float | None, test: str, notes: list[str]
) -> CurveResult | None:
    """Mean of the CSM Hardness/Modulus channels over [lo, hi] nm of the loading segment.

    Default band without file limits: 10-20 % of the maximum depth (the 10 % rule for films; bulk
    samples are flat there too), and the warnings say so.
    """
    assert curve.hardness_gpa is not None
    load, depth = curve.load_mn, curve.depth_nm
    peak_values = peak_of(curve)
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
    h, e = loading_band_means(depth, peak, lo, hi, curve.hardness_gpa, curve.modulus_gpa)
    return CurveResult(h, e, p_peak, h_peak)


def loading_band_means(
    depth_nm: np.ndarray, peak: int, lo_nm: float, hi_nm: float, *channels: np.ndarray | None
) -> list[float | None]:
    """Each CSM channel's mean over the loading segment's samples (up to index ``peak``) with a depth in
    [lo_nm, hi_nm], the way InView averages over its calculation depth range; None for a missing channel
    or one without a finite sample there."""
    band = np.zeros(depth_nm.size, dtype=bool)
    band[: peak + 1] = (depth_nm[: peak + 1] >= lo_nm) & (depth_nm[: peak + 1] <= hi_nm)
    means: list[float | None] = []
    for channel in channels:
        values = np.empty(0) if channel is None else channel[band & np.isfinite(channel)]
        means.append(float(values.mean()) if values.size else None)
    return means


def frame_compliance_from_cycles(sheets: Mapping[str, pd.DataFrame], notes: list[str]) -> float | None:
    """Frame compliance (nm/mN) from a multi-cycle test: 1/S = Cf + k/sqrt(P) per test, median intercept.

    Uses an InView "Cycles-*" sheet (Cycle Pmax, Cycle Su per "test:cycle" row) and only the cycles
    above 10 % of the test's peak load (the shallow ones suffer from tip rounding). Each test gets its own
    slope, so a map whose hardness varies between tests does not bias the intercept; the median shrugs off
    a bad indent.
    """
    label = re.compile(r"^\s*(\d+)\s*:\s*(\d+)\s*$")
    for name, raw in sheets.items():
        if not norm_key(name).startswith("cycles"):
            continue
        table = split_table(raw, ("cycle pmax", "cycle su"))
        if table is None:
            continue
        cp, cs = table.column(("cycle pmax",)), table.column(("cycle su",))
        if cp is None or cs is None:
            continue
        f_p = unit_factor("load", table.units[cp], f"{name}: Cycle Pmax", notes)
        f_s = unit_factor("stiffness", table.units[cs], f"{name}: Cycle Su", notes)
        rows: dict[str, list[tuple[float, float]]] = {}
        p_all, s_all = numeric(table.data[cp]) * f_p, numeric(table.data[cs]) * f_s
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


def area_coeffs_of(values: Mapping[str, float]) -> tuple[float, ...] | None:
    """NanoSuite 'Area Coefficient k' -> (C0, C1, ...) for A = C0 hc² + C1 hc + C2 hc^½ + ..."""
    ks = sorted(int(k[4:]) for k in values if k.startswith("area") and k[4:].isdigit())
    if not ks or ks[0] != 1:
        return None
    coeffs = tuple(values[f"area{k}"] for k in range(1, ks[-1] + 1) if f"area{k}" in values)
    return coeffs if len(coeffs) == ks[-1] and coeffs[0] > 0 else None


def cycle_results(
    curve: Curve,
    *,
    test: str,
    frame_compliance_nm_mn: float,
    poisson: float,
    area_coeffs: tuple[float, ...] | None,
    min_share: float = 0.1,
) -> list[CurveResult]:
    """Oliver-Pharr on every unload of a multi-cycle test whose peak is at least ``min_share`` of the
    test's (the shallow ones are tip rounding), shallowest first: the record cut after each cycle's unload
    is analysed as a test of its own. A homogeneous sample has one modulus at every depth, so moduli that
    drift with depth say the area function is not the tip's (``plausibility.cycles_disagree``)."""
    load = curve.load_mn
    if np.isfinite(load).sum() < 20:
        return []
    filled = np.where(np.isfinite(load), load, 0.0)
    top = float(filled.max())
    results: list[CurveResult] = []
    running = 0.0
    i = 0
    while i < filled.size:
        p = filled[i]
        running = max(running, p)
        if running >= min_share * top and p < 0.6 * running:  # this cycle's unload is past 60 %
            while i + 1 < filled.size and filled[i + 1] <= filled[i]:
                i += 1  # to where the unload ends
            clock = None if curve.time_s is None else curve.time_s[: i + 1]
            sub = Curve(curve.depth_nm[: i + 1], load[: i + 1], clock, None, None, {})
            result = oliver_pharr(
                sub,
                test=test,
                frame_compliance_nm_mn=frame_compliance_nm_mn,
                poisson=poisson,
                area_coeffs=area_coeffs,
                notes=[],
            )
            if result is not None:
                results.append(result)
            running = 0.0
        i += 1
    return results

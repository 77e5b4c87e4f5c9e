"""Physically consistent load-depth records and the files InView writes from them, for the reader's tests.

A Berkovich tip with an area function ``A(hc) = C0 hc² + C1 hc + C2 hc^½ + ...`` indents a material of
hardness H and modulus E: on loading A = P/H, the unloading stiffness is S = 2/√π Er √A, the unload follows
P = Pm ((h - hf)/(hm - hf))^1.5 (so hc = hm - 0.75 Pm/S), a reload retraces it, and the frame adds P·Cf to
the measured depth. The instrument's own analysis (what it writes in a Cycles sheet or a per-test record's
HARDNESS/MODULUS channels) is computed from the same numbers, so a reader can be checked against the file.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

DIAMOND_E_GPA, DIAMOND_NU = 1141.0, 0.07


@dataclass(frozen=True)
class Material:
    hardness_gpa: float = 9.3  # fused silica
    modulus_gpa: float = 72.0
    poisson: float = 0.17

    @property
    def reduced_gpa(self) -> float:
        return 1.0 / ((1 - self.poisson**2) / self.modulus_gpa + (1 - DIAMOND_NU**2) / DIAMOND_E_GPA)


@dataclass(frozen=True)
class Tip:
    coeffs: tuple[float, ...] = (24.5,)  # nm², nm, nm^1.5 ...

    def area(self, hc: float | np.ndarray) -> float | np.ndarray:
        return sum(c * np.power(hc, 2.0 ** (1 - k)) for k, c in enumerate(self.coeffs))

    def contact_depth(self, area_nm2: float) -> float:
        lo, hi = 0.0, 1e6
        for _ in range(100):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if self.area(mid) < area_nm2 else (lo, mid)
        return 0.5 * (lo + hi)


@dataclass
class Record:
    """One test: arrays as the instrument writes them (depth from the file's own zero) and its analysis."""

    time_s: np.ndarray
    load_mn: np.ndarray
    depth_nm: np.ndarray
    markers: dict[int, str]
    cycles: list[dict[str, float]] = field(default_factory=list)  # per cycle: Pmax, hmax, S, A, hc, H, E
    hardness_gpa: np.ndarray | None = None  # the instrument's running H (CSM-like), NaN before contact
    modulus_gpa: np.ndarray | None = None


def indent(
    material: Material,
    tip: Tip,
    peaks_mn: tuple[float, ...],
    *,
    unload_to: float = 0.5,
    frame_nm_mn: float = 0.1,
    zero_before_contact_nm: float = 90.0,
    points: int = 40,
    noise_mn: float = 0.0004,
    seed: int = 0,
) -> Record:
    """A multi-cycle test to ``peaks_mn`` (the last is the test's peak), each cycle unloading to
    ``unload_to`` of its peak, the last one to 10 % for a drift hold. The file's depth zero (its Surface
    Index) sits ``zero_before_contact_nm`` before the real contact, as in FusedSilica.xlsx."""
    rng = np.random.default_rng(seed)
    er = material.reduced_gpa
    t: list[float] = []
    p: list[float] = []
    h: list[float] = []
    markers: dict[int, str] = {0: "Surface Index"}
    cycles: list[dict[str, float]] = []

    def add(load: float, depth: float) -> None:
        t.append(0.2 * len(t))
        p.append(load)
        h.append(depth)

    for k in range(points):  # approach: depth runs, the load is noise
        add(float(rng.normal(0.0, noise_mn)), zero_before_contact_nm * k / (points - 1))

    def plastic(load: float) -> tuple[float, float, float]:
        area = load * 1e6 / material.hardness_gpa
        hc = tip.contact_depth(area)
        s = 2 / math.sqrt(math.pi) * er * math.sqrt(area) * 1e-6
        return hc + 0.75 * load / s, s, hc

    prev: tuple[float, float, float] | None = None  # (Pm, hm, hf) of the last unload
    for i, pm in enumerate(peaks_mn):
        last = i == len(peaks_mn) - 1
        start = p[-1] if prev else 0.0
        for load in np.linspace(max(start, 0.0), pm, points)[1:]:
            if prev is not None and load <= prev[0]:
                depth = prev[2] + (prev[1] - prev[2]) * (load / prev[0]) ** (2 / 3)
            else:
                depth = plastic(load)[0]
            add(load, depth + load * frame_nm_mn + zero_before_contact_nm)
        if last:
            markers[len(p) - 1] = "End Of Loading Index"
        hm, s, hc = plastic(pm)
        for _ in range(5):
            add(pm, hm + pm * frame_nm_mn + zero_before_contact_nm)
        if last:
            markers[len(p) - 1] = "End Of Hold At Load Index"
        hf = hm - 1.5 * pm / s
        floor = 0.1 if last else unload_to
        for j, load in enumerate(np.linspace(pm, floor * pm, points)[1:]):
            add(load, hf + (hm - hf) * (load / pm) ** (2 / 3) + load * frame_nm_mn + zero_before_contact_nm)
            if last and j == 0:
                markers[len(p) - 1] = "Begin Stiffness Data Index"
            if last and load <= 0.5 * pm and "End Of Stiffness Data Index" not in markers.values():
                markers[len(p) - 1] = "End Of Stiffness Data Index"
        prev = (pm, hm, hf)
        area = float(tip.area(hc))
        s_measured = 1.0 / (1.0 / s + frame_nm_mn)
        cycles.append(
            {
                "Pmax": pm,
                "hmax": hm + pm * frame_nm_mn + zero_before_contact_nm,
                "S": s_measured,
                "A": area,
                "hc": hc,
                "H": pm / area * 1e6,
                "E": material.modulus_gpa,
            }
        )
    for k in range(20):  # drift hold at 10 %
        add(p[-1], h[-1])
        if k in (1, 18):
            markers[len(p) - 1] = "Begin Drift Data Index" if k == 1 else "End Drift Data Index"
    for load in np.linspace(p[-1], 0.0, 10)[1:]:
        pm, hm, hf = prev  # type: ignore[misc]
        add(load, hf + (hm - hf) * (load / pm) ** (2 / 3) + load * frame_nm_mn + zero_before_contact_nm)
    load_arr = np.array(p)
    load_arr[points:] += rng.normal(0.0, noise_mn, load_arr.size - points)
    return Record(np.array(t), load_arr, np.array(h), markers, cycles)


def curve_sheet(rec: Record, *, load_unit: str = "mN", depth_unit: str = "nm") -> list[list[object]]:
    """An InView 'Test N' sheet: Markers, Time, Load, Depth with a units row."""
    lf = {"mN": 1.0, "µN": 1e3, "uN": 1e3}[load_unit]
    df = {"nm": 1.0, "µm": 1e-3, "um": 1e-3}[depth_unit]
    rows: list[list[object]] = [["Markers", "Time", "Load", "Depth"], ["", "s", load_unit, depth_unit]]
    for i in range(rec.time_s.size):
        rows.append(
            [
                rec.markers.get(i),
                float(rec.time_s[i]),
                float(rec.load_mn[i] * lf),
                float(rec.depth_nm[i] * df),
            ]
        )
    return rows


def cycles_sheet(records: list[Record]) -> list[list[object]]:
    """InView's 'Cycles-GroupedByTest': the instrument's own per-cycle analysis ('test:cycle' rows)."""
    rows: list[list[object]] = [
        ["", "Cycle Pmax", "Cycle hmax", "Cycle Su", "Cycle Acu", "Cycle Eu", "Cycle Hu", "Cycle hcu"],
        ["", "mN", "nm", "N/m", "nm²", "GPa", "GPa", "nm"],
    ]
    for n, rec in enumerate(records, start=1):
        rows.append([f"Test {n}"])
        for c, cyc in enumerate(rec.cycles, start=1):
            rows.append(
                [
                    f"{n}:{c}",
                    cyc["Pmax"],
                    cyc["hmax"],
                    cyc["S"] * 1e6,
                    cyc["A"],
                    cyc["E"],
                    cyc["H"],
                    cyc["hc"],
                ]
            )
    return rows


def inview_workbook(
    records: list[Record], *, poisson: float = 0.17, cycles: bool = True
) -> dict[str, list[list[object]]]:
    """An InView multi-cycle workbook whose Results sheet holds no H or E (as FusedSilica.xlsx)."""
    results: list[list[object]] = [
        ["Test", "Pmax", "Target  Load", "X_Position", "Y_Position"],
        ["", "mN", "mN", "Âµm", "Âµm"],
    ]
    for n, rec in enumerate(records, start=1):
        results.append(
            [n, float(np.max(rec.load_mn)), round(float(np.max(rec.load_mn))), 1000.0 + 30 * n, 2000.0]
        )
    sheets: dict[str, list[list[object]]] = {
        "Results": results,
        "Pre-Test Inputs": [["Test", "Poisson's Ratio of Sample"], ["", "None"]]
        + [[n, poisson] for n in range(1, len(records) + 1)],
    }
    if cycles:
        sheets["Cycles-GroupedByTest"] = cycles_sheet(records)
    for n, rec in enumerate(records, start=1):
        sheets[f"Test {n}"] = curve_sheet(rec)
    return sheets


RECORD_HEADER = [
    "Markers",
    "Displacement",
    "Force",
    "Time",
    "DEPTH",
    "LOAD",
    "STIFFNESS",
    "HARDNESS",
    "MODULUS",
    "hdotOverh",
    "Velocity",
    "Dyn. Phase",
    "X Axis Position",
    "Y Axis Position",
]
RECORD_UNITS = ["", "nm", "mN", "s", "nm", "mN", "N/m", "GPa", "GPa", "1/s", "nm/s", "deg", "µm", "µm"]
INVALID = 1.797e308


@dataclass(frozen=True)
class RecordStyle:
    """How one InView per-test CSV is written: the ways real ones differ."""

    markers: str = "top"  # "top": marker rows gathered under the units row; "inline": on their sample
    bom: bool = False
    crlf: bool = False
    semicolon: bool = False  # ';' separated with decimal commas (a German/French Windows locale)
    invalid: str = "blank"  # how an invalid HARDNESS is written: "blank" or "dbl_max"
    window_nm: tuple[float, float] | None = None  # a preamble naming the method's averaging window
    drift_nm_s: float = 0.05  # the raw Displacement drifts by this; DEPTH is corrected
    fail: bool = False  # the surface was not found: every HARDNESS/MODULUS sample invalid
    size_effect: bool = True  # the running H and E change with depth (so where they are taken matters)


def record_rows(
    rec: Record,
    material: Material,
    x_um: float,
    y_um: float,
    style: RecordStyle,
    *,
    pos_unit: str = "µm",
    h_unit: str = "GPa",
) -> tuple[list[list[object]], dict[str, float]]:
    """An InView per-test record and the values InView reports from it (the truth for a reader):
    H and E at the End Of Loading marker, or averaged over the style's window."""
    n = rec.time_s.size
    contact = np.argmax(rec.load_mn > 0.01 * rec.load_mn.max())
    depth = rec.depth_nm - rec.depth_nm[contact]
    # the instrument's running hardness and modulus: a mild size effect so that "where" matters
    hc = np.clip(depth, 1.0, None)
    grow_h = 1 + 30.0 / (hc + 30.0) if style.size_effect else np.ones(n)
    grow_e = 1 + 5.0 / (hc + 50.0) if style.size_effect else np.ones(n)
    hardness = np.where(np.arange(n) >= contact, material.hardness_gpa * grow_h, np.nan)
    modulus = np.where(np.arange(n) >= contact, material.modulus_gpa * grow_e, np.nan)
    end_loading = next(i for i, m in rec.markers.items() if m == "End Of Loading Index")
    if style.window_nm is not None:
        lo, hi = style.window_nm
        band = np.zeros(n, dtype=bool)
        band[: end_loading + 1] = (depth[: end_loading + 1] >= lo) & (depth[: end_loading + 1] <= hi)
        truth = {"H": float(np.nanmean(hardness[band])), "E": float(np.nanmean(modulus[band]))}
    else:
        truth = {"H": float(hardness[end_loading]), "E": float(modulus[end_loading])}
    truth.update(x=x_um, y=y_um, drift=style.drift_nm_s, P=float(rec.load_mn[end_loading]))
    markers = dict(rec.markers)

    ps = {"µm": 1.0, "mm": 1e-3}[pos_unit]
    hs = {"GPa": 1.0, "MPa": 1e3}[h_unit]

    def value(v: float) -> object:
        if not math.isfinite(v):
            return INVALID if style.invalid == "dbl_max" else None
        return v * hs

    samples: list[list[object]] = []
    for i in range(n):
        failed = style.fail or not math.isfinite(hardness[i])
        samples.append(
            [
                None,
                float(rec.depth_nm[i] + style.drift_nm_s * rec.time_s[i]),
                float(rec.load_mn[i]),
                float(rec.time_s[i]),
                float(depth[i]),
                float(rec.load_mn[i]),
                None
                if failed
                else 1e6 * 2 / math.sqrt(math.pi) * material.reduced_gpa * 1e-6 * math.sqrt(24.5) * hc[i],
                value(math.nan if failed else float(hardness[i])),
                value(math.nan if failed else float(modulus[i])),
                0.05,
                10.0,
                1.2,
                x_um * ps,
                y_um * ps,
            ]
        )
    if style.fail:
        truth["H"] = truth["E"] = math.nan
    rows: list[list[object]] = []
    if style.window_nm is not None:
        rows += [
            ["Minimum Calculation Depth", style.window_nm[0], "nm"],
            ["Maximum Calculation Depth", style.window_nm[1], "nm"],
            [],
        ]
    units = list(RECORD_UNITS)
    units[7] = units[8] = h_unit
    units[12] = units[13] = pos_unit
    rows += [list(RECORD_HEADER), units]
    if style.markers == "top":
        for i, label in sorted(markers.items(), key=lambda kv: kv[1]):  # by name: not in row order
            rows.append([label, *samples[i][1:]])
        rows += samples
    else:
        for i, row in enumerate(samples):
            rows.append([markers.get(i), *row[1:]])
    return rows, truth


def write_record(path: str, rows: list[list[object]], style: RecordStyle) -> None:
    sep = ";" if style.semicolon else ","

    def cell(v: object) -> str:
        if v is None:
            return ""
        if isinstance(v, float):
            text = repr(v)
            return text.replace(".", ",") if style.semicolon else text
        return str(v)

    text = ("\r\n" if style.crlf else "\n").join(sep.join(cell(v) for v in row) for row in rows) + "\n"
    data = text.encode("utf-8")
    with open(path, "wb") as fh:
        fh.write((b"\xef\xbb\xbf" if style.bom else b"") + data)

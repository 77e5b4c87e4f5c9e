"""Plausibility: values no material has, and indents far from the rest of their file."""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import cast

import numpy as np
import pandas as pd

from drivers.kla.readers.columns import clean_unit, norm_key, unit_factor
from drivers.kla.readers.curves import CurveResult, area_of, describe_area
from drivers.kla.readers.indents import KlaIndent
from drivers.kla.readers.tables import numeric, split_table

# values no material has: hardness above diamond's, modulus above diamond's (GPa)
MAX_HARDNESS_GPA = 200.0


MAX_MODULUS_GPA = 1500.0


def implausible(value: float | None, what: str, limit: float) -> str | None:
    """Why a hardness or modulus value cannot be real (zero, negative, above diamond's), or None."""
    if value is None:
        return None
    if value <= 0:
        return f"{what} {value:.4g} GPa is not physical (≤ 0)"
    if value > limit:
        return f"{what} {value:.4g} GPa is not physical (> {limit:g})"
    return None


def note_outliers(indents: list[KlaIndent], notes: list[str]) -> None:
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


# ------------------------------------------------------------------ the file's own analysis as a check


@dataclass(frozen=True)
class OwnCycle:
    """One cycle of the instrument's own analysis (InView 'Cycles-*' sheets), in mN, nm, mN/nm, nm²."""

    load_mn: float
    depth_nm: float | None
    stiffness_mn_nm: float | None
    area_nm2: float | None
    contact_depth_nm: float | None


_CYCLE_ROW = re.compile(r"^\s*(\d+)\s*:\s*(\d+)\s*$")


def own_cycles(sheets: Mapping[str, pd.DataFrame], notes: list[str]) -> tuple[str, dict[str, list[OwnCycle]]]:
    """The file's per-cycle analysis by test ('test:cycle' rows), from the first Cycles sheet that has it."""
    for name, raw in sheets.items():
        if not norm_key(name).startswith("cycles"):
            continue
        table = split_table(raw, ("cycle pmax",))
        if table is None or table.column(("cycle pmax",)) is None:
            continue
        quantities = {
            "load": ("cycle pmax",),
            "depth": ("cycle hmax",),
            "stiffness": ("cycle su", "cycle s"),
            "area": ("cycle acu", "cycle ac"),
            "contact": ("cycle hcu", "cycle hc"),
        }
        columns: dict[str, np.ndarray] = {}
        for key, aliases in quantities.items():
            col = table.column(aliases)
            if col is None:
                continue
            unit = {"load": "load", "stiffness": "stiffness"}.get(key, "depth")
            factor = (
                1.0 if key == "area" else unit_factor(unit, table.units[col], f"{name}: {aliases[0]}", notes)
            )
            if key == "area" and clean_unit(table.units[col]) in ("µm²", "µm2", "um²", "um2"):
                factor = 1e6
            columns[key] = numeric(table.data[col]) * factor
        out: dict[str, list[OwnCycle]] = {}
        for i, cell in enumerate(table.data[0]):
            m = _CYCLE_ROW.match(str(cell))
            if m is None or not np.isfinite(columns["load"][i]):
                continue

            def get(key: str, row: int = i, columns: dict[str, np.ndarray] = columns) -> float | None:
                v = columns[key][row] if key in columns else math.nan
                return float(v) if np.isfinite(v) and v > 0 else None

            out.setdefault(m.group(1), []).append(
                OwnCycle(
                    float(columns["load"][i]), get("depth"), get("stiffness"), get("area"), get("contact")
                )
            )
        if out:
            return name, out
    return "", {}


AREA_TOLERANCE = 0.10  # FusedSilica.xlsx: the ideal 24.5 hc² is 3-8 % above the file's own contact areas
LOAD_DEPTH_TOLERANCE = 0.05  # peak load and depth: the same numbers, read twice (units, which cycle)


def contradiction(
    test: str,
    *,
    load_mn: float | None,
    raw_depth_nm: float | None,
    area_coeffs: tuple[float, ...] | None,
    own: OwnCycle | None,
    own_sheet: str,
    results_load_mn: float | None,
) -> str | None:
    """Why a value computed from a test's curve contradicts what the file itself says, or None.

    Checked where the file says it: the peak load (the Results' Pmax, the last cycle's Pmax) and depth
    (the last cycle's hmax, on the file's own zero) catch a unit or a wrong cycle; the file's own contact
    area at its own contact depth catches an area function that is not the tip's (an area too small by
    2.2x reads hardness 2.2x and modulus 1.5x high: the ratio of the squares is an area's fingerprint).
    """
    if load_mn is not None and results_load_mn is not None:
        ratio = load_mn / results_load_mn
        if abs(ratio - 1) > LOAD_DEPTH_TOLERANCE:
            return (
                f"test {test}: the curve's peak load {load_mn:.4g} mN is {ratio:.3g}x the Results' Pmax "
                f"{results_load_mn:.4g} mN (a load unit or another cycle)"
            )
    if own is None:
        return None
    if load_mn is not None and abs(load_mn / own.load_mn - 1) > LOAD_DEPTH_TOLERANCE:
        return (
            f"test {test}: the curve's peak load {load_mn:.4g} mN is {load_mn / own.load_mn:.3g}x the last "
            f"cycle's Pmax {own.load_mn:.4g} mN in {own_sheet!r} (a load unit or another cycle)"
        )
    if raw_depth_nm is not None and own.depth_nm is not None:
        ratio = raw_depth_nm / own.depth_nm
        if abs(ratio - 1) > LOAD_DEPTH_TOLERANCE:
            return (
                f"test {test}: the curve's depth at peak load {raw_depth_nm:.4g} nm is {ratio:.3g}x the last "
                f"cycle's hmax {own.depth_nm:.4g} nm in {own_sheet!r} (a depth unit or another cycle)"
            )
    if own.area_nm2 is not None and own.contact_depth_nm is not None:
        ratio = area_of(area_coeffs, own.contact_depth_nm) / own.area_nm2
        if abs(ratio - 1) > AREA_TOLERANCE:
            return (
                f"test {test}: the area function {describe_area(area_coeffs)} gives {ratio:.2f}x the file's "
                f"own contact area at hc = {own.contact_depth_nm:.0f} nm ({own_sheet!r}): it is not this tip's; "
                "hardness would read "
                f"{1 / ratio:.2f}x"
            )
    return None


CYCLE_MODULUS_SPREAD = 0.20  # FusedSilica.xlsx: 5-9 % over 150-465 nm; an area 2x off at 100 nm: 80 %


def cycle_spread(results: list[CurveResult]) -> tuple[float, str] | None:
    """How far a test's per-cycle moduli drift with depth (max/min - 1) and a phrase naming the extremes;
    None with fewer than three cycles to compare."""
    usable = [r for r in results if r.modulus_gpa is not None and r.contact_depth_nm is not None]
    if len({round(cast(float, r.contact_depth_nm)) for r in usable}) < 3:
        return None
    shallow, deep = usable[0], usable[-1]
    moduli = [cast(float, r.modulus_gpa) for r in usable]
    phrase = (
        f"E {shallow.modulus_gpa:.0f} GPa at hc = {shallow.contact_depth_nm:.0f} nm but "
        f"{deep.modulus_gpa:.0f} GPa at {deep.contact_depth_nm:.0f} nm"
    )
    return max(moduli) / min(moduli) - 1.0, phrase

"""Results read from the Test sheets themselves (TestWorks, InView templates without a Results sheet)."""

from __future__ import annotations

import re
from collections.abc import Mapping
from pathlib import Path

import pandas as pd

from core.errors import InputError
from drivers.kla.readers.columns import (
    CURVE_ALIASES,
    NOT_A_VALUE,
    RESULT_ALIASES,
    TEST_SHEET,
    norm_key,
    unit_factor,
)
from drivers.kla.readers.curves import parse_curve
from drivers.kla.readers.tables import as_number, is_blank, parse_header


def curve_sheet_names(sheets: Mapping[str, pd.DataFrame]) -> dict[str, str]:
    """test key -> curve sheet; 'Test 004' wins over 'Test 004 Tagged' when both exist."""
    out: dict[str, str] = {}
    for name in sheets:
        m = TEST_SHEET.match(name)
        if m is None:
            continue
        key = str(int(m.group(1)))
        exact = name.strip().lower().replace(" ", "") == f"test{m.group(1)}".lower()
        if key not in out or exact:
            out[key] = name
    return out


def _key_of(text: str) -> str | None:
    """Which result a label names ('Hardness At Max Load (GPa)' -> hardness_gpa), or None."""
    key = norm_key(parse_header(text)[0])
    for name, aliases in RESULT_ALIASES.items():
        if name != "test_id" and key in aliases:
            return name
    words = set(re.split(r"[^a-z%]+", key))
    if not words & NOT_A_VALUE:
        if "hardness" in key:
            return "hardness_gpa"
        if "modulus" in key and "reduced" not in words:
            return "modulus_gpa"
    return None


def _sheet_own_result(raw: pd.DataFrame, sheet: str, notes: list[str]) -> dict[str, float]:
    """A Test sheet's own result (TestWorks, some InView templates), as 'label | value | unit' rows or as a
    one-row table (labels, an optional units row, one row of values), converted to µm / GPa / nm/s / mN /
    nm. A curve's header row is not a result: its labels have a column of numbers below them."""
    grid = [list(r) for r in raw.iloc[:200, :60].itertuples(index=False)]
    load_words = set(CURVE_ALIASES["load"])
    depth_words = set(CURVE_ALIASES["depth"])

    def at(r: int, j: int) -> object:
        return grid[r][j] if r < len(grid) and j < len(grid[r]) else None

    out: dict[str, float] = {}
    for r, row in enumerate(grid):
        keys = {norm_key(parse_header(c)[0]) for c in row if isinstance(c, str)}
        curve_header = bool(keys & load_words) and bool(keys & depth_words)
        for j, cell in enumerate(row):
            if not isinstance(cell, str) or not cell.strip():
                continue
            key = _key_of(cell)
            if key is None or key in out:
                continue
            unit: object = parse_header(cell)[1]
            right = [c for c in row[j + 1 : j + 4] if not is_blank(c)]
            value = as_number(right[0]) if right else None
            if value is not None:
                if unit is None and len(right) > 1 and isinstance(right[1], str):
                    unit = right[1]
            elif not curve_header:
                below = [at(r + k, j) for k in (1, 2, 3)]
                if as_number(below[0]) is not None and as_number(below[1]) is None:
                    value = as_number(below[0])
                elif (
                    isinstance(below[0], str)
                    and as_number(below[1]) is not None
                    and as_number(below[2]) is None
                ):
                    value, unit = as_number(below[1]), unit or below[0]
            if value is not None:
                out[key] = value * unit_factor(key, unit, f"{sheet}: {cell.strip()}", notes)
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


def results_from_test_sheets(
    path: Path, sheets: Mapping[str, pd.DataFrame], notes: list[str]
) -> pd.DataFrame:
    """A Results table built from the Test sheets' own results, one row per sheet in test order (a test
    without a result there gets its hardness from its curve, as for a Results sheet without hardness)."""
    curve_sheets = curve_sheet_names(sheets)
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
    elif any(parse_curve(sheets[n], n, []) is not None for n in curve_sheets.values()):
        notes.append("no Results sheet and no result on the Test sheets: hardness from each test's curve")
    else:
        raise InputError(
            str(path),
            f"no Results sheet, and its {len(curve_sheets)} Test sheets hold neither a hardness value nor "
            "Load/Depth columns",
        )
    return pd.DataFrame(rows, dtype=object)

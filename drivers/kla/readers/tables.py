"""A sheet as a table: the header row, the optional units row, the data; cells to numbers and test keys."""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import cast

import numpy as np
import pandas as pd

from drivers.kla.readers.columns import (
    HEADER_RANGE,
    HEADER_UNIT,
    INVALID_THRESHOLD,
    LENGTH_NM,
    SUMMARY_LABELS,
    TEST_SHEET,
    clean_unit,
    norm_key,
)


@dataclass(frozen=True)
class Table:
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


def is_number(value: object) -> bool:
    return isinstance(value, int | float | np.integer | np.floating) and not isinstance(value, bool)


def parse_header(text: str) -> tuple[str, str | None, tuple[float, float] | None]:
    """'Avg Hardness [75-85 nm] (GPa)' -> ('Avg Hardness', 'GPa', (75.0, 85.0)): name, unit, range in nm."""
    depth_range: tuple[float, float] | None = None
    m = HEADER_RANGE.search(text)
    if m:
        factor = LENGTH_NM[clean_unit(m.group(3))]
        depth_range = (float(m.group(1)) * factor, float(m.group(2)) * factor)
        text = (text[: m.start()] + " " + text[m.end() :]).strip()
    u = HEADER_UNIT.match(text)
    if u:
        return u.group(1).strip(), u.group(2), depth_range
    return text, None, depth_range


def looks_like_units_row(cells: list[object]) -> bool:
    """A row of short unit labels ('µm', 'GPa', 'nm/s') and blanks: no numbers, no test labels, no '--'."""
    texts = [c.strip() for c in cells if isinstance(c, str) and c.strip()]
    if not texts or any(is_number(c) and not math.isnan(float(cast(float, c))) for c in cells):
        return False
    return all(len(t) <= 16 and not TEST_SHEET.match(t) and t.strip("-") for t in texts)


def split_table(raw: pd.DataFrame, header_aliases: Iterable[str]) -> Table | None:
    """Find the header row (first of the top 30 naming a known column) and an optional units row."""
    wanted = set(header_aliases)
    header_row = None
    for r in range(min(30, len(raw))):
        if any(norm_key(parse_header(v)[0]) in wanted for v in raw.iloc[r] if isinstance(v, str)):
            header_row = r
            break
    if header_row is None:
        return None
    headers: list[str] = []
    units: list[object] = []
    ranges: list[tuple[float, float] | None] = []
    for v in raw.iloc[header_row]:
        text = "" if v is None or (isinstance(v, float) and math.isnan(v)) else str(v)
        name, unit, depth_range = parse_header(text)
        headers.append(name)
        units.append(unit)
        ranges.append(depth_range)
    start = header_row + 1
    if start < len(raw):
        cells = list(raw.iloc[start])
        if looks_like_units_row(cells):
            units = [cells[i] if units[i] is None else units[i] for i in range(len(cells))]
            start += 1
    data = raw.iloc[start:].reset_index(drop=True)
    data.columns = range(data.shape[1])
    return Table(tuple(headers), tuple(norm_key(h) for h in headers), tuple(units), data, tuple(ranges))


def twin_columns(table: Table, col: int) -> list[int]:
    """The other columns with the very same name as ``col``, as written (an export with a duplicated
    header); case counts: 'H' (hardness) and 'h' (a depth) are not twins."""
    name = " ".join(table.headers[col].split())
    return [i for i, h in enumerate(table.headers) if i != col and " ".join(h.split()) == name]


def numeric(series: pd.Series) -> np.ndarray:
    values = np.array(pd.to_numeric(series, errors="coerce"), dtype=float)
    values[np.abs(values) >= INVALID_THRESHOLD] = np.nan
    return values


def test_key_of(label: object) -> str | None:
    """'1', 1, 1.0, 'Test 001' -> '1'; other labels as written; blanks -> None."""
    if label is None or (isinstance(label, float) and math.isnan(label)):
        return None
    if is_number(label):
        f = float(cast(float, label))
        return str(int(f)) if f.is_integer() else str(f)
    s = str(label).strip()
    if not s:
        return None
    m = TEST_SHEET.match(s)
    if m:
        return str(int(m.group(1)))
    try:
        f = float(s)
    except ValueError:
        return s
    return str(int(f)) if f.is_integer() else s


def finite(value: float | None) -> float | None:
    return None if value is None or not math.isfinite(value) else float(value)


def is_blank(cell: object) -> bool:
    return (
        cell is None
        or (isinstance(cell, float) and math.isnan(cell))
        or (isinstance(cell, str) and not cell.strip())
    )


def as_number(cell: object) -> float | None:
    """A finite number from a cell (numeric text too, decimal comma allowed); None for anything else."""
    if is_number(cell):
        value = float(cast(float, cell))
    elif isinstance(cell, str) and cell.strip():
        try:
            value = float(cell.strip().replace(",", "."))
        except ValueError:
            return None
    else:
        return None
    return value if math.isfinite(value) and abs(value) < INVALID_THRESHOLD else None


def missing_value(raw: object) -> str:
    """What a cell that gave no number held, for the failure reason."""
    if raw is None or (isinstance(raw, float) and math.isnan(raw)):
        return "blank"
    if is_number(raw):
        v = float(cast(float, raw))
        if not math.isfinite(v) or abs(v) >= INVALID_THRESHOLD:
            return "1.797e308 (the instrument's 'invalid')"
        return f"{v:g}"
    text = str(raw).strip()
    return repr(text) if text else "blank"


def is_summary_row(cells: list[object]) -> bool:
    """'Average', 'Std Dev', '% COV' ... in any text cell of the row (the label column varies)."""
    return any(isinstance(cell, str) and norm_key(cell).rstrip(":") in SUMMARY_LABELS for cell in cells)

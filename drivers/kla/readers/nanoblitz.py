"""The NanoBlitz family: KLA's fast mapping (NanoBlitz 3D: one indent per row; 4D: CSM, hardness and
modulus by depth for every indent), exported as one CSV or sheet of tens of thousands of rows.

What marks one: the program's own name in the file, or its columns -- a stage position spelt
``X Position``/``Y Position`` (InView's Results write ``X Test Position``/``X_Position``), hardness and modulus,
and a per-indent peak measure (load, depth or stiffness at max load) in one table without Test sheets. 4D:
the word "4D", a depth column beside a test column that repeats (one row per depth), or several hardness
columns at named depths ("Hardness [100-200 nm]", "Hardness [200-300 nm]"). The rows are read by the
results-table reader (``readers.workbook``); failed indents (blank cells) are failed, never numbers.
"""

from __future__ import annotations

import re
from collections.abc import Mapping

import pandas as pd

from drivers.kla.readers.columns import RESULT_ALIASES, TEST_SHEET, norm_key
from drivers.kla.readers.tables import parse_header

SOFTWARE_NANOBLITZ_3D = "NanoBlitz 3D"
SOFTWARE_NANOBLITZ_4D = "NanoBlitz 4D"

_PEAK_KEYS = frozenset(
    RESULT_ALIASES["max_load_mn"]
    + RESULT_ALIASES["max_depth_nm"]
    + ("stiffness", "stiffness at max load", "load", "depth")
)


def nanoblitz_kind(sheets: Mapping[str, pd.DataFrame], text: str) -> str | None:
    """'NanoBlitz 3D', 'NanoBlitz 4D', or None when the file is not a NanoBlitz export."""
    named = re.search(r"\bnano\s?blitz\b", text) is not None
    if not named and (len(sheets) != 1 or any(TEST_SHEET.match(n) for n in sheets)):
        return None
    raw = next(iter(sheets.values())) if len(sheets) == 1 else None
    headers: list[str] = []
    if raw is not None:
        for r in range(min(30, len(raw))):
            cells = [str(c).strip() for c in raw.iloc[r] if isinstance(c, str) and c.strip()]
            if sum(norm_key(parse_header(c)[0]) in ("x position", "y position") for c in cells) == 2:
                headers = cells
                break
    spelt = [parse_header(h)[0].lower() for h in headers]
    keys = [norm_key(s) for s in spelt]
    fingerprint = (
        "x position" in spelt  # a space, not InView's X_Position
        and any("hardness" in k for k in keys)
        and any("modulus" in k for k in keys)
        and bool(set(keys) & _PEAK_KEYS)
    )
    if not (named or fingerprint):
        return None
    depth_tagged = sum(1 for h in headers if "hardness" in h.lower() and parse_header(h)[2] is not None)
    if re.search(r"\b4d\b", text) or depth_tagged >= 2 or (raw is not None and _depth_rows(raw, headers)):
        return SOFTWARE_NANOBLITZ_4D
    return SOFTWARE_NANOBLITZ_3D


def _depth_rows(raw: pd.DataFrame, headers: list[str]) -> bool:
    """A test column whose ids repeat beside a depth column: one row per depth of each indent."""
    keys = [norm_key(parse_header(h)[0]) for h in headers]
    if "depth" not in keys or not set(keys) & set(RESULT_ALIASES["test_id"]):
        return False
    header_row = next(
        r
        for r in range(min(30, len(raw)))
        if [str(c).strip() for c in raw.iloc[r] if isinstance(c, str) and c.strip()] == headers
    )
    col = next(
        i
        for i, c in enumerate(raw.iloc[header_row])
        if isinstance(c, str) and norm_key(parse_header(c)[0]) in RESULT_ALIASES["test_id"]
    )
    ids = raw.iloc[header_row + 1 : header_row + 200, col].dropna()
    return bool(ids.duplicated().any())

"""The fake InView's NanoBlitz export: one CSV row per indent of a fast array, as the NanoBlitz map arrives.

What it writes (issue 36's description of the NanoBlitz CSV, and the layouts ``drivers.kla.readers`` reads,
tests/test_kla_records.py and tests/test_kla_layouts.py): a UTF-8 BOM, CRLF line ends, a header row
``Test, X Position, Y Position, Load at Max Load, Depth at Max Load, Modulus, Hardness``, a units row
(µm, mN, nm, GPa), one row per indent in the order the instrument made them, and no summary rows. A failed
indent keeps its row and its position (the stage went there) with blank cells where its values would be:
InView writes no number for an indent it could not evaluate. Numbers carry an instrument's fixed decimals, not
a float's every digit. No real NanoBlitz export was at hand (../shared/data/kla/ holds InView and NanoSuite
workbooks only), so the column names are the reader's NanoBlitz fingerprint, not a copy of a real file.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

from core.plan import IndentResult

NANOBLITZ_HEADER = (
    "Test",
    "X Position",
    "Y Position",
    "Load at Max Load",
    "Depth at Max Load",
    "Modulus",
    "Hardness",
)
NANOBLITZ_UNITS = ("", "µm", "µm", "mN", "nm", "GPa", "GPa")


def nanoblitz_csv(
    results: Sequence[IndentResult],
    peak_load_mn: float,
    failed: Callable[[IndentResult], bool],
    position_scale: float = 1.0,
) -> bytes:
    """The export of these indents (``failed``: which have blank values; ``position_scale`` 1e-3 writes mm
    under the µm units row, a lab template's mistake the driver detects)."""
    lines = [",".join(NANOBLITZ_HEADER), ",".join(NANOBLITZ_UNITS)]
    for n, r in enumerate(results, start=1):
        x = f"{r.commanded_x_um * position_scale:.4f}"
        y = f"{r.commanded_y_um * position_scale:.4f}"
        if failed(r) or not r.measured or not math.isfinite(r.hardness_gpa):
            values = ["", "", "", ""]
        else:
            values = [
                f"{peak_load_mn:.4f}",
                f"{r.depth_nm:.2f}",
                f"{r.modulus_gpa:.3f}",
                f"{r.hardness_gpa:.4f}",
            ]
        lines.append(",".join([str(n), x, y, *values]))
    return ("\r\n".join(lines) + "\r\n").encode("utf-8-sig")

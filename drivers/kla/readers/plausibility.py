"""Plausibility: values no material has, and indents far from the rest of their file."""

from __future__ import annotations

import numpy as np

from drivers.kla.readers.records import KlaIndent

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

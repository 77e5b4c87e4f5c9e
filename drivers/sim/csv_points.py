"""The rows of a truth CSV (x_um, y_um and values per point): one reader for the truth's columns
(``drivers.sim.truth_csv``) and the fast channel's (``drivers.sim.fast_channel``), so a file is read and
checked alike whichever of them reads it, and any problem is one line naming the file."""

from __future__ import annotations

import csv
import math
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

from core.errors import InputError
from core.plausible import (
    MAX_STAGE_UM,
    check_hardness_gpa,
    check_modulus_gpa,
    check_noise_sd_gpa,
    check_stage_um,
)

if TYPE_CHECKING:
    from _csv import Reader


def read_header(path: str | Path, empty: str = "empty file") -> tuple[list[str], Reader]:
    """The CSV's header (stripped, lower case) and a reader positioned on its first data row; ``empty`` is
    the message for a file without even a header."""
    source = str(path)
    try:
        text = Path(path).read_bytes().decode("utf-8-sig")
    except OSError as exc:
        raise InputError(source, f"cannot read ({exc.strerror})") from None
    except UnicodeDecodeError:
        raise InputError(source, "not a UTF-8 text CSV") from None
    reader = csv.reader(text.splitlines())
    try:
        header = [h.strip().lower() for h in next(reader)]
    except StopIteration:
        raise InputError(source, empty) from None
    return header, reader


def number_rows(
    source: str, header: list[str], reader: Reader, columns: tuple[str, ...]
) -> Iterator[tuple[int, dict[str, float]]]:
    """(line number, {column: value}) for each non-blank row, ``columns`` read as finite numbers."""
    where = {c: header.index(c) for c in columns}
    for raw in reader:
        if not raw or all(not cell.strip() for cell in raw):
            continue
        line = reader.line_num
        if len(raw) != len(header):
            raise InputError(source, f"line {line}: expected {len(header)} values, found {len(raw)}")
        values: dict[str, float] = {}
        for col, i in where.items():
            cell = raw[i].strip()
            try:
                value = float(cell)
            except ValueError:
                raise InputError(source, f"line {line}: {col} {cell!r} is not a number") from None
            if not math.isfinite(value):
                raise InputError(source, f"line {line}: {col} is {cell}, must be finite")
            values[col] = value
        yield line, values


def check_point(source: str, line: int, values: dict[str, float], prefix: str = "") -> None:
    """A point no real sample or stage has is named (a unit slip: MPa under a GPa column, nm under x_um).
    ``prefix`` names the columns' family (``fast_`` for the fast channel's)."""
    hardness, modulus = f"{prefix}hardness_gpa", f"{prefix}modulus_gpa"
    for col, noise_col, check in (
        (hardness, f"{prefix}noise_sd_gpa", check_hardness_gpa),
        (modulus, f"{prefix}modulus_noise_sd_gpa", check_modulus_gpa),
    ):
        if col in values:
            centre = check(source, values[col], f"line {line}: {col}")
            if noise_col in values:
                check_noise_sd_gpa(source, values[noise_col], centre, f"line {line}: {noise_col}")
    for axis in ("x_um", "y_um"):
        check_stage_um(source, f"line {line}: {axis}", values[axis], -MAX_STAGE_UM, MAX_STAGE_UM)

"""Read KLA/Agilent nanoindenter exports into tidy indent records: the public entry of ``readers/``.

The file is sniffed (``readers.sniff``: workbook or text, the program that wrote it) and read by the reader of
its family (``readers.workbook``: InView/NanoSuite workbooks and results tables).
"""

from __future__ import annotations

from pathlib import Path

from core.errors import InputError
from drivers.kla.readers.records import (
    NO_POSITIONS,
    SOFTWARE_ANTON_PAAR,
    SOFTWARE_FISCHERSCOPE,
    SOFTWARE_HYSITRON,
    SOFTWARE_INVIEW,
    SOFTWARE_MICRO_MATERIALS,
    SOFTWARE_NANOSUITE,
    SOFTWARE_TESTWORKS,
    SOFTWARE_UNKNOWN,
    KlaExport,
    KlaIndent,
    records,
)
from drivers.kla.readers.sniff import VENDOR_HINTS, check_file, detect_software, read_sheets
from drivers.kla.readers.workbook import read_workbook

__all__ = [
    "NO_POSITIONS",
    "SOFTWARE_ANTON_PAAR",
    "SOFTWARE_FISCHERSCOPE",
    "SOFTWARE_HYSITRON",
    "SOFTWARE_INVIEW",
    "SOFTWARE_MICRO_MATERIALS",
    "SOFTWARE_NANOSUITE",
    "SOFTWARE_TESTWORKS",
    "SOFTWARE_UNKNOWN",
    "KlaExport",
    "KlaIndent",
    "read_kla_export",
    "records",
]


def read_kla_export(path: str | Path, *, frame_compliance_nm_mn: float | None = None) -> KlaExport:
    """Read one nanoindenter export; ``frame_compliance_nm_mn`` overrides the estimate from the file.

    Every per-test row of the file is one indent (per-cycle rows and summary rows are not tests). A row
    whose hardness is missing, marked invalid or impossible (≤ 0, or modulus ≤ 0) comes back as a failed
    indent with its reason and no hardness number. A file it cannot read is refused in one line that names
    the program that wrote it, when it can tell.
    """
    path = Path(path)
    engine = check_file(path)
    sheets = read_sheets(path, engine)
    software = detect_software(sheets)
    try:
        return read_workbook(path, sheets, software, frame_compliance_nm_mn)
    except InputError as exc:
        if software == SOFTWARE_UNKNOWN:
            raise
        hint = VENDOR_HINTS.get(software, "")
        raise InputError(exc.source, f"{software} export: {exc.problem}{hint}") from None

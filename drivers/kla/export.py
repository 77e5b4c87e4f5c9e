"""Read KLA/Agilent nanoindenter exports into tidy indent records: the public entry of ``readers/``.

The file is sniffed (``readers.sniff``: workbook or text, the program that wrote it) and read by the reader of
its family (``readers.workbook``: InView/NanoSuite workbooks and results tables). The names of the programs
(``KlaExport.software``) are ``readers.indents``' ``SOFTWARE_*``.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path

from core.errors import InputError
from drivers.kla.readers.indents import (
    NO_POSITIONS,
    SOFTWARE_INVIEW,
    SOFTWARE_UNKNOWN,
    KlaExport,
    KlaIndent,
    records,
)
from drivers.kla.readers.inview_record import is_record, read_record_export
from drivers.kla.readers.sniff import VENDOR_HINTS, check_file, detect_software, read_sheets
from drivers.kla.readers.workbook import read_workbook

__all__ = [
    "NO_POSITIONS",
    "SOFTWARE_INVIEW",
    "SOFTWARE_UNKNOWN",
    "KlaExport",
    "KlaIndent",
    "export_files",
    "natural_key",
    "read_kla_export",
    "read_kla_exports",
    "records",
]


def read_kla_export(path: str | Path, *, frame_compliance_nm_mn: float | None = None) -> KlaExport:
    """Read one nanoindenter export (a file, or a folder of files that are one export together);
    ``frame_compliance_nm_mn`` overrides the estimate from the file.

    Every per-test row of the file is one indent (per-cycle rows and summary rows are not tests). A row
    whose hardness is missing, marked invalid or impossible (≤ 0, or modulus ≤ 0) comes back as a failed
    indent with its reason and no hardness number. A file it cannot read is refused in one line that names
    the program that wrote it, when it can tell.
    """
    path = Path(path)
    if path.is_dir():
        return read_kla_exports([path], frame_compliance_nm_mn=frame_compliance_nm_mn)
    engine = check_file(path)
    sheets = read_sheets(path, engine)
    if is_record(sheets):
        return read_record_export(path, next(iter(sheets.values())))
    software = detect_software(sheets)
    if software in (SOFTWARE_INVIEW, SOFTWARE_UNKNOWN) and is_record(sheets, unmarked=True):
        return read_record_export(path, next(iter(sheets.values())))
    try:
        return read_workbook(path, sheets, software, frame_compliance_nm_mn)
    except InputError as exc:
        if software == SOFTWARE_UNKNOWN:
            raise
        hint = VENDOR_HINTS.get(software, "")
        raise InputError(exc.source, f"{software} export: {exc.problem}{hint}") from None


_EXPORT_SUFFIXES = (".csv", ".txt", ".tsv", ".xlsx", ".xls")


def natural_key(path: Path) -> tuple[object, ...]:
    """Test2 before Test10 before Test100: digit runs compare as numbers."""
    parts = re.split(r"(\d+)", path.name.lower())
    return tuple((0, int(p), "") if p.isdigit() else (1, 0, p) for p in parts)


def export_files(sources: Sequence[str | Path]) -> list[Path]:
    """The files of an export given as files and/or folders: a folder's export files (not hidden, not an
    Excel lock file '~$...'), in natural test order."""
    files: list[Path] = []
    for source in map(Path, sources):
        if source.is_dir():
            found = sorted(
                (
                    f
                    for f in source.iterdir()
                    if f.is_file()
                    and f.suffix.lower() in _EXPORT_SUFFIXES
                    and not f.name.startswith(("~$", "."))
                ),
                key=natural_key,
            )
            if not found:
                raise InputError(
                    str(source), f"is a folder with no export file in it ({', '.join(_EXPORT_SUFFIXES)})"
                )
            files.extend(found)
        else:
            files.append(source)
    return sorted(files, key=natural_key)  # a shell's glob gives Test1, Test10, Test2


def read_kla_exports(
    sources: Sequence[str | Path], *, frame_compliance_nm_mn: float | None = None
) -> KlaExport:
    """Several files (or folders of them) read as ONE export, tests in natural order: one CSV per test
    (InView's per-test records), or results files of one run. A test that two files both hold is refused:
    which one is this run's cannot be told."""
    files = export_files(sources)
    if len(files) == 1:
        return read_kla_export(files[0], frame_compliance_nm_mn=frame_compliance_nm_mn)
    parts = [read_kla_export(f, frame_compliance_nm_mn=frame_compliance_nm_mn) for f in files]
    seen: dict[str, tuple[str, str]] = {}
    indents: list[KlaIndent] = []
    notes: list[str] = []
    for f, part in zip(files, parts, strict=True):
        for indent in part.indents:
            if indent.test_id in seen:
                name, kind = seen[indent.test_id]
                mixed = (
                    f" ({name} is {kind}, {f.name} is format {part.software}: a results summary beside per-test "
                    "records? read one or the other)"
                    if kind != f"format {part.software}"
                    else ""
                )
                raise InputError(
                    str(f), f"test {indent.test_id} is also in {name}: one export holds each test once{mixed}"
                )
            seen[indent.test_id] = (f.name, f"format {part.software}")
            indents.append(indent)
        # notes shared by the files are said once; a note about a file's own column names the file
        notes.extend(f"{f.name}: {n}" if "column" in n and f.name not in n else n for n in part.warnings)
    formats = sorted({p.software for p in parts})
    wheres = sorted({p.hardness_column for p in parts if p.hardness_column})
    name = str(sources[0]) if len(sources) == 1 else f"{files[0].parent}"
    notes.insert(0, f"{len(files)} files read as one export ({files[0].name} ... {files[-1].name})")
    return KlaExport(
        name,
        " + ".join(formats),
        tuple(indents),
        tuple(dict.fromkeys(notes)),
        None,
        "; ".join(wheres),
        "; ".join(sorted({p.analysis for p in parts if p.analysis})),
    )

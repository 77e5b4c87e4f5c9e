"""What a file is before it is read: workbook or text, its encoding and separator, and the program that wrote it.

The content decides, never the extension; vendor names in the file's own text win over column-based guesses.
"""

from __future__ import annotations

import csv
import io
import re
import warnings
from collections.abc import Mapping
from pathlib import Path

import openpyxl
import pandas as pd
from openpyxl.worksheet._read_only import ReadOnlyWorksheet

from core.errors import InputError
from drivers.kla.readers.columns import TEST_SHEET, norm_key
from drivers.kla.readers.indents import (
    SOFTWARE_ANTON_PAAR,
    SOFTWARE_FISCHERSCOPE,
    SOFTWARE_HYSITRON,
    SOFTWARE_INVIEW,
    SOFTWARE_MICRO_MATERIALS,
    SOFTWARE_NANOSUITE,
    SOFTWARE_TESTWORKS,
    SOFTWARE_UNKNOWN,
)
from drivers.kla.readers.nanoblitz import SOFTWARE_NANOBLITZ_4D, nanoblitz_kind
from drivers.kla.readers.tables import parse_header

_XLSX_MAGIC = b"PK\x03\x04"


_XLS_MAGIC = b"\xd0\xcf\x11\xe0\xa1\xb1\x1a\xe1"


def check_file(path: Path) -> str:
    """Refuse early and clearly: missing, empty, or neither a workbook nor a text table.

    The content decides, never the extension: labs rename files, and InView's "Excel" export can be an
    .xlsx named .xls or a tab-separated text file. Returns "openpyxl", "xlrd" or "text".
    """
    if not path.is_file():
        raise InputError(str(path), "file not found")
    with path.open("rb") as fh:
        head = fh.read(4096)
    if not head:
        raise InputError(str(path), "empty file")
    if head.startswith(_XLSX_MAGIC):
        return "openpyxl"
    if head.startswith(_XLS_MAGIC):
        return "xlrd"
    text = decode(head, path, partial=True).lstrip().lower()
    if text.startswith(("<html", "<!doctype", "<?xml", "<table")):
        raise InputError(str(path), "an HTML/XML page, not a workbook or CSV export (export as .xlsx or CSV)")
    return "text"


def decode(data: bytes, path: Path, *, partial: bool = False) -> str:
    """UTF-16 (with BOM), UTF-8 or Windows-1252 text; binary junk is refused."""
    if data.startswith((b"\xff\xfe", b"\xfe\xff")):
        return data.decode("utf-16", errors="replace" if partial else "strict")
    if b"\x00" in data:
        raise InputError(str(path), "not an Excel workbook (.xlsx or .xls) or a text (CSV) export")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        if partial and exc.start >= len(data) - 3:  # a multi-byte character cut by the 4 kB sniff
            return data[: exc.start].decode("utf-8-sig")
        return data.decode("cp1252", errors="replace")


_NUMBER = re.compile(r"^[-+]?(?:\d+[.,]?\d*|[.,]\d+)(?:[eE][-+]?\d+)?$")
_DECIMAL_COMMA = re.compile(r"^[-+]?\d+,\d+(?:[eE][-+]?\d+)?$")
# a decimal-comma locale's digit grouping: '12.345,678', '-1.000,5', '12.345' (a '.' there is never a decimal point)
_GROUPED = re.compile(r"^[-+]?\d{1,3}(?:\.\d{3})+(?:,\d+)?$")
CUT_OFF = "(cut off: the file ends mid-line)"


def _sniff_delimiter(lines: list[str]) -> str:
    """The separator that splits the most lines into the same number of fields (tab, ';' or ',')."""
    best, best_score = ",", -1
    for delim in ("\t", ";", ","):
        counts = [ln.count(delim) for ln in lines if ln.strip()]
        nonzero = [c for c in counts if c > 0]
        if not nonzero:
            continue
        mode = max(set(nonzero), key=nonzero.count)
        score = sum(c == mode for c in counts)
        if score > best_score:
            best, best_score = delim, score
    return best


def _text_cell(cell: str, decimal_comma: bool) -> object:
    text = cell.strip()
    if not text:
        return None
    if decimal_comma and _GROUPED.match(text):
        text = text.replace(".", "").replace(",", ".")
    elif decimal_comma and _DECIMAL_COMMA.match(text):
        text = text.replace(",", ".")
    try:
        return float(text)
    except ValueError:
        return text


def _decimals(cell: str, mark: str) -> int:
    """Characters after the decimal mark (an exponent included): a number's printed format."""
    _head, sep, tail = cell.strip().partition(mark)
    return len(tail) if sep else 0


def _shorter_than_its_column(rows: list[list[str]], k: int, i: int, mark: str) -> bool:
    """Whether cell (k, i) is printed shorter than every other number of its column: a cut number."""
    siblings = [
        r[i] for j, r in enumerate(rows) if j != k and i < len(r) and _NUMBER.match(r[i].strip() or "x")
    ]
    if not siblings:
        return False
    return _decimals(rows[k][i], mark) < min(_decimals(c, mark) for c in siblings)


def read_text(path: Path) -> dict[str, pd.DataFrame]:
    """A CSV/TSV export as one 'Results' sheet; ';'-separated files may use decimal commas (and a locale's
    digit grouping, '12.345,678').

    A file that ends without a line break may have been cut while it was written: its last cell may be a
    cut number ('9' of '9.35'). It is not trusted -- it reads as missing (a failed hardness says why), never
    as a number -- when its row is short of cells or the cell is shorter than its column's format (fewer
    characters after the decimal mark than every other value of the column). A whole last line that only
    lacks its line break (many scripts write files so) is read as it is."""
    text = decode(path.read_bytes(), path)
    lines = text.splitlines()
    delimiter = _sniff_delimiter(lines)
    rows = list(csv.reader(lines, delimiter=delimiter))
    decimal_comma = delimiter != "," and any(_DECIMAL_COMMA.match(c.strip()) for r in rows for c in r)
    width = max((len(r) for r in rows), default=0)
    table = [[_text_cell(c, decimal_comma) for c in r] + [None] * (width - len(r)) for r in rows]
    cut = False
    if text.strip() and not text.endswith(("\n", "\r")):
        k = next(k for k in range(len(table) - 1, -1, -1) if any(c is not None for c in table[k]))
        i = max(i for i, c in enumerate(table[k]) if c is not None)
        mark = "," if decimal_comma else "."
        cut = len(rows[k]) < width or _shorter_than_its_column(rows, k, i, mark)
        if cut:
            table[k][i] = f"{rows[k][i].strip()} {CUT_OFF}"
    frame = pd.DataFrame(table, dtype=object)
    frame.attrs["cut_off"] = cut
    return {"Results": frame}


def read_xlsx(path: Path) -> dict[str, pd.DataFrame]:
    """openpyxl directly, not pandas: an .xlsx stores DBL_MAX as text that parses to inf, and pandas'
    openpyxl reader then dies on int(inf). Here inf just becomes a missing value later. The file is
    passed open, so openpyxl does not refuse an .xlsx named .xls by its extension."""
    with path.open("rb") as fh:
        book = openpyxl.load_workbook(fh, read_only=True, data_only=True)
        try:
            out = {}
            for sheet in book.worksheets:
                if isinstance(sheet, ReadOnlyWorksheet):
                    sheet.reset_dimensions()  # exporters often write a wrong <dimension>
                out[sheet.title] = pd.DataFrame(list(sheet.iter_rows(values_only=True)))
            return out
        finally:
            book.close()


def read_sheets(path: Path, engine: str) -> dict[str, pd.DataFrame]:
    log = io.StringIO()  # xlrd prints its file-format complaints to a log that is stdout by default
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # pandas deprecates xlrd; openpyxl warns on styles
            if engine == "text":
                sheets = read_text(path)
            elif engine == "openpyxl":
                sheets = read_xlsx(path)
            else:
                kwargs = {"logfile": log} if engine == "xlrd" else {}
                sheets = pd.read_excel(
                    path, sheet_name=None, header=None, engine=engine, engine_kwargs=kwargs
                )
    except InputError:
        raise
    except Exception as exc:  # the engines raise a zoo of types on corrupt files
        what = "text export" if engine == "text" else "Excel workbook"
        raise InputError(str(path), f"unreadable {what} ({type(exc).__name__}: {exc})") from exc
    for line in log.getvalue().splitlines():  # kept, as warnings (the CLI prints them on stderr)
        if line.strip():
            warnings.warn(f"{path.name}: {line.strip()}", UserWarning, stacklevel=2)
    if any(df.attrs.get("cut_off") for df in sheets.values()):
        warnings.warn(
            f"{path.name}: ends mid-line, without a line break (cut off while it was written?): "
            "its last value is not trusted",
            UserWarning,
            stacklevel=2,
        )
    if not sheets or all(df.empty for df in sheets.values()):
        raise InputError(str(path), "workbook has no data")
    return {str(name): df for name, df in sheets.items()}


def _sheet_words(sheets: Mapping[str, pd.DataFrame]) -> tuple[str, set[str]]:
    """Lower-case text of the sheets' top cells (vendor names live there) and every header-like key."""
    texts: list[str] = []
    keys: set[str] = set()
    for raw in sheets.values():
        top = raw.iloc[:40, :40]
        for row in top.itertuples(index=False):
            for cell in row:
                if isinstance(cell, str) and cell.strip():
                    texts.append(cell.lower())
                    keys.add(norm_key(parse_header(cell)[0]))
    return " | ".join(texts), keys


# vendor words in a file's own text, checked before any column-based guess
_VENDOR_WORDS: tuple[tuple[str, tuple[str, ...]], ...] = (
    (SOFTWARE_TESTWORKS, ("testworks",)),
    (SOFTWARE_NANOSUITE, ("nanosuite",)),
    (SOFTWARE_INVIEW, ("inview",)),
    (SOFTWARE_HYSITRON, ("hysitron", "triboscan", "triboview", "tribo indenter", "triboindenter", "xpm")),
    (SOFTWARE_ANTON_PAAR, ("anton paar", "csm instruments")),
    (SOFTWARE_MICRO_MATERIALS, ("micro materials", "micromaterials", "nanotest")),
    (SOFTWARE_FISCHERSCOPE, ("fischerscope", "helmut fischer", "winhcu")),
)


def detect_software(sheets: Mapping[str, pd.DataFrame]) -> str:
    """The program that wrote the file: its sheet names, then its own words, then its column names."""
    names = {norm_key(n) for n in sheets}
    if names & {"required inputs", "inputs editable post test"}:
        return SOFTWARE_NANOSUITE
    if names & {"pre-test inputs", "post-test inputs", "sample summary", "sample information"} or any(
        n.startswith("cycles-") for n in names
    ):
        return SOFTWARE_INVIEW
    text, keys = _sheet_words(sheets)
    said = [sw for sw, words in _VENDOR_WORDS if any(re.search(rf"\b{re.escape(w)}\b", text) for w in words)]
    if said and said[0] != SOFTWARE_INVIEW:
        return said[0]
    blitz = nanoblitz_kind(sheets, text)  # NanoBlitz runs inside InView: its files may say "InView"
    if blitz is not None:
        return blitz
    if said:
        return said[0]
    if {"hit", "eit"} <= keys and keys & {"hvit", "fmax", "cit", "rit"}:  # ISO 14577 names, Anton Paar's
        return SOFTWARE_ANTON_PAAR
    # Hysitron's contact depth, peak force and reduced modulus (short or spelt out)
    if {"hc", "er"} <= keys or {"pmax", "er"} <= keys or {"contact depth", "reduced modulus"} <= keys:
        return SOFTWARE_HYSITRON
    test_sheets = [n for n in names if TEST_SHEET.match(n)]
    if test_sheets and not any("result" in n for n in names):
        return SOFTWARE_TESTWORKS  # MTS TestWorks writes one sheet per test and no Results sheet
    if any(re.match(r"^test 0\d+$", n) for n in test_sheets):
        return SOFTWARE_NANOSUITE
    return SOFTWARE_UNKNOWN


# what to export instead, for programs whose usual files are one test's raw curve
VENDOR_HINTS = {
    SOFTWARE_NANOBLITZ_4D: " (export NanoBlitz's per-indent summary, or name the depth window in the columns)",
    SOFTWARE_HYSITRON: " (export the analysed results table from TriboScan/TriboView, not a single .hld/.txt curve)",
    SOFTWARE_MICRO_MATERIALS: " (export the NanoTest results table with one row per indent)",
    SOFTWARE_FISCHERSCOPE: " (export the WIN-HCU results table with one row per indent, not a .hap file)",
    SOFTWARE_ANTON_PAAR: " (export the Indentation Software results table with one row per indent)",
}

"""The export reader on files from labs it has never seen: generated CSV/xlsx variants and the bug reports.

Each generated file varies what real exports vary (column spellings, units in the header or in a units row,
summary rows above or below, metadata lines, separators, decimal commas, invalid markers, extra columns)
and the reader must give back exactly the values that were written, with every invalid row a failed indent.
"""

from __future__ import annotations

import csv
import os
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import openpyxl
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from core.errors import InputError
from drivers.kla.export import read_kla_export

ROOT = Path(__file__).resolve().parents[1]

# --------------------------------------------------------------------------------------------- writers


def write_xlsx(path: Path, sheets: dict[str, list[list[object]]]) -> Path:
    book = openpyxl.Workbook()
    book.remove(book.active)
    for name, rows in sheets.items():
        sheet = book.create_sheet(name)
        for row in rows:
            sheet.append(row)
    book.save(path)
    return path


def write_csv(
    path: Path, rows: list[list[object]], delimiter: str = ",", decimal_comma: bool = False
) -> Path:
    def cell(v: object) -> str:
        if v is None:
            return ""
        if isinstance(v, float):
            text = repr(v)
            return text.replace(".", ",") if decimal_comma else text
        return str(v)

    with path.open("w", newline="", encoding="utf-8") as fh:
        writer = csv.writer(fh, delimiter=delimiter)
        for row in rows:
            writer.writerow([cell(v) for v in row])
    return path


# ------------------------------------------------------------------------------------ generated exports

INVALID = {"dbl_max": 1.797e308, "blank": None, "dashes": "--", "negative": -4.2, "zero": 0.0}


@dataclass(frozen=True)
class Variant:
    test_header: str | None
    x_header: str
    y_header: str
    h_header: str
    e_header: str
    drift_header: str | None
    pos_unit: str  # "µm", "mm", "Âµm", "um"
    h_unit: str  # "GPa", "MPa"
    unit_style: str  # "row", "header", "none" (none: the canonical units are meant)
    summary: str  # "bottom", "top", "none"
    metadata_lines: int
    fmt: str  # "csv", "csv;", "tsv", "xlsx"
    extra_column: bool
    invalid: tuple[tuple[int, str], ...]  # row index -> kind of invalid hardness (or modulus for "negative")
    n_rows: int
    shuffle_seed: int


variants = st.builds(
    Variant,
    test_header=st.sampled_from([None, "Test", "TEST", "Test #", "Test No."]),
    x_header=st.sampled_from(["X Position", "X", "X Test Position", "X_Position", "X Pos"]),
    y_header=st.sampled_from(["Y Position", "Y", "Y Test Position", "Y_Position"]),
    h_header=st.sampled_from(
        [
            "HARDNESS",
            "Hardness",
            "H-IT",
            "Avg Hardness [75-85 nm]",
            "H Average Over Defined Range",
            "Mean Hardness",
        ]
    ),
    e_header=st.sampled_from(["MODULUS", "Modulus", "E-IT", "Avg Modulus [75-85 nm]"]),
    drift_header=st.sampled_from([None, "Drift Rate", "Drift Correction"]),
    pos_unit=st.sampled_from(["µm", "mm", "Âµm", "um"]),
    h_unit=st.sampled_from(["GPa", "MPa"]),
    unit_style=st.sampled_from(["row", "header", "none"]),
    summary=st.sampled_from(["bottom", "top", "none"]),
    metadata_lines=st.integers(0, 4),
    fmt=st.sampled_from(["csv", "csv;", "tsv", "xlsx"]),
    extra_column=st.booleans(),
    invalid=st.lists(
        st.tuples(st.integers(0, 11), st.sampled_from(sorted(INVALID))), max_size=4, unique_by=lambda t: t[0]
    ).map(tuple),
    n_rows=st.integers(1, 12),
    shuffle_seed=st.integers(0, 1000),
)


def build(variant: Variant, folder: Path) -> tuple[Path, list[dict[str, object]]]:
    """Write the variant; return the file and what each row should read back as."""
    v = variant
    if v.unit_style == "none":  # no units anywhere: the file means µm and GPa
        v = Variant(**{**v.__dict__, "pos_unit": "µm", "h_unit": "GPa"})
    pos_scale = 1e-3 if v.pos_unit == "mm" else 1.0  # written value = µm × scale
    h_scale = 1e3 if v.h_unit == "MPa" else 1.0
    columns: list[tuple[str, str, str | None]] = []  # key, header, unit
    columns.append(("test", v.test_header or "", None))
    columns += [("x", v.x_header, v.pos_unit), ("y", v.y_header, v.pos_unit)]
    columns += [("h", v.h_header, v.h_unit), ("e", v.e_header, v.h_unit)]
    if v.drift_header:
        columns.append(("drift", v.drift_header, "nm/s"))
    if v.extra_column:
        columns.append(("sd", "Hardness Std Dev", v.h_unit))
        columns.append(("note", "Notes", None))
    order = list(range(1, len(columns)))
    rng = __import__("random").Random(v.shuffle_seed)
    rng.shuffle(order)
    columns = [columns[0]] + [columns[i] for i in order]  # the label column stays first (where summaries go)

    invalid = {row: kind for row, kind in v.invalid if row < v.n_rows}
    expected: list[dict[str, object]] = []
    data: list[list[object]] = []
    for r in range(v.n_rows):
        x_um, y_um = 1000.0 + 7.5 * r, 2000.0 - 2.5 * r
        h, e = 5.0 + 0.25 * r, 100.0 + r
        kind = invalid.get(r)
        cells = {
            "test": f"{r + 1}" if v.test_header else None,
            "x": x_um * pos_scale,
            "y": y_um * pos_scale,
            "h": h * h_scale,
            "e": e * h_scale,
            "drift": 0.01 * r,
            "sd": 0.1,
            "note": "ok",
        }
        if kind == "negative":
            cells["e"] = INVALID[kind]  # a negative modulus fails the indent as surely as a bad hardness
        elif kind is not None:
            cells["h"] = INVALID[kind]
        data.append([cells[key] for key, _, _ in columns])
        expected.append(
            {"x_um": x_um, "y_um": y_um, "h": None if kind else h, "e": e, "failed": kind is not None}
        )

    header = [name + (f" ({unit})" if v.unit_style == "header" and unit else "") for _, name, unit in columns]
    rows: list[list[object]] = [[f"Metadata line {i}: Sample A{i}"] for i in range(v.metadata_lines)]
    rows.append(header)
    if v.unit_style == "row":
        rows.append([unit or "" for _, _, unit in columns])
    summary = [
        [label] + [1.0] * (len(columns) - 1) for label in ("Mean", "Std. Dev.", "% COV")
    ]  # numbers that must never become indents
    if v.summary == "top":
        rows += summary
    rows += data
    if v.summary == "bottom":
        rows += [[None] * len(columns), *summary]
    if v.fmt == "xlsx":
        if v.metadata_lines:
            rows = rows[v.metadata_lines :]  # workbooks keep metadata on other sheets
        return write_xlsx(folder / "export.xlsx", {"Results": rows}), expected
    delimiter = {"csv": ",", "csv;": ";", "tsv": "\t"}[v.fmt]
    path = write_csv(folder / "export.csv", rows, delimiter, decimal_comma=v.fmt == "csv;")
    return path, expected


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(variant=variants)
def test_reads_exports_from_labs_it_has_never_seen(
    variant: Variant, tmp_path_factory: pytest.TempPathFactory
) -> None:
    folder = tmp_path_factory.mktemp("variant")
    path, expected = build(variant, folder)
    export = read_kla_export(path)
    assert len(export.indents) == len(expected), export.warnings
    for got, want in zip(export.indents, expected, strict=True):
        assert got.x_um == pytest.approx(want["x_um"]) and got.y_um == pytest.approx(want["y_um"])
        assert got.failed is want["failed"], (got, want)
        if want["failed"]:
            assert got.hardness_gpa is None and got.failure
        else:
            assert got.hardness_gpa == pytest.approx(want["h"]) and got.modulus_gpa == pytest.approx(
                want["e"]
            )
    if "[75-85 nm]" in variant.h_header:
        assert export.hardness_range_nm == (75.0, 85.0)


# ------------------------------------------------------------------------------------ the bug reports


def _nanoblitz_rows() -> list[list[object]]:
    return [
        ["Test", "X Position", "Y Position", "MODULUS", "HARDNESS", "Drift Rate", "Displacement at Max Load"],
        ["", "µm", "µm", "GPa", "GPa", "nm/s", "nm"],
        [1, 100.0, 200.0, 120.0, 6.5, 0.02, 98.0],
        [2, 105.0, 200.0, 1.797e308, 1.797e308, 0.02, 1.797e308],
        [3, 110.0, 200.0, "--", "--", "--", "--"],
        [4, 115.0, 200.0, 118.0, None, 0.03, 101.0],
        [5, 120.0, 200.0, 119.0, -73.0, 0.03, 100.0],
        [6, 125.0, 200.0, -5.0, 6.4, 0.03, 100.0],
        [7, 130.0, 200.0, 121.0, 0.0, 0.03, 100.0],
        [8, 135.0, 200.0, 121.0, 6.6, 0.01, 99.0],
        ["Mean", 117.5, 200.0, 80.0, 4.0, 0.02, 99.0],
        ["Std. Dev.", 12.0, 0.0, 60.0, 5.0, 0.01, 1.0],
        ["% COV", 10.0, 0.0, 75.0, 120.0, 50.0, 1.0],
    ]


@pytest.mark.parametrize("fmt", ["csv", "xlsx"])
def test_nanoblitz_export_with_units_row_summary_rows_and_invalid_values(tmp_path: Path, fmt: str) -> None:
    rows = _nanoblitz_rows()
    path = (
        write_csv(tmp_path / "nb.csv", rows)
        if fmt == "csv"
        else write_xlsx(tmp_path / "nb.xlsx", {"Results": rows})
    )
    export = read_kla_export(path)
    assert [i.test_id for i in export.indents] == [str(n) for n in range(1, 9)]
    by_id = {i.test_id: i for i in export.indents}
    assert (
        by_id["1"].hardness_gpa == 6.5
        and by_id["1"].max_depth_nm == 98.0
        and by_id["1"].drift_rate_nm_s == 0.02
    )
    assert by_id["8"].hardness_gpa == 6.6 and not by_id["8"].failed
    # every invalid value is a failed indent with its reason, never a number the model could learn
    reasons = {k: by_id[k].failure for k in ("2", "3", "4", "5", "6", "7")}
    assert "1.797e308" in str(reasons["2"]) and "'--'" in str(reasons["3"]) and "blank" in str(reasons["4"])
    assert "-73 GPa is not physical" in str(reasons["5"])
    assert "modulus -5 GPa is not physical" in str(reasons["6"])
    assert "hardness 0 GPa is not physical" in str(reasons["7"])
    for k in reasons:
        assert by_id[k].hardness_gpa is None
    assert by_id["6"].modulus_gpa is None and by_id["2"].max_depth_nm is None
    assert any("6 failed indent(s)" in w for w in export.warnings)
    frame = export.to_frame()
    assert frame.failure.notna().sum() == 6 and frame.hardness_gpa.notna().sum() == 2


def _csm_curve(h_plateau: float) -> list[list[object]]:
    """A CSM test sheet: depth 0-200 nm, a hardness channel that is wild near the surface (10-40 nm)
    and flat at h_plateau from 60 nm on, where the file's own range (75-85 nm) sits."""
    rows: list[list[object]] = [
        ["Displacement Into Surface", "Load On Sample", "Time On Sample", "Hardness", "Modulus"],
        ["nm", "mN", "s", "GPa", "GPa"],
    ]
    for k in range(201):
        depth = float(k)
        wild = -73.0 if k % 2 else 114.0
        hardness = wild if depth < 60 else h_plateau
        rows.append([depth, 0.002 * depth**2, 0.5 * k, hardness, 100.0])
    for k in range(200, -1, -10):  # unload
        rows.append([float(k) * 0.9 + 20.0, 0.002 * k**2, 100.0 + (200 - k), None, None])
    return rows


def test_avg_hardness_column_with_its_range_is_the_files_own_value(tmp_path: Path) -> None:
    """The bug: 'Avg Hardness [75-85 nm]' was not recognised, curves were re-averaged over 10-20 % of the
    depth, and the reader exited 0 with -73..+114 GPa. The file's own value must be used."""
    results = [
        ["Test", "X Position", "Y Position", "Avg Hardness [75-85 nm]", "Avg Modulus [75-85 nm]"],
        ["", "µm", "µm", "GPa", "GPa"],
        [1, 0.0, 0.0, 9.1, 71.0],
        [2, 10.0, 0.0, 9.3, 72.0],
    ]
    path = write_xlsx(
        tmp_path / "lab.xlsx",
        {"Results": results, "Test 001": _csm_curve(9.1), "Test 002 Tagged": _csm_curve(9.3)},
    )
    export = read_kla_export(path)
    assert [i.hardness_gpa for i in export.indents] == [9.1, 9.3]
    assert all(i.source == "results" for i in export.indents)
    assert export.hardness_range_nm == (75.0, 85.0)
    assert any("file's own average over 75-85 nm" in w for w in export.warnings)


def test_curve_sheets_with_suffixes_are_matched(tmp_path: Path) -> None:
    # no hardness in Results: hardness comes from the CSM channel of 'Test 004 Tagged'-style sheets,
    # averaged over the file's own calculation range (60-200 nm here: the plateau), never the wild surface
    results = [
        ["Test", "X Position", "Y Position", "Minimum Calculation Depth", "Maximum Calculation Depth"],
        ["", "µm", "µm", "nm", "nm"],
        [3, 0.0, 0.0, 60.0, 200.0],
        [4, 10.0, 0.0, 60.0, 200.0],
    ]
    path = write_xlsx(
        tmp_path / "tagged.xlsx",
        {"Results": results, "Test 003 Tagged": _csm_curve(8.0), "Test 004 Tagged": _csm_curve(8.5)},
    )
    export = read_kla_export(path)
    assert [i.test_id for i in export.indents] == ["3", "4"]
    assert [i.hardness_gpa for i in export.indents] == pytest.approx([8.0, 8.5])
    assert all(i.source == "curve" and not i.failed for i in export.indents)


def test_physically_impossible_curve_result_is_a_failed_indent(tmp_path: Path) -> None:
    # no range in the file: the default 10-20 % band lands on the wild surface; the mean there is
    # whatever it is, but a value ≤ 0 or above diamond is refused, and the default band is named
    results = [["Test", "X Position", "Y Position"], ["", "µm", "µm"], [1, 0.0, 0.0]]
    curve = _csm_curve(9.0)
    for row in curve[2:40]:
        row[3] = -73.0
    path = write_xlsx(tmp_path / "wild.xlsx", {"Results": results, "Test 001": curve})
    export = read_kla_export(path)
    (only,) = export.indents
    assert only.failed and only.hardness_gpa is None and "not physical" in str(only.failure)
    assert any("names no calculation depth range" in w for w in export.warnings)


def test_real_xlsx_named_xls_is_read_by_content(kla_dir: Path, tmp_path: Path) -> None:
    renamed = tmp_path / "FusedSilica.xls"
    shutil.copyfile(kla_dir / "FusedSilica.xlsx", renamed)
    export = read_kla_export(renamed)
    assert export.software == "InView" and len(export.indents) == 16
    generated = write_xlsx(tmp_path / "generated.xls", {"Results": _nanoblitz_rows()})
    assert len(read_kla_export(generated).indents) == 8


def test_semicolon_csv_with_decimal_commas_and_latin1(tmp_path: Path) -> None:
    text = "Probe;X Position;Y Position;HARDNESS;MODULUS\n;µm;µm;GPa;GPa\nTest 1;1,5;2,5;6,25;110,5\n"
    path = tmp_path / "de.csv"
    path.write_bytes(text.encode("cp1252"))
    (only,) = read_kla_export(path).indents
    assert (only.x_um, only.y_um, only.hardness_gpa, only.modulus_gpa) == (1.5, 2.5, 6.25, 110.5)


def test_text_export_without_known_columns_is_refused_by_name(tmp_path: Path) -> None:
    path = write_csv(tmp_path / "other.csv", [["a", "b"], [1.0, 2.0]])
    with pytest.raises(InputError, match=r"other\.csv: sheet 'Results' has no header row"):
        read_kla_export(path)


# ------------------------------------------------------------------------------------------------ CLI


def _cli(*args: str, **kw: object) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run(
        [sys.executable, "-m", "aeni_console.cli.main", *args], capture_output=True, text=True, env=env, **kw
    )


def test_json_piped_into_head_ends_without_a_traceback(tmp_path: Path) -> None:
    # 3000 rows of JSON (~700 kB) overflow the pipe long before `head` has read its line
    rows: list[list[object]] = [["Test", "X Position", "Y Position", "HARDNESS"]]
    rows += [[n, float(n), 0.0, 5.0] for n in range(1, 3001)]
    path = write_csv(tmp_path / "big.csv", rows)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    cmd = f"{sys.executable} -m aeni_console.cli.main kla read {path} --json | head -n 3"
    proc = subprocess.run(["bash", "-o", "pipefail", "-c", cmd], capture_output=True, text=True, env=env)
    assert proc.stdout.splitlines()[0] == "["
    assert "Traceback" not in proc.stderr and "BrokenPipeError" not in proc.stderr, proc.stderr
    assert proc.returncode == 0


def test_cli_bad_file_is_one_line_and_exit_2(tmp_path: Path) -> None:
    junk = tmp_path / "junk.xls"
    junk.write_bytes(b"\x00\x00garbage")
    proc = _cli("kla", "read", str(junk))
    assert proc.returncode == 2
    assert (
        proc.stderr.strip().count("\n") == 0 and "junk.xls" in proc.stderr and "Traceback" not in proc.stderr
    )


def test_bare_letter_columns_count_only_with_a_pressure_unit(tmp_path: Path) -> None:
    rows: list[list[object]] = [["Test", "X", "Y", "H", "E", "h"], ["", "µm", "µm", "GPa", "GPa", "nm"]]
    rows.append([1, 0.0, 0.0, 7.0, 150.0, 95.0])
    (only,) = read_kla_export(write_csv(tmp_path / "letters.csv", rows)).indents
    assert (only.hardness_gpa, only.modulus_gpa) == (7.0, 150.0)

"""The layouts labs have (issue 24): per-test rows among per-cycle rows, per-test sheets without a Results
sheet, header spellings, text test ids, Y before X, copies of sheets, summary blocks, no positions, and
other vendors' tables. Generated files must read back within 2 % of what was written, or be refused in one
line; the format recognised is named.
"""

from __future__ import annotations

import csv
import random
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import openpyxl
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from kla_synth import Material, RecordStyle, Tip, indent, record_rows, write_record

from core.errors import InputError
from drivers.kla.export import read_kla_export

ROOT = Path(__file__).resolve().parents[1]


def write_xlsx(path: Path, sheets: dict[str, list[list[object]]]) -> Path:
    book = openpyxl.Workbook()
    book.remove(book.active)
    for name, rows in sheets.items():
        sheet = book.create_sheet(name)
        for row in rows:
            sheet.append(row)
    book.save(path)
    return path


def write_text(path: Path, rows: list[list[object]], delimiter: str) -> Path:
    with path.open("w", newline="", encoding="utf-8") as fh:
        writer = csv.writer(fh, delimiter=delimiter)
        for row in rows:
            writer.writerow(["" if v is None else v for v in row])
    return path


HARDNESS_HEADERS = [
    "Hardness At Max Load",
    "Avg Hardness [100-200 nm]",
    "H Average Over Defined Range",
    "H-IT",
    "HIT",
    "Avg H",
    "Mean Hardness",
    "HARDNESS",
]
MODULUS_HEADERS = ["Modulus At Max Load", "Avg Modulus [100-200 nm]", "E Average Over Defined Range", "EIT"]
SUMMARY_LABELS = ["Minimum", "Maximum", "Average", "Standard Deviation", "Mean", "Std. Dev.", "% COV"]


@dataclass(frozen=True)
class Layout:
    hardness_header: str
    modulus_header: str
    cycles: int  # per-cycle rows after each per-test row ('1-1' ...), 0 for none
    text_ids: bool  # test ids stored as text ('001')
    y_first: bool
    positions: bool
    pos_unit: str  # µm or mm
    h_unit: str  # GPa or MPa
    summary: tuple[str, ...]
    decoy_copy: bool  # a copy of the Results sheet with other numbers, under an unrelated name
    cycle_column: bool  # per-cycle rows marked by a 'Cycle' column instead of '1-1' labels
    stray_rows: bool  # a note line and a repeated header inside the table
    # "results-xlsx", "results-csv", "test-sheets" (label | value rows), "test-sheets-table",
    # "records-folder" (InView's one CSV per test), "nanoblitz-csv"
    shape: str
    n_tests: int
    seed: int


layouts = st.builds(
    Layout,
    hardness_header=st.sampled_from(HARDNESS_HEADERS),
    modulus_header=st.sampled_from(MODULUS_HEADERS),
    cycles=st.sampled_from([0, 0, 3, 5]),
    text_ids=st.booleans(),
    y_first=st.booleans(),
    positions=st.booleans(),
    pos_unit=st.sampled_from(["µm", "mm"]),
    h_unit=st.sampled_from(["GPa", "MPa"]),
    summary=st.lists(st.sampled_from(SUMMARY_LABELS), max_size=4, unique=True).map(tuple),
    decoy_copy=st.booleans(),
    cycle_column=st.booleans(),
    stray_rows=st.booleans(),
    shape=st.sampled_from(
        ["results-xlsx", "results-csv", "test-sheets", "test-sheets-table", "records-folder", "nanoblitz-csv"]
    ),
    n_tests=st.integers(1, 9),
    seed=st.integers(0, 10_000),
)


def truth(layout: Layout) -> list[dict[str, float]]:
    rng = random.Random(layout.seed)
    return [
        {
            "x": 5000.0 + 50.0 * k,
            "y": 8000.0 - 25.0 * k,
            "h": rng.uniform(2.0, 15.0),
            "e": rng.uniform(60.0, 300.0),
        }
        for k in range(layout.n_tests)
    ]


def build(layout: Layout, folder: Path) -> Path:
    """Write the layout; the truth is ``truth(layout)`` in µm and GPa."""
    v = layout
    tests = truth(v)
    p_scale = 1e-3 if v.pos_unit == "mm" else 1.0
    h_scale = 1e3 if v.h_unit == "MPa" else 1.0

    def tid(k: int) -> object:
        return f"{k + 1:03d}" if v.text_ids else k + 1

    if v.shape == "records-folder":
        return _records_folder(v, tests, folder)
    if v.shape == "nanoblitz-csv":
        return _nanoblitz_csv(v, tests, folder)
    if v.shape == "test-sheets-table":  # one sheet per test: a one-row results table above its curve
        sheets = {}
        for k, t in enumerate(tests):
            names = [v.hardness_header, v.modulus_header]
            values: list[object] = [t["h"] * h_scale, t["e"] * h_scale]
            units = [v.h_unit, v.h_unit]
            if v.positions:
                pos = [("X Test Position", t["x"] * p_scale), ("Y Test Position", t["y"] * p_scale)]
                for name, value in pos[::-1] if v.y_first else pos:
                    names.append(name)
                    values.append(value)
                    units.append(v.pos_unit)
            rows = [["TestWorks 4 test", tid(k)], [], names, units, values, []]
            rows.append(["Displacement Into Surface", "Load On Sample", "Time On Sample", "Hardness"])
            rows.append(["nm", "mN", "s", "GPa"])
            rows += [[float(d), 0.01 * d, 0.1 * d, 99.0] for d in range(0, 50, 5)]  # a CSM channel: not it
            sheets[f"Test {k + 1:03d}"] = rows
        return write_xlsx(folder / "testworks_table.xlsx", sheets)
    if v.shape == "test-sheets":  # TestWorks: one sheet per test with its own result, no Results sheet
        sheets: dict[str, list[list[object]]] = {}
        for k, t in enumerate(tests):
            rows: list[list[object]] = [["Test", tid(k)], ["Sample", "film A"]]
            if v.positions:
                pos = [
                    ["X Test Position", t["x"] * p_scale, v.pos_unit],
                    ["Y Test Position", t["y"] * p_scale, v.pos_unit],
                ]
                rows += pos[::-1] if v.y_first else pos
            rows.append([v.hardness_header, t["h"] * h_scale, v.h_unit])
            rows.append([v.modulus_header, t["e"] * h_scale, v.h_unit])
            rows.append([])
            rows.append(["Displacement Into Surface", "Load On Sample", "Time On Sample"])
            rows.append(["nm", "mN", "s"])
            rows += [[float(d), 0.01 * d, 0.1 * d] for d in range(0, 50, 5)]
            sheets[f"Test {k + 1:03d}"] = rows
        if v.decoy_copy:
            sheets["Chart Data"] = [row[:] for row in sheets["Test 001"]]
        return write_xlsx(folder / "testworks.xlsx", sheets)

    columns = ["Test"]
    if v.positions:
        columns += (
            ["Y Test Position", "X Test Position"] if v.y_first else ["X Test Position", "Y Test Position"]
        )
    columns += [v.hardness_header, v.modulus_header]
    cycle_h = "H" if v.cycles else None
    if cycle_h:  # a per-cycle 'H' that is empty on the per-test rows
        columns.insert(1, cycle_h)
    if v.cycles and v.cycle_column:
        columns.insert(1, "Cycle")
    units = ["" if c in ("Test", "Cycle") else (v.pos_unit if "Position" in c else v.h_unit) for c in columns]
    body: list[list[object]] = []
    for k, t in enumerate(tests):
        cell = {
            "Test": tid(k),
            "X Test Position": t["x"] * p_scale,
            "Y Test Position": t["y"] * p_scale,
            v.hardness_header: t["h"] * h_scale,
            v.modulus_header: t["e"] * h_scale,
            "H": None,
            "Cycle": None,
        }
        body.append([cell[c] for c in columns])
        if v.stray_rows and k == 0:
            body.append(["Note: tip changed after this test"] + [None] * (len(columns) - 1))
            body.append(list(columns))
        for c in range(1, v.cycles + 1):  # cycles: their own H, no per-test average
            label = (tid(k), c) if v.cycle_column else (f"{k + 1}-{c}", None)
            row = {**cell, "Test": label[0], "Cycle": label[1], "H": 3.0 * t["h"] * h_scale / c}
            row[v.hardness_header] = None
            row[v.modulus_header] = 2.0 * t["e"] * h_scale
            body.append([row[col] for col in columns])
    summary = [[label] + [1.0] * (len(columns) - 1) for label in v.summary]
    rows = [columns, units, *body, [], *summary]
    if v.shape == "results-csv":
        return write_text(folder / "results.csv", rows, ",")
    sheets = {"Results": rows}
    if v.decoy_copy:  # an older copy with other numbers (and positions) under an unrelated name: never read
        decoy_cols = ["Test", "X Test Position", "Y Test Position", v.hardness_header]
        sheets["Sheet2"] = [
            decoy_cols,
            ["", "µm", "µm", "GPa"],
            *[[k + 1, 9.99, 9.99, 9.99] for k in range(len(tests))],
        ]
    return write_xlsx(folder / "results.xlsx", sheets)


def _records_folder(v: Layout, tests: list[dict[str, float]], folder: Path) -> Path:
    """InView's one CSV per test, each written its own way (markers on top or inline, BOM, CRLF, ';' with
    decimal commas, invalid samples blank or 1.797e308); the folder is the export."""
    out = folder / "records"
    out.mkdir()
    rng = random.Random(v.seed)
    for k, t in enumerate(tests):
        style = RecordStyle(
            markers=rng.choice(["top", "inline"]),
            bom=rng.random() < 0.5,
            crlf=rng.random() < 0.5,
            semicolon=rng.random() < 0.3,
            invalid=rng.choice(["blank", "dbl_max"]),
            size_effect=False,
        )
        material = Material(t["h"], t["e"])
        rec = indent(material, Tip(), (0.3, 1.0), seed=k, points=12)
        rows, _ = record_rows(rec, material, t["x"], t["y"], style, pos_unit=v.pos_unit, h_unit=v.h_unit)
        if not v.positions:  # a template without the stage's X/Y Axis Position
            rows = [row[:12] for row in rows]
        write_record(str(out / (f"Test{k + 1:03d}.csv" if v.text_ids else f"Test{k + 1}.csv")), rows, style)
    return out


def _nanoblitz_csv(v: Layout, tests: list[dict[str, float]], folder: Path) -> Path:
    """A NanoBlitz 3D map as it arrives: UTF-8 BOM, CRLF, a units row, X/Y Position, summary rows."""
    p_scale = 1e-3 if v.pos_unit == "mm" else 1.0
    h_scale = 1e3 if v.h_unit == "MPa" else 1.0
    pos = ["Y Position", "X Position"] if v.y_first else ["X Position", "Y Position"]
    names = [
        "Test",
        *(pos if v.positions else []),
        "Load at Max Load",
        "Depth at Max Load",
        "Modulus",
        "Hardness",
    ]
    units = ["", *([v.pos_unit] * 2 if v.positions else []), "mN", "nm", v.h_unit, v.h_unit]
    lines = [",".join(names), ",".join(units)]
    for k, t in enumerate(tests):
        xy = [t["y"], t["x"]] if v.y_first else [t["x"], t["y"]]
        cells = [f"{k + 1:03d}" if v.text_ids else str(k + 1)]
        cells += [repr(c * p_scale) for c in xy] if v.positions else []
        cells += ["1.5", "120.0", repr(t["e"] * h_scale), repr(t["h"] * h_scale)]
        lines.append(",".join(cells))
    lines += [",".join([label] + ["1.0"] * (len(names) - 1)) for label in v.summary]
    path = folder / "nanoblitz.csv"
    path.write_bytes(b"\xef\xbb\xbf" + ("\r\n".join(lines) + "\r\n").encode("utf-8"))
    return path


@settings(max_examples=36, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(layout=layouts)
def test_generated_lab_layouts_read_within_two_percent(
    layout: Layout, tmp_path_factory: pytest.TempPathFactory
) -> None:
    folder = tmp_path_factory.mktemp("layout")
    path = build(layout, folder)
    export = read_kla_export(path)
    want = truth(layout)
    assert [i.test_id for i in export.indents] == [str(k + 1) for k in range(layout.n_tests)], export.warnings
    for got, t in zip(export.indents, want, strict=True):
        assert got.hardness_gpa == pytest.approx(t["h"], rel=0.02), (got, export.warnings)
        assert got.modulus_gpa == pytest.approx(t["e"], rel=0.02)
        if layout.positions:
            assert got.x_um == pytest.approx(t["x"], rel=0.02) and got.y_um == pytest.approx(t["y"], rel=0.02)
        else:
            assert got.x_um is None and got.y_um is None
    assert export.has_positions is layout.positions
    if layout.shape.startswith("test-sheets"):
        assert export.software == "TestWorks"
    if layout.shape == "records-folder":
        assert export.software == "InView per-test record"
    if layout.shape == "nanoblitz-csv" and layout.positions:
        assert export.software == "NanoBlitz 3D"
    if layout.cycles and layout.shape.startswith("results"):
        assert any("per-cycle row" in w for w in export.warnings)
        # the per-test hardness is the averaged column, named; 'H' is empty on the per-test rows
        assert any("hardness from" in w and "'H'" in w for w in export.warnings), export.warnings
        assert export.hardness_column != "H"
    assert export.hardness_column


# ------------------------------------------------------------------------------------------ vendors


def test_hysitron_xpm_text_export_is_labelled_hysitron_and_read_in_gpa(tmp_path: Path) -> None:
    rows: list[list[object]] = [
        ["XPM Results", "", "", "", "", "", "", ""],
        ["Indent", "X(um)", "Y(um)", "hc(nm)", "Pmax(uN)", "hmax(nm)", "Er(GPa)", "H(GPa)"],
    ]
    for k in range(6):
        rows.append([k + 1, 2.0 * k, 0.0, 40.0 + k, 1000.0, 55.0 + k, 120.0, 8.0 + 0.1 * k])
    path = write_text(tmp_path / "xpm.txt", rows, "\t")
    export = read_kla_export(path)
    assert export.software == "Hysitron"
    assert [i.hardness_gpa for i in export.indents] == pytest.approx([8.0 + 0.1 * k for k in range(6)])
    assert export.indents[0].max_load_mn == pytest.approx(1.0)  # µN -> mN
    assert export.indents[1].x_um == pytest.approx(2.0)


def test_anton_paar_table_in_mpa_and_mm_is_read_in_gpa_and_um(tmp_path: Path) -> None:
    rows: list[list[object]] = [
        ["Anton Paar Indentation Software", "", "", "", "", ""],
        ["Indentation", "X [mm]", "Y [mm]", "HIT [MPa]", "EIT [GPa]", "HVIT [Vickers]", "Fmax [mN]"],
    ]
    for k in range(4):
        rows.append([k + 1, 1.0 + 0.01 * k, 2.0, 9000.0 + 100 * k, 70.0, 850.0, 10.0])
    path = write_xlsx(tmp_path / "ap.xlsx", {"Results": rows})
    export = read_kla_export(path)
    assert export.software == "Anton Paar"
    assert [i.hardness_gpa for i in export.indents] == pytest.approx([9.0, 9.1, 9.2, 9.3])
    assert export.indents[1].x_um == pytest.approx(1010.0) and export.indents[0].y_um == pytest.approx(2000.0)
    assert export.hardness_column == "HIT"


@pytest.mark.parametrize(
    ("text", "vendor"),
    [
        ("File Version: Hysitron 9.4\nTime (s)\tDepth (nm)\tLoad (uN)\n0\t0\t0\n", "Hysitron"),
        ("Micro Materials NanoTest\nDepth (nm)\tLoad (mN)\n0\t0\n", "Micro Materials"),
        ("FISCHERSCOPE HM2000\nh [um]\tF [mN]\n0\t0\n", "Fischerscope"),
    ],
)
def test_a_single_curve_from_another_vendor_is_refused_in_one_line_naming_it(
    tmp_path: Path, text: str, vendor: str
) -> None:
    path = tmp_path / "curve.txt"
    path.write_text(text)
    with pytest.raises(InputError) as info:
        read_kla_export(path)
    assert info.value.problem.startswith(f"{vendor} export:") and "\n" not in str(info.value)


def test_per_cycle_rows_only_are_refused(tmp_path: Path) -> None:
    rows: list[list[object]] = [["Test", "X", "Y", "H"], ["", "µm", "µm", "GPa"]]
    rows += [[f"1-{c}", 0.0, 0.0, 5.0] for c in range(1, 4)]
    path = write_xlsx(tmp_path / "cycles.xlsx", {"Results": rows})
    with pytest.raises(InputError, match="per-cycle rows only"):
        read_kla_export(path)


def test_test_sheets_without_result_or_curve_are_refused(tmp_path: Path) -> None:
    sheets: dict[str, list[list[object]]] = {"Test 001": [["Sample", "A"]], "Test 002": [["Sample", "A"]]}
    path = write_xlsx(tmp_path / "empty_tests.xlsx", sheets)
    with pytest.raises(InputError) as info:
        read_kla_export(path)
    assert info.value.problem.startswith("TestWorks export:") and "Load/Depth" in info.value.problem


def test_cli_names_the_format_and_reads_a_file_without_positions(tmp_path: Path) -> None:
    path = write_text(tmp_path / "nopos.csv", [["Test", "Hardness"], ["", "GPa"], [1, 4.5], [2, 4.6]], ",")
    done = subprocess.run(
        [sys.executable, "-m", "aeni_console.cli.main", "kla", "read", str(path)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    assert "format unknown, 2 tests" in done.stdout and "no positions" in done.stdout
    assert "4.500" in done.stdout


def test_two_different_results_tables_without_a_results_sheet_are_refused(tmp_path: Path) -> None:
    table = [["Test", "X", "Y", "Hardness"], ["", "µm", "µm", "GPa"], [1, 0.0, 0.0, 5.0]]
    copy = [row[:] for row in table]
    same = write_xlsx(tmp_path / "same.xlsx", {"Sheet1": table, "Sheet1 (2)": copy})
    assert read_kla_export(same).indents[0].hardness_gpa == 5.0
    copy[2][3] = 7.0
    other = write_xlsx(tmp_path / "other.xlsx", {"Sheet1": table, "Old": copy})
    with pytest.raises(InputError, match="'Sheet1' and 'Old' both hold a different results table"):
        read_kla_export(other)

"""The results-table family: InView .xlsx and NanoSuite .xls workbooks, and tidy CSV/TSV results tables.

Both programs write one workbook per sample: a ``Results`` sheet with one row per test (plus a units row
under the header and summary rows at the bottom) and one ``Test N`` sheet per test with the raw curve; a
CSV export is the Results sheet alone. They share this reader; what differs between them (sheet names, the
1.797e308 "invalid", per-cycle rows) is handled where it shows.

Where the hardness comes from (``KlaIndent.source``):

* ``"results"``: the Results sheet has a hardness column (Example.xls: "H Average Over Defined Range").
* ``"curve"``: it does not (the InView template of FusedSilica.xlsx has only Pmax, target load and
  position), so hardness is derived from the test's own sheet (``drivers.kla.readers.curves``).

Drift: ``drift_rate_nm_s`` comes from the Results sheet only. The curves are exported already drift-
corrected (InView's drift-hold segment is flat to 1e-14 nm/s), and what slope remains in a NanoSuite
drift hold is creep recovery, so neither is re-measured nor re-applied.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from pathlib import Path
from typing import cast

import numpy as np
import pandas as pd

from core.errors import InputError
from drivers.kla.readers.columns import (
    AREA_COEFF,
    CURVE_ALIASES,
    CYCLE_COLUMN,
    CYCLE_LABEL,
    INPUT_ALIASES,
    NOT_A_VALUE,
    PRESSURE_GPA,
    RESULT_ALIASES,
    SUMMARY_LABELS,
    TEST_ID,
    TEST_SHEET,
    clean_unit,
    norm_key,
    unit_factor,
)
from drivers.kla.readers.curves import (
    DEFAULT_POISSON,
    CurveResult,
    area_coeffs_of,
    csm_average,
    cycle_results,
    describe_area,
    frame_compliance_from_cycles,
    oliver_pharr,
    parse_curve,
    peak_of,
)
from drivers.kla.readers.indents import NO_POSITIONS, KlaExport, KlaIndent
from drivers.kla.readers.plausibility import (
    CYCLE_MODULUS_SPREAD,
    MAX_HARDNESS_GPA,
    MAX_MODULUS_GPA,
    contradiction,
    cycle_spread,
    implausible,
    note_outliers,
    own_cycles,
)
from drivers.kla.readers.tables import (
    Table,
    finite,
    is_blank,
    is_number,
    is_summary_row,
    looks_like_units_row,
    missing_value,
    numeric,
    parse_header,
    split_table,
    test_key_of,
    twin_columns,
)
from drivers.kla.readers.test_sheets import curve_sheet_names, results_from_test_sheets


def _results_sheet(sheets: Mapping[str, pd.DataFrame]) -> str | None:
    for name in sheets:
        if norm_key(name) == "results":
            return name
    for name in sheets:
        if "result" in norm_key(name):
            return name
    return None


def _table_sheet(path: Path, sheets: Mapping[str, pd.DataFrame]) -> str | None:
    """A sheet of another name that holds a per-test results table (a test column and a hardness column,
    no load-depth curve): a workbook without a Results sheet and without Test sheets. Two such sheets
    that differ are refused: which one is this run's cannot be told."""
    found: list[str] = []
    for name, raw in sheets.items():
        table = split_table(raw, RESULT_ALIASES["test_id"])
        if table is None or table.column(RESULT_ALIASES["test_id"]) is None:
            continue
        if (
            table.column(CURVE_ALIASES["load"]) is not None
            and table.column(CURVE_ALIASES["depth"]) is not None
        ):
            continue
        if _value_columns(table, "hardness_gpa", "hardness", "h"):
            found.append(name)
    differing = [n for n in found[1:] if not sheets[n].equals(sheets[found[0]])]
    if differing:
        raise InputError(
            str(path),
            f"no 'Results' sheet, and sheets {found[0]!r} and {differing[0]!r} both hold a different results "
            "table: keep this run's one (or name it Results)",
        )
    return found[0] if found else None


def _value_columns(table: Table, key: str, word: str, letter: str) -> list[int]:
    """Columns that hold a per-test value of ``word``: exact aliases first, then names that contain the
    word ('Avg Hardness', 'Hardness@CSM'), then a bare letter with a pressure unit ('H' in GPa).
    Spreads and errors ('Hardness Std Dev') are not values."""
    exact = [i for i, k in enumerate(table.keys) if k in RESULT_ALIASES[key]]
    loose = []
    for i, k in enumerate(table.keys):
        named = word in k and not set(re.split(r"[^a-z%]+", k)) & NOT_A_VALUE
        lettered = k == letter and clean_unit(table.units[i]) in PRESSURE_GPA
        if i not in exact and (named or lettered):
            loose.append(i)
    loose.sort(key=lambda i: not ({"avg", "average", "mean"} & set(table.keys[i].split())))
    return exact + loose


def _result_columns(table: Table) -> dict[str, list[int]]:
    """Every candidate column per quantity, best first (hardness and modulus may have several)."""
    cols: dict[str, list[int]] = {}
    for key, aliases in RESULT_ALIASES.items():
        col = table.column(aliases)
        cols[key] = [] if col is None else [col]
    cols["hardness_gpa"] = _value_columns(table, "hardness_gpa", "hardness", "h")
    cols["modulus_gpa"] = _value_columns(table, "modulus_gpa", "modulus", "e")
    return cols


_INPUT_SHEET_WORDS = ("input", "information", "sample", "parameter", "setup", "position", "method")


def _inputs_by_test(
    sheets: Mapping[str, pd.DataFrame],
    skip: set[str],
    notes: list[str],
    reads: frozenset[str] = frozenset(),
    known: frozenset[str] = frozenset(),
) -> dict[str, dict[str, float]]:
    """Per-test values from the input sheets (positions, Poisson ratio, calculation depths, area function).

    Only the results sheet and sheets named as inputs or sample information are read: a copy of a sheet
    under an unrelated name ('Sheet2', 'Chart Data') may hold another run's numbers."""
    out: dict[str, dict[str, float]] = {}
    for name, raw in sheets.items():
        if name in skip or TEST_SHEET.match(name) or norm_key(name).startswith("cycles"):
            continue
        if not (name in reads or any(w in norm_key(name) for w in _INPUT_SHEET_WORDS)):
            continue
        table = split_table(raw, RESULT_ALIASES["test_id"])
        if table is None:
            continue
        test_col = table.column(RESULT_ALIASES["test_id"])
        assert test_col is not None
        wanted: dict[str, tuple[int, float]] = {}
        for key, aliases in INPUT_ALIASES.items():
            if name in reads and key in known:
                continue  # the results sheet's own column, already read (a 40,000-row map reads it once)
            col = table.column(aliases)
            if col is not None:
                factor = 1.0 if key == "poisson" else unit_factor(key, table.units[col], name, notes)
                wanted[key] = (col, factor)
        for i, k in enumerate(table.keys):
            m = AREA_COEFF.match(k)
            if m:
                wanted[f"area{int(m.group(1))}"] = (i, 1.0)
        if not wanted:
            continue
        columns = {key: numeric(table.data[col]) * f for key, (col, f) in wanted.items()}
        for row, label in enumerate(table.data[test_col]):
            test = test_key_of(label)
            if test is None or norm_key(test) in SUMMARY_LABELS:
                continue
            record = out.setdefault(test, {})
            for key, values in columns.items():
                if math.isfinite(values[row]):
                    record.setdefault(key, float(values[row]))
    return out


def _test_rows(
    table: Table, test_col: int | None, sheet: str, path: Path, notes: list[str]
) -> list[tuple[int, str]]:
    """(row, test id) for every per-test row. Not tests: summary rows, blank rows, a repeated header or
    units row, text lines without a number, and per-cycle rows ('1-1', or a filled 'Cycle' column beside
    per-test rows with it empty). A sheet of per-cycle rows only is refused (it has no per-test result)."""
    cycle_col = table.column(CYCLE_COLUMN)
    cycle_filled = (
        [not is_blank(v) for v in table.data[cycle_col]]
        if cycle_col is not None
        else [False] * len(table.data)
    )
    if all(cycle_filled):  # every row has a cycle: one cycle per test, or no per-test rows (duplicates show)
        cycle_filled = [False] * len(table.data)
    rows: list[tuple[int, str]] = []
    cycles: list[str] = []
    other = 0
    all_cells: list[list[object]] = table.data.to_numpy(dtype=object).tolist()  # rows, not pandas per row
    for row, cells in enumerate(all_cells):
        label = cells[test_col] if test_col is not None else None
        if is_summary_row(cells):
            continue
        if all(is_blank(c) for c in (cells[i] for i in range(len(cells)) if i != test_col)):
            continue
        texts = [norm_key(parse_header(c)[0]) for c in cells if isinstance(c, str) and c.strip()]
        if sum(t in table.keys for t in texts) >= 2 or (texts and looks_like_units_row(cells)):
            other += 1  # a second header or units row (a table pasted below, a copy)
            continue
        if (isinstance(label, str) and CYCLE_LABEL.match(label)) or cycle_filled[row]:
            cycles.append(
                str(label).strip() if not cycle_filled[row] else f"{label}/{cells[cast(int, cycle_col)]}"
            )
            continue
        id_like = is_number(label) or (isinstance(label, str) and bool(TEST_ID.match(label)))
        if not id_like and not any(is_number(c) for c in cells):
            other += 1  # a note or a metadata line inside the table
            continue
        test_key = test_key_of(label)
        rows.append((row, test_key if test_key is not None else str(len(rows) + 1)))
    if cycles and not rows:
        raise InputError(
            str(path),
            f"sheet {sheet!r} has per-cycle rows only ({cycles[0]!r} ...), no per-test rows: "
            "export the per-test results",
        )
    if cycles:
        notes.append(
            f"{sheet}: {len(cycles)} per-cycle row(s) ({cycles[0]!r} ...) are not tests: "
            f"read the {len(rows)} per-test row(s)"
        )
    if other:
        notes.append(f"{sheet}: {other} row(s) without test data (a repeated header, a note) skipped")
    seen: dict[str, int] = {}
    for _, test in rows:
        seen[test] = seen.get(test, 0) + 1
    repeated = [t for t, n in seen.items() if n > 1]
    if repeated and test_col is not None:
        raise InputError(
            str(path),
            f"sheet {sheet!r}: test {repeated[0]!r} is on {seen[repeated[0]]} rows (per-cycle rows without "
            "their per-test row?): export one row per test",
        )
    return rows


def _pick_value_column(
    table: Table, candidates: list[int], key: str, rows: list[int], sheet: str, notes: list[str]
) -> int | None:
    """The first candidate with a number on a per-test row ('H' may be empty there while 'Avg H' holds
    the test's result); says which column was used when there was a choice."""
    word = "hardness" if key == "hardness_gpa" else "modulus"
    filled = [c for c in candidates if np.isfinite(numeric(table.data[c].iloc[rows])).any()]
    if not candidates:
        return None
    chosen = filled[0] if filled else candidates[0]
    empty = [c for c in candidates if c not in filled and candidates.index(c) < candidates.index(chosen)]
    others = [c for c in candidates if c != chosen and c not in empty]
    if empty:
        names = ", ".join(repr(table.headers[c]) for c in empty)
        notes.append(f"{sheet}: {word} from {table.headers[chosen]!r} ({names} empty on the per-test rows)")
    elif others:
        names = ", ".join(repr(table.headers[c]) for c in others)
        notes.append(f"{sheet}: {word} from {table.headers[chosen]!r}; also present, not used: {names}")
    return chosen


def _refuse_twins(
    path: Path, sheet: str, table: Table, key: str, col: int, rows: list[int], values: np.ndarray
) -> None:
    """Two columns of the same name that disagree on a test: which one is the file's value cannot be told
    (taking the first would be a guess). Copies that agree are one value."""
    for twin in twin_columns(table, col):
        factor = unit_factor(key, table.units[twin], f"{sheet}: {table.headers[twin]}", [])
        other = numeric(table.data[twin]) * factor
        mine, theirs = values[rows], other[rows]
        both = np.isfinite(mine) & np.isfinite(theirs)
        differ = both & ~np.isclose(mine, theirs, rtol=1e-6, atol=0.0)
        if differ.any():
            r = rows[int(np.flatnonzero(differ)[0])]
            raise InputError(
                str(path),
                f"sheet {sheet!r} has two {table.headers[col]!r} columns (columns {col + 1} and {twin + 1}) "
                f"that disagree ({mine[differ][0]:g} and {theirs[differ][0]:g} on data row {r + 1}): "
                "which one is the file's value cannot be told; rename or remove one",
            )


def read_workbook(
    path: Path, sheets: dict[str, pd.DataFrame], software: str, frame_compliance_nm_mn: float | None
) -> KlaExport:
    notes: list[str] = []
    res_name = _results_sheet(sheets)
    if res_name is None and curve_sheet_names(sheets):
        res_name = "Test sheets"
        sheets = {**sheets, res_name: results_from_test_sheets(path, sheets, notes)}
    elif res_name is None:
        res_name = _table_sheet(path, sheets)
        if res_name is None:
            raise InputError(
                str(path),
                f"no 'Results' sheet, no 'Test N' sheets and no sheet with a test and a hardness column "
                f"(sheets: {', '.join(sheets)})",
            )
        notes.append(f"no 'Results' sheet: results read from sheet {res_name!r}")
    table = split_table(sheets[res_name], [a for aliases in RESULT_ALIASES.values() for a in aliases])
    if table is None or table.data.empty:
        raise InputError(str(path), f"sheet {res_name!r} has no header row with known columns")
    candidates = _result_columns(table)
    test_col = candidates["test_id"][0] if candidates["test_id"] else None
    if test_col is None and table.keys and table.keys[0] == "":
        test_col = 0  # an unnamed first column holds the test labels (and 'Average', '1-1' ...)
    test_ids = _test_rows(table, test_col, res_name, path, notes)
    if not test_ids:
        raise InputError(str(path), f"sheet {res_name!r} has no test rows")
    row_index = [r for r, _ in test_ids]
    cols: dict[str, int | None] = {}
    for key, found in candidates.items():
        if key in ("hardness_gpa", "modulus_gpa"):
            cols[key] = _pick_value_column(table, found, key, row_index, res_name, notes)
        else:
            cols[key] = found[0] if found else None
    values: dict[str, np.ndarray] = {}
    for key, col in cols.items():
        if col is not None and key != "test_id":
            factor = unit_factor(key, table.units[col], f"{res_name}: {table.headers[col]}", notes)
            values[key] = numeric(table.data[col]) * factor
            _refuse_twins(path, res_name, table, key, col, row_index, values[key])
    hardness_column = table.headers[cols["hardness_gpa"]] if cols["hardness_gpa"] is not None else ""
    hardness_range = table.ranges_nm[cols["hardness_gpa"]] if cols["hardness_gpa"] is not None else None
    if hardness_range is not None:
        lo, hi = hardness_range
        notes.append(
            f"hardness is the file's own average over {lo:g}-{hi:g} nm "
            f"(column {table.headers[cast(int, cols['hardness_gpa'])]!r})"
        )
    area_cols = {int(m.group(1)): i for i, k in enumerate(table.keys) if (m := AREA_COEFF.match(k))}

    known = frozenset(k for k in ("x_um", "y_um") if k in values)
    inputs = _inputs_by_test(
        sheets, set(), notes, frozenset({res_name}), known
    )  # Results may carry depths too
    for row, test in test_ids:
        for k, col in area_cols.items():
            v = numeric(table.data[col].iloc[[row]])[0]
            if math.isfinite(v):
                inputs.setdefault(test, {})[f"area{k}"] = float(v)

    has_xy = "x_um" in values and "y_um" in values
    if not has_xy and not any(
        "x_um" in inputs.get(t, {}) and "y_um" in inputs.get(t, {}) for _, t in test_ids
    ):
        notes.append(f"{NO_POSITIONS} (no X/Y column in {res_name!r} or any inputs sheet)")

    curve_sheets = curve_sheet_names({n: df for n, df in sheets.items() if n != res_name})
    need_h = "hardness_gpa" not in values
    need_curve = need_h or "max_load_mn" not in values or "max_depth_nm" not in values
    if need_h and not curve_sheets:
        raise InputError(
            str(path), f"no hardness column in {res_name!r} and no 'Test N' sheets with load-depth data"
        )

    cf = frame_compliance_nm_mn
    cf_notes: list[str] = []
    cf_source = "given by the caller" if cf is not None else ""
    if need_h and cf is None:
        cf = frame_compliance_from_cycles(sheets, cf_notes)
        cf_source = cf_notes[-1].split(" estimated ")[-1] if cf else ""
    own_sheet, own = own_cycles(sheets, notes) if need_h else ("", {})
    areas_used: set[str] = set()
    contradictions: list[str] = []
    spreads: list[tuple[float, str, str]] = []  # per test: how its cycles' moduli drift with depth

    indents: list[KlaIndent] = []
    missing_curves: list[str] = []
    used_op = False
    parsed_curves = 0
    for row, test in test_ids:

        def get(key: str, r: int = row) -> float | None:
            return finite(values[key][r]) if key in values else None

        extra = inputs.get(test, {})
        x = get("x_um") if get("x_um") is not None else extra.get("x_um")
        y = get("y_um") if get("y_um") is not None else extra.get("y_um")
        h, e, drift, p_max, h_max = (
            get("hardness_gpa"),
            get("modulus_gpa"),
            get("drift_rate_nm_s"),
            get("max_load_mn"),
            get("max_depth_nm"),
        )
        failure: str | None = None
        if not need_h and h is None:
            raw = table.data.iat[row, cast(int, cols["hardness_gpa"])]
            failure = f"hardness {missing_value(raw)}"
        derived: CurveResult | None = None
        if need_curve and test in curve_sheets:
            curve = parse_curve(sheets[curve_sheets[test]], curve_sheets[test], notes)
            parsed_curves += curve is not None
            if curve is None:
                notes.append(f"test {test}: sheet {curve_sheets[test]!r} has no Load/Depth columns")
            elif need_h and curve.hardness_gpa is not None and np.isfinite(curve.hardness_gpa).any():
                derived = csm_average(
                    curve, extra.get("min_calc_depth"), extra.get("max_calc_depth"), test, notes
                )
            elif need_h:
                poisson = extra.get("poisson")
                if poisson is None:
                    notes.append(f"test {test}: no Poisson ratio in the file, {DEFAULT_POISSON} assumed")
                    poisson = DEFAULT_POISSON
                used_op = True
                coeffs = area_coeffs_of(extra)
                areas_used.add(describe_area(coeffs))
                derived = oliver_pharr(
                    curve,
                    test=test,
                    frame_compliance_nm_mn=cf or 0.0,
                    poisson=poisson,
                    area_coeffs=coeffs,
                    notes=notes,
                )
                if derived is not None:
                    why = contradiction(
                        test,
                        load_mn=derived.max_load_mn,
                        raw_depth_nm=derived.raw_depth_nm,
                        area_coeffs=coeffs,
                        own=own[test][-1] if own.get(test) else None,
                        own_sheet=own_sheet,
                        results_load_mn=p_max,
                    )
                    if why is not None:
                        contradictions.append(why)
                    spread = cycle_spread(
                        cycle_results(
                            curve,
                            test=test,
                            frame_compliance_nm_mn=cf or 0.0,
                            poisson=poisson,
                            area_coeffs=coeffs,
                        )
                    )
                    if spread is not None:
                        spreads.append((spread[0], test, spread[1]))
            else:  # hardness from Results; the curve only fills the peak load/depth
                peak_values = peak_of(curve)
                if peak_values is not None:
                    derived = CurveResult(None, None, peak_values[0], peak_values[1])
        elif need_h:
            missing_curves.append(test)
        if derived is not None:
            if need_h:
                h, e = finite(derived.hardness_gpa), finite(derived.modulus_gpa)
            p_max = p_max if p_max is not None else finite(derived.max_load_mn)
            h_max = h_max if h_max is not None else finite(derived.max_depth_nm)
        if need_h and h is None:
            failure = "no hardness from its curve" if test in curve_sheets else "no curve sheet"
        failure = failure or implausible(h, "hardness", MAX_HARDNESS_GPA)
        failure = failure or implausible(e, "modulus", MAX_MODULUS_GPA)
        if failure is not None:
            h = None
            e = e if implausible(e, "modulus", MAX_MODULUS_GPA) is None else None
        source = "curve" if need_h else "results"
        indents.append(KlaIndent(test, x, y, h, e, drift, p_max, h_max, source, failure))

    if need_h and parsed_curves == 0:
        raise InputError(
            str(path), f"no hardness in {res_name!r} and no Test sheet with Load/Depth columns to derive it"
        )
    _refuse_contradictions(path, contradictions, spreads, areas_used, len(test_ids))
    if missing_curves:
        notes.append(f"no Test sheet for test(s) {', '.join(missing_curves)}: hardness missing")
    analysis = ""
    if used_op:
        cf_text = f"{cf:.3f} nm/mN ({cf_source})" if cf else "none (not estimable from the file: E reads low)"
        analysis = (
            f"Oliver-Pharr on each test's final unload; area function {'; '.join(sorted(areas_used))}; "
            f"frame compliance {cf_text}"
        )
        checked = [f"the file's own analysis in {own_sheet!r}"] if own else []
        if spreads:
            drift = float(np.median([d for d, _, _ in spreads]))
            checked.append(f"its cycles' moduli (median drift {100 * drift:.0f} % with depth)")
        if checked:
            analysis += f"; checked against {' and '.join(checked)}"
        notes.append(f"hardness computed from the curves: {analysis}")
    if used_op:
        notes.extend(cf_notes)
        if not cf:
            notes.append("modulus not corrected for frame compliance (none given or estimable): reads low")
    failed = [i for i in indents if i.failed]
    if failed:
        shown = "; ".join(f"test {i.test_id}: {i.failure}" for i in failed[:5])
        more = f" (and {len(failed) - 5} more)" if len(failed) > 5 else ""
        notes.append(f"{len(failed)} failed indent(s), no hardness recorded: {shown}{more}")
    note_outliers(indents, notes)
    return KlaExport(
        str(path),
        software,
        tuple(indents),
        tuple(dict.fromkeys(notes)),
        hardness_range,
        hardness_column if not need_h else "load-depth curve",
        analysis,
    )


def _refuse_contradictions(
    path: Path,
    contradictions: list[str],
    spreads: list[tuple[float, str, str]],
    areas_used: set[str],
    n_tests: int,
) -> None:
    """One line for values computed from curves that the file itself contradicts: per test (its own load,
    depth, contact area) or as a whole (the cycles' moduli drift with depth in the median test)."""
    if contradictions:
        more = f" ({len(contradictions)} of {n_tests} tests)" if len(contradictions) > 1 else ""
        raise InputError(str(path), f"hardness from the curves refused: {contradictions[0]}{more}")
    if spreads and float(np.median([s for s, _, _ in spreads])) > CYCLE_MODULUS_SPREAD:
        drift, test, phrase = sorted(spreads)[len(spreads) // 2]
        raise InputError(
            str(path),
            f"hardness from the curves refused: the curves' own cycles contradict the area function "
            f"{'; '.join(sorted(areas_used))}: test {test} has {phrase} (median drift {100 * drift:.0f} % over "
            f"{len(spreads)} tests; a sample has one modulus, so the area is not this tip's)",
        )

"""The per-test record family: InView can write one CSV per test, the test's whole record.

Columns such as ``Markers, Displacement, Force, Time, DEPTH, LOAD, STIFFNESS, HARDNESS, MODULUS, hdotOverh,
Velocity, Dyn. Phase, X Axis Position, Y Axis Position``, a units row, and marker rows (``Surface Index``,
``End Of Loading Index``, ``Begin Drift Data Index`` ...) that may sit anywhere in the file, not at the
sample they mark. Such a file is ONE test, never a table of tests: read as a results table it would be
thousands of "tests". Its hardness and modulus are InView's own channels, taken where InView reports them:

* over the method's averaging window when the file names one (``Minimum/Maximum Calculation Depth`` in the
  preamble, or a range in the HARDNESS header) -- InView's "Average Over Defined Range";
* else at the ``End Of Loading Index`` marker -- InView's "At Max Load";
* else at the peak load, and the notes say so.

The position is the stage's (X/Y Axis Position, constant through a test). The drift rate is the file's own
when it states one; otherwise it is measured where InView measures it, over the ``Begin/End Drift Data``
markers on the raw ``Displacement`` channel (DEPTH is already drift-corrected), and the notes say so.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from core.errors import InputError
from drivers.kla.readers.columns import RESULT_ALIASES, norm_key, unit_factor
from drivers.kla.readers.curves import loading_band_means
from drivers.kla.readers.indents import KlaExport, KlaIndent
from drivers.kla.readers.plausibility import MAX_HARDNESS_GPA, MAX_MODULUS_GPA, implausible
from drivers.kla.readers.tables import (
    Table,
    as_number,
    is_blank,
    missing_value,
    numeric,
    parse_header,
    split_table,
)

SOFTWARE_INVIEW_RECORD = "InView per-test record"

# surface-referenced channels first: DEPTH/LOAD are on the sample, Displacement/Force are the raw column
_CHANNELS: dict[str, tuple[str, ...]] = {
    "marker": ("markers", "marker"),
    "time": ("time", "time on sample"),
    "depth": ("depth", "displacement into surface"),
    "load": ("load", "load on sample"),
    "raw_depth": ("displacement", "raw displacement"),
    "raw_load": ("force", "raw load"),
    "hardness": ("hardness",),
    "modulus": ("modulus",),
    "x": RESULT_ALIASES["x_um"],
    "y": RESULT_ALIASES["y_um"],
    "drift": RESULT_ALIASES["drift_rate_nm_s"],
}
_UNIT_OF = {
    "time": "time",
    "depth": "depth",
    "raw_depth": "depth",
    "load": "load",
    "raw_load": "load",
    "hardness": "hardness",
    "modulus": "modulus",
    "x": "x_um",
    "y": "y_um",
    "drift": "drift_rate_nm_s",
}
_TEST_IN_NAME = re.compile(r"test\s*[_#\- ]?\s*0*(\d+)", re.IGNORECASE)
_CALC_DEPTH = {
    "min": ("minimum calculation depth", "min calculation depth"),
    "max": ("maximum calculation depth",),
}


def is_record(sheets: dict[str, pd.DataFrame], *, unmarked: bool = False) -> bool:
    """One sheet whose header names markers, a time, a load and a depth channel: a test's record.
    ``unmarked``: also without a Markers column, when it has a HARDNESS channel and no test column (a
    results table has a test column; a record without markers would otherwise be hundreds of "tests")."""
    if len(sheets) != 1:
        return False
    table = _table(next(iter(sheets.values())))
    if table is None:
        return False
    cols = {k: table.column(a) for k, a in _CHANNELS.items()}
    has_load = cols["load"] is not None or cols["raw_load"] is not None
    has_depth = cols["depth"] is not None or cols["raw_depth"] is not None
    if cols["time"] is None or not has_load or not has_depth:
        return False
    if cols["marker"] is not None:
        return True
    no_test_column = table.column(RESULT_ALIASES["test_id"]) is None
    return unmarked and no_test_column and cols["hardness"] is not None and len(table.data) >= 50


def _table(raw: pd.DataFrame) -> Table | None:
    return split_table(raw, _CHANNELS["marker"] + _CHANNELS["time"] + _CHANNELS["load"] + _CHANNELS["depth"])


def test_id_of(path: Path) -> str:
    """'Test 007.csv', 'FS_test7.csv' -> '7'; a name without a number is its own id."""
    m = _TEST_IN_NAME.search(path.stem)
    if m:
        return str(int(m.group(1)))
    digits = re.findall(r"\d+", path.stem)
    return str(int(digits[-1])) if digits else path.stem


@dataclass(frozen=True)
class _Record:
    channels: dict[str, np.ndarray]  # samples in time order, canonical units
    markers: dict[str, tuple[str, int]]  # normalised label -> (label as written, sample index)
    preamble: dict[str, float]  # 'label: value' lines above the header, canonical units where known
    hardness_cells: np.ndarray  # the HARDNESS cells as written (for a failure's reason)


def _preamble(raw: pd.DataFrame, header_row: int, notes: list[str], where: str) -> dict[str, float]:
    out: dict[str, float] = {}
    for r in range(header_row):
        cells = [c for c in raw.iloc[r] if not is_blank(c)]
        if len(cells) < 2 or not isinstance(cells[0], str):
            continue
        value = as_number(cells[1])
        if value is None:
            continue
        key = norm_key(str(cells[0]).rstrip(":"))
        unit = cells[2] if len(cells) > 2 and isinstance(cells[2], str) else None
        if key in _CALC_DEPTH["min"] or key in _CALC_DEPTH["max"]:
            out[key] = value * unit_factor("depth", unit, f"{where}: {cells[0]}", notes)
        elif key in RESULT_ALIASES["drift_rate_nm_s"]:
            out["drift"] = value * unit_factor("drift_rate_nm_s", unit, f"{where}: {cells[0]}", notes)
    return out


def _parse(path: Path, raw: pd.DataFrame, notes: list[str]) -> _Record:
    table = _table(raw)
    if table is None:
        raise InputError(str(path), "per-test record without a header row")
    header_row = next(
        r
        for r in range(len(raw))
        if any(isinstance(c, str) and norm_key(parse_header(c)[0]) in _CHANNELS["time"] for c in raw.iloc[r])
    )
    cols = {k: table.column(a) for k, a in _CHANNELS.items()}
    marker_col = cols.pop("marker")
    labels = table.data[marker_col] if marker_col is not None else pd.Series([None] * len(table.data))
    is_marker = np.array([isinstance(v, str) and bool(v.strip()) for v in labels])
    channels: dict[str, np.ndarray] = {}
    for key, col in cols.items():
        if col is not None:
            where = f"{path.name}: {table.headers[col]}"
            channels[key] = numeric(table.data[col]) * unit_factor(
                _UNIT_OF[key], table.units[col], where, notes
            )
    time = channels["time"]
    sample = ~is_marker & np.isfinite(time)
    order = np.flatnonzero(sample)[np.argsort(time[sample], kind="stable")]
    samples = {k: v[order] for k, v in channels.items()}
    if samples["time"].size < 10:
        raise InputError(
            str(path), f"per-test record with {samples['time'].size} samples: not a test's record"
        )
    markers: dict[str, tuple[str, int]] = {}
    for row in np.flatnonzero(is_marker):
        label = norm_key(str(labels.iloc[row]))
        t = time[row]
        end = samples["time"].size - 1
        if math.isfinite(t):  # the marker row carries its sample's values: find that sample by its time
            index = int(np.searchsorted(samples["time"], t))
            beyond = t > samples["time"][end] and index > end
        else:  # a marker row that holds only the sample's index
            numbers = [n for n in map(as_number, table.data.iloc[row]) if n is not None]
            if not numbers or not numbers[0].is_integer():
                continue
            index = int(numbers[0])
            beyond = index > end
        if beyond:  # a marker past the last sample: the file was cut, its samples stop short
            raise InputError(
                str(path),
                f"per-test record cut short: its {str(labels.iloc[row]).strip()!r} marker is past its last "
                f"sample (t = {samples['time'][end]:g} s, {end + 1} samples): export the test again",
            )
        index = max(0, min(index, end))
        markers.setdefault(label, (str(labels.iloc[row]).strip(), index))
    cells = (
        np.array(table.data[cols["hardness"]], dtype=object)[order]
        if cols["hardness"] is not None
        else np.full(order.size, None, dtype=object)
    )
    return _Record(samples, markers, _preamble(raw, header_row, notes, path.name), cells)


def _marker(rec: _Record, *words: str) -> tuple[str, int] | None:
    for key, (label, index) in rec.markers.items():
        if all(w in key for w in words):
            return label, index
    return None


def _drift(rec: _Record, notes: list[str]) -> float | None:
    if "drift" in rec.preamble:
        return rec.preamble["drift"]
    if "drift" in rec.channels:
        values = rec.channels["drift"][np.isfinite(rec.channels["drift"])]
        if values.size:
            return float(values[0])
    begin, end = _marker(rec, "begin", "drift"), _marker(rec, "end", "drift")
    raw = rec.channels.get("raw_depth")
    if begin is None or end is None or raw is None or end[1] - begin[1] < 5:
        notes.append(
            "the record states no drift rate and has no drift segment on the raw Displacement: drift missing"
        )
        return None
    t = rec.channels["time"][begin[1] : end[1] + 1]
    d = raw[begin[1] : end[1] + 1]
    ok = np.isfinite(t) & np.isfinite(d)
    if ok.sum() < 5:
        return None
    notes.append(
        f"drift rate measured over the drift segment ({begin[0]!r} to {end[0]!r}) of the raw Displacement"
    )
    return float(np.polyfit(t[ok], d[ok], 1)[0])


def read_record(path: Path, raw: pd.DataFrame, notes: list[str]) -> tuple[KlaIndent, str]:
    """One test from its record file, and where its hardness was taken (for the notes)."""
    rec = _parse(path, raw, notes)
    test = test_id_of(path)
    ch = rec.channels
    load = ch.get("load", ch.get("raw_load"))
    depth = ch.get("depth", ch.get("raw_depth"))
    assert load is not None and depth is not None
    hardness, modulus = ch.get("hardness"), ch.get("modulus")
    if hardness is None:
        raise InputError(
            str(path), "per-test record without a HARDNESS channel: InView's own values are needed"
        )
    lo, hi = rec.preamble.get("minimum calculation depth"), rec.preamble.get("maximum calculation depth")
    where: str
    failure: str | None = None
    peak = int(np.nanargmax(np.where(np.isfinite(load), load, -np.inf))) if np.isfinite(load).any() else 0
    end_of_loading = _marker(rec, "end of loading")
    if lo is not None and hi is not None:
        h, e = loading_band_means(depth, peak, lo, hi, hardness, modulus)
        where = f"the method's averaging window {lo:g}-{hi:g} nm"
        if h is None:
            failure = f"no valid HARDNESS sample in {lo:g}-{hi:g} nm"
        index = peak
    else:
        if end_of_loading is not None:
            index, where = end_of_loading[1], f"the {end_of_loading[0]!r} marker"
        else:
            index, where = peak, "the peak load (the record has no End Of Loading marker)"
            after = load[peak:][np.isfinite(load[peak:])]
            if after.size and after.min() > 0.9 * load[peak]:
                raise InputError(
                    str(path),
                    f"per-test record that never unloads (its last load {after[-1]:g} mN is its peak's "
                    f"{after[-1] / load[peak]:.0%}) and has no End Of Loading marker: cut short? "
                    "export the test again",
                )
        h = float(hardness[index]) if math.isfinite(hardness[index]) else None
        e = float(modulus[index]) if modulus is not None and math.isfinite(modulus[index]) else None
        if h is None:
            failure = f"HARDNESS at {where} is {missing_value(rec.hardness_cells[index])}"
    failure = (
        failure or implausible(h, "hardness", MAX_HARDNESS_GPA) or implausible(e, "modulus", MAX_MODULUS_GPA)
    )
    if failure is not None:
        h = None
        e = e if implausible(e, "modulus", MAX_MODULUS_GPA) is None else None

    def position(key: str) -> float | None:
        values = ch.get(key)
        if values is None:
            return None
        finite = values[np.isfinite(values)]
        if not finite.size:
            return None
        if float(np.ptp(finite)) > 1.0:
            notes.append(
                f"test {test}: the stage's {key.upper()} moved {np.ptp(finite):.1f} µm during the test"
            )
        return float(np.median(finite))

    p_max = float(load[index]) if math.isfinite(load[index]) else None
    h_max = float(depth[index]) if math.isfinite(depth[index]) else None
    indent = KlaIndent(
        test, position("x"), position("y"), h, e, _drift(rec, notes), p_max, h_max, "record", failure
    )
    return indent, where


def read_record_export(path: Path, raw: pd.DataFrame) -> KlaExport:
    notes: list[str] = []
    indent, where = read_record(path, raw, notes)
    notes.insert(0, f"one test's record (InView per-test export): H and E are InView's own, at {where}")
    return KlaExport(str(path), SOFTWARE_INVIEW_RECORD, (indent,), tuple(notes), None, f"HARDNESS at {where}")

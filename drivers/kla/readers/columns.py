"""Column aliases, label patterns and unit tables: how a header names a quantity and how to convert it.

Column names drift between templates and versions, so every column is found through an alias table
(case-insensitive, whitespace- and underscore-normalised) and every value is converted with the units row
to µm / GPa / nm/s / mN / nm. NanoSuite marks invalid samples with 1.797e308; those become missing.
"""

from __future__ import annotations

import math
import re

INVALID_THRESHOLD = 1.0e307  # NanoSuite writes DBL_MAX (1.797e308) for "no value"


def norm_key(text: object) -> str:
    """Header key: lower case, underscores and runs of whitespace collapse to one space, no apostrophes."""
    s = str(text).replace("_", " ").replace("\u00a0", " ").replace("'", "").replace("\u2019", "")
    return " ".join(s.split()).lower()


RESULT_ALIASES: dict[str, tuple[str, ...]] = {
    "test_id": (
        "test",
        "test #",
        "test number",
        "test no",
        "test no.",
        "test id",
        "test name",
        "indent",
        "indent #",
        "indent number",
        "indent no",
        "indent no.",
        "indent id",
        "indentation",
        "point",
        "point #",
        "#",
        "no.",
        "nr.",
        "nr",
    ),
    "x_um": ("x position", "x", "x test position", "x pos", "x axis position"),
    "y_um": ("y position", "y", "y test position", "y pos", "y axis position"),
    "hardness_gpa": (
        "hardness",
        "h-it",
        "hit",
        "h it",
        "h average over defined range",
        "hardness average over defined range",
        "avg hardness",
        "average hardness",
        "mean hardness",
        "hardness avg",
        "hardness average",
        "hardness mean",
        "hardness at max load",
        "h at max load",
        "avg h",
        "average h",
        "mean h",
        "h avg",
        "h average",
        "h mean",
        "h avg over defined range",
        "h average over range",
    ),
    "modulus_gpa": (
        "modulus",
        "e-it",
        "eit",
        "e it",
        "e average over defined range",
        "modulus average over defined range",
        "avg modulus",
        "average modulus",
        "mean modulus",
        "modulus avg",
        "modulus average",
        "modulus mean",
        "modulus at max load",
        "e at max load",
        "avg e",
        "average e",
        "mean e",
        "e avg",
        "e average",
        "e mean",
        "e avg over defined range",
        "e average over range",
    ),
    "drift_rate_nm_s": ("drift rate", "drift correction"),
    # "Maximum Displacement" and "Target Load" are the programmed limits, not measurements: not aliased.
    "max_load_mn": (
        "pmax",
        "p max",
        "max load",
        "maximum load",
        "load at max load",
        "peak load",
        "fmax",
        "f max",
        "max force",
        "maximum force",
    ),
    "max_depth_nm": (
        "hmax",
        "h max",
        "max depth",
        "maximum depth",
        "depth at max load",
        "displacement at max load",
    ),
}


CURVE_ALIASES: dict[str, tuple[str, ...]] = {
    "depth": ("depth", "displacement into surface", "displacement"),
    "load": ("load", "load on sample", "force"),
    "time": ("time", "time on sample"),
    "hardness": RESULT_ALIASES["hardness_gpa"],
    "modulus": RESULT_ALIASES["modulus_gpa"],
    "marker": ("markers", "marker", "segment"),
}


INPUT_ALIASES: dict[str, tuple[str, ...]] = {
    "x_um": RESULT_ALIASES["x_um"],
    "y_um": RESULT_ALIASES["y_um"],
    "poisson": ("poissons ratio of sample", "poissons ratio", "poisson ratio", "sample poissons ratio"),
    "min_calc_depth": ("minimum calculation depth", "min calculation depth"),
    "max_calc_depth": ("maximum calculation depth", "max calculation depth"),
}


SUMMARY_LABELS = frozenset(
    {
        "average",
        "mean",
        "median",
        "standard deviation",
        "std dev",
        "std. dev.",
        "std",
        "stdev",
        "coefficient of variation",
        "cov",
        "% cov",
        "%cov",
        "cv",
        "minimum",
        "maximum",
        "min",
        "max",
        "min.",
        "max.",
        "range",
        "count",
        "sum",
        "total",
        "variance",
        "sd",
        "s.d.",
        "std. deviation",
        "std deviation",
        "standard dev",
        "standard dev.",
        "std. dev",
        "std dev.",
        "mean value",
        "average value",
        "avg",
        "avg.",
        "statistics",
        "summary",
        "valid tests",
    }
)


# a per-cycle row of a multi-cycle test: "1-1", "1:2", "3.5" written as text, "Test 1 Cycle 2"
CYCLE_LABEL = re.compile(
    r"^\s*(?:test\s*)?#?\s*\d+\s*(?:[-:/_]\s*\d+|\.[1-9]\d*|\s+cycle\s*\d+)\s*$", re.IGNORECASE
)


AREA_COEFF = re.compile(r"^area coefficient\s*(\d+)$")


# "Test 004", and curve sheets some InView templates suffix: "Test 004 Tagged", "Test 4 (2)"
TEST_SHEET = re.compile(r"^\s*test\s*#?\s*(\d+)(?:[\s_\-(].*)?$", re.IGNORECASE)


HEADER_UNIT = re.compile(r"^(.*?)\s*[\(\[]([^\)\]]*)[\)\]]\s*$")


# an averaging range carried in a header: "Avg Hardness [75-85 nm]", "H (100 to 200 nm) GPa"
HEADER_RANGE = re.compile(
    r"[\(\[]?\s*(\d+(?:\.\d+)?)\s*(?:-|–|—|to|\.\.)\s*(\d+(?:\.\d+)?)\s*(nm|µm|μm|um)\s*[\)\]]?",
    re.IGNORECASE,
)


TEST_ID = re.compile(r"^\s*(?:test\s*)?#?\s*\d+\s*$", re.IGNORECASE)


CYCLE_COLUMN = ("cycle", "cycle #", "cycle number", "cycle no", "cycle no.", "cycle id")


NOT_A_VALUE = frozenset(
    {
        "vickers",
        "hv",
        "hvit",
        "martens",
        "hm",
        "std",
        "stdev",
        "dev",
        "deviation",
        "sd",
        "sigma",
        "error",
        "err",
        "cov",
        "cv",
        "uncertainty",
        "%",
        "range",
    }
)


LENGTH_NM = {"nm": 1.0, "µm": 1e3, "mm": 1e6, "cm": 1e7, "m": 1e9, "a": 0.1, "å": 0.1}


PRESSURE_GPA = {"gpa": 1.0, "mpa": 1e-3, "kpa": 1e-6, "pa": 1e-9, "n/mm²": 1e-3, "n/mm2": 1e-3}
PRESSURE_GPA |= dict.fromkeys(("kgf/mm²", "kgf/mm2", "kg/mm²", "kg/mm2"), 9.80665e-3)  # Vickers-style units


SPEED_NM_S = {"nm/s": 1.0, "µm/s": 1e3, "nm/min": 1.0 / 60.0, "a/s": 0.1}


FORCE_MN = {"mn": 1.0, "µn": 1e-3, "nn": 1e-6, "n": 1e3, "gf": 9.80665}


STIFFNESS_MN_NM = {"n/m": 1e-6, "kn/m": 1e-3, "mn/nm": 1.0, "mn/µm": 1e-3, "µn/nm": 1e-3}


# target unit name and factor table per quantity (factor converts to the *first* unit of the name)
QUANTITY: dict[str, tuple[str, dict[str, float], float]] = {
    "x_um": ("µm", LENGTH_NM, 1e-3),
    "y_um": ("µm", LENGTH_NM, 1e-3),
    "hardness_gpa": ("GPa", PRESSURE_GPA, 1.0),
    "modulus_gpa": ("GPa", PRESSURE_GPA, 1.0),
    "drift_rate_nm_s": ("nm/s", SPEED_NM_S, 1.0),
    "max_load_mn": ("mN", FORCE_MN, 1.0),
    "max_depth_nm": ("nm", LENGTH_NM, 1.0),
    "depth": ("nm", LENGTH_NM, 1.0),
    "load": ("mN", FORCE_MN, 1.0),
    "time": ("s", {"s": 1.0, "ms": 1e-3, "min": 60.0}, 1.0),
    "hardness": ("GPa", PRESSURE_GPA, 1.0),
    "modulus": ("GPa", PRESSURE_GPA, 1.0),
    "min_calc_depth": ("nm", LENGTH_NM, 1.0),
    "max_calc_depth": ("nm", LENGTH_NM, 1.0),
    "stiffness": ("mN/nm", STIFFNESS_MN_NM, 1.0),
}


def clean_unit(unit: object) -> str:
    """'Âµm' (UTF-8 read as Latin-1), 'μm' (Greek mu) and 'um' all mean µm."""
    if unit is None or (isinstance(unit, float) and math.isnan(unit)):
        return ""
    s = str(unit).strip().replace("Âµ", "µ").replace("\u03bc", "µ").replace("Â", "")
    if len(s) >= 2 and s[0] == "u" and s[1].isalpha():
        s = "µ" + s[1:]
    return s.lower()


def unit_factor(quantity: str, unit: object, column: str, notes: list[str]) -> float:
    """Multiplier from the column's unit to the quantity's canonical unit; unknown units are kept as-is."""
    target, table, scale = QUANTITY[quantity]
    u = clean_unit(unit)
    if u in ("", "none", "integer", target.lower()):
        return 1.0
    if u in table:
        return table[u] * scale
    notes.append(f"column {column!r}: unknown unit {unit!r}, read as {target}")
    return 1.0

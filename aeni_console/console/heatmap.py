"""Heatmaps for a terminal: colour mapping, real µm ticks, orientation and the plotext drawing.

plotext's matrix plot is greyscale and labels bins; here every character cell gets an RGB colour
sampled from the GP field at that cell's stage position, ticks are placed at round µm values, and the
x axis is reversed when the instrument shows the sample mirrored. Everything is a pure function of its
arguments so a worker thread can build the picture while the UI thread only swaps it in.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from rich.style import Style
from rich.text import Text

from core.runview import IndentMark, MapFields, RunSnapshot
from core.sample.model import Exclusion, PolygonExclusion

# The four GP fields of the paper's Figure 8, in the order `m` cycles through them, then the modulus map's
# mean and sd and H/E where the run learns a modulus map (issue 27), then the fast channel's learnt bias where
# the run's two-fidelity map is active (issue 36)
HARDNESS_KEYS: tuple[str, ...] = ("mean", "epistemic", "noise", "total")
MODULUS_KEYS: tuple[str, ...] = ("modulus", "modulus_sd", "h_over_e")
BIAS_KEYS: tuple[str, ...] = ("bias",)
FIELD_KEYS: tuple[str, ...] = HARDNESS_KEYS + MODULUS_KEYS + BIAS_KEYS
FIELD_LABELS: dict[str, str] = {
    "mean": "mean hardness",
    "epistemic": "epistemic sd",
    "noise": "noise sd",
    "total": "total sd",
    "modulus": "mean modulus",
    "modulus_sd": "modulus epistemic sd",
    "h_over_e": "H/E",
    "bias": "fast-channel bias H_csm − H_fast",
}
FIELD_UNITS: dict[str, str] = {key: "GPa" for key in FIELD_KEYS} | {"h_over_e": "H/E, no unit"}


def field_keys_of(fields: MapFields | None) -> tuple[str, ...]:
    """The fields `m` cycles through: the modulus ones only where there is a modulus map, the bias only where
    the run has learnt one."""
    if fields is None:
        return HARDNESS_KEYS
    modulus = MODULUS_KEYS if fields.modulus_mean_gpa is not None else ()
    bias = BIAS_KEYS if fields.bias_gpa is not None else ()
    return HARDNESS_KEYS + modulus + bias


# Perceptually ordered anchors (viridis for the mean, inferno for the uncertainties): readable on a dark
# terminal and monotone in lightness, so the greyscale fallback keeps the order.
_VIRIDIS = np.array(
    [
        (68, 1, 84),
        (72, 40, 120),
        (62, 74, 137),
        (49, 104, 142),
        (38, 130, 142),
        (31, 158, 137),
        (53, 183, 121),
        (110, 206, 88),
        (181, 222, 43),
        (253, 231, 37),
    ],
    dtype=float,
)
_INFERNO = np.array(
    [
        (0, 0, 4),
        (31, 12, 72),
        (85, 15, 109),
        (136, 34, 106),
        (186, 54, 85),
        (227, 89, 51),
        (249, 140, 10),
        (249, 201, 50),
        (252, 255, 164),
    ],
    dtype=float,
)
# diverging, for a signed field (the bias): blue below zero, white at zero, red above; its range is made
# symmetric about zero (``value_range(..., symmetric=True)``) so white always means no bias
_BALANCE = np.array(
    [
        (33, 102, 172),
        (103, 169, 207),
        (209, 229, 240),
        (247, 247, 247),
        (253, 219, 199),
        (239, 138, 98),
        (178, 24, 43),
    ],
    dtype=float,
)
COLOUR_MAPS: dict[str, np.ndarray] = {"viridis": _VIRIDIS, "inferno": _INFERNO, "balance": _BALANCE}

HALF_BLOCK = "▀"

# Shading characters for NO_COLOR terminals, lowest to highest.
SHADES = "·░▒▓█"

# Overlay markers, each (colour character, no-colour character, colour); every meaning has its own
# character in both, and none is one of the no-colour SHADES, so a map reads the same without colour.
MARK_OUTLINE = ("#", "#", (205, 205, 205))
MARK_EXCLUDED = ("/", "/", (170, 170, 170))
MARK_EARLIER = ("·", ":", (200, 200, 200))
MARK_FAST = ("*", "*", (120, 230, 255))  # a measured indent of a fast array (NanoBlitz-class)
MARK_MEASURED = ("•", "o", (240, 240, 240))
MARK_NOT_RUN = ("○", "-", (140, 170, 255))
MARK_UNVERIFIED = ("?", "?", (255, 205, 0))
MARK_FAILED = ("✗", "x", (255, 80, 80))
MARK_NEWEST = ("◉", "@", (255, 255, 255))
MARK_PLANNED = ("+", "+", (255, 64, 160))
STATUS_MARKS: dict[str, tuple[str, str, tuple[int, int, int]]] = {
    "measured": MARK_MEASURED,
    "failed": MARK_FAILED,
    "not_run": MARK_NOT_RUN,
    "unverified": MARK_UNVERIFIED,
}
# (marker, legend word) in the order they are drawn: a later one wins a shared character cell
LEGEND: tuple[tuple[tuple[str, str, tuple[int, int, int]], str], ...] = (
    (MARK_OUTLINE, "edge"),
    (MARK_EXCLUDED, "excl."),
    (MARK_EARLIER, "earlier"),
    (MARK_FAST, "fast"),  # under a CSM indent: arrays are dense, the CSM indents few
    (MARK_MEASURED, "measured"),
    (MARK_NOT_RUN, "not run"),
    (MARK_UNVERIFIED, "unverified"),
    (MARK_FAILED, "failed"),
    (MARK_NEWEST, "newest"),
    (MARK_PLANNED, "planned"),
)


@dataclass(frozen=True)
class MapMarks:
    """What the map draws over the field: the sample as it is and the run's indents, in stage µm.

    ``planned_um`` holds one group of sites per array still to run (the pending block, the rest of the
    running one; a stretch of several arrays is several groups), each drawn the same way.
    """

    outline_um: tuple[tuple[float, float], ...] = ()
    exclusions: tuple[Exclusion, ...] = ()
    earlier_um: tuple[tuple[float, float], ...] = ()
    indents: tuple[IndentMark, ...] = ()
    planned_um: tuple[tuple[tuple[float, float], ...], ...] = ()
    newest_block_id: int | None = None


def mark_of(m: IndentMark, newest_block_id: int | None) -> tuple[str, str, tuple[int, int, int]]:
    """How the map draws an indent: by its status; a measured fast indent apart from a CSM one (the newest
    block's fast indents stay fast marks, drawn bold, so an array does not read as hundreds of newest)."""
    if m.status == "measured" and m.channel == "fast":
        return MARK_FAST
    if m.block_id == newest_block_id and m.status == "measured":
        return MARK_NEWEST
    return STATUS_MARKS.get(m.status, MARK_UNVERIFIED)


def marks_for(snap: RunSnapshot) -> MapMarks:
    """The map's marks for a snapshot: the journal's sample, every indent, the sites still to run."""
    sample = snap.sample
    outline: tuple[tuple[float, float], ...] = ()
    if sample is not None:
        c = sample.calibration
        outline = tuple((k.x_um, k.y_um) for k in (c.tl, c.tr, c.br, c.bl))
    planned: list[tuple[tuple[float, float], ...]] = []
    cur = snap.current_block
    if cur is not None:  # the running block's sites still to run (the queue lists them)
        rest = [q.indent_index for q in snap.queue if q.block_id == cur.block_id]
        if rest:
            planned.append(tuple((cur.indents[i].x_um, cur.indents[i].y_um) for i in rest))
    if snap.pending is not None:
        planned.append(tuple((s.x_um, s.y_um) for s in snap.pending.block.indents))
    return MapMarks(
        outline_um=outline,
        exclusions=tuple(sample.exclusions) if sample is not None else (),
        earlier_um=tuple(sample.earlier_indents_um) if sample is not None else (),
        indents=snap.indents,
        planned_um=tuple(planned),
        newest_block_id=max((m.block_id for m in snap.indents), default=None),
    )


def _cells_of_points(
    pts: Sequence[tuple[float, float]],
    cols: int,
    rows: int,
    bounds_um: tuple[float, float, float, float],
    reverse_x: bool,
) -> list[tuple[int, int]]:
    out = []
    for x, y in pts:
        cell = cell_of(x, y, cols, rows, bounds_um, reverse_x)
        if cell is not None:
            out.append(cell)
    return out


def _cell_centres(
    cols: int, rows: int, bounds_um: tuple[float, float, float, float], reverse_x: bool
) -> tuple[np.ndarray, np.ndarray]:
    """Stage (x, y) of every character cell's centre, shaped (rows, cols)."""
    x_min, x_max, y_min, y_max = bounds_um
    xs = x_min + (np.arange(cols) + 0.5) * (x_max - x_min) / cols
    if reverse_x:
        xs = xs[::-1]
    ys = y_max - (np.arange(rows) + 0.5) * (y_max - y_min) / rows
    return np.meshgrid(xs, ys)


def outline_cells(
    outline_um: Sequence[tuple[float, float]],
    cols: int,
    rows: int,
    bounds_um: tuple[float, float, float, float],
    reverse_x: bool,
) -> list[tuple[int, int]]:
    """Character cells the sample's edge passes through (each edge walked in steps under half a cell)."""
    if len(outline_um) < 2:
        return []
    x_min, x_max, y_min, y_max = bounds_um
    cell_um = min((x_max - x_min) / max(cols, 1), (y_max - y_min) / max(rows, 1)) or 1.0
    cells: set[tuple[int, int]] = set()
    pts = list(outline_um)
    for (x0, y0), (x1, y1) in zip(pts, pts[1:] + pts[:1], strict=True):
        n = max(int(math.hypot(x1 - x0, y1 - y0) / (cell_um / 2)) + 1, 2)
        for t in np.linspace(0.0, 1.0, n):
            # a hair inside the bounds, so an edge on the bounding box still lands in a cell
            x = min(max(x0 + t * (x1 - x0), x_min), x_max)
            y = min(max(y0 + t * (y1 - y0), y_min), y_max)
            cell = cell_of(x, y, cols, rows, bounds_um, reverse_x)
            if cell is not None:
                cells.add(cell)
    return sorted(cells)


def colour_map_for(field_key: str) -> str:
    if field_key == "bias":
        return "balance"
    return "viridis" if field_key in ("mean", "modulus", "h_over_e") else "inferno"


def field_array(fields: MapFields, field_key: str) -> np.ndarray:
    """The (ny, nx) array of one field, by its key."""
    nan = np.full(np.shape(fields.mean_gpa), np.nan)
    e_mean = fields.modulus_mean_gpa if fields.modulus_mean_gpa is not None else nan
    arrays = {
        "mean": fields.mean_gpa,
        "epistemic": fields.epistemic_sd_gpa,
        "noise": fields.noise_sd_gpa,
        "total": fields.total_sd_gpa,
        "modulus": e_mean,
        "modulus_sd": fields.modulus_sd_gpa if fields.modulus_sd_gpa is not None else nan,
        "h_over_e": np.asarray(fields.mean_gpa, float) / np.where(np.asarray(e_mean) > 0, e_mean, np.nan),
        "bias": fields.bias_gpa if fields.bias_gpa is not None else nan,
    }
    if field_key not in arrays:
        raise ValueError(f"unknown map field {field_key!r}; expected one of {', '.join(FIELD_KEYS)}")
    return np.asarray(arrays[field_key], dtype=float)


def value_range(values: np.ndarray, symmetric: bool = False) -> tuple[float, float]:
    """Finite min and max, widened a little when flat so the scale never divides by zero; ``symmetric``:
    about zero (a signed field on a diverging colour map)."""
    finite = values[np.isfinite(values)]
    if finite.size == 0:
        return (-1.0, 1.0) if symmetric else (0.0, 1.0)
    lo, hi = float(finite.min()), float(finite.max())
    if symmetric:
        lo, hi = -max(abs(lo), abs(hi)), max(abs(lo), abs(hi))
    if hi - lo < 1e-12:
        pad = max(abs(lo) * 0.01, 1e-6)
        lo, hi = lo - pad, hi + pad
    return lo, hi


def normalise(values: np.ndarray, vmin: float, vmax: float) -> np.ndarray:
    """Values to [0, 1]; NaN stays NaN."""
    span = vmax - vmin if vmax > vmin else 1.0
    return np.clip((np.asarray(values, dtype=float) - vmin) / span, 0.0, 1.0)


def to_rgb(levels: np.ndarray, cmap: str = "viridis") -> np.ndarray:
    """Levels in [0, 1] to uint8 RGB by linear interpolation between the map's anchors (NaN → grey)."""
    anchors = COLOUR_MAPS[cmap]
    lv = np.asarray(levels, dtype=float)
    nan = ~np.isfinite(lv)
    pos = np.clip(np.nan_to_num(lv, nan=0.0), 0.0, 1.0) * (len(anchors) - 1)
    i0 = np.minimum(np.floor(pos).astype(int), len(anchors) - 2)
    frac = (pos - i0)[..., None]
    rgb = anchors[i0] * (1.0 - frac) + anchors[i0 + 1] * frac
    rgb[nan] = (90.0, 90.0, 90.0)
    return np.rint(rgb).astype(np.uint8)


def to_shades(levels: np.ndarray) -> np.ndarray:
    """Levels in [0, 1] to shading characters (NaN → blank), for NO_COLOR terminals."""
    lv = np.asarray(levels, dtype=float)
    idx = np.clip(np.floor(np.nan_to_num(lv, nan=0.0) * len(SHADES)), 0, len(SHADES) - 1).astype(int)
    out = np.array(list(SHADES), dtype=object)[idx]
    out[~np.isfinite(lv)] = " "
    return out


def nice_ticks(lo: float, hi: float, max_ticks: int = 5) -> list[float]:
    """Round tick values (1, 2, 2.5, 5 × 10^k) inside [lo, hi], at most ``max_ticks`` of them."""
    if not (math.isfinite(lo) and math.isfinite(hi)):
        return []
    if hi < lo:
        lo, hi = hi, lo
    if hi - lo < 1e-12 or max_ticks < 2:
        return [lo]
    raw = (hi - lo) / (max_ticks - 1)
    mag = 10 ** math.floor(math.log10(raw))
    for mult in (1.0, 2.0, 2.5, 5.0, 10.0):
        step = mult * mag
        first = math.ceil(lo / step - 1e-9) * step
        ticks = [first + k * step for k in range(int((hi - first) / step + 1e-9) + 1)]
        if len(ticks) <= max_ticks:
            return [round(t, 9) + 0.0 for t in ticks]
    return [lo, hi]


def tick_label(value: float) -> str:
    """µm tick text: integers where possible, one decimal otherwise."""
    return f"{value:.0f}" if abs(value - round(value)) < 1e-6 else f"{value:.1f}"


@dataclass(frozen=True)
class Raster:
    """A field resampled to character cells: row 0 is the top (largest y), column 0 the left edge."""

    values: np.ndarray  # (rows, cols)
    x_um: np.ndarray  # (cols,) stage x at each column centre (descending when reversed)
    y_um: np.ndarray  # (rows,) stage y at each row centre, top to bottom (descending)


def _interp_axis(coords: np.ndarray, targets: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Indices and weights for linear interpolation along one (possibly descending) lattice axis."""
    c = np.asarray(coords, dtype=float)
    order = np.argsort(c)
    cs = c[order]
    t = np.clip(targets, cs[0], cs[-1])
    if len(cs) == 1:
        zeros = np.zeros(len(t), dtype=int)
        return order[zeros], order[zeros], np.zeros(len(t))
    hi = np.clip(np.searchsorted(cs, t, side="right"), 1, len(cs) - 1)
    lo = hi - 1
    w = (t - cs[lo]) / np.where(cs[hi] > cs[lo], cs[hi] - cs[lo], 1.0)
    return order[lo], order[hi], np.clip(w, 0.0, 1.0)


def resample(
    values: np.ndarray,
    x_um: np.ndarray,
    y_um: np.ndarray,
    cols: int,
    rows: int,
    bounds_um: tuple[float, float, float, float],
    reverse_x: bool = False,
) -> Raster:
    """Bilinear resampling of a (ny, nx) lattice field onto ``rows × cols`` character cells.

    Each cell takes the value at its centre in stage µm, so what one character shows does not depend on
    the lattice resolution; the sample's area is ``bounds_um`` = (x_min, x_max, y_min, y_max).
    """
    cols, rows = max(int(cols), 1), max(int(rows), 1)
    x_min, x_max, y_min, y_max = bounds_um
    xs = x_min + (np.arange(cols) + 0.5) * (x_max - x_min) / cols
    ys = y_max - (np.arange(rows) + 0.5) * (y_max - y_min) / rows
    if reverse_x:
        xs = xs[::-1]
    v = np.asarray(values, dtype=float)
    x0, x1, wx = _interp_axis(np.asarray(x_um), xs)
    y0, y1, wy = _interp_axis(np.asarray(y_um), ys)
    top = v[np.ix_(y0, x0)] * (1 - wx) + v[np.ix_(y0, x1)] * wx
    bottom = v[np.ix_(y1, x0)] * (1 - wx) + v[np.ix_(y1, x1)] * wx
    out = top * (1 - wy)[:, None] + bottom * wy[:, None]
    return Raster(values=out, x_um=xs, y_um=ys)


def cell_of(
    x_um: float,
    y_um: float,
    cols: int,
    rows: int,
    bounds_um: tuple[float, float, float, float],
    reverse_x: bool = False,
) -> tuple[int, int] | None:
    """The (column, row-from-top) character cell that holds a stage point, or None outside the area."""
    x_min, x_max, y_min, y_max = bounds_um
    if not (x_min <= x_um <= x_max and y_min <= y_um <= y_max):
        return None
    fx = (x_um - x_min) / (x_max - x_min) if x_max > x_min else 0.5
    fy = (y_max - y_um) / (y_max - y_min) if y_max > y_min else 0.5
    if reverse_x:
        fx = 1.0 - fx
    return min(int(fx * cols), cols - 1), min(int(fy * rows), rows - 1)


@dataclass(frozen=True)
class HeatmapImage:
    """A finished picture: ANSI text, the same as Rich Text ready to show, and the scale it was drawn with."""

    ansi: str
    width: int
    height: int
    field_key: str
    vmin: float
    vmax: float
    cmap: str
    snapshot_id: int | None
    text: Text = field(default_factory=Text, compare=False)


def plot_area(width: int, height: int, y_labels: Sequence[str]) -> tuple[int, int]:
    """Character cells inside plotext's frame: minus the y tick column, the frame and two label rows."""
    label_w = max((len(s) for s in y_labels), default=1)
    return max(width - label_w - 2, 1), max(height - 4, 1)


def _fit_aspect(
    width: int,
    height: int,
    bounds_um: tuple[float, float, float, float],
    cell_aspect: float,
    max_stretch: float,
) -> int:
    """Widest plot the sample's aspect allows (a character is ``cell_aspect`` × taller than wide),
    tolerating ``max_stretch`` × distortion so a wide panel is not mostly empty."""
    x_min, x_max, y_min, y_max = bounds_um
    span_x, span_y = max(x_max - x_min, 1e-9), max(y_max - y_min, 1e-9)
    rows = max(height - 4, 1)
    want_cols = round(rows * cell_aspect * max_stretch * span_x / span_y)
    return min(width, want_cols + 7)


SCALE_W = 10  # columns of the colour scale drawn right of the plot


def _scale_lines(vmin: float, vmax: float, rows: int, cmap: str, no_color: bool) -> list[str]:
    """ANSI lines of a vertical colour scale (top = vmax), one per plot row, labelled in GPa."""
    lines = []
    label_rows = {0: vmax, rows - 1: vmin}
    if rows >= 7:
        label_rows[(rows - 1) // 2] = vmin + (vmax - vmin) * (1 - ((rows - 1) // 2) / (rows - 1))
    for r in range(rows):
        level = 1.0 - r / (rows - 1) if rows > 1 else 1.0
        if no_color:
            cell = to_shades(np.array([min(level, 0.999)]))[0] * 2
        else:
            red, green, blue = (int(c) for c in to_rgb(np.array([level]), cmap)[0])
            cell = f"\x1b[48;2;{red};{green};{blue}m  \x1b[0m"
        label = f" {label_rows[r]:.3g}" if r in label_rows else ""
        lines.append(" " + cell + label)
    return lines


def _x_ticks(x_min: float, x_max: float, cols: int, reverse_x: bool) -> tuple[list[float], list[float]]:
    """Round x ticks whose labels never touch: plotext drops one of two overlapping labels, and which one
    depends on the process (string hashing), so a crowded axis would not draw the same twice."""
    for max_ticks in range(max(2, min(6, cols // 9 + 1)), 1, -1):
        ticks = nice_ticks(x_min, x_max, max_ticks=max_ticks)
        pos = []
        for tick in ticks:
            frac = (tick - x_min) / (x_max - x_min) if x_max > x_min else 0.5
            pos.append((1.0 - frac if reverse_x else frac) * cols - 0.5)
        width = max((len(tick_label(t)) for t in ticks), default=1) + 2
        gaps = np.diff(sorted(pos))
        if len(ticks) < 2 or gaps.min() >= width:
            return ticks, pos
    return ticks, pos


def render_heatmap(
    fields: MapFields | None,
    field_key: str,
    width: int,
    height: int,
    bounds_um: tuple[float, float, float, float],
    marks: MapMarks | None = None,
    reverse_x: bool = False,
    no_color: bool = False,
    keep_aspect: bool = True,
    cell_aspect: float = 2.0,
    max_stretch: float = 1.6,
    scale: bool = True,
) -> HeatmapImage:
    """Draw one GP field with plotext: RGB cells, µm ticks, and the marks (the sample's edge, exclusions,
    earlier indents, every indent of the run by its status, the newest block, the sites still to run).
    Cells outside the sample's outline show no field (grey, or blank without colour)."""
    from textual_plotext.plot import Plot  # plotext is heavy to import; only the worker thread needs it

    width, height = max(int(width), 12), max(int(height), 6)
    total_width = width
    if scale:
        width = max(width - SCALE_W, 12)
    x_min, x_max, y_min, y_max = bounds_um
    if keep_aspect:
        width = max(_fit_aspect(width, height, bounds_um, cell_aspect, max_stretch), 12)
    y_ticks = nice_ticks(y_min, y_max, max_ticks=max(2, min(5, (height - 4) // 3 + 1)))
    y_labels = [tick_label(t) for t in y_ticks]
    cols, rows = plot_area(width, height, y_labels)

    cmap = colour_map_for(field_key)
    # in colour, every character shows two vertically stacked pixels (▀: foreground on top, background
    # below), so a pixel is about as tall as it is wide and the map has twice the rows
    sub_rows = 1 if no_color else 2
    if fields is not None:
        z = field_array(fields, field_key)
        vmin, vmax = value_range(z, symmetric=cmap == "balance")
        raster = resample(z, fields.x_um, fields.y_um, cols, rows * sub_rows, bounds_um, reverse_x)
        pixels = normalise(raster.values, vmin, vmax)
    else:
        vmin, vmax = 0.0, 1.0
        pixels = np.full((rows * sub_rows, cols), np.nan)
    marks = marks if marks is not None else MapMarks()
    if len(marks.outline_um) >= 3:
        # the field is only the sample's: outside its outline a cell shows nothing
        px, py = _cell_centres(cols, rows * sub_rows, bounds_um, reverse_x)
        outside = PolygonExclusion(marks.outline_um).clearance_um(px, py) > 0
        pixels = np.where(outside, np.nan, pixels)
    levels = pixels[0::sub_rows]  # the top pixel of each character row

    plt: Any = Plot()  # plotext's own type hints are narrower than what it accepts (RGB, marker lists)
    plt._limit_size(False, False)  # plotext clips to the *process's* terminal size otherwise
    plt.plotsize(width, height)
    plt._set_size(width, height)  # as textual-plotext does: plotsize alone does not always stick
    plt.theme("clear")
    # plotext puts matrix row 0 at the bottom; our raster row 0 is the top row.
    if fields is None:  # no fit yet: the frame, the markers and a word on why the map is empty
        note = "no GP fit yet"
        if cols > len(note) + 2 and rows > 2:
            plt.text(note, x=cols // 2, y=rows // 2, color=(150, 150, 150), alignment="center")
    elif no_color:
        shades = to_shades(levels)
        for r in range(rows):
            plt.scatter(list(range(cols)), [rows - 1 - r] * cols, marker=list(shades[r]))
    else:
        rgb = to_rgb(levels, cmap)
        matrix = [[tuple(int(c) for c in rgb[r, k]) for k in range(cols)] for r in range(rows)]
        plt.matrix_plot(matrix, marker=HALF_BLOCK)

    # overlay, least important first so the more important mark wins a shared cell; each marker later
    # gets its cell's heat colour as background, so it does not punch a black hole
    layers: dict[tuple[str, str, tuple[int, int, int]], list[tuple[int, int]]] = {m: [] for m, _ in LEGEND}
    layers[MARK_OUTLINE] = outline_cells(marks.outline_um, cols, rows, bounds_um, reverse_x)
    if marks.exclusions:
        cx, cy = _cell_centres(cols, rows, bounds_um, reverse_x)
        inside = np.zeros(cx.shape, dtype=bool)
        for ex in marks.exclusions:
            inside |= ex.clearance_um(cx, cy) <= 0
        layers[MARK_EXCLUDED] = [(int(c), int(r)) for r, c in zip(*np.nonzero(inside), strict=True)]
    layers[MARK_EARLIER] = _cells_of_points(marks.earlier_um, cols, rows, bounds_um, reverse_x)
    for m in marks.indents:
        kind = mark_of(m, marks.newest_block_id)
        cell = cell_of(m.x_um, m.y_um, cols, rows, bounds_um, reverse_x)
        if cell is not None:
            layers[kind].append(cell)
    layers[MARK_PLANNED] = _cells_of_points(
        [p for group in marks.planned_um for p in group], cols, rows, bounds_um, reverse_x
    )
    owner: dict[tuple[int, int], tuple[str, str, tuple[int, int, int]]] = {}
    for mark, _ in LEGEND:
        for cell in layers[mark]:
            owner[cell] = mark
    by_mark: dict[tuple[str, str, tuple[int, int, int]], list[tuple[int, int]]] = {}
    for cell, mark in owner.items():
        by_mark.setdefault(mark, []).append(cell)
    newest_cells = {c for c, mk in owner.items() if mk != MARK_PLANNED} & {
        c
        for m in marks.indents
        if m.block_id == marks.newest_block_id
        for c in [cell_of(m.x_um, m.y_um, cols, rows, bounds_um, reverse_x)]
        if c is not None
    }
    for mark, _ in LEGEND:
        cells = by_mark.get(mark, [])
        plain = [c for c in cells if c not in newest_cells or mark == MARK_NEWEST]
        bold = [c for c in cells if c in newest_cells and mark != MARK_NEWEST]
        for group, style in ((plain, None), (bold, "bold")):
            if not group:
                continue
            kw: dict[str, Any] = {"marker": mark[1] if no_color else mark[0], "color": mark[2]}
            if style:
                kw["style"] = style
            plt.scatter([c[0] for c in group], [rows - 1 - c[1] for c in group], **kw)
    x_ticks, x_pos = _x_ticks(x_min, x_max, cols, reverse_x)
    y_pos = [((t - y_min) / (y_max - y_min) if y_max > y_min else 0.5) * rows - 0.5 for t in y_ticks]
    plt.xlim(-0.5, cols - 0.5)
    plt.ylim(-0.5, rows - 0.5)
    plt.xticks(x_pos, [tick_label(t) for t in x_ticks])
    plt.yticks(y_pos, y_labels)
    mirrored = "x µm (mirrored, as seen)"
    plt.xlabel(mirrored if reverse_x and cols >= len(mirrored) + 10 else "x µm")
    plt.ylabel("y µm")
    ansi = plt.build().rstrip("\n")
    if scale and fields is not None:
        lines = ansi.split("\n")
        bar = _scale_lines(vmin, vmax, rows, cmap, no_color)
        lines[0] += "  GPa"
        for r in range(rows):
            if r + 1 < len(lines):
                lines[r + 1] += bar[r]
        ansi = "\n".join(lines)
        width = min(width + SCALE_W, total_width)
    text = Text.from_ansi(ansi, no_wrap=True, end="")
    if not no_color and fields is not None:
        # the lower pixel of each cell as its background; a marker's cell gets the lower pixel too
        lower = to_rgb(pixels[1::2], cmap)
        text_lines = text.split("\n", allow_blank=True)
        x0 = max(len(s) for s in y_labels) + 1  # first plot column: after the y labels and the axis
        styles: dict[tuple[int, int, int], Style] = {}
        for row in range(rows):
            line = text_lines[row + 1]
            for col in range(cols):
                key = (int(lower[row, col, 0]), int(lower[row, col, 1]), int(lower[row, col, 2]))
                bg = styles.get(key)
                if bg is None:
                    bg = styles[key] = Style(bgcolor=f"rgb({key[0]},{key[1]},{key[2]})")
                line.stylize(bg, x0 + col, x0 + col + 1)
        text = Text("\n", no_wrap=True, end="").join(text_lines)
    return HeatmapImage(
        text=text,
        ansi=ansi,
        width=width,
        height=height,
        field_key=field_key,
        vmin=vmin,
        vmax=vmax,
        cmap=cmap,
        snapshot_id=fields.snapshot_id if fields is not None else None,
    )

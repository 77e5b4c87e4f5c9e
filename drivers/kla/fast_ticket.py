"""A fast (NanoBlitz-class) array's part of a ticket: what the operator sets up in InView's NanoBlitz method.

A fast array (``core.fast_array``) goes out like any block: the origin to move to and the sites file to import
(the same exchange, the same sign convention, the same 3-site check). What differs is what the operator types
into the NanoBlitz method, and that is what this records:

- the method's name (the profile's ``fast.method``) and its peak load (``fast.peak_load_mn``): a NanoBlitz
  indent is load-controlled, so the load is the one input that sets what it reads;
- the grid the sites lie on: rows × cols at the pitch, and its first site. A method that lays out its own
  grid needs exactly these; but a planned array may leave out sites of its grid (off the sample, near an
  exclusion or an earlier indent: the interlock's rules), and a full grid typed in would put indents there.
  So the ticket says how many are left out, and when any are, that only the sites file may be run.

The export is the NanoBlitz CSV (BOM, units row, ``X Position``/``Y Position``, blank cells on failed
indents), read by ``drivers.kla.readers`` and matched to the sites by position like any export.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from core.profile import FastMode

# sites off the grid's lattice by more than this share of the pitch make it no grid (a float's rounding is
# far below it; a planner's grid is exact)
_ON_LATTICE = 1e-6


@dataclass(frozen=True)
class FastArrayTicket:
    """What a fast array's ticket adds: the NanoBlitz method, its load, and the grid its sites lie on."""

    method: str
    peak_load_mn: float
    rows: int  # the grid that holds the sites: rows along stage y, cols along stage x (0, 0: no grid)
    cols: int
    pitch_um: float
    first_x_um: float  # the grid's first site: lowest stage x and y (µm)
    first_y_um: float
    left_out: int  # sites of that grid the plan leaves out (-1: the sites lie on no grid)

    @property
    def full_grid(self) -> bool:
        return self.left_out == 0

    def to_dict(self) -> dict[str, Any]:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> FastArrayTicket:
        return cls(
            method=str(d["method"]),
            peak_load_mn=float(d["peak_load_mn"]),
            rows=int(d["rows"]),
            cols=int(d["cols"]),
            pitch_um=float(d["pitch_um"]),
            first_x_um=float(d["first_x_um"]),
            first_y_um=float(d["first_y_um"]),
            left_out=int(d["left_out"]),
        )


def fast_array_ticket(
    sites_um: tuple[tuple[float, float], ...], pitch_um: float, fast: FastMode
) -> FastArrayTicket:
    """The fast part of the ticket for these sites (the array's, or what is left of it on a resume)."""
    xy = np.asarray(sites_um, dtype=float).reshape(-1, 2)
    lo = xy.min(axis=0)
    steps = (xy - lo) / pitch_um if pitch_um > 0 else np.zeros_like(xy)
    on_lattice = pitch_um > 0 and bool(
        np.all(np.abs(steps - np.round(steps)) <= _ON_LATTICE * max(1.0, steps.max()))
    )
    if not on_lattice:
        return FastArrayTicket(fast.method, fast.peak_load_mn, 0, 0, pitch_um, float(lo[0]), float(lo[1]), -1)
    ij = np.round(steps).astype(int)
    cols, rows = int(ij[:, 0].max()) + 1, int(ij[:, 1].max()) + 1
    distinct = len({(int(i), int(j)) for i, j in ij})
    return FastArrayTicket(
        fast.method,
        fast.peak_load_mn,
        rows,
        cols,
        pitch_um,
        float(lo[0]),
        float(lo[1]),
        rows * cols - distinct,
    )


def fast_steps(
    f: FastArrayTicket, n_sites: int, sites_file: str, sign: str, export_stem: str
) -> tuple[str, ...]:
    """Steps 3, 4 and 6 of a fast array's ticket (the array, the method, the export) for a person."""
    first = f"first site at X {f.first_x_um / 1000:.4f} mm, Y {f.first_y_um / 1000:.4f} mm"
    if f.full_grid:
        grid = (
            f"   The sites are a full grid of {f.rows} rows (y) × {f.cols} columns (x) at {f.pitch_um:g} µm,\n"
            f"   {first}: a NanoBlitz method that lays out its own grid may take these instead.\n"
        )
    elif f.left_out > 0:
        grid = (
            f"   The sites are {n_sites} of a grid of {f.rows} rows (y) × {f.cols} columns (x) at {f.pitch_um:g} µm\n"
            f"   ({first}): {f.left_out} sites are left out (off the sample, near an exclusion or an earlier\n"
            f"   indent). Run the sites file; do NOT run the full grid.\n"
        )
    else:
        grid = "   The sites lie on no regular grid: run the sites file.\n"
    array = (
        f"3. Array dialog: import outbox/{sites_file}\n"
        f"   {n_sites} sites, µm offsets from the crosshair, {sign}.\n"
        f"{grid}"
    )
    method = (
        f'4. Test method: "{f.method}" (NanoBlitz: load-controlled, no hold, no CSM), peak load\n'
        f"   {f.peak_load_mn:g} mN, for all {n_sites} sites.\n"
    )
    export = (
        f"6. Export the NanoBlitz results (one row per indent, with X Position and Y Position) as CSV:\n"
        f"   inbox/{export_stem}.csv\n"
    )
    return array, method, export


def fast_panel(f: FastArrayTicket, n_sites: int) -> tuple[str, ...]:
    """The fast array's lines of the console's ticket panel (≤ 40 characters where it can)."""
    if f.full_grid:
        grid = f"grid {f.rows}×{f.cols} at {f.pitch_um:g} µm, full"
    elif f.left_out > 0:
        grid = f"{f.left_out} of {f.rows}×{f.cols} left out: sites file"
    else:
        grid = "no regular grid: sites file"
    return (
        f"NANOBLITZ fast array: {n_sites} sites",
        f"method {f.method}, {f.peak_load_mn:g} mN",
        grid,
    )

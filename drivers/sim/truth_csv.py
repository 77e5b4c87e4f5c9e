"""Ground truth from a file: a CSV of x_um, y_um, hardness_gpa[, noise_sd_gpa, modulus_gpa,
modulus_noise_sd_gpa] on a lattice or scattered, interpolated (SPEC §4); a bad file is one clear error.

The file may also say what a fast indent reads (``drivers.sim.fast_channel.FAST_CSV_COLUMNS``); the map is
still scored against its CSM columns."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from core.errors import InputError
from drivers.sim.csv_points import check_point, number_rows, read_header
from drivers.sim.fast_channel import FAST_CSV_COLUMNS, FastTable, read_fast_table
from drivers.sim.truth import (
    DEFAULT_MODULUS_REL_SD,
    Bounds,
    FloatArray,
    broadcast_xy,
    modulus_from_hardness_gpa,
)

_CSV_REQUIRED = ("x_um", "y_um", "hardness_gpa")
_CSV_OPTIONAL = ("noise_sd_gpa", "modulus_gpa", "modulus_noise_sd_gpa")
CSV_DEFAULT_MODULUS_REL_SD = 0.015  # a truth file with a modulus but no modulus scatter: 1.5 % of its max E


class CsvTruth:
    """Ground truth measured or simulated elsewhere: a lattice or scattered points, interpolated linearly.

    Outside the data (scattered: outside the convex hull; lattice: beyond its edges) the nearest value is
    used, so an indent that lands slightly outside the file's area still gets a sensible truth.
    """

    def __init__(
        self,
        x_um: ArrayLike,
        y_um: ArrayLike,
        hardness_gpa: ArrayLike,
        noise_sd_gpa: ArrayLike | None = None,
        name: str = "csv",
        modulus_gpa: ArrayLike | None = None,
        modulus_noise_sd_gpa: ArrayLike | None = None,
        fast_table: FastTable | None = None,
    ) -> None:
        """``fast_table``: what a fast indent reads where the file says it (None: the fast channel's physics)."""
        x = np.asarray(x_um, dtype=float).ravel()
        y = np.asarray(y_um, dtype=float).ravel()
        h = np.asarray(hardness_gpa, dtype=float).ravel()
        if not (x.shape == y.shape == h.shape):
            raise InputError(name, "x_um, y_um and hardness_gpa have different lengths")
        self.name = name
        self.fast_table = fast_table
        self.bounds_um: Bounds = (float(x.min()), float(x.max()), float(y.min()), float(y.max()))
        self.default_noise = noise_sd_gpa is None
        sd = (
            np.full(h.shape, 0.015 * float(h.max()))
            if noise_sd_gpa is None
            else np.asarray(noise_sd_gpa, float)
        )
        # no modulus in the file: E(H) as for any field without one, 1 % scatter
        self.has_modulus = modulus_gpa is not None
        e = (
            modulus_from_hardness_gpa(h)
            if modulus_gpa is None
            else np.asarray(modulus_gpa, dtype=float).ravel()
        )
        if modulus_noise_sd_gpa is not None:
            e_sd = np.asarray(modulus_noise_sd_gpa, dtype=float).ravel()
        elif modulus_gpa is None:
            e_sd = DEFAULT_MODULUS_REL_SD * e
        else:
            e_sd = np.full(e.shape, CSV_DEFAULT_MODULUS_REL_SD * float(e.max()))
        columns = {"h": h, "sd": sd, "e": e, "e_sd": e_sd}
        xs, ys = np.unique(x), np.unique(y)
        self.is_lattice = xs.size >= 2 and ys.size >= 2 and xs.size * ys.size == x.size
        self._lat: dict[str, Callable[[FloatArray], FloatArray]] = {}
        self._lin: dict[str, Callable[[FloatArray, FloatArray], FloatArray]] = {}
        self._near: dict[str, Callable[[FloatArray, FloatArray], FloatArray]] = {}
        if self.is_lattice:
            from scipy.interpolate import RegularGridInterpolator

            ix, iy = np.searchsorted(xs, x), np.searchsorted(ys, y)
            for key, values in columns.items():
                grid = np.full((xs.size, ys.size), np.nan)
                grid[ix, iy] = values
                self._lat[key] = RegularGridInterpolator((xs, ys), grid)
        else:
            from scipy.interpolate import LinearNDInterpolator, NearestNDInterpolator
            from scipy.spatial import QhullError

            pts = np.column_stack([x, y])
            try:
                for key, values in columns.items():
                    self._lin[key] = LinearNDInterpolator(pts, values)
            except QhullError:
                raise InputError(
                    name, "the points are (nearly) collinear: cannot interpolate a map"
                ) from None
            for key, values in columns.items():
                self._near[key] = NearestNDInterpolator(pts, values)

    def _interp(self, x_um: ArrayLike, y_um: ArrayLike, which: str) -> FloatArray:
        x, y = broadcast_xy(x_um, y_um)
        if self.is_lattice:
            x_min, x_max, y_min, y_max = self.bounds_um
            pts = np.stack([np.clip(x, x_min, x_max), np.clip(y, y_min, y_max)], axis=-1)
            return np.asarray(self._lat[which](pts), dtype=float).reshape(x.shape)
        out = np.asarray(self._lin[which](x, y), dtype=float)
        missing = np.isnan(out)
        if missing.any():
            out[missing] = self._near[which](x[missing], y[missing])
        return out

    def hardness_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        return self._interp(x_um, y_um, "h")

    def noise_sd_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        return self._interp(x_um, y_um, "sd")

    def modulus_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        return self._interp(x_um, y_um, "e")

    def modulus_noise_sd_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        return self._interp(x_um, y_um, "e_sd")

    @classmethod
    def from_file(cls, path: str | Path) -> CsvTruth:
        """Read ``x_um, y_um, hardness_gpa[, noise_sd_gpa, modulus_gpa, modulus_noise_sd_gpa]``; any problem is
        one InputError naming the file."""
        source = str(path)
        p = Path(path)
        if p.is_dir():
            raise InputError(source, "is a folder, not a truth file")
        if not p.exists():
            raise InputError(source, "no such truth file")
        if not p.is_file():
            raise InputError(source, "not a regular file (a truth CSV was expected)")
        header, reader = read_header(
            path, "empty file: expected a header x_um, y_um, hardness_gpa[, noise_sd_gpa]"
        )
        allowed = _CSV_REQUIRED + _CSV_OPTIONAL + FAST_CSV_COLUMNS
        unknown = [h for h in header if h not in allowed]
        if unknown:
            raise InputError(
                source,
                f"unknown column(s) {', '.join(repr(u) for u in unknown)} (allowed: {', '.join(allowed)})",
            )
        dupes = sorted({h for h in header if header.count(h) > 1})
        if dupes:
            raise InputError(source, f"column(s) {', '.join(dupes)} appear more than once")
        missing = [c for c in _CSV_REQUIRED if c not in header]
        if missing:
            raise InputError(
                source,
                f"missing column(s) {', '.join(missing)} (needs x_um, y_um, hardness_gpa[, noise_sd_gpa])",
            )
        rows: list[list[float]] = []
        lines: list[int] = []
        for line, row in number_rows(source, header, reader, tuple(header)):
            if row["hardness_gpa"] <= 0:
                raise InputError(
                    source, f"line {line}: hardness_gpa must be > 0, got {row['hardness_gpa']:g}"
                )
            for col in ("noise_sd_gpa", "modulus_noise_sd_gpa"):
                if row.get(col, 0.0) < 0:
                    raise InputError(source, f"line {line}: {col} must be ≥ 0, got {row[col]:g}")
            # values no real sample has: a unit slip (MPa under hardness_gpa, nm under x_um) is named
            check_point(source, line, row)
            rows.append([row[c] for c in header])
            lines.append(line)
        if len(rows) < 4:
            raise InputError(source, f"needs at least 4 points, found {len(rows)}")
        data = np.array(rows)
        columns = {name: data[:, i] for i, name in enumerate(header)}
        seen: dict[tuple[float, float], int] = {}
        for (xv, yv), line in zip(zip(columns["x_um"], columns["y_um"], strict=True), lines, strict=True):
            first = seen.setdefault((float(xv), float(yv)), line)
            if first != line:
                raise InputError(
                    source, f"line {line}: duplicate point ({xv:g}, {yv:g}), already on line {first}"
                )
        if "modulus_noise_sd_gpa" in columns and "modulus_gpa" not in columns:
            raise InputError(source, "has modulus_noise_sd_gpa but no modulus_gpa column")
        centred = np.column_stack([columns["x_um"], columns["y_um"]])
        centred = centred - centred.mean(axis=0)
        sv = np.linalg.svd(centred, compute_uv=False)
        if sv[1] <= 1e-9 * sv[0]:
            raise InputError(source, "all points lie on one line: a map needs points spread in x and y")
        return cls(
            columns["x_um"],
            columns["y_um"],
            columns["hardness_gpa"],
            columns.get("noise_sd_gpa"),
            name=f"csv:{p.name}",
            modulus_gpa=columns.get("modulus_gpa"),
            modulus_noise_sd_gpa=columns.get("modulus_noise_sd_gpa"),
            fast_table=read_fast_table(path),  # its fast columns, checked with their own rules
        )

"""What is on the stage: a Sample is the calibrated area plus everything a run must keep away from.

The planner reads a Sample to build its lattice and to mask candidates (edge band, exclusion regions,
earlier indents); the safety interlock reads the same Sample with its own geometry code. A Sample is
plain data and round-trips through ``to_dict`` / ``sample_from_dict`` so the journal can hold it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from core.cost import grid_baseline_blocks, price_sequence
from core.errors import InputError
from core.geometry import Calibration, exclusion_mask
from core.profile import InstrumentProfile

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

UNLIMITED_STAGE_UM: tuple[float, float, float, float] = (-1e9, -1e9, 1e9, 1e9)


@dataclass(frozen=True)
class CircleExclusion:
    """A round region no indent may enter (a clamp, a particle, an earlier test spot)."""

    x_um: float
    y_um: float
    radius_um: float

    def clearance_um(self, x_um: FloatArray, y_um: FloatArray) -> FloatArray:
        """Distance from each point to the region (≤ 0 inside)."""
        return np.asarray(np.hypot(x_um - self.x_um, y_um - self.y_um) - self.radius_um, dtype=float)

    def to_dict(self) -> dict[str, Any]:
        return {"circle_um": [self.x_um, self.y_um, self.radius_um]}


@dataclass(frozen=True)
class PolygonExclusion:
    """A polygonal region no indent may enter (a scratch, a clamp edge, an earlier test area)."""

    vertices_um: tuple[tuple[float, float], ...]

    def clearance_um(self, x_um: FloatArray, y_um: FloatArray) -> FloatArray:
        """Distance from each point to the polygon's boundary, negated inside (non-zero winding rule)."""
        v = np.asarray(self.vertices_um, dtype=float)
        p = np.column_stack([np.ravel(x_um), np.ravel(y_um)])
        a = v
        b = np.roll(v, -1, axis=0)
        ab = b - a
        ap = p[:, None, :] - a[None, :, :]
        length2 = np.maximum(np.einsum("ki,ki->k", ab, ab), 1e-300)  # a repeated vertex is a zero-length edge
        t = np.clip(np.einsum("pki,ki->pk", ap, ab) / length2, 0.0, 1.0)
        nearest = a[None] + t[..., None] * ab[None]
        dist = np.hypot(*(p[:, None, :] - nearest).transpose(2, 0, 1)).min(axis=1)
        ya, yb = a[None, :, 1], b[None, :, 1]
        py = p[:, 1:2]
        up = (ya <= py) & (yb > py)
        down = (ya > py) & (yb <= py)
        with np.errstate(divide="ignore", invalid="ignore"):
            x_at = a[None, :, 0] + (py - ya) * ab[None, :, 0] / ab[None, :, 1]
        right = p[:, 0:1] < x_at
        # non-zero winding: a region traced twice, or a self-crossing outline, is all inside (the cautious reading)
        inside = (np.sum(up & right, axis=1) - np.sum(down & right, axis=1)) != 0
        return np.asarray(np.where(inside, -dist, dist).reshape(np.shape(x_um)), dtype=float)

    def to_dict(self) -> dict[str, Any]:
        return {"polygon_um": [list(v) for v in self.vertices_um]}


Exclusion = CircleExclusion | PolygonExclusion


@dataclass(frozen=True)
class Sample:
    """A mounted sample: calibrated corners, instrument profile, safety distances and what to avoid."""

    name: str
    profile: str
    calibration: Calibration
    lattice_n: int = 50
    dz_safe_um: float = 5.0
    r_excl_um: float = 20.0
    edge_band_um: float = 25.0
    stage_rect_um: tuple[float, float, float, float] = UNLIMITED_STAGE_UM
    exclusions: tuple[Exclusion, ...] = ()
    earlier_indents_um: tuple[tuple[float, float], ...] = ()
    source: str = ""

    @property
    def earlier_xy_um(self) -> FloatArray:
        return np.asarray(self.earlier_indents_um, dtype=float).reshape(-1, 2)

    def exclusion_clearance_um(self, x_um: FloatArray, y_um: FloatArray) -> FloatArray:
        """Distance to the nearest exclusion region (+inf without any; ≤ 0 inside one)."""
        x = np.asarray(x_um, dtype=float)
        y = np.asarray(y_um, dtype=float)
        out = np.full(np.broadcast(x, y).shape, np.inf)
        for region in self.exclusions:
            out = np.minimum(out, region.clearance_um(x, y))
        return out

    def allowed(self, xy_um: FloatArray, grid_halfwidth_um: float = 0.0) -> BoolArray:
        """Where this sample may be indented: centres whose whole square sub-grid (half-width h; 0 for a
        single indent) stays inside the area off the edge band, clear of the exclusions, within the stage
        limits and r_excl from the indents the sample came with.

        The one home of this rule: the planners (through the campaign's lattice mask), the grid baseline,
        ``aeni sample check`` and the maps all ask it. A run's own indents are the run's to avoid
        (core.geometry.exclusion_mask).
        """
        xy = np.asarray(xy_um, dtype=float).reshape(-1, 2)
        h = max(float(grid_halfwidth_um), 0.0)
        # an axis-aligned square keeps distance d from a side with normal n when its centre keeps d + h(|nx| + |ny|)
        normals, offsets = self.calibration._edge_frames()
        dist = xy @ normals.T - offsets
        need = self.edge_band_um + h * (np.abs(normals[:, 0]) + np.abs(normals[:, 1]))
        tol = 1e-9 * self.calibration.diagonal_um
        inside = np.all(dist >= need - tol, axis=1)
        reach = math.sqrt(2.0) * h  # the square's corners are its furthest points from any exclusion
        clear = self.exclusion_clearance_um(xy[:, 0], xy[:, 1]) > reach
        x0, y0, x1, y1 = self.stage_rect_um
        on_stage = (xy[:, 0] - h >= x0) & (xy[:, 0] + h <= x1) & (xy[:, 1] - h >= y0) & (xy[:, 1] + h <= y1)
        ok = inside & clear & on_stage
        if len(self.earlier_indents_um):
            ok &= exclusion_mask(xy, self.earlier_xy_um, self.r_excl_um, h)
        return np.asarray(ok, dtype=bool)

    def to_dict(self) -> dict[str, Any]:
        """The sample file's own layout, with earlier indents inlined (the journal keeps what the run avoided)."""
        return {
            "name": self.name,
            "profile": self.profile,
            "lattice_n": self.lattice_n,
            "corners": self.calibration.to_dict(),
            "safety": {
                "dz_safe_um": self.dz_safe_um,
                "r_excl_um": self.r_excl_um,
                "edge_band_um": self.edge_band_um,
                "stage_rect_um": list(self.stage_rect_um),
            },
            "exclusions": [e.to_dict() for e in self.exclusions],
            "earlier": {"indents_um": [list(p) for p in self.earlier_indents_um]},
            "source": self.source,
        }


def check_positive(source: str, name: str, value: Any, *, allow_zero: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise InputError(source, f"field {name} must be a finite number, got {value!r}")
    if value < 0 or (value == 0 and not allow_zero):
        raise InputError(source, f"field {name} must be {'≥' if allow_zero else '>'} 0, got {value!r}")
    return float(value)


def grid_baseline_s(sample: Sample, profile: InstrumentProfile, pitch_um: float = 5.0) -> float:
    """Instrument seconds of the paper's grid baseline (9×9 blocks of 5×5) over the sample's extent."""

    x0, x1, y0, y1 = sample.calibration.bounds_um
    blocks = grid_baseline_blocks(
        x1 - x0, y1 - y0, 9, 5, pitch_um, profile.default_hold_s, origin_um=(x0, y0)
    )
    return price_sequence(profile, blocks).total_s

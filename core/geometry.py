"""Stage geometry: the calibrated sample area, its (u, v) chart, the surface plane and the placement rules.

Models and acquisition work in the unit square (u, v); people and the instrument work in stage µm. This
module is the only place that converts between the two, and the only place that decides whether a
position is allowed (inside the calibrated area, inside the safe band, clear of earlier indents).
"""

from __future__ import annotations

import functools
import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from core.errors import InputError

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

CORNER_NAMES: tuple[str, str, str, str] = ("TL", "TR", "BR", "BL")
# Where each corner lands in (u, v): BL is the origin, v points from BL to TL.
CORNER_UV: FloatArray = np.array([[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]])
CORNER_UV.flags.writeable = False

# Corners further than this fraction of the diagonal from a parallelogram earn a warning.
PARALLELOGRAM_WARN_FRACTION = 0.02
# A triangle of corners with area below this fraction of (largest corner distance)² counts as collinear.
_COLLINEAR_REL_AREA = 1e-6
# Corners closer than this fraction of the largest corner distance count as the same point.
_REPEAT_REL_DIST = 1e-9
# Slack for "on the boundary" tests, relative to the size of the area (rounding only, never physics).
_BOUNDARY_REL_TOL = 1e-9
_Z_TOL_UM = 1e-9
# Slack on distances between sites (rounding only, never physics): a lattice whose pitch is exactly r_excl
# (50×50 over 1,000 µm at 20 µm) must stay usable when float noise makes a pitch 19.999999999999996 µm.
DISTANCE_TOL_UM = 1e-6


def far_enough(distance_um: ArrayLike, min_um: float) -> BoolArray:
    """True where a distance is at least ``min_um`` (exactly ``min_um`` is allowed, up to rounding)."""
    return np.asarray(np.asarray(distance_um) >= min_um - DISTANCE_TOL_UM, dtype=bool)


@dataclass(frozen=True)
class Corner:
    """One recorded calibration corner in stage coordinates (z: the surface height found there)."""

    x_um: float
    y_um: float
    z_um: float = 0.0


CornerLike = Corner | Sequence[float]


def _as_corner(value: Any, source: str, name: str) -> Corner:
    if isinstance(value, Corner):
        return value
    if isinstance(value, Mapping):
        try:
            return Corner(float(value["x_um"]), float(value["y_um"]), float(value.get("z_um", 0.0)))
        except KeyError as exc:
            raise InputError(source, f"corner {name} is missing {exc.args[0]}") from None
        except (TypeError, ValueError):
            raise InputError(source, f"corner {name} has a non-numeric coordinate: {dict(value)!r}") from None
    try:
        vals = [float(v) for v in value]
    except (TypeError, ValueError):
        raise InputError(
            source, f"corner {name} must be (x_um, y_um[, z_um]) numbers, got {value!r}"
        ) from None
    if len(vals) not in (2, 3):
        raise InputError(source, f"corner {name} must have 2 or 3 coordinates, got {len(vals)}")
    return Corner(*vals)


def _tri_area(p: FloatArray, q: FloatArray, r: FloatArray) -> float:
    return 0.5 * float((q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0]))


@dataclass(frozen=True)
class SurfacePlane:
    """The sample surface as z = a·x + b·y + c (µm), used to keep local grids within reach of the tip."""

    a: float
    b: float
    c: float

    @classmethod
    def through(cls, p1: Corner, p2: Corner, p3: Corner, source: str = "surface plane") -> SurfacePlane:
        pts = np.array([[p.x_um, p.y_um, p.z_um] for p in (p1, p2, p3)], dtype=float)
        if not np.all(np.isfinite(pts)):
            raise InputError(source, "a point of the plane has a non-finite coordinate")
        xy = pts[:, :2]
        scale = max(float(np.linalg.norm(xy[i] - xy[j])) for i, j in itertools.combinations(range(3), 2))
        if scale == 0.0 or abs(_tri_area(xy[0], xy[1], xy[2])) < _COLLINEAR_REL_AREA * scale**2:
            raise InputError(source, "the three points are collinear in (x, y): no unique plane through them")
        design = np.column_stack([xy, np.ones(3)])
        a, b, c = np.linalg.solve(design, pts[:, 2])
        return cls(float(a), float(b), float(c))

    def z_um(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        x = np.asarray(x_um, dtype=float)
        y = np.asarray(y_um, dtype=float)
        return np.asarray(self.a * x + self.b * y + self.c, dtype=float)

    @property
    def slope(self) -> float:
        """|∇z| (µm of height per µm of travel): the steepest rise of the surface."""
        return math.hypot(self.a, self.b)


@dataclass(frozen=True)
class Calibration:
    """The four recorded corners and the least-squares affine chart (u, v) they define.

    The fit is stage = B·(u, v, 1) over the four corners, so its residuals are in µm and say how far the
    corners are from a parallelogram (each corner misses by |TL + BR − TR − BL| / 4). ``to_uv`` is the exact
    inverse of that fit. Whether a point is inside the sample uses the actual corners, not the fit.
    """

    tl: Corner
    tr: Corner
    br: Corner
    bl: Corner
    _origin: FloatArray = field(init=False, repr=False, compare=False)
    _lin: FloatArray = field(init=False, repr=False, compare=False)
    _inv: FloatArray = field(init=False, repr=False, compare=False)
    _residual_um: float = field(init=False, repr=False, compare=False)
    _plane: SurfacePlane = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        xy = _validate_corners((self.tl, self.tr, self.br, self.bl), "calibration")
        tl, tr, br, bl = xy
        # Closed-form least squares over the unit-square corners (every corner misses by defect / 4),
        # anchored at BL so that large stage offsets do not cost precision.
        defect = tl + br - tr - bl
        origin = bl + defect / 4.0
        lin = np.column_stack([((tr - tl) + (br - bl)) / 2.0, ((tl - bl) + (tr - br)) / 2.0])
        inv = np.linalg.inv(lin)
        for arr in (origin, lin, inv):
            arr.flags.writeable = False
        object.__setattr__(self, "_origin", origin)
        object.__setattr__(self, "_lin", lin)
        object.__setattr__(self, "_inv", inv)
        object.__setattr__(self, "_residual_um", float(np.linalg.norm(defect)) / 4.0)
        object.__setattr__(
            self, "_plane", SurfacePlane.through(self.tl, self.tr, self.br, source="calibration")
        )

    # ------------------------------------------------------------------ construction

    @classmethod
    def from_corners(
        cls, tl: CornerLike, tr: CornerLike, br: CornerLike, bl: CornerLike, source: str = "calibration"
    ) -> Calibration:
        corners = tuple(_as_corner(c, source, n) for c, n in zip((tl, tr, br, bl), CORNER_NAMES, strict=True))
        _validate_corners(corners, source)
        return cls(*corners)

    @classmethod
    def rectangle(
        cls,
        x0_um: float,
        y0_um: float,
        width_um: float,
        height_um: float,
        z_plane: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ) -> Calibration:
        """An axis-aligned area with BL at (x0, y0), for emulators; corner heights from z = a·x + b·y + c."""
        if not (math.isfinite(width_um) and width_um > 0 and math.isfinite(height_um) and height_um > 0):
            raise InputError(
                "calibration", f"area must have positive width and height, got {width_um} × {height_um} µm"
            )
        a, b, c = (float(v) for v in z_plane)

        def corner(x: float, y: float) -> Corner:
            return Corner(x, y, a * x + b * y + c)

        x1, y1 = x0_um + width_um, y0_um + height_um
        return cls.from_corners(corner(x0_um, y1), corner(x1, y1), corner(x1, y0_um), corner(x0_um, y0_um))

    def to_dict(self) -> dict[str, dict[str, float]]:
        return {
            name.lower(): {"x_um": c.x_um, "y_um": c.y_um, "z_um": c.z_um}
            for name, c in zip(CORNER_NAMES, self.corners, strict=True)
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], source: str = "calibration") -> Calibration:
        if not isinstance(d, Mapping):
            raise InputError(source, f"expected a table of corners tl, tr, br, bl, got {type(d).__name__}")
        missing = [n.lower() for n in CORNER_NAMES if n.lower() not in d]
        if missing:
            raise InputError(source, f"missing corner(s): {', '.join(missing)}")
        tl, tr, br, bl = (_as_corner(d[n.lower()], source, n) for n in CORNER_NAMES)
        return cls.from_corners(tl, tr, br, bl, source=source)

    # ------------------------------------------------------------------ the chart

    @property
    def corners(self) -> tuple[Corner, Corner, Corner, Corner]:
        return (self.tl, self.tr, self.br, self.bl)

    @property
    def corners_xy_um(self) -> FloatArray:
        """(4, 2) in TL, TR, BR, BL order."""
        return np.array([[c.x_um, c.y_um] for c in self.corners], dtype=float)

    @property
    def stage_from_uv(self) -> FloatArray:
        """The fitted 2×3 affine matrix: (x, y) = M @ (u, v, 1)."""
        return np.column_stack([self._lin, self._origin])

    def to_uv(self, x_um: ArrayLike, y_um: ArrayLike) -> tuple[FloatArray, FloatArray]:
        x = np.asarray(x_um, dtype=float)
        y = np.asarray(y_um, dtype=float)
        dx = x - self._origin[0]
        dy = y - self._origin[1]
        m = self._inv
        return np.asarray(m[0, 0] * dx + m[0, 1] * dy), np.asarray(m[1, 0] * dx + m[1, 1] * dy)

    def to_stage(self, u: ArrayLike, v: ArrayLike) -> tuple[FloatArray, FloatArray]:
        uu = np.asarray(u, dtype=float)
        vv = np.asarray(v, dtype=float)
        m = self._lin
        x = np.asarray(m[0, 0] * uu + m[0, 1] * vv + self._origin[0])
        y = np.asarray(m[1, 0] * uu + m[1, 1] * vv + self._origin[1])
        return x, y

    @property
    def parallelogram_residual_um(self) -> float:
        return self._residual_um

    @property
    def diagonal_um(self) -> float:
        """Mean length of the two diagonals: the size against which misfits are judged."""
        xy = self.corners_xy_um
        return 0.5 * float(np.linalg.norm(xy[0] - xy[2]) + np.linalg.norm(xy[1] - xy[3]))

    @property
    def plane_misfit_um(self) -> float:
        """How far BL's recorded height is from the plane through TL, TR, BR (a warped or mis-found surface)."""
        return abs(self.bl.z_um - float(self._plane.z_um(self.bl.x_um, self.bl.y_um)))

    def warnings(self) -> tuple[str, ...]:
        out: list[str] = []
        limit = PARALLELOGRAM_WARN_FRACTION * self.diagonal_um
        if self._residual_um > limit:
            out.append(
                f"calibration corners are far from a parallelogram: the affine fit misses them by "
                f"{self._residual_um:.1f} µm (> {100 * PARALLELOGRAM_WARN_FRACTION:.0f} % of the "
                f"{self.diagonal_um:.0f} µm diagonal); check the corners"
            )
        return tuple(out)

    # ------------------------------------------------------------------ the area

    @property
    def bounds_um(self) -> tuple[float, float, float, float]:
        xy = self.corners_xy_um
        return float(xy[:, 0].min()), float(xy[:, 0].max()), float(xy[:, 1].min()), float(xy[:, 1].max())

    @property
    def area_um2(self) -> float:
        return abs(_signed_area(self.corners_xy_um))

    @property
    def plane(self) -> SurfacePlane:
        return self._plane

    def _edge_frames(self) -> tuple[FloatArray, FloatArray]:
        """Inward unit normals (4, 2) and offsets (4,) so that signed distance = p·n − offset."""
        xy = self.corners_xy_um
        orient = 1.0 if _signed_area(xy) > 0 else -1.0
        p = xy
        q = np.roll(xy, -1, axis=0)
        e = q - p
        # Left normal of each edge is inward for a counter-clockwise polygon.
        n = orient * np.column_stack([-e[:, 1], e[:, 0]]) / np.linalg.norm(e, axis=1)[:, None]
        return n, np.sum(n * p, axis=1)

    def edge_distance_um(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        """Signed distance to the nearest side of the quadrilateral: positive inside, negative outside."""
        x = np.asarray(x_um, dtype=float)
        y = np.asarray(y_um, dtype=float)
        n, off = self._edge_frames()
        d = x[..., None] * n[:, 0] + y[..., None] * n[:, 1] - off
        return np.asarray(d.min(axis=-1), dtype=float)

    def contains_stage(self, x_um: ArrayLike, y_um: ArrayLike, margin_um: float = 0.0) -> BoolArray:
        """Inside the quadrilateral of the recorded corners, at least margin_um from every side."""
        tol = _BOUNDARY_REL_TOL * self.diagonal_um
        return np.asarray(self.edge_distance_um(x_um, y_um) >= margin_um - tol, dtype=bool)

    def safe_band(self, center_x_um: float, center_y_um: float, dz_safe_um: float = 5.0) -> SafeBand:
        return SafeBand(self._plane, float(center_x_um), float(center_y_um), float(dz_safe_um))


def _signed_area(xy: FloatArray) -> float:
    x, y = xy[:, 0], xy[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def _validate_corners(corners: Sequence[Corner], source: str) -> FloatArray:
    """Refuse corners that cannot define an area; return their (4, 2) stage positions."""
    for name, c in zip(CORNER_NAMES, corners, strict=True):
        if not isinstance(c, Corner):
            raise InputError(source, f"corner {name} must be a Corner, got {type(c).__name__}")
        for axis in ("x_um", "y_um", "z_um"):
            value = getattr(c, axis)
            if not isinstance(value, (int, float, np.floating, np.integer)) or not math.isfinite(value):
                raise InputError(
                    source, f"corner {name} has a non-finite or non-numeric {axis} ({value!r}): NaN/inf"
                )
    xy = np.array([[c.x_um, c.y_um] for c in corners], dtype=float)
    scale = max(float(np.linalg.norm(xy[i] - xy[j])) for i, j in itertools.combinations(range(4), 2))
    for i, j in itertools.combinations(range(4), 2):
        if float(np.linalg.norm(xy[i] - xy[j])) <= _REPEAT_REL_DIST * scale:
            raise InputError(
                source,
                f"repeated corner: {CORNER_NAMES[i]} and {CORNER_NAMES[j]} are the same point "
                f"({xy[i, 0]:g}, {xy[i, 1]:g}) µm",
            )
    for idx in itertools.combinations(range(4), 3):
        if abs(_tri_area(*(xy[k] for k in idx))) < _COLLINEAR_REL_AREA * scale**2:
            names = ", ".join(CORNER_NAMES[k] for k in idx)
            raise InputError(source, f"collinear corners: {names} lie on one line (the area is degenerate)")
    cross = []
    for k in range(4):
        a, b, c = xy[k - 1], xy[k], xy[(k + 1) % 4]
        cross.append(_tri_area(a, b, c))
    if not (all(v > 0 for v in cross) or all(v < 0 for v in cross)):
        raise InputError(
            source,
            "corners are not a convex quadrilateral in TL, TR, BR, BL order (the outline folds or crosses "
            "itself); check the order and the values",
        )
    return xy


@dataclass(frozen=True)
class SafeBand:
    """Points whose surface height is within dz_safe_um of the global centre's: reachable without re-engaging."""

    plane: SurfacePlane
    center_x_um: float
    center_y_um: float
    dz_safe_um: float = 5.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.dz_safe_um) and self.dz_safe_um >= 0):
            raise InputError("safe band", f"dz_safe_um must be a finite number ≥ 0, got {self.dz_safe_um}")
        if not (math.isfinite(self.center_x_um) and math.isfinite(self.center_y_um)):
            raise InputError("safe band", "the centre must have finite coordinates")

    @property
    def z0_um(self) -> float:
        return float(self.plane.z_um(self.center_x_um, self.center_y_um))

    def contains(self, x_um: ArrayLike, y_um: ArrayLike, grid_halfwidth_um: float = 0.0) -> BoolArray:
        """In the band; with grid_halfwidth_um > 0, the whole axis-aligned square around each point is.

        z is linear, so a square's extreme heights are at its corners: |Δz(centre)| + (|a| + |b|)·h.
        """
        dz = np.abs(self.plane.z_um(x_um, y_um) - self.z0_um)
        spread = (abs(self.plane.a) + abs(self.plane.b)) * max(grid_halfwidth_um, 0.0)
        return np.asarray(dz + spread <= self.dz_safe_um + _Z_TOL_UM, dtype=bool)


@dataclass(frozen=True)
class CandidateLattice:
    """The n×n candidate centres, inset by margin_uv so a local grid around any of them stays on the sample.

    One margin serves both axes (the lattice stays square in (u, v)); it is the smallest that keeps an
    axis-aligned square of half-width grid_halfwidth_um around every centre inside the recorded corners.
    """

    calibration: Calibration
    n: int
    margin_uv: float
    grid_halfwidth_um: float = 0.0
    uv: FloatArray = field(default_factory=lambda: np.empty((0, 2)), repr=False, compare=False)
    xy_um: FloatArray = field(default_factory=lambda: np.empty((0, 2)), repr=False, compare=False)

    @classmethod
    def build(cls, calibration: Calibration, n: int, grid_halfwidth_um: float = 10.0) -> CandidateLattice:
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 2:
            raise InputError("lattice", f"n must be an integer ≥ 2, got {n!r}")
        if not (math.isfinite(grid_halfwidth_um) and grid_halfwidth_um >= 0):
            raise InputError("lattice", f"grid_halfwidth_um must be finite and ≥ 0, got {grid_halfwidth_um}")
        margin = _lattice_margin(calibration, grid_halfwidth_um)
        axis = np.linspace(margin, 1.0 - margin, int(n))
        uu, vv = np.meshgrid(axis, axis)  # rows: v, columns: u -> ravel is v slow, u fast
        uv = np.column_stack([uu.ravel(), vv.ravel()])
        x, y = calibration.to_stage(uv[:, 0], uv[:, 1])
        xy = np.column_stack([x, y])
        uv.flags.writeable = False
        xy.flags.writeable = False
        return cls(calibration, int(n), float(margin), float(grid_halfwidth_um), uv, xy)

    @property
    def pitch_uv(self) -> tuple[float, float]:
        step = (1.0 - 2.0 * self.margin_uv) / (self.n - 1)
        return (step, step)

    @property
    def pitch_um(self) -> tuple[float, float]:
        """Stage distance between neighbours along u and along v."""
        m = self.calibration.stage_from_uv
        pu, pv = self.pitch_uv
        return (float(np.linalg.norm(m[:, 0])) * pu, float(np.linalg.norm(m[:, 1])) * pv)

    def nearest_index(self, x_um: float, y_um: float) -> int:
        d2 = (self.xy_um[:, 0] - float(x_um)) ** 2 + (self.xy_um[:, 1] - float(y_um)) ** 2
        return int(np.argmin(d2))

    def spaced_sites(self, min_um: float) -> BoolArray:
        """The densest regular subset of the lattice whose sites are all at least ``min_um`` apart on the
        stage (a sub-lattice of it, tilted where that packs tighter).

        Sites picked one by one from a lattice finer than the exclusion jam: each pick blocks neighbours
        that a regular packing would have used, and the 100×100 lattice on 1,000 µm (9.9 µm apart, 20 µm
        exclusion) fills with ~1,500 singles where its 5-to-1 tilted sub-lattice (22.1 µm apart) holds 2,000.
        Any pick from this subset leaves every other one of it usable."""
        m = self.calibration.stage_from_uv
        pu, pv = self.pitch_uv
        eu = (float(m[0, 0]) * pu, float(m[1, 0]) * pu)
        ev = (float(m[0, 1]) * pv, float(m[1, 1]) * pv)
        (b00, b01, b10, b11), (a, b, d) = _packing_basis(eu, ev, float(min_um))
        k = np.arange(self.n * self.n, dtype=np.int64)
        iu, iv = k % self.n, k // self.n  # ravel is v slow, u fast (see build)
        # (iu, iv) = p·row0 + q·row1 of the reduced basis (unimodular): (p, q) by its integer inverse
        det = b00 * b11 - b01 * b10
        p = (iu * b11 - iv * b10) * det
        q = (iv * b00 - iu * b01) * det
        return np.asarray((q % d == 0) & ((p - b * (q // d)) % a == 0), dtype=bool)


# Past this many lattice steps per spacing the search for the densest sub-lattice is not worth its cost: a
# square stride of the reduced lattice is used (at most 13 % fewer sites than a hexagonal packing).
_PACKING_SEARCH_STEPS = 12


def _reduced_basis(e: FloatArray) -> NDArray[np.int64]:
    """Lagrange–Gauss reduction of the lattice steps: integer rows (unimodular) whose stage steps are the
    lattice's two shortest independent ones, so a stride of the first is never shorter than it looks."""
    b = np.eye(2, dtype=np.int64)
    for _ in range(200):
        f = b @ e
        if f[0] @ f[0] > f[1] @ f[1]:
            b = b[::-1].copy()
            f = f[::-1]
        mu = round(float(f[0] @ f[1]) / float(f[0] @ f[0]))
        if mu == 0:
            break
        b[1] -= mu * b[0]
    return b


@functools.lru_cache(maxsize=32)
def _packing_basis(
    eu: tuple[float, float], ev: tuple[float, float], min_um: float
) -> tuple[tuple[int, int, int, int], tuple[int, int, int]]:
    """The reduced lattice basis (row-major) and (a, b, d): the sub-lattice {s·(a, 0) + t·(b, d)} of it
    (Hermite form, 0 ≤ b < a) with the fewest lattice points per site (a·d) whose shortest step is at least
    ``min_um``; among those the one with the longest shortest step.

    The search runs from the hexagonal bound (no packing of points ``min_um`` apart has fewer than
    √3/2·min²/cell lattice points per site) up to the square stride of the reduced basis, which always
    qualifies (its shortest step is the stride times the lattice's shortest)."""
    basis = _reduced_basis(np.array([eu, ev], dtype=float))
    key = (int(basis[0, 0]), int(basis[0, 1]), int(basis[1, 0]), int(basis[1, 1]))
    e = basis.astype(float) @ np.array([eu, ev], dtype=float)  # rows: the reduced stage steps
    shortest_step = float(np.hypot(*e[0]))
    if min_um <= DISTANCE_TOL_UM or shortest_step >= min_um - DISTANCE_TOL_UM:
        return key, (1, 0, 1)
    stride = math.ceil(min_um / shortest_step - 1e-9)
    if stride > _PACKING_SEARCH_STEPS:
        return key, (stride, 0, stride)
    cell = abs(float(np.linalg.det(e)))
    # a step shorter than min_um has |s|, |t| below r in the Hermite coordinates (r from the least
    # stretch of the reduced lattice), so ±r sees every step that could disqualify a basis
    r = math.ceil(min_um / float(np.linalg.svd(e, compute_uv=False).min()))
    c = np.arange(-r, r + 1)
    s, t = (x.ravel() for x in np.meshgrid(c, c))
    keep = (s != 0) | (t != 0)
    s, t = s[keep], t[keep]
    lo = max(1, math.floor(math.sqrt(3.0) / 2.0 * min_um**2 / cell))
    for n in range(lo, stride * stride):
        bases = np.array([(a, b, n // a) for a in range(1, n + 1) if n % a == 0 for b in range(a)])
        p = s[None, :] * bases[:, :1] + t[None, :] * bases[:, 1:2]
        q = t[None, :] * bases[:, 2:3]
        step = np.hypot(p * e[0, 0] + q * e[1, 0], p * e[0, 1] + q * e[1, 1]).min(axis=1)
        ok = np.flatnonzero(far_enough(step, min_um))
        if len(ok):
            best = min(ok, key=lambda i: (-step[i], i))
            a, b, d = (int(x) for x in bases[best])
            return key, (a, b, d)
    return key, (stride, 0, stride)


def _lattice_margin(calibration: Calibration, halfwidth_um: float) -> float:
    """Smallest uniform inset m so that every centre in [m, 1 − m]² keeps its square inside every side.

    Signed distance to side i is affine in (u, v): d_i = d_i(½, ½) + β_i(u − ½) + γ_i(v − ½). Over the
    square of half-size t = ½ − m its minimum is d_i(½, ½) − t(|β_i| + |γ_i|), and a square of half-width h
    needs d_i ≥ h(|n_x| + |n_y|). Hence t = min_i (d_i(½, ½) − h(|n_x| + |n_y|)) / (|β_i| + |γ_i|).
    """
    n, off = calibration._edge_frames()
    m = calibration.stage_from_uv
    cx, cy = calibration.to_stage(0.5, 0.5)
    d_center = n[:, 0] * float(cx) + n[:, 1] * float(cy) - off
    grad = np.abs(n @ m[:, :2])  # (4, 2): |∂d_i/∂u|, |∂d_i/∂v|
    need = halfwidth_um * (np.abs(n[:, 0]) + np.abs(n[:, 1]))
    slack = d_center - need
    if np.any(slack <= 0):
        raise InputError(
            "lattice",
            f"the calibrated area is too small for a local grid of half-width {halfwidth_um:g} µm",
        )
    t = float(np.min(slack / grad.sum(axis=1)))
    return float(min(max(0.5 - min(t, 0.5), 0.0), 0.5))


def exclusion_mask(
    candidates_xy_um: ArrayLike,
    indents_xy_um: ArrayLike,
    r_excl_um: float = 20.0,
    grid_halfwidth_um: float = 0.0,
) -> BoolArray:
    """True where a candidate is allowed: no point of its square (half-width grid_halfwidth_um) lies closer
    than r_excl_um to an earlier indent. Exactly r_excl_um away is allowed.
    """
    cand = np.asarray(candidates_xy_um, dtype=float).reshape(-1, 2)
    ind = np.asarray(indents_xy_um, dtype=float).reshape(-1, 2)
    allowed = np.ones(len(cand), dtype=bool)
    if len(cand) == 0 or len(ind) == 0 or r_excl_um <= 0:
        return allowed
    h = max(float(grid_halfwidth_um), 0.0)
    r = float(r_excl_um)
    pad = 1.0 + 1e-9
    tree = cKDTree(ind)
    if h == 0.0:
        dist, _ = tree.query(cand, k=1, distance_upper_bound=r * pad)
        return far_enough(dist, r)
    # Chebyshev pairs within h + r are a superset of the rounded square; check those exactly.
    pairs = cKDTree(cand).sparse_distance_matrix(tree, (h + r) * pad, p=np.inf, output_type="ndarray")
    i = pairs["i"]
    gap = np.maximum(np.abs(cand[i] - ind[pairs["j"]]) - h, 0.0)
    close = ~far_enough(np.sqrt(np.einsum("ij,ij->i", gap, gap)), r)
    allowed[i[close]] = False
    return allowed


def edge_penalty(uv: ArrayLike, strength: float = 0.5, width_uv: float = 0.1) -> FloatArray:
    """Acquisition multiplier: 1 beyond width_uv from the unit square's boundary, easing (C¹ smoothstep) down
    to 1 − strength on it. Points outside the square get the boundary value.
    """
    if not (math.isfinite(strength) and 0.0 <= strength < 1.0):
        raise InputError("edge_penalty", f"strength must be in [0, 1), got {strength}")
    if not (math.isfinite(width_uv) and 0.0 < width_uv <= 0.5):
        raise InputError("edge_penalty", f"width_uv must be in (0, 0.5], got {width_uv}")
    p = np.asarray(uv, dtype=float)
    if p.shape[-1:] != (2,):
        raise ValueError(f"uv must have shape (..., 2), got {p.shape}")
    u, v = p[..., 0], p[..., 1]
    d = np.minimum(np.minimum(u, 1.0 - u), np.minimum(v, 1.0 - v))
    t = np.clip(d / width_uv, 0.0, 1.0)
    smooth = t * t * (3.0 - 2.0 * t)
    return np.asarray(1.0 - strength * (1.0 - smooth), dtype=float)


def _segments_cross(p: FloatArray, q: FloatArray, r: FloatArray, s: FloatArray, tol: float) -> bool:
    """Whether segments pq and rs meet (crossing or touching), to within ``tol`` of area."""

    def orient(a: FloatArray, b: FloatArray, c: FloatArray) -> int:
        v = float((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]))
        return 0 if abs(v) <= tol else (1 if v > 0 else -1)

    def on(a: FloatArray, b: FloatArray, c: FloatArray) -> bool:  # c on segment ab, given collinear
        return bool(min(a[0], b[0]) <= c[0] <= max(a[0], b[0]) and min(a[1], b[1]) <= c[1] <= max(a[1], b[1]))

    o1, o2, o3, o4 = orient(p, q, r), orient(p, q, s), orient(r, s, p), orient(r, s, q)
    if o1 != o2 and o3 != o4 and 0 not in (o1, o2, o3, o4):
        return True
    return (
        (o1 == 0 and on(p, q, r))
        or (o2 == 0 and on(p, q, s))
        or (o3 == 0 and on(r, s, p))
        or (o4 == 0 and on(r, s, q))
    )


def polygon_self_crossing(vertices_um: ArrayLike) -> tuple[int, int] | None:
    """The first two edges (edge k joins vertex k to vertex k+1) of a closed outline that cross or touch,
    or None for a simple polygon. A crossing outline (a "bow-tie") is vertices typed out of order."""
    v = np.asarray(vertices_um, dtype=float).reshape(-1, 2)
    n = len(v)
    tol = 1e-12 * max(float(np.ptp(v)), 1.0) ** 2
    for i in range(n):
        for j in range(i + 2, n):
            if i == 0 and j == n - 1:
                continue  # neighbours through the closing vertex
            if _segments_cross(v[i], v[(i + 1) % n], v[j], v[(j + 1) % n], tol):
                return i, j
    return None


def polygon_meets_polygon(a_um: ArrayLike, b_um: ArrayLike) -> bool:
    """Whether two simple polygons share any point (overlap, touch, or one holds the other)."""
    a = np.asarray(a_um, dtype=float).reshape(-1, 2)
    b = np.asarray(b_um, dtype=float).reshape(-1, 2)
    tol = 1e-12 * max(float(np.ptp(np.vstack([a, b]))), 1.0) ** 2
    for i in range(len(a)):
        for j in range(len(b)):
            if _segments_cross(a[i], a[(i + 1) % len(a)], b[j], b[(j + 1) % len(b)], tol):
                return True
    return _point_in_polygon(a[0], b) or _point_in_polygon(b[0], a)


def _point_in_polygon(p: FloatArray, poly: FloatArray) -> bool:
    inside = False
    for k in range(len(poly)):
        (x1, y1), (x2, y2) = poly[k], poly[(k + 1) % len(poly)]
        if (y1 > p[1]) != (y2 > p[1]) and p[0] < x1 + (p[1] - y1) * (x2 - x1) / (y2 - y1):
            inside = not inside
    return inside


def mm_typed(points_um: ArrayLike, bounds_um: tuple[float, float, float, float]) -> bool:
    """Whether stage coordinates were typed in mm: every point lies far off the area (more than its span
    beyond ``bounds_um`` = x0, x1, y0, y1) while every point × 1000 lies near it (within its span).

    The rule is the same for exclusions, earlier indents and avoided centres: one coordinate list, all of it
    implausible in µm and all of it plausible once read as mm. A list that is only partly off is a typo of
    another kind, left to the other checks.
    """
    pts = np.asarray(points_um, dtype=float).reshape(-1, 2)
    if not len(pts):
        return False
    x0, x1, y0, y1 = bounds_um
    span = max(x1 - x0, y1 - y0)

    def near(q: FloatArray) -> BoolArray:
        return np.asarray(
            (q[:, 0] >= x0 - span) & (q[:, 0] <= x1 + span) & (q[:, 1] >= y0 - span) & (q[:, 1] <= y1 + span),
            dtype=bool,
        )

    return bool((~near(pts)).all() and near(pts * 1000.0).all())


def distance_to_polygon_um(x_um: float, y_um: float, polygon_um: ArrayLike) -> float:
    """How far a point lies from a simple polygon (0 inside or on it)."""
    poly = np.asarray(polygon_um, dtype=float).reshape(-1, 2)
    p = np.array([x_um, y_um], dtype=float)
    if _point_in_polygon(p, poly):
        return 0.0
    a, b = poly, np.roll(poly, -1, axis=0)
    ab = b - a
    t = np.clip(
        np.einsum("ki,ki->k", p - a, ab) / np.maximum(np.einsum("ki,ki->k", ab, ab), 1e-300), 0.0, 1.0
    )
    return float(np.min(np.hypot(*(p - (a + t[:, None] * ab)).T)))

"""The safety interlock: an independent check of every block before any driver receives it.

The planner already tries to keep indents on the sample, off the exclusions, away from earlier indents and
inside the safe band. The interlock does not trust it: it re-derives every rule from the Sample's raw
numbers with its own geometry (its own plane, its own edge test, its own polygon test, brute-force
distances), sharing no code with ``core.geometry`` or the policies; only which places are taken is one rule
for both (``core.taken``). A block it refuses never reaches a
driver; the engine holds it for the operator with the interlock's reason.

Rules, per site of the block (commanded positions):
- finite, inside the stage's safe travel rectangle;
- inside the four corners and at least ``edge_band_um`` from every side;
- outside every exclusion region (on its boundary counts as inside);
- at least ``r_excl_um`` from every indent of earlier blocks (this run's and earlier runs'); a block's own
  sites only need the method's pitch between them;
- within ``dz_safe_um`` of the surface height at the program's centre (the global block that opened it);
- no engaged hop of ``SAFETY_HOP_UM`` or more on either axis unless the instrument profile reconfigures
  (lifts, re-engages, settles) for it.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

import numpy as np
from numpy.typing import NDArray

from core.geometry import DISTANCE_TOL_UM, far_enough
from core.plan import Block, IndentResult
from core.profile import InstrumentProfile
from core.sample import CircleExclusion, PolygonExclusion, Sample
from core.taken import taken_xy_um

FloatArray = NDArray[np.float64]

SAFETY_HOP_UM = 1000.0  # SPEC §3: a hop this long on either axis needs a reconfiguration
MIN_OWN_PITCH_UM = 5.0  # SPEC §2: the method's sub-grid pitch; a block's own sites keep at least this apart
_TOL_UM = DISTANCE_TOL_UM  # rounding slack on distances, never physics


class Interlock:
    """Checks blocks against one Sample; remembers the indents of the blocks that passed."""

    def __init__(self, sample: Sample, profile: InstrumentProfile) -> None:
        self.sample = sample
        self.profile = profile
        c = sample.calibration
        self._quad = np.array([[k.x_um, k.y_um] for k in (c.tl, c.tr, c.br, c.bl)], dtype=float)
        self._z = np.array([k.z_um for k in (c.tl, c.tr, c.br, c.bl)], dtype=float)
        # plane z = a·x + b·y + c through TL, TR, BR (SPEC §2), solved here from the raw corners
        m = np.column_stack([self._quad[:3], np.ones(3)])
        self._plane = np.linalg.solve(m, self._z[:3])
        # inward-facing edge frames of the convex quad: orientation from the shoelace sum
        q = self._quad
        shoelace = float(np.sum(q[:, 0] * np.roll(q[:, 1], -1) - np.roll(q[:, 0], -1) * q[:, 1]))
        self._ccw = shoelace > 0
        self._earlier: list[FloatArray] = [sample.earlier_xy_um.copy()]
        self._program_centre: tuple[float, float] | None = None

    # -- what the interlock remembers -------------------------------------------------------------
    def passed(self, block: Block, results: Sequence[IndentResult]) -> None:
        """A block ran: its indents join the ones to keep away from; a global block opens a program."""
        if block.kind == "global":
            self._program_centre = (float(block.center_x_um), float(block.center_y_um))
        # the places these indents take, by the rule the planners use too (core.taken)
        spots = taken_xy_um(results)
        if len(spots):
            self._earlier.append(spots)

    def restore(self, observed: Iterable[tuple[Block, Sequence[IndentResult]]]) -> None:
        """Rebuild after a crash from the journal's observed blocks, in order."""
        for block, results in observed:
            self.passed(block, results)

    @property
    def program_centre_um(self) -> tuple[float, float] | None:
        return self._program_centre

    def _earlier_xy(self) -> FloatArray:
        return np.concatenate(self._earlier) if len(self._earlier) > 1 else self._earlier[0]

    # -- the check ----------------------------------------------------------------------------------
    def check(self, block: Block, position_um: tuple[float, float], program_open: bool) -> str | None:
        """None when the block may run from ``position_um``; else the first reason it may not."""
        if block.n_indents == 0:
            return f"block {block.block_id} has no indents"
        xy = np.array([(s.x_um, s.y_um) for s in block.indents], dtype=float)
        if not np.all(np.isfinite(xy)):
            return "a site has a non-finite coordinate"
        for reason in (
            self._stage(xy),
            self._inside(xy),
            self._exclusions(xy),
            self._own_pitch(xy),
            self._earlier_indents(xy),
            self._band(block, xy),
            self._hops(block, xy, position_um, program_open),
        ):
            if reason is not None:
                return reason
        return None

    def _stage(self, xy: FloatArray) -> str | None:
        x0, y0, x1, y1 = self.sample.stage_rect_um
        bad = (xy[:, 0] < x0) | (xy[:, 0] > x1) | (xy[:, 1] < y0) | (xy[:, 1] > y1)
        if bad.any():
            i = int(np.argmax(bad))
            return (
                f"site {i} ({xy[i, 0]:.1f}, {xy[i, 1]:.1f}) µm is outside the stage's safe travel rectangle"
            )
        return None

    def _inside(self, xy: FloatArray) -> str | None:
        q = self._quad
        worst = np.full(len(xy), np.inf)
        for k in range(4):
            a, b = q[k], q[(k + 1) % 4]
            ex, ey = b[0] - a[0], b[1] - a[1]
            cross = ex * (xy[:, 1] - a[1]) - ey * (xy[:, 0] - a[0])
            dist = (cross if self._ccw else -cross) / math.hypot(ex, ey)
            worst = np.minimum(worst, dist)
        band = self.sample.edge_band_um
        bad = worst < band - _TOL_UM
        if bad.any():
            i = int(np.argmax(bad))
            where = "outside the corners" if worst[i] < 0 else f"{worst[i]:.1f} µm from the edge"
            return f"site {i} ({xy[i, 0]:.1f}, {xy[i, 1]:.1f}) µm is {where} (edge band {band:g} µm)"
        return None

    def _exclusions(self, xy: FloatArray) -> str | None:
        for k, region in enumerate(self.sample.exclusions):
            if isinstance(region, CircleExclusion):
                hit = np.hypot(xy[:, 0] - region.x_um, xy[:, 1] - region.y_um) <= region.radius_um
            elif isinstance(region, PolygonExclusion):
                hit = _in_or_on_polygon(np.asarray(region.vertices_um, dtype=float), xy)
            else:  # pragma: no cover - the Sample type admits only these two
                return f"exclusion {k} has an unknown shape"
            if hit.any():
                i = int(np.argmax(hit))
                return f"site {i} ({xy[i, 0]:.1f}, {xy[i, 1]:.1f}) µm is inside exclusion region {k}"
        return None

    def _own_pitch(self, xy: FloatArray) -> str | None:
        if len(xy) < 2:
            return None
        d = np.hypot(xy[:, None, 0] - xy[None, :, 0], xy[:, None, 1] - xy[None, :, 1])
        d[np.diag_indices(len(xy))] = np.inf
        if d.min() < MIN_OWN_PITCH_UM - _TOL_UM:
            i, j = np.unravel_index(int(np.argmin(d)), d.shape)
            return f"sites {i} and {j} are {d[i, j]:.2f} µm apart (the sub-grid pitch is at least {MIN_OWN_PITCH_UM:g} µm)"
        return None

    def _earlier_indents(self, xy: FloatArray) -> str | None:
        r = self.sample.r_excl_um
        earlier = self._earlier_xy()
        if r <= 0 or len(earlier) == 0:
            return None
        for start in range(0, len(earlier), 4096):
            chunk = earlier[start : start + 4096]
            d = np.hypot(xy[:, None, 0] - chunk[None, :, 0], xy[:, None, 1] - chunk[None, :, 1])
            if not far_enough(d, r).all():
                i, j = np.unravel_index(int(np.argmin(d)), d.shape)
                return (
                    f"site {i} ({xy[i, 0]:.1f}, {xy[i, 1]:.1f}) µm is {d[i, j]:.1f} µm from an earlier indent "
                    f"at ({chunk[j, 0]:.1f}, {chunk[j, 1]:.1f}) µm (r_excl {r:g} µm)"
                )
        return None

    def _band(self, block: Block, xy: FloatArray) -> str | None:
        if block.kind == "global":
            centre = (float(block.center_x_um), float(block.center_y_um))
        elif self._program_centre is None:
            return "a local block with no program open (no global block has run)"
        else:
            centre = self._program_centre
        a, b, c = (float(v) for v in self._plane)
        z0 = a * centre[0] + b * centre[1] + c
        dz = np.abs(a * xy[:, 0] + b * xy[:, 1] + c - z0)
        limit = self.sample.dz_safe_um
        bad = dz > limit + _TOL_UM
        if bad.any():
            i = int(np.argmax(bad))
            return (
                f"site {i} ({xy[i, 0]:.1f}, {xy[i, 1]:.1f}) µm is {dz[i]:.2f} µm off the surface height at the "
                f"program centre ({centre[0]:.0f}, {centre[1]:.0f}) µm (safe band {limit:g} µm)"
            )
        return None

    def _hops(
        self, block: Block, xy: FloatArray, position_um: tuple[float, float], program_open: bool
    ) -> str | None:
        # a global block lifts before its first move; a local one moves engaged from where the tip is
        path = xy if block.kind == "global" else np.vstack([np.asarray(position_um, dtype=float), xy])
        steps = np.abs(np.diff(path, axis=0))
        far = (steps[:, 0] >= SAFETY_HOP_UM) | (steps[:, 1] >= SAFETY_HOP_UM)
        for k in np.flatnonzero(far):
            dx, dy = float(steps[k, 0]), float(steps[k, 1])
            if not self.profile.needs_reconfiguration(dx, dy):
                into = int(k) if block.kind == "global" else int(k) - 1
                frm = "the current position" if into < 0 else f"site {into}"
                return (
                    f"hop of ({dx:.0f}, {dy:.0f}) µm from {frm} to site {into + 1} without a reconfiguration "
                    f"(profile {self.profile.name} reconfigures only from {self.profile.reconfig_threshold_um:g} µm)"
                )
        return None


def _in_or_on_polygon(vertices: FloatArray, xy: FloatArray) -> NDArray[np.bool_]:
    """Winding-number test (non-zero rule), with points on an edge counted as inside."""
    a = vertices
    b = np.roll(vertices, -1, axis=0)
    px, py = xy[:, 0:1], xy[:, 1:2]
    ax, ay, bx, by = a[None, :, 0], a[None, :, 1], b[None, :, 0], b[None, :, 1]
    side = (bx - ax) * (py - ay) - (by - ay) * (px - ax)
    up = (ay <= py) & (by > py) & (side > 0)
    down = (ay > py) & (by <= py) & (side < 0)
    winding = up.sum(axis=1) - down.sum(axis=1)
    # on an edge: collinear and within the segment's box (with rounding slack)
    seg = np.hypot(bx - ax, by - ay)
    on_line = np.abs(side) <= _TOL_UM * np.maximum(seg, 1.0)
    within = (
        (px >= np.minimum(ax, bx) - _TOL_UM)
        & (px <= np.maximum(ax, bx) + _TOL_UM)
        & (py >= np.minimum(ay, by) - _TOL_UM)
        & (py <= np.maximum(ay, by) + _TOL_UM)
    )
    return np.asarray((winding != 0) | (on_line & within).any(axis=1), dtype=bool)

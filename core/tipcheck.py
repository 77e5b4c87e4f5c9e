"""The tip check: a small array on the tray's reference block, its hardness against the block's nominal value.

A worn or contaminated Berkovich tip changes the contact area the instrument assumes, so every hardness it
reads drifts; a reference of known hardness (fused silica) shows it. The tray indents the reference before
its first library, every ``check_every_h`` hours of instrument time and after its last; a median hardness
further than ``tolerance_pct`` from the nominal fails the check, and the run pauses (core.run.tray).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from core.errors import InputError
from core.geometry import CandidateLattice, exclusion_mask
from core.plan import Block, IndentResult, local_grid
from core.sample import Sample
from core.sample.tray import Reference

CHECK_PITCH_UM = 10.0  # tens of indent widths at ~100 nm depth; the check grids keep r_excl from each other
# Fused silica's scatter per indent at ~100 nm depth, % of H: the low end of what calibration round robins see
# at shallow depth. An assumption to check against the block's own certificate (the simulated block uses it).
REFERENCE_SCATTER_PCT = 1.5
# The check's median must be sure enough that a good tip does not pause a night (a false alarm in under 1 check
# of 100, two-sided z = 2.576) and that a tip worn just past the tolerance is caught (95 % of the time,
# z = 1.645, once it is off by the tolerance plus that margin: 1.4× the tolerance at the sizes below).
FALSE_ALARM_Z = 2.576
CATCH_Z = 1.645
MIN_CHECK_INDENTS = 3  # a median that one lost or odd indent cannot decide


def check_indents(tolerance_pct: float, scatter_pct: float = REFERENCE_SCATTER_PCT) -> int:
    """Reference indents a check needs to see a drift of ``tolerance_pct`` at ``scatter_pct`` per indent: the
    median of n has sd ≈ sqrt(π/2)·scatter/√n, and the tolerance must hold both margins,
    (z_false_alarm + z_catch)·sd ≤ tolerance. 5 % at 1.5 %: 3 (the earlier fixed 3×3 grid spent 9)."""
    z = FALSE_ALARM_Z + CATCH_Z
    n = math.ceil(math.pi / 2 * (z * scatter_pct / tolerance_pct) ** 2)
    return max(n, MIN_CHECK_INDENTS)


def check_grid_g(tolerance_pct: float, scatter_pct: float = REFERENCE_SCATTER_PCT) -> int:
    """The side of the smallest square check grid that holds :func:`check_indents`."""
    return math.ceil(math.sqrt(check_indents(tolerance_pct, scatter_pct)))


@dataclass(frozen=True)
class TipCheck:
    """One check's verdict."""

    block_id: int
    t_s: float
    median_gpa: float  # NaN: nothing measured
    n_measured: int
    deviation_pct: float  # (median − nominal) / nominal, %
    passed: bool

    def text(self, ref: Reference) -> str:
        if self.n_measured == 0:
            return f"tip check failed: block {self.block_id} on the reference measured nothing"
        verdict = "passed" if self.passed else "failed (tip worn or contaminated?)"
        return (
            f"tip check {verdict}: {ref.material} reads {self.median_gpa:.2f} GPa (median of "
            f"{self.n_measured}), {self.deviation_pct:+.1f} % from its nominal {ref.hardness_gpa:g} GPa "
            f"(tolerance ±{ref.tolerance_pct:g} %)"
        )


def judge(block: Block, results: Sequence[IndentResult], ref: Reference) -> TipCheck:
    values = np.array([r.hardness_gpa for r in results if r.measured], dtype=float)
    t = max((r.t_s for r in results), default=math.nan)
    if len(values) == 0:
        return TipCheck(block.block_id, t, math.nan, 0, math.nan, False)
    median = float(np.median(values))
    dev = 100.0 * (median - ref.hardness_gpa) / ref.hardness_gpa
    return TipCheck(block.block_id, t, median, len(values), dev, abs(dev) <= ref.tolerance_pct)


def check_block(
    sample: Sample,
    taken_xy_um: np.ndarray,
    avoid_xy_um: Sequence[tuple[float, float]],
    position_um: tuple[float, float],
    block_id: int,
    hold_s: float,
    grid_g: int,
) -> Block:
    """A global ``grid_g``×``grid_g`` array (:func:`check_grid_g`) at the free place of the reference nearest
    the tip (r_excl from every earlier indent and from vetoed places)."""
    h = (grid_g - 1) / 2 * CHECK_PITCH_UM
    lattice = CandidateLattice.build(sample.calibration, sample.lattice_n, grid_halfwidth_um=h)
    xy = lattice.xy_um
    ok = sample.allowed(xy, h) & exclusion_mask(xy, taken_xy_um, max(sample.r_excl_um, CHECK_PITCH_UM), h)
    for ax, ay in avoid_xy_um:
        ok &= np.hypot(xy[:, 0] - ax, xy[:, 1] - ay) > 2 * h + sample.r_excl_um
    if not ok.any():
        raise InputError(f"reference {sample.name!r}", "no free place left for a tip check")
    free = np.flatnonzero(ok)
    d = np.hypot(xy[free, 0] - position_um[0], xy[free, 1] - position_um[1])
    cx, cy = (float(v) for v in xy[free[int(np.argmin(d))]])
    indents = local_grid(cx, cy, grid_g, CHECK_PITCH_UM, hold_s)
    return Block(block_id, "global", cx, cy, grid_g, CHECK_PITCH_UM, hold_s, indents)

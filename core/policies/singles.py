"""Where the singles of a block may go: the candidate sites, a block's box, and the order it visits them."""

from __future__ import annotations

import numpy as np

from core.policies.base import PlanContext, base_mask
from core.policies.blocks import ScatteredSingles

MAX_CANDIDATES = 2500  # candidates scored per decision (a large lattice is thinned evenly)
BOX_FRACTION = 0.45  # a block's indents lie within ± this × the reconfiguration threshold of its anchor


def single_sites(ctx: PlanContext, design: ScatteredSingles) -> np.ndarray:
    """The lattice indices a single may go to now: outside the exclusion zone and on the lattice's spaced
    sites (``CandidateLattice.spaced_sites``: picks from a lattice finer than the spacing would jam it long
    before it is full), thinned evenly past ``MAX_CANDIDATES``. When no spaced site is left but other
    places are (earlier indents on the sample that are off the spaced sites), those."""
    spacing = design.spacing_um(ctx.r_excl_um)
    allowed = base_mask(ctx, 0.0)
    spaced = allowed & ctx.lattice.spaced_sites(spacing)
    cand = np.flatnonzero(spaced if spaced.any() else allowed)
    if len(cand) > MAX_CANDIDATES:
        cand = cand[np.linspace(0, len(cand) - 1, MAX_CANDIDATES).astype(int)]
    return cand


def in_box(xy: np.ndarray, at: tuple[float, float], half_um: float) -> np.ndarray:
    """The points within ± ``half_um`` of ``at`` on both axes (a block's box around its anchor)."""
    return np.asarray((np.abs(xy[:, 0] - at[0]) < half_um) & (np.abs(xy[:, 1] - at[1]) < half_um))


def travel_order(pts: np.ndarray, start: tuple[float, float], ctx: PlanContext) -> list[int]:
    """A short path through ``pts`` from ``start``: nearest neighbour, then 2-opt, on the stage's move times."""
    n = len(pts)
    if n <= 1:
        return list(range(n))
    move = ctx.profile.move.axis_s_array
    allp = np.vstack([np.asarray(start, dtype=float)[None, :], pts])
    dist = move(allp[:, None, 0] - allp[None, :, 0]) + move(allp[:, None, 1] - allp[None, :, 1])
    route = [0]
    left = set(range(1, n + 1))
    while left:
        last = route[-1]
        nxt = min(left, key=lambda j: dist[last, j])
        route.append(nxt)
        left.remove(nxt)
    improved = True
    while improved:
        improved = False
        for i in range(1, n):
            for k in range(i + 1, n + 1):
                a, b = route[i - 1], route[i]
                c = route[k]
                e = route[k + 1] if k + 1 <= n else None
                before = dist[a, b] + (dist[c, e] if e is not None else 0.0)
                after = dist[a, c] + (dist[b, e] if e is not None else 0.0)
                if after < before - 1e-9:
                    route[i : k + 1] = route[i : k + 1][::-1]
                    improved = True
    return [j - 1 for j in route[1:]]

"""Scattered singles' candidate sites and their value (maximin at the start, integrated variance reduction
after): shared by the scattered planner and its unattended stretches."""

from __future__ import annotations

import math

import numpy as np

from core.model import Prediction
from core.policies.base import (
    GPSummary,
    PlanContext,
    base_mask,
)
from core.policies.bends import bend_factor, relative_curvature
from core.policies.blocks import ScatteredSingles
from core.policies.variance import PosteriorCov, design_rel_error

MAX_CANDIDATES = 2500  # candidates scored per decision (a large lattice is thinned evenly)
REFERENCE_N = 24  # reference points per side on which the relative map error is integrated
FULL_WEIGHT_REL_SLOPE = 2.0  # a relative slope (per side of the area) that gets the full structure weight
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


def program_life_indents(ctx: PlanContext) -> float:
    """How many indents a program has served on average in this run (its life), for pricing a new one."""
    return len(ctx.indents_xy_um) / max(1, ctx.globals_done)


def _in_box(xy: np.ndarray, at: tuple[float, float], half_um: float) -> np.ndarray:
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


class _Value:
    """What one more single indent at candidate j adds; ``take`` commits it so the next pick sees it.

    ``take`` rebinds its state instead of changing it in place, so ``copy.copy`` gives an independent
    branch: the stay and the jump options are each picked against the same posterior."""

    def best(self, mask: np.ndarray) -> int | None:
        raise NotImplementedError

    def gains(self) -> np.ndarray:
        raise NotImplementedError

    def take(self, j: int) -> float:
        raise NotImplementedError


class _Maximin(_Value):
    """Distance (in u, v) to the nearest earlier indent: the greedy space-filling design."""

    def __init__(self, ctx: PlanContext, cand: np.ndarray) -> None:
        self.uv = ctx.lattice.uv[cand]
        done = ctx.indents_xy_um
        if len(done):
            u, v = ctx.calibration.to_uv(done[:, 0], done[:, 1])
            done_uv = np.column_stack([u, v])
            self.d = np.min(np.hypot(*(self.uv[:, None, :] - done_uv[None, :, :]).transpose(2, 0, 1)), axis=1)
        else:
            # nothing yet: start from the candidate nearest the area's centre
            self.d = 1.0 - np.hypot(self.uv[:, 0] - 0.5, self.uv[:, 1] - 0.5)

    def best(self, mask: np.ndarray) -> int | None:
        if not mask.any():
            return None
        return int(np.flatnonzero(mask)[np.argmax(self.d[mask])])

    def gains(self) -> np.ndarray:
        return np.asarray(self.d, dtype=float).copy()

    def take(self, j: int) -> float:
        gain = float(self.d[j])
        self.d = np.minimum(self.d, np.hypot(self.uv[:, 0] - self.uv[j, 0], self.uv[:, 1] - self.uv[j, 1]))
        return gain


class _Ivr(_Value):
    """Integrated variance reduction of the relative map error under the fitted kernel (y-free but for
    the weights, which the fitted mean sets).

    With a modulus view (``map_weights``) each map's reduction counts relative to that map's own remaining
    error: the gain is Σ weight · log(V_before / V_after), V a map's mean relative error variance under its
    own GP, so a map whose relative error is already small (the modulus: a few % scatter on 100-200 GPa) is
    not starved by one whose error is large in absolute terms, and both progress toward their own targets.
    The greedy picks update each V, so a map's gain shrinks as the block already covers it. A weight of 0
    drops that map; one map alone keeps its plain reduction (a monotone transform of it would rank the
    same, and the default path stays bit for bit)."""

    def __init__(
        self, ctx: PlanContext, cand: np.ndarray, structure_weight: float, bend_weight: float = 0.0
    ) -> None:
        pred, gp = ctx.prediction, ctx.gp
        assert pred is not None and gp is not None and ctx.tested_noise_var_gpa2 is not None
        lat = ctx.lattice
        n = lat.n
        step = max(1, n // REFERENCE_N)
        rows = np.arange(step // 2, n, step)
        ref_idx = (rows[:, None] * n + rows[None, :]).ravel()
        # (weight, model, one indent's noise variance at each candidate) per map
        self.parts: list[tuple[float, PosteriorCov, np.ndarray]] = []
        mod = ctx.modulus
        maps = [
            (
                1.0 if mod is None else mod.weight_hardness,
                pred,
                gp,
                ctx.tested_xy_um,
                ctx.tested_noise_var_gpa2,
            )
        ]
        if mod is not None:
            maps.append(
                (mod.weight_modulus, mod.prediction, mod.gp, mod.tested_xy_um, mod.tested_noise_var_gpa2)
            )
        maps = [m for m in maps if m[0] > 0]
        several = len(maps) > 1
        self.remaining: list[float] = []  # with several maps: each one's V (in its gain's units), as picked
        for weight, p, g, xy, nv in maps:
            model, noise_var, remaining = _ivr_part(
                ctx,
                p,
                g,
                xy,
                nv,
                cand,
                ref_idx,
                structure_weight,
                with_remaining=several,
                bend_weight=bend_weight,
            )
            self.parts.append((weight, model, noise_var))
            if several:
                self.remaining.append(remaining)

    def _gain(self) -> np.ndarray:
        if len(self.parts) == 1:
            w, model, noise_var = self.parts[0]
            gain = model.gain(noise_var)
            return gain if w == 1.0 else w * gain
        return np.asarray(
            sum(
                w * _log_reduction(model.gain(nv), v)
                for (w, model, nv), v in zip(self.parts, self.remaining, strict=True)
            ),
            dtype=float,
        )

    def best(self, mask: np.ndarray) -> int | None:
        if not mask.any():
            return None
        gain = self._gain()
        return int(np.flatnonzero(mask)[np.argmax(gain[mask])])

    def gains(self) -> np.ndarray:
        return self._gain()

    def take(self, j: int) -> float:
        gain = float(self._gain()[j])
        if self.remaining:
            # what the pick removes from each map's V is its plain reduction there
            self.remaining = [
                max(v - float(model.gain(nv)[j]), v * _MIN_LEFT)
                for (_, model, nv), v in zip(self.parts, self.remaining, strict=True)
            ]
        self.parts = [(w, model.condition_on(j, float(nv[j])), nv) for w, model, nv in self.parts]
        return gain


_MIN_LEFT = 1e-9  # a map's V never reaches 0 (a pick cannot remove more than the variance there is)


def _log_reduction(gain: np.ndarray, remaining: float) -> np.ndarray:
    """log(V / (V − gain)): a map's progress as a fraction of its own remaining error (scale-free)."""
    return np.asarray(-np.log1p(-np.minimum(gain / max(remaining, 1e-300), 1.0 - _MIN_LEFT)), dtype=float)


def _ivr_part(
    ctx: PlanContext,
    pred: Prediction,
    gp: GPSummary,
    tested_xy_um: np.ndarray,
    tested_noise_var: np.ndarray,
    cand: np.ndarray,
    ref_idx: np.ndarray,
    structure_weight: float,
    with_remaining: bool = False,
    bend_weight: float = 0.0,
) -> tuple[PosteriorCov, np.ndarray, float]:
    """One map's posterior covariance over the candidates and the reference points, weighted by 1/μ² (and
    its structure); the noise variance of one indent at each candidate; and, if asked (else NaN), the map's
    current weighted error variance over the reference points in the gain's units (GPa², weights
    normalised), which its gains use up."""
    lat = ctx.lattice
    n = lat.n
    mu = np.maximum(np.abs(pred.mean[ref_idx]), 1e-6)
    w = 1.0 / mu**2  # relative error: what MAPE counts
    if structure_weight > 0:
        # relative slope of the fitted mean per unit of (u, v): 0 on a flat map, ≥ 1 where it bends hard
        grad_v, grad_u = np.gradient(pred.mean.reshape(n, n), lat.pitch_uv[0])
        rel = np.hypot(grad_u, grad_v).ravel()[ref_idx] / mu
        w = w * (1.0 + structure_weight * np.minimum(rel / FULL_WEIGHT_REL_SLOPE, 1.0))
    if bend_weight > 0:  # where the map bends (core.policies.bends): the stationary GP's bias
        kappa = relative_curvature(pred.mean.reshape(n, n), lat.pitch_uv).ravel()[ref_idx]
        w = w * bend_factor(kappa, bend_weight)
    u, v = ctx.calibration.to_uv(tested_xy_um[:, 0], tested_xy_um[:, 1])
    train_uv = np.column_stack([u, v])
    model = PosteriorCov.build(gp, train_uv, tested_noise_var, lat.uv[cand], lat.uv[ref_idx], w)
    remaining = math.nan
    if with_remaining:
        # mean(var·w) over the reference points (design_rel_error's mean(var/μ²) with μ = 1/√w), normalised
        rms = design_rel_error(gp, train_uv, tested_noise_var, lat.uv[ref_idx], 1.0 / np.sqrt(w))
        remaining = rms**2 / float(np.mean(w))
    return model, pred.noise_sd[cand] ** 2 + gp.site_var_gpa2, remaining  # one indent: no estimator loss

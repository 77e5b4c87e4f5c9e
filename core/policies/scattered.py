"""The scattered-singles planner (``aeni``): blocks of single indents, each its own centre, ordered for travel.

Why singles: the oracle study (benchmarks/oracle_bound.py) finds evenly spread single indents about 1.7×
more informative per indent than replicate grids, because a grid spends g² indents on one point of a smooth
map. One program (lift, engage, drift settle) then serves many singles: the only per-indent costs left are
the indent, its hold and a short move.

How a block is chosen:

- a space-filling start: until ``space_filling_indents`` singles are in, each next indent is the candidate
  farthest from every earlier one (a greedy maximin design), since a model fitted on a handful of points
  cannot yet say where the map is unknown;
- then integrated variance reduction of the relative map error (what MAPE counts) under the fitted kernel,
  picked greedily with the posterior conditioned on the earlier picks, so one block spreads out by itself.
  The reference points are weighted by 1/μ² and, where the fitted mean shows structure (a steep gradient),
  up to ``1 + structure_weight`` times more: on a flat map that is an even design, on a structured one it
  places more indents where the map bends;
- every block is priced twice: staying in the engaged program (the safe band it can reach without a lift)
  and opening a new one around the best candidate anywhere; the better gain per second wins. In the
  space-filling start the new program opens where the stay would not reach (farthest from the earlier
  indents and the stay's picks), so the start spreads over several programs;
- the indents of a block stay within a box small enough that no hop needs a reconfiguration, and are
  visited in a nearest-neighbour order improved by 2-opt.
"""

from __future__ import annotations

import copy
import math
from dataclasses import replace

import numpy as np

from core.cost import block_costs_for
from core.geometry import far_enough
from core.model import Prediction
from core.plan import Alternative, Block, BlockKind, Decision, IndentSpec
from core.policies.base import (
    GPSummary,
    PlanContext,
    alternatives,
    base_mask,
    block_costs_s,
    preferred_index,
    reachable_mask,
)
from core.policies.bends import bend_factor, relative_curvature
from core.policies.blocks import ScatteredSingles
from core.policies.parts import PolicyParts
from core.policies.planner import aim_rel_error
from core.policies.variance import PosteriorCov, design_rel_error

MAX_CANDIDATES = 2500  # candidates scored per decision (a large lattice is thinned evenly)
REFERENCE_N = 24  # reference points per side on which the relative map error is integrated
FULL_WEIGHT_REL_SLOPE = 2.0  # a relative slope (per side of the area) that gets the full structure weight
PRICED_ALTERNATIVES = 3  # alternatives listed (the decision panel shows three; a veto takes the first)
BOX_FRACTION = 0.45  # a block's indents lie within ± this × the reconfiguration threshold of its anchor


class ScatteredPlanner:
    """Blocks of scattered single indents (see the module docstring)."""

    def __init__(self, name: str, parts: PolicyParts) -> None:
        if not isinstance(parts.blocks, ScatteredSingles):
            raise TypeError(
                f"{name}: ScatteredPlanner plans scattered singles, not {type(parts.blocks).__name__}"
            )
        self.name = name
        self.parts = parts
        self.design: ScatteredSingles = parts.blocks

    def propose(self, ctx: PlanContext) -> Decision | None:
        d = self.design
        cand = single_sites(ctx, d)
        if not len(cand):
            return None
        map_rel_err = aim_rel_error(ctx) if self.parts.hold.bias_aware else None
        hold, err, hold_mode = self.parts.hold.choose(ctx, map_rel_err, self.parts.noise.drift_correction)
        exploring = len(ctx.indents_xy_um) < d.space_filling_indents or ctx.gp is None
        value = _Maximin(ctx, cand) if exploring else _Ivr(ctx, cand, d.structure_weight, d.bend_weight)
        xy = ctx.lattice.xy_um[cand]
        box = BOX_FRACTION * ctx.profile.reconfig_threshold_um
        options: list[tuple[BlockKind, list[int], float, list[float]]] = []  # kind, picks, hold, gains
        prog_hold = ctx.program_hold_s
        after_stay: _Value | None = None
        if (
            ctx.program_open
            and ctx.program_center_um is not None
            and prog_hold is not None
            and prog_hold >= hold
        ):
            # a running program keeps its hold; one slower than needed may still be worth staying in
            here = ctx.position_um
            band = reachable_mask(ctx, ctx.program_center_um, here, 0.0, math.inf, idx=cand)
            band &= _in_box(xy, here, box)
            if band.any():
                after_stay = copy.copy(value)
                picks, gains = self._batch(after_stay, xy, band, None, ctx)
                options.append(("local", picks, prog_hold, gains))
        # in the space-filling start a jump opens where the stay would not reach (farthest from the earlier
        # indents and the stay's picks), so the start spreads over programs; it is scored on the same design.
        # The alternatives (where a veto moves to) are ranked the same way, the anchor first
        placing = after_stay if exploring and after_stay is not None else value
        everywhere = np.ones(len(cand), dtype=bool)
        preferred = preferred_index(ctx, xy, everywhere)
        if preferred is not None:
            options = []  # a veto: open the program at the alternative listed first, as it was priced
        first = preferred if preferred is not None else placing.best(everywhere)
        assert first is not None
        anchor = (float(xy[first, 0]), float(xy[first, 1]))
        picks, gains = self._program_at(ctx, value, xy, cand, first, box)
        options.append(("global", picks, hold, gains))
        alts = self._alternatives(ctx, cand, placing.gains(), hold, value, box)

        # each option at every block size the design allows: the size with the best gain per second wins, so
        # a program that is dear to open (a lift, engage and drift settle, a reconfiguration) serves more
        # indents, and a cheap stay refits sooner
        best: tuple[float, Block, float, BlockKind, float] | None = None
        rates: dict[str, float] = {}
        for kind, idx, h, option_gains in options:
            rate, block, cost, gain = self._best_size(
                ctx, kind, xy, idx, h, option_gains, anchor if kind == "global" else None
            )
            rates[kind] = max(rates.get(kind, -math.inf), rate)
            if best is None or rate > best[0]:
                best = (rate, block, cost, kind, gain)
        assert best is not None
        rate, block, cost, kind, gain = best
        what = "maximin spacing" if exploring else "IVR"
        if preferred is not None:
            reason = f"after a veto, the next best listed: {block.n_indents} singles, {what}/cost {rate:.3g}"
        elif kind == "local":
            reason = f"stay: {block.n_indents} singles, {what}/cost {rate:.3g} ≥ jump {rates['global']:.3g}"
        elif "local" in rates:
            reason = f"jump: {block.n_indents} singles, {what}/cost {rate:.3g} > stay {rates['local']:.3g}"
        else:
            reason = f"new program: {block.n_indents} singles around the best candidate ({what})"
        return Decision(
            block=block,
            policy=self.name,
            acquisition=gain,
            score=rate,
            predicted_cost_s=cost,
            stay_score=rates.get("local"),
            jump_score=rates.get("global"),
            alternatives=alts,
            reason=reason,
            phase="explore" if exploring else "exploit",
            hold_mode=hold_mode if kind == "global" else f"program hold {block.hold_s:g} s",
            area_error_pct=err,
        )

    def propose_stretch(self, ctx: PlanContext) -> list[Decision] | None:
        """Before an absence: the arrays of one stretch that fills it (core.policies.stretch); None when no
        stretch is due (the next block is planned adaptively)."""
        from core.policies.stretch import plan_stretch, stretch_due

        if not stretch_due(self, ctx):
            return None
        return plan_stretch(self, ctx) or None

    def _program_at(
        self, ctx: PlanContext, value: _Value, xy: np.ndarray, cand: np.ndarray, first: int, box: float
    ) -> tuple[list[int], list[float]]:
        """The singles of a new program engaged at candidate ``first`` (its anchor), with their gains."""
        anchor = (float(xy[first, 0]), float(xy[first, 1]))
        band = reachable_mask(ctx, anchor, anchor, 0.0, math.inf, idx=cand) & _in_box(xy, anchor, box)
        band[first] = True
        return self._batch(copy.copy(value), xy, band, first, ctx)

    def _best_size(
        self,
        ctx: PlanContext,
        kind: BlockKind,
        xy: np.ndarray,
        idx: list[int],
        hold_s: float,
        gains: list[float],
        anchor: tuple[float, float] | None,
    ) -> tuple[float, Block, float, float]:
        """(gain per second, block, cost, gain) of the block size the design allows that pays best."""
        best: tuple[float, Block, float, float] | None = None
        life = program_life_indents(ctx) if self.design.program_life and kind == "global" else None
        for n in self.design.block_sizes(len(idx), len(ctx.indents_xy_um)):
            block = self._block(ctx, kind, xy[idx[:n]], hold_s, anchor)
            cost = block_costs_for(ctx.profile, block, ctx.position_um, ctx.program_open)
            gain = float(sum(gains[:n]))
            charged = cost
            if life is not None:
                # the program's overhead, shared with the blocks that will stay in it
                overhead = min(ctx.profile.global_overhead_s, cost)
                charged = cost - overhead * (1.0 - n / max(life, float(n)))
            rate = gain / charged if charged > 0 else 0.0
            if best is None or rate > best[0]:
                best = (rate, block, cost, gain)
        assert best is not None
        return best

    def _alternatives(
        self,
        ctx: PlanContext,
        cand: np.ndarray,
        gain: np.ndarray,
        hold_s: float,
        value: _Value,
        box: float,
    ) -> tuple[Alternative, ...]:
        """Other places to open the next program (what a veto moves to): spread-out candidates by the gain
        of one indent there, each then priced as the whole program it would open, so its score is on the
        proposal's scale (gain per second of its block) and a veto brings exactly the block listed first."""
        n = len(ctx.lattice.xy_um)
        score = np.full(n, -np.inf)
        score[cand] = gain
        cost = np.full(n, np.inf)
        cost[cand] = block_costs_s(ctx, ctx.lattice.xy_um[cand], 1, hold_s, "global")
        order = np.argsort(-score, kind="stable")[: len(cand)]
        spread = alternatives(ctx, order, score, score, cost, np.full(n, "global"), skip=1)
        spread = spread[:PRICED_ALTERNATIVES]  # each priced costs as much as the proposal's own program
        xy = ctx.lattice.xy_um[cand]
        priced = []
        for a in spread:
            j = int(np.argmin(np.hypot(xy[:, 0] - a.center_x_um, xy[:, 1] - a.center_y_um)))
            picks, gains = self._program_at(ctx, value, xy, cand, j, box)
            anchor = (float(xy[j, 0]), float(xy[j, 1]))
            rate, _, block_cost, block_gain = self._best_size(ctx, "global", xy, picks, hold_s, gains, anchor)
            priced.append(replace(a, score=rate, acquisition=block_gain, cost_s=block_cost))
        return tuple(sorted(priced, key=lambda a: -a.score))

    def _batch(
        self, value: _Value, xy: np.ndarray, mask: np.ndarray, first: int | None, ctx: PlanContext
    ) -> tuple[list[int], list[float]]:
        """Greedy picks (each conditioned on the earlier ones) within ``mask``, kept apart by the spacing,
        with the gain of each. ``value`` is conditioned on the picks: pass a copy."""
        free = mask.copy()
        picks: list[int] = []
        gains: list[float] = []
        spacing = self.design.spacing_um(ctx.r_excl_um)
        for _ in range(self.design.max_indents_per_block):
            j = first if first is not None and not picks else value.best(free)
            if j is None:
                break
            gains.append(value.take(j))
            picks.append(j)
            free &= far_enough(np.hypot(xy[:, 0] - xy[j, 0], xy[:, 1] - xy[j, 1]), spacing)
            if not free.any():
                break
        return picks, gains

    def _block(
        self,
        ctx: PlanContext,
        kind: BlockKind,
        pts: np.ndarray,
        hold_s: float,
        centre: tuple[float, float] | None,
    ) -> Block:
        start = ctx.position_um if kind == "local" else (centre if centre is not None else ctx.position_um)
        order = travel_order(pts, start, ctx)
        if kind == "global" and centre is not None:
            # the program is engaged at its first indent: the anchor, where the safe band is centred
            k = int(np.argmin(np.hypot(pts[order, 0] - centre[0], pts[order, 1] - centre[1])))
            order = order[k:] + order[:k] if k else order
        p = pts[order]
        cx, cy = centre if centre is not None else (float(p[0, 0]), float(p[0, 1]))
        if kind == "local" and ctx.program_center_um is not None:
            cx, cy = ctx.program_center_um
        return Block(
            block_id=ctx.block_id,
            kind=kind,
            center_x_um=float(cx),
            center_y_um=float(cy),
            grid_g=1,
            pitch_um=ctx.pitch_um,
            hold_s=hold_s,
            indents=tuple(IndentSpec(float(x), float(y), hold_s) for x, y in p),
        )


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

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
from core.plan import Alternative, Block, BlockKind, Decision, IndentSpec
from core.policies.acquisition import IntegratedVarianceReduction, variance_reduction
from core.policies.base import (
    PlanContext,
    alternatives,
    block_costs_s,
    preferred_index,
    reachable_mask,
)
from core.policies.blocks import ScatteredSingles
from core.policies.greedy import GreedyIvr, GreedyValue, Maximin
from core.policies.parts import PolicyParts
from core.policies.singles import BOX_FRACTION, in_box, single_sites, travel_order
from core.policies.stretch import plan_stretch, stretch_due
from core.policies.variance import aim_rel_error

PRICED_ALTERNATIVES = 3  # alternatives listed (the decision panel shows three; a veto takes the first)


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
        ivr = variance_reduction(parts.acquisition)
        if ivr is None or not parts.acquisition.cost_weighted:
            raise TypeError(f"{name}: ScatteredPlanner places singles by variance reduction per second")
        self.ivr: IntegratedVarianceReduction = ivr

    def value(self, ctx: PlanContext, cand: np.ndarray) -> tuple[GreedyValue, bool]:
        """The greedy value that places the next singles among ``cand``, and whether it is the space-filling
        start (a model fitted on a handful of points cannot yet say where the map is unknown)."""
        d = self.design
        exploring = len(ctx.learnt_xy_um) < d.space_filling_indents or ctx.gp is None
        return (Maximin(ctx, cand) if exploring else GreedyIvr(ctx, cand, self.ivr)), exploring

    def propose(self, ctx: PlanContext) -> Decision | None:
        d = self.design
        cand = single_sites(ctx, d)
        if not len(cand):
            return None
        map_rel_err = aim_rel_error(ctx) if self.parts.hold.bias_aware else None
        hold, err, hold_mode = self.parts.hold.choose(ctx, map_rel_err, self.parts.noise.drift_correction)
        value, exploring = self.value(ctx, cand)
        xy = ctx.lattice.xy_um[cand]
        box = BOX_FRACTION * ctx.profile.reconfig_threshold_um
        options: list[tuple[BlockKind, list[int], float, list[float]]] = []  # kind, picks, hold, gains
        prog_hold = ctx.program_hold_s
        after_stay: GreedyValue | None = None
        if (
            ctx.program_open
            and ctx.program_center_um is not None
            and prog_hold is not None
            and prog_hold >= hold
        ):
            # a running program keeps its hold; one slower than needed may still be worth staying in
            here = ctx.position_um
            band = reachable_mask(ctx, ctx.program_center_um, here, 0.0, math.inf, idx=cand)
            band &= in_box(xy, here, box)
            if band.any():
                after_stay = copy.copy(value)
                picks, gains = self.batch(after_stay, xy, band, None, ctx)
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
        if not stretch_due(self, ctx):
            return None
        return plan_stretch(self, ctx) or None

    def _program_at(
        self, ctx: PlanContext, value: GreedyValue, xy: np.ndarray, cand: np.ndarray, first: int, box: float
    ) -> tuple[list[int], list[float]]:
        """The singles of a new program engaged at candidate ``first`` (its anchor), with their gains."""
        anchor = (float(xy[first, 0]), float(xy[first, 1]))
        band = reachable_mask(ctx, anchor, anchor, 0.0, math.inf, idx=cand) & in_box(xy, anchor, box)
        band[first] = True
        return self.batch(copy.copy(value), xy, band, first, ctx)

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
        for n in self.design.block_sizes(len(idx), len(ctx.learnt_xy_um)):
            block = self.block(ctx, kind, xy[idx[:n]], hold_s, anchor)
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
        value: GreedyValue,
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

    def batch(
        self, value: GreedyValue, xy: np.ndarray, mask: np.ndarray, first: int | None, ctx: PlanContext
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

    def block(
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


def program_life_indents(ctx: PlanContext) -> float:
    """How many indents a program has served on average in this run (its life), for pricing a new one."""
    return len(ctx.learnt_xy_um) / max(1, ctx.globals_done)

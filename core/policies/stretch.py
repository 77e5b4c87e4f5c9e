"""A stretch: the arrays an operator loads in one visit before an absence, planned together to fill it.

With nobody there, the model cannot be asked again between arrays, so the stretch is planned as one batch
under the current model: each array is one program (one method, so one hold), opened at the candidate
that adds most to the map's integrated relative variance given every site the stretch has chosen so far
(the posterior conditioned on the stretch's earlier sites, y-free, as a block's own picks are), filled
with the singles its safe band reaches, ordered for travel and priced by the cost model from where the
previous array ends (its lift, engage and drift settle: one reconfiguration each). Arrays are added until
their instrument time fills the absence, and a stretch never ends where nobody could load the next one (see
:func:`plan_stretch`).

Each array still passes the interlock as its own block when the engine offers it; the ones after the
first carry ``phase = "stretch-continues"`` (loaded with the first: no visit of their own).
"""

from __future__ import annotations

import functools
import math
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from core.cost import block_costs_for
from core.geometry import far_enough
from core.plan import STRETCH_CONTINUES, STRETCH_PHASE, Block, Decision
from core.policies.base import PlanContext, reachable_mask
from core.policies.singles import BOX_FRACTION, in_box, single_sites

if TYPE_CHECKING:
    # the planner whose blocks a stretch's arrays are (it imports this module to plan one)
    from core.policies.scattered import ScatteredPlanner


MAX_ARRAYS = 60  # a weekend is not filled with more (the run's budget stops it earlier anyway)


def stretch_due(planner: ScatteredPlanner, ctx: PlanContext) -> bool:
    """A stretch is planned when the next load runs unattended for longer than the design's threshold."""
    d = planner.design
    w = ctx.unattended
    return d.stretch_min_s is not None and w is not None and w.fill_s > d.stretch_min_s


def plan_stretch(planner: ScatteredPlanner, ctx: PlanContext) -> list[Decision]:
    """The stretch's arrays, in the order they run (empty when nothing can be placed).

    The instrument must never idle while someone could have loaded it: a stretch that a visit during the
    hours follows ends by the day's last answerable moment (else nobody loads the next arrays and the
    instrument stands idle until the next morning); when not one array fits before that moment, the
    stretch fills the night now instead.
    """
    window = ctx.unattended
    assert window is not None
    fill_s = window.fill_s
    end_by_s = window.last_answer_s if fill_s <= window.last_answer_s else math.inf
    planned, exploring, hold_mode = _arrays(planner, ctx, fill_s, end_by_s)
    if not planned and math.isfinite(end_by_s):
        fill_s = window.next_answer_s
        planned, exploring, hold_mode = _arrays(planner, ctx, fill_s, math.inf)
    total_s = sum(cost for _, cost, _ in planned)
    n = len(planned)
    out: list[Decision] = []
    for k, (block, cost, gain) in enumerate(planned):
        out.append(
            Decision(
                block=block,
                policy=planner.name,
                acquisition=gain,
                score=gain / cost if cost > 0 else 0.0,
                predicted_cost_s=cost,
                reason=(
                    f"stretch array {k + 1} of {n}: {block.n_indents} singles, {'maximin spacing' if exploring else 'IVR'} over the whole stretch; "
                    f"the stretch runs ~{total_s / 3600:.1f} h unattended (nobody for {fill_s / 3600:.1f} h)"
                ),
                phase=STRETCH_PHASE if k == 0 else STRETCH_CONTINUES,
                hold_mode=hold_mode,
            )
        )
    return out


def _arrays(
    planner: ScatteredPlanner, ctx: PlanContext, fill_s: float, end_by_s: float
) -> tuple[list[tuple[Block, float, float]], bool, str]:
    """Arrays (block, cost, gain) until their instrument time fills ``fill_s``, the last one trimmed to the
    singles that fit (at least one program's worth), and none that cannot end by ``end_by_s``; whether they
    are the space-filling start, and the hold's mode."""
    d = planner.design
    cand = single_sites(ctx, d)
    if not len(cand):
        return [], False, ""
    hold, _, hold_mode = planner.parts.hold.choose(ctx, None, planner.parts.noise.drift_correction)
    # in the space-filling start (no model yet) the stretch is the start itself: its maximin design, which
    # asks nothing of the data, loaded in one visit, and no more of it than the start has left
    value, exploring = planner.value(ctx, cand)
    indents_left = max(d.space_filling_indents - len(ctx.learnt_xy_um), 1) if exploring else None
    xy = ctx.lattice.xy_um[cand]
    box = BOX_FRACTION * ctx.profile.reconfig_threshold_um
    spacing = d.spacing_um(ctx.r_excl_um)
    free = np.ones(len(cand), dtype=bool)
    pos, program_open = ctx.position_um, ctx.program_open
    planned: list[tuple[Block, float, float]] = []  # block, cost, gain
    total_s = 0.0
    while total_s < fill_s and len(planned) < MAX_ARRAYS and free.any() and indents_left != 0:
        first = value.best(free)
        if first is None:
            break
        anchor = (float(xy[first, 0]), float(xy[first, 1]))
        band = reachable_mask(ctx, anchor, anchor, 0.0, math.inf, idx=cand) & in_box(xy, anchor, box)
        band &= free
        band[first] = True
        # the stretch's value is conditioned on every pick: later arrays see the earlier ones' sites
        picks, gains = planner.batch(value, xy, band, first, ctx)
        if indents_left is not None:
            picks, gains = picks[:indents_left], gains[:indents_left]

        array_of = functools.cache(
            functools.partial(_array, planner, ctx, xy[picks], hold, anchor, pos, program_open)
        )
        keep = len(picks)
        for limit_s in (fill_s if planned else math.inf, end_by_s):
            # the singles that fit the limit, but at least one program's worth of them
            while keep > d.indents_per_block and total_s + array_of(keep)[1] > limit_s:
                keep -= 1
        block, cost = array_of(keep)
        if total_s + cost > end_by_s:
            break  # not even one program's worth ends by then
        picks, gains = picks[:keep], gains[:keep]
        if indents_left is not None:
            indents_left -= len(picks)
        for j in picks:
            free &= far_enough(np.hypot(xy[:, 0] - xy[j, 0], xy[:, 1] - xy[j, 1]), spacing)
        planned.append((block, cost, float(sum(gains))))
        total_s += cost
        last = block.indents[-1]
        pos, program_open = (last.x_um, last.y_um), True
    return planned, exploring, hold_mode


def _array(
    planner: ScatteredPlanner,
    ctx: PlanContext,
    sites_xy_um: np.ndarray,
    hold_s: float,
    anchor: tuple[float, float],
    pos: tuple[float, float],
    program_open: bool,
    keep: int,
) -> tuple[Block, float]:
    """The array of the first ``keep`` sites, ordered for travel, and its instrument seconds from ``pos``."""
    block = planner.block(ctx, "global", sites_xy_um[:keep], hold_s, anchor)
    return block, block_costs_for(ctx.profile, block, pos, program_open)


def renumbered(decision: Decision, block_id: int) -> Decision:
    """A queued array of a stretch, as the block the engine runs next."""
    return replace(decision, block=replace(decision.block, block_id=block_id))


__all__ = ["STRETCH_CONTINUES", "STRETCH_PHASE", "plan_stretch", "renumbered", "stretch_due"]

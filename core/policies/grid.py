"""The fixed grid baseline: 9×9 blocks of 5×5 over the calibrated area, in snake order.

On a sample with an edge band, exclusions, a stage limit or earlier indents, the blocks that would break
them are left out of the pattern (the rest keep their places and order).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from core.cost import block_costs_for, grid_baseline_blocks
from core.geometry import exclusion_mask
from core.plan import Block, Decision
from core.policies.base import PlanContext
from core.policies.parts import PolicyParts


class GridPolicy:
    def __init__(self, name: str = "grid", n_blocks: int = 9, g: int = 5) -> None:
        self.name = name
        self.parts = PolicyParts()  # the grid never looks at the model; its map is fitted with the defaults
        self.n_blocks = n_blocks
        self.g = g

    def propose(self, ctx: PlanContext) -> Decision | None:
        x0, x1, y0, y1 = ctx.calibration.bounds_um
        blocks = grid_baseline_blocks(
            x1 - x0,
            y1 - y0,
            self.n_blocks,
            self.g,
            ctx.pitch_um,
            ctx.fixed_hold_s,
            origin_um=(x0, y0),
        )
        blocks = _placeable(ctx, blocks)
        # the next block in snake order; one whose place an indent has taken since (a failed one, an
        # unverified one, another run's) is passed over, as the interlock would refuse it
        free = [b for b in blocks[ctx.blocks_done :] if _free(ctx, b.center_x_um, b.center_y_um, b.grid_g)]
        if not free:
            return None
        block = replace(free[0], block_id=ctx.block_id)
        cost = block_costs_for(ctx.profile, block, ctx.position_um, ctx.program_open)
        return Decision(
            block=block,
            policy=self.name,
            acquisition=float("nan"),
            score=float("nan"),
            predicted_cost_s=cost,
            reason=f"grid block {ctx.blocks_done + 1} of {len(blocks)}",
            phase="grid",
            hold_mode=f"fixed {ctx.fixed_hold_s:g} s",
        )


def _halfwidth_um(ctx: PlanContext, g: int) -> float:
    return (g - 1) / 2.0 * ctx.pitch_um


def _placeable(ctx: PlanContext, blocks: list[Block]) -> list[Block]:
    """The pattern's blocks the sample allows at all: off its edge band, exclusions, stage limits and the
    indents it came with (fixed for the run, so the pattern's order is too)."""
    sample = ctx.sample
    if sample is None or not blocks:
        return blocks
    xy = np.array([(b.center_x_um, b.center_y_um) for b in blocks])
    h = _halfwidth_um(ctx, blocks[0].grid_g)
    ok = sample.allowed(xy, h)
    return [b for b, keep in zip(blocks, ok, strict=True) if keep]


def _free(ctx: PlanContext, x_um: float, y_um: float, g: int) -> bool:
    """No earlier indent (of any status that takes a place, core.taken) within r_excl of the block."""
    if not len(ctx.indents_xy_um):
        return True
    return bool(exclusion_mask([(x_um, y_um)], ctx.indents_xy_um, ctx.r_excl_um, _halfwidth_um(ctx, g))[0])

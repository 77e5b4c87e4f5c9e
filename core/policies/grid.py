"""The fixed grid baseline: 9×9 blocks of 5×5 over the calibrated area, in snake order."""

from __future__ import annotations

from dataclasses import replace

from core.cost import block_costs_for, grid_baseline_blocks
from core.plan import Decision
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
        if ctx.blocks_done >= len(blocks):
            return None
        block = replace(blocks[ctx.blocks_done], block_id=ctx.block_id)
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

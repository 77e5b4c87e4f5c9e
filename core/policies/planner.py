"""One Bayesian planner whose features switch on one by one, so each idea's contribution is measurable.

``uncertainty`` is the plain GP baseline (jump to the highest σ after every block, cost ignored);
``cost-aware`` ranks σ/cost where staying engaged is cheap and a global jump pays the program overhead;
the adaptive grid, meta-grid, adaptive hold and the full ``aeni`` workflow add features on top.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal

import numpy as np

from core.acquisition import ei, ucb, ue
from core.drift import AREA_ERROR_THRESHOLD_PCT, area_error_pct
from core.geometry import edge_penalty
from core.plan import BlockKind, Decision
from core.policies.base import (
    PlanContext,
    alternatives,
    base_mask,
    block_costs_s,
    grid_size_for_noise,
    make_block,
)

FAST_HOLD_S = 5.0
SLOW_HOLD_S = 80.0


@dataclass(frozen=True)
class PlannerFeatures:
    cost_aware: bool = True
    adaptive_grid: bool = False
    meta_grid: bool = False  # local sub-grids ≤ local_hop_um apart inside the safe band
    adaptive_hold: bool = False
    edge_penalty: bool = False
    acquisition: Literal["ue", "ucb", "ei"] = "ue"
    n_seed_blocks: int = 2
    seed_g: int = 5
    fixed_g: int = 5
    local_hop_um: float = 1000.0
    exploratory_iterations: int = 0  # aeni: first iterations allow at most one local centre per program
    exploratory_local_limit: int = 1


def choose_hold(
    last_drift_rate_nm_s: float | None, threshold_pct: float = AREA_ERROR_THRESHOLD_PCT
) -> tuple[float, float | None]:
    """SPEC §6.6: fast 5 s hold when the last drift rate's area error is below 2 %, else 80 s."""
    if last_drift_rate_nm_s is None:
        return SLOW_HOLD_S, None
    err = area_error_pct(last_drift_rate_nm_s)
    return (FAST_HOLD_S if err < threshold_pct else SLOW_HOLD_S), err


class BayesPlanner:
    def __init__(self, name: str, features: PlannerFeatures) -> None:
        self.name = name
        self.features = features

    # -- pieces --------------------------------------------------------------------------------
    def _acquisition(self, ctx: PlanContext) -> np.ndarray:
        pred = ctx.prediction
        assert pred is not None
        f = self.features
        if f.acquisition == "ucb":
            acq = ucb(pred, ctx.settings.beta)
            acq = acq - float(np.min(acq)) + 1e-9  # shift positive so acquisition / cost ranks sensibly
        elif f.acquisition == "ei":
            best = ctx.best_observed_gpa if ctx.best_observed_gpa is not None else float(np.max(pred.mean))
            acq = ei(pred, best) + 1e-12
        else:
            acq = ue(pred)
        if f.edge_penalty and ctx.settings.edge_penalty > 0:
            acq = acq * edge_penalty(ctx.lattice.uv, strength=ctx.settings.edge_penalty)
        return np.asarray(acq, dtype=float)

    def _grid_sizes(self, ctx: PlanContext) -> np.ndarray:
        n = len(ctx.lattice.xy_um)
        if self.features.adaptive_grid and ctx.prediction is not None:
            return grid_size_for_noise(ctx.prediction.noise_sd, ctx.settings.target_sem_gpa)
        return np.full(n, self.features.fixed_g, dtype=int)

    def _hold(self, ctx: PlanContext) -> tuple[float, float | None, str]:
        if self.features.adaptive_hold or ctx.settings.hold_policy == "adaptive":
            hold, err = choose_hold(ctx.last_drift_rate_nm_s)
            return hold, err, f"adaptive: {'fast' if hold == FAST_HOLD_S else 'slow'} {hold:g} s"
        hold = ctx.settings.fixed_hold_s
        return hold, None, f"fixed {hold:g} s"

    def _local_limit(self, ctx: PlanContext) -> int:
        f = self.features
        if ctx.blocks_done - f.n_seed_blocks < f.exploratory_iterations:
            return min(f.exploratory_local_limit, ctx.settings.local_center_limit)
        return ctx.settings.local_center_limit

    def _seed(self, ctx: PlanContext, hold: float) -> Decision:
        rng = ctx.rng(salt=17)
        mask = base_mask(ctx, (self.features.seed_g - 1) / 2 * ctx.pitch_um)
        idx = np.flatnonzero(mask)
        pick = int(idx[rng.integers(len(idx))])
        x, y = ctx.lattice.xy_um[pick]
        block = make_block(ctx, x, y, self.features.seed_g, hold, "global")
        cost = float(block_costs_s(ctx, ctx.lattice.xy_um[[pick]], self.features.seed_g, hold, "global")[0])
        return Decision(
            block=block,
            policy=self.name,
            acquisition=float("nan"),
            score=float("nan"),
            predicted_cost_s=cost,
            reason=f"seed grid {ctx.blocks_done + 1} of {self.features.n_seed_blocks} at a random centre",
            phase="seed",
            hold_mode=f"fixed {hold:g} s",
        )

    # -- the decision --------------------------------------------------------------------------
    def propose(self, ctx: PlanContext) -> Decision | None:
        f = self.features
        if ctx.blocks_done < f.n_seed_blocks or ctx.prediction is None:
            return self._seed(ctx, SLOW_HOLD_S)
        xy = ctx.lattice.xy_um
        acq = self._acquisition(ctx)
        g = self._grid_sizes(ctx)
        hold, err, hold_mode = self._hold(ctx)
        halfwidth = (int(np.max(g)) - 1) / 2 * ctx.pitch_um
        allowed = base_mask(ctx, halfwidth)
        if not allowed.any():
            return None

        cost_g = block_costs_s(ctx, xy, g, hold, "global")
        score_g = acq / cost_g if f.cost_aware else acq.copy()
        score_g = np.where(allowed, score_g, -np.inf)

        score_l = np.full(len(xy), -np.inf)
        cost_l = np.full(len(xy), np.inf)
        may_stay = f.cost_aware and ctx.program_open and ctx.locals_in_program < self._local_limit(ctx)
        if may_stay:
            from core.policies.base import local_mask

            # a local block keeps the program's hold: changing the method needs a new program
            local_hold = ctx.program_hold_s if ctx.program_hold_s is not None else hold
            lmask = allowed & local_mask(ctx, halfwidth, f.local_hop_um)
            if lmask.any():
                cost_l = block_costs_s(ctx, xy, g, local_hold, "local")
                score_l = np.where(lmask, acq / cost_l, -np.inf)
                if (
                    f.adaptive_hold
                    and local_hold > hold
                    and int(np.max(g[lmask])) ** 2 * (local_hold - hold) >= ctx.profile.reconfiguration_s
                ):
                    # SPEC §6.6: leave a slow program for a fast one when the saved hold time pays the reconfiguration
                    score_l[:] = -np.inf
            else:
                local_hold = hold
        else:
            local_hold = hold

        best_g = int(np.argmax(score_g))
        best_l = int(np.argmax(score_l))
        jump_score = float(score_g[best_g])
        stay_score = float(score_l[best_l]) if np.isfinite(score_l[best_l]) else None
        kind: BlockKind = "local" if stay_score is not None and stay_score >= jump_score else "global"

        if kind == "local":
            pick, pick_hold, cost = best_l, local_hold, float(cost_l[best_l])
        else:
            pick, pick_hold, cost = best_g, hold, float(cost_g[best_g])
        x, y = xy[pick]
        block = make_block(ctx, x, y, int(g[pick]), pick_hold, kind)

        score = np.maximum(score_g, score_l)
        kinds = np.where(score_l > score_g, "local", "global")
        cost_any = np.where(score_l > score_g, cost_l, cost_g)
        order = np.argsort(-score, kind="stable")
        order = order[np.isfinite(score[order])]
        order = np.concatenate([[pick], order[order != pick]])
        alts = alternatives(ctx, order, score, acq, cost_any, kinds, skip=1)

        phase = "explore" if ctx.blocks_done - f.n_seed_blocks < f.exploratory_iterations else "exploit"
        if kind == "local":
            reason = f"stay: local σ/cost {stay_score:.3g} ≥ jump {jump_score:.3g}"
        elif stay_score is not None:
            reason = f"jump: global σ/cost {jump_score:.3g} > local {stay_score:.3g}"
        elif f.cost_aware:
            reason = f"jump: best σ/cost {jump_score:.3g} (no local centre available)"
        else:
            reason = f"jump to the highest σ ({acq[pick]:.3g} GPa), cost ignored"
        return Decision(
            block=block,
            policy=self.name,
            acquisition=float(acq[pick]),
            score=float(score[pick]) if f.cost_aware else float(acq[pick]),
            predicted_cost_s=cost,
            stay_score=stay_score,
            jump_score=jump_score if f.cost_aware else None,
            alternatives=alts,
            reason=reason,
            phase=phase,
            hold_mode=hold_mode,
            area_error_pct=err,
        )


def with_features(planner: BayesPlanner, name: str, **changes: object) -> BayesPlanner:
    return BayesPlanner(name, replace(planner.features, **changes))  # type: ignore[arg-type]

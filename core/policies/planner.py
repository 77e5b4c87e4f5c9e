"""The replicate-grid planner: the paper's policies, composed of parts so each idea's contribution is measurable.

``uncertainty`` is the plain GP baseline (jump to the highest σ after every block, cost ignored);
``cost-aware`` ranks σ/cost where staying engaged is cheap and a global jump pays the program overhead;
``adaptive-grid``, ``meta-grid``, ``adaptive-hold`` add the paper's ideas one at a time, ``aeni-paper`` all of
them with the real-film phases. Ablations change one part at a time (Huber centre values, bias-aware hold,
integrated variance reduction with sub-grids planned jointly so that a jump is priced with its program).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from core.acquisition import ei, ucb, ue
from core.geometry import edge_penalty
from core.plan import BlockKind, Decision
from core.policies.base import (
    PlanContext,
    alternatives,
    base_mask,
    block_costs_s,
    grid_size_for_noise,
    local_mask,
    make_block,
    preferred_index,
    reachable_mask,
)
from core.policies.blocks import ReplicateGrid
from core.policies.hold import choose_hold
from core.policies.parts import PolicyParts
from core.policies.variance import PosteriorCov, design_rel_error, median_noise_var, reference_lattice

__all__ = ["BayesPlanner", "aim_rel_error", "choose_hold", "nearest_lattice"]

G_MIN, G_MAX = 2, 5
PROGRAM_SUBSET = 300  # sub-grid candidates considered when a program is planned ahead
PROGRAM_CANDIDATES = 6  # with joint programs: global centres whose whole program is planned before a jump


@dataclass
class _Scored:
    """Per-candidate score, acquisition, cost and grid size for one kind of block (global or local)."""

    score: np.ndarray
    acq: np.ndarray
    cost: np.ndarray
    g: np.ndarray
    hold_s: float


class BayesPlanner:
    """Replicate grids at centres chosen by σ (or IVR) per block time, staying in a program or jumping."""

    def __init__(self, name: str, parts: PolicyParts) -> None:
        if not isinstance(parts.blocks, ReplicateGrid):
            raise TypeError(f"{name}: BayesPlanner plans replicate grids, not {type(parts.blocks).__name__}")
        self.name = name
        self.parts = parts
        self.design: ReplicateGrid = parts.blocks

    # -- acquisition ---------------------------------------------------------------------------
    def _acquisition(self, ctx: PlanContext) -> np.ndarray:
        pred = ctx.prediction
        assert pred is not None
        if self.parts.acquisition.kind == "ucb":
            acq = ucb(pred, ctx.settings.beta)
            acq = acq - float(np.min(acq)) + 1e-9  # shift positive so acquisition / cost ranks sensibly
        elif self.parts.acquisition.kind == "ei":
            best = ctx.best_observed_gpa if ctx.best_observed_gpa is not None else float(np.max(pred.mean))
            acq = ei(pred, best) + 1e-12
        else:
            acq = ue(pred)
        if self.parts.acquisition.edge_penalty and ctx.settings.edge_penalty > 0:
            acq = acq * edge_penalty(ctx.lattice.uv, strength=ctx.settings.edge_penalty)
        return np.asarray(acq, dtype=float)

    def _grid_sizes(self, ctx: PlanContext) -> np.ndarray:
        n = len(ctx.lattice.xy_um)
        if self.design.adaptive_grid and ctx.prediction is not None:
            return grid_size_for_noise(ctx.prediction.noise_sd, ctx.settings.target_sem_gpa, G_MIN, G_MAX)
        return np.full(n, self.design.fixed_g, dtype=int)

    def _jump_overhead_s(self, ctx: PlanContext) -> float:
        p = ctx.profile
        return p.global_jump_s if p.global_jump_s is not None else p.reconfiguration_s

    def _local_limit(self, ctx: PlanContext) -> int:
        f = self.design
        limit = ctx.settings.local_center_limit if f.local_limit is None else f.local_limit
        if self._in_exploratory_program(ctx):
            return min(f.exploratory_local_limit, limit)
        return limit

    def _exploring(self, ctx: PlanContext) -> bool:
        """The next program would be one of the exploratory iterations after the seeds."""
        f = self.design
        return ctx.globals_done - f.n_seed_blocks < f.exploratory_iterations

    def _in_exploratory_program(self, ctx: PlanContext) -> bool:
        """The running program is a seed or an exploratory iteration (few local centres there)."""
        f = self.design
        return ctx.globals_done - f.n_seed_blocks <= f.exploratory_iterations and f.exploratory_iterations > 0

    # -- seeds ---------------------------------------------------------------------------------
    def _seed(self, ctx: PlanContext) -> Decision | None:
        f = self.design
        rng = ctx.rng(salt=17)
        mask = base_mask(ctx, (f.seed_g - 1) / 2 * ctx.pitch_um)
        idx = np.flatnonzero(mask)
        if len(idx) == 0:
            return None
        pick = int(idx[rng.integers(len(idx))])
        x, y = ctx.lattice.xy_um[pick]
        hold = ctx.profile.default_hold_s
        block = make_block(ctx, x, y, f.seed_g, hold, "global")
        cost = float(block_costs_s(ctx, ctx.lattice.xy_um[[pick]], f.seed_g, hold, "global")[0])
        return Decision(
            block=block,
            policy=self.name,
            acquisition=float("nan"),
            score=float("nan"),
            predicted_cost_s=cost,
            reason=f"seed grid {ctx.blocks_done + 1} of {f.n_seed_blocks} at a random centre",
            phase="seed",
            hold_mode=f"fixed {hold:g} s",
        )

    # -- scoring: σ-based (the paper) ----------------------------------------------------------
    def _score_sigma(
        self, ctx: PlanContext, kind: BlockKind, mask: np.ndarray, hold: float, acq: np.ndarray, g: np.ndarray
    ) -> _Scored:
        n = len(mask)
        cost = np.full(n, np.inf)
        score = np.full(n, -np.inf)
        if mask.any():
            idx = np.flatnonzero(mask)
            cost[idx] = block_costs_s(ctx, ctx.lattice.xy_um[idx], g[idx], hold, kind)
            score[idx] = acq[idx] / cost[idx] if self.parts.acquisition.cost_aware else acq[idx]
        return _Scored(score, acq, cost, g, hold)

    # -- scoring: integrated variance reduction (aeni-plus) --------------------------------------
    def _ivr_model(
        self, ctx: PlanContext, allowed: np.ndarray
    ) -> tuple[object, np.ndarray, np.ndarray] | None:

        pred = ctx.prediction
        if pred is None or ctx.gp is None or ctx.tested_noise_var_gpa2 is None or len(ctx.tested_xy_um) < 2:
            return None
        idx = np.flatnonzero(allowed)
        if len(idx) == 0:
            return None
        lat = ctx.lattice
        ref = reference_lattice()
        nearest = nearest_lattice(lat.uv, ref)
        mu = np.maximum(np.abs(pred.mean[nearest]), 1e-6)
        w = 1.0 / mu**2  # relative error: what MAPE counts
        u, v = ctx.calibration.to_uv(ctx.tested_xy_um[:, 0], ctx.tested_xy_um[:, 1])
        model = PosteriorCov.build(
            ctx.gp, np.column_stack([u, v]), ctx.tested_noise_var_gpa2, lat.uv[idx], ref, w
        )
        noise_sd = pred.noise_sd[idx]
        # noise variance of a g×g median at every allowed candidate, one row per g
        est = self.parts.noise.centre_estimator
        nvar = np.stack([median_noise_var(noise_sd, g * g, est) for g in range(G_MIN, G_MAX + 1)])
        nvar = nvar + ctx.gp.site_var_gpa2
        return model, idx, nvar

    def _score_ivr(
        self,
        ctx: PlanContext,
        kind: BlockKind,
        mask: np.ndarray,
        hold: float,
        model: object,
        idx: np.ndarray,
        nvar: np.ndarray,
    ) -> _Scored:

        assert isinstance(model, PosteriorCov)
        n = len(mask)
        score = np.full(n, -np.inf)
        acq = np.zeros(n)
        cost = np.full(n, np.inf)
        g_out = np.full(n, self.design.fixed_g, dtype=int)
        sub = mask[idx]
        if sub.any():
            j = np.flatnonzero(sub)
            xy = ctx.lattice.xy_um[idx[j]]
            g_choices = range(G_MIN, G_MAX + 1) if self.design.adaptive_grid else [self.design.fixed_g]
            best = np.full(len(j), -np.inf)
            for g in g_choices:
                gain = model.gain(nvar[g - G_MIN])[j]
                c = block_costs_s(ctx, xy, g, hold, kind)
                rate = gain / c
                better = rate > best
                best = np.where(better, rate, best)
                acq[idx[j]] = np.where(better, gain, acq[idx[j]])
                cost[idx[j]] = np.where(better, c, cost[idx[j]])
                g_out[idx[j]] = np.where(better, g, g_out[idx[j]])
            score[idx[j]] = best
        return _Scored(score, acq, cost, g_out, hold)

    def _program_rates(
        self,
        ctx: PlanContext,
        glob: _Scored,
        model: object,
        idx: np.ndarray,
        nvar: np.ndarray,
        allowed: np.ndarray,
        hold: float,
    ) -> np.ndarray:
        """Average gain per second of the best few programs: the global grid plus the sub-grids it enables,
        chosen greedily with the posterior conditioned on the earlier picks (a jump's value is its program)."""

        assert isinstance(model, PosteriorCov)
        f = self.design
        rates = glob.score.copy()
        limit = ctx.settings.local_center_limit if f.local_limit is None else f.local_limit
        if self._exploring(ctx):  # the program being priced is an exploratory one
            limit = min(limit, f.exploratory_local_limit)
        if limit <= 0:
            return rates
        order = np.argsort(-glob.score)[:PROGRAM_CANDIDATES]
        order = order[np.isfinite(glob.score[order])]
        pos_in_idx = np.full(len(allowed), -1)
        pos_in_idx[idx] = np.arange(len(idx))
        half = (G_MAX - 1) / 2 * ctx.pitch_um
        g_choices = list(range(G_MIN, G_MAX + 1)) if f.adaptive_grid else [f.fixed_g]
        xy_idx = ctx.lattice.xy_um[idx]
        for c in order:
            centre = (float(ctx.lattice.xy_um[c, 0]), float(ctx.lattice.xy_um[c, 1]))
            # every sub-grid the program could reach: in the band, within limit hops of the centre
            near = reachable_mask(ctx, centre, centre, half, f.local_hop_um * limit, idx=idx)
            cols = np.flatnonzero(near)
            if len(cols) > PROGRAM_SUBSET:
                # thin a large band evenly: the plan needs the shape of the gain, not every lattice point
                cols = cols[np.linspace(0, len(cols) - 1, PROGRAM_SUBSET).astype(int)]
            cols = np.union1d(cols, [pos_in_idx[c]])
            here = int(np.flatnonzero(cols == pos_in_idx[c])[0])
            g0 = int(glob.g[c])
            m = model.subset(cols).condition_on(here, float(nvar[g0 - G_MIN][pos_in_idx[c]]))
            sub_xy = xy_idx[cols]
            sub_nvar = nvar[:, cols]
            free = np.hypot(*(sub_xy - np.array(centre)).T) > 2 * ctx.r_excl_um
            total_gain, total_cost = float(glob.acq[c]), float(glob.cost[c])
            best_rate = total_gain / total_cost
            pos = centre
            for _ in range(limit):
                reach = free & reachable_mask(ctx, centre, pos, half, f.local_hop_um, idx=idx[cols])
                if not reach.any():
                    break
                j = np.flatnonzero(reach)
                step_best, step = -np.inf, (-1, 0, 0.0, 0.0)
                for g in g_choices:
                    gain = m.gain(sub_nvar[g - G_MIN])[j]
                    cost = block_costs_s(ctx, sub_xy[j], g, hold, "local", from_um=pos)
                    k = int(np.argmax(gain / cost))
                    if gain[k] / cost[k] > step_best:
                        step_best, step = gain[k] / cost[k], (int(j[k]), g, float(gain[k]), float(cost[k]))
                jj, g, gain_k, cost_k = step
                if (total_gain + gain_k) / (total_cost + cost_k) <= best_rate:
                    break  # marginal value theorem: the program ends where its average rate peaks
                total_gain += gain_k
                total_cost += cost_k
                best_rate = total_gain / total_cost
                m = m.condition_on(jj, float(sub_nvar[g - G_MIN][jj]))
                pos = (float(sub_xy[jj, 0]), float(sub_xy[jj, 1]))
                free &= np.hypot(*(sub_xy - sub_xy[jj]).T) > 2 * ctx.r_excl_um
            rates[c] = best_rate
        return rates

    # -- the decision --------------------------------------------------------------------------
    def propose(self, ctx: PlanContext) -> Decision | None:
        f = self.design
        if ctx.blocks_done < f.n_seed_blocks or ctx.prediction is None:
            return self._seed(ctx)
        xy = ctx.lattice.xy_um
        halfwidth = (G_MAX if f.adaptive_grid else f.fixed_g) - 1
        halfwidth_um = halfwidth / 2 * ctx.pitch_um
        allowed = base_mask(ctx, halfwidth_um)
        if not allowed.any():
            return None

        ivr = None
        map_rel_err: float | None = None
        if self.parts.acquisition.kind == "ivr":
            ivr = self._ivr_model(ctx, allowed)
        if self.parts.hold.bias_aware:
            # the aim is known once the seeds have shaped a model; the exploratory programs need not hold
            # 80 s where a 5 s hold's bias is already far below it
            map_rel_err = aim_rel_error(ctx)
        hold, err, hold_mode = self.parts.hold.choose(ctx, map_rel_err, self.parts.noise.drift_correction)

        # where the program may continue, and at which hold (a running program keeps its method)
        may_stay = (
            self.parts.acquisition.cost_aware
            and f.stay
            and ctx.program_open
            and ctx.locals_in_program < self._local_limit(ctx)
        )
        prog_hold = ctx.program_hold_s if ctx.program_hold_s is not None else hold
        lmask = (
            allowed & local_mask(ctx, halfwidth_um, f.local_hop_um) if may_stay else np.zeros_like(allowed)
        )
        hold_note = ""
        if lmask.any() and prog_hold < hold:
            lmask[:] = False  # drift got worse: indents at the running program's fast hold would be biased
            hold_note = "; drift rose: a fast program cannot continue"

        if ivr is not None:
            model, idx, nvar = ivr
            glob = self._score_ivr(ctx, "global", allowed, hold, model, idx, nvar)
            loc = self._score_ivr(ctx, "local", lmask, prog_hold, model, idx, nvar)
        else:
            acq = self._acquisition(ctx)
            g = self._grid_sizes(ctx)
            glob = self._score_sigma(ctx, "global", allowed, hold, acq, g)
            loc = self._score_sigma(ctx, "local", lmask, prog_hold, acq, g)

        best_l = int(np.argmax(loc.score))
        if np.isfinite(loc.score[best_l]) and prog_hold > hold:
            saved = int(loc.g[best_l]) ** 2 * (prog_hold - hold)
            if ivr is None and saved >= self._jump_overhead_s(ctx):
                # SPEC §6.6: leave a slow program for a fast one when the hold time saved pays the jump
                loc.score[:] = -np.inf
                hold_note = f"; fast hold saves {saved:.0f} s ≥ the {self._jump_overhead_s(ctx):.0f} s jump"

        jump_rates = glob.score
        if ivr is not None and f.joint_program and f.stay:
            jump_rates = self._program_rates(ctx, glob, model, idx, nvar, allowed, hold)

        best_g = int(np.argmax(jump_rates))
        best_l = int(np.argmax(loc.score))
        jump_score = float(jump_rates[best_g])
        stay_score = float(loc.score[best_l]) if np.isfinite(loc.score[best_l]) else None
        if not np.isfinite(jump_score) and stay_score is None:
            return None
        kind: BlockKind = "local" if stay_score is not None and stay_score >= jump_score else "global"
        pick = best_l if kind == "local" else best_g

        score = np.maximum(jump_rates, loc.score)
        kinds = np.where(loc.score > jump_rates, "local", "global")
        preferred = preferred_index(ctx, xy, np.isfinite(score))
        if preferred is not None:  # a veto: the alternative listed first, as it was scored there
            pick = preferred
            kind = "local" if kinds[pick] == "local" else "global"
        chosen = loc if kind == "local" else glob
        x, y = xy[pick]
        block = make_block(ctx, x, y, int(chosen.g[pick]), chosen.hold_s, kind)
        acq_any = np.where(loc.score > jump_rates, loc.acq, glob.acq)
        cost_any = np.where(loc.score > jump_rates, loc.cost, glob.cost)
        order = np.argsort(-score, kind="stable")
        order = order[np.isfinite(score[order])]
        order = np.concatenate([[pick], order[order != pick]]).astype(int)
        alts = alternatives(ctx, order, score, acq_any, cost_any, kinds, skip=1)

        what = "IVR" if ivr is not None else "σ"
        if kind == "local":
            reason = f"stay: local {what}/cost {stay_score:.3g} ≥ jump {jump_score:.3g}"
        elif stay_score is not None:
            reason = f"jump: global {what}/cost {jump_score:.3g} > local {stay_score:.3g}"
        elif self.parts.acquisition.cost_aware:
            reason = f"jump: best {what}/cost {jump_score:.3g} (no local centre available)"
        else:
            reason = f"jump to the highest σ ({chosen.acq[pick]:.3g} GPa), cost ignored"
        if ivr is not None and f.joint_program and kind == "global":
            reason += " (jump priced with its planned sub-grids)"
        if preferred is not None:
            reason = f"after a veto, the next best listed: {kind} {what}/cost {score[pick]:.3g}"
        return Decision(
            block=block,
            policy=self.name,
            acquisition=float(chosen.acq[pick]),
            score=float(score[pick]),
            predicted_cost_s=float(chosen.cost[pick]),
            stay_score=stay_score,
            jump_score=jump_score,
            alternatives=alts,
            reason=reason + hold_note,
            phase="explore"
            if (self._in_exploratory_program(ctx) if kind == "local" else self._exploring(ctx))
            else "exploit",
            hold_mode=hold_mode if kind == "global" else f"program hold {chosen.hold_s:g} s",
            area_error_pct=err,
        )


def aim_rel_error(ctx: PlanContext) -> float | None:
    """The map precision aimed at: the operator's σ target if set, else what the 9×9 grid of 5×5
    baseline would reach on this sample (relative RMS error, from the fitted kernel and noise)."""

    pred = ctx.prediction
    if pred is None:
        return None
    ref = reference_lattice()
    near = nearest_lattice(ctx.lattice.uv, ref)
    mu = np.abs(pred.mean[near])
    if ctx.settings.sigma_target_gpa is not None:
        return float(ctx.settings.sigma_target_gpa / max(float(np.mean(mu)), 1e-6))
    if ctx.gp is None:
        return None
    axis = np.arange(1, 10) / 10.0
    du, dv = np.meshgrid(axis, axis)
    design = np.column_stack([du.ravel(), dv.ravel()])
    noise = median_noise_var(pred.noise_sd[nearest_lattice(ctx.lattice.uv, design)], 25)
    noise = noise + ctx.gp.site_var_gpa2  # the grid's medians carry the site scatter too
    return design_rel_error(ctx.gp, design, noise, ref, mu)


def nearest_lattice(lattice_uv: np.ndarray, pts_uv: np.ndarray) -> np.ndarray:
    from scipy.spatial import cKDTree

    _, nearest = cKDTree(lattice_uv).query(pts_uv)
    return np.asarray(nearest, dtype=int)

"""One plan over two fidelities: per block, a fast array or CSM indents, whichever buys more per second.

The CSM block is the design's own (``ScatteredPlanner``: where, how many, which hold). Beside it the planner
prices a few fast arrays (``FastArrays``: where, how many indents, what extent, within the profile's
``[fast]`` limits) and runs the one whose expected reduction of the CSM map's integrated relative error
variance per second is the larger (the same reference points and weights as the design's
``IntegratedVarianceReduction``, the same cost model: ``core.cost`` prices a fast array's opening, surface
find, drift settle, indents and column changes as ``core.fast_array`` does). There is no "fast map first"
rule: an array wins only where the model says its readings will teach the CSM map more per second.

What a measurement would teach is read off a ``FidelityView`` of the model:
- with fast data, the two-fidelity GP (``core.model.two_fidelity``, H_csm = ρ·H_fast + δ): a fast array only
  reduces ρ²·(the fast channel's variance); where the CSM values disagree with the fast channel (a bias that
  jumps at a phase boundary, a layer that hides a feature), δ carries the variance, which only CSM indents
  reduce, so the CSM block wins there;
- before any fast data, ``PriorFidelityView``: the CSM-only GP with the fast channel as the CSM map plus a bias
  GP of the same kernel holding ``prior_bias_share`` of its variance, read with ``prior_noise_ratio`` × the CSM
  noise (assumptions, named in ``FastArrays``; the first array's data replace them);
- with fast data whose two-fidelity map predicts the held-out CSM values worse than the CSM-only GP
  (``HeldOutView``): the fast channel misleads as the model reads it, so no array is bought, only CSM blocks,
  until the held-out values say otherwise.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Protocol

import numpy as np
from scipy.linalg import cho_factor, cho_solve

from core.fast_array import FastArray, check_fast_array, fast_block, fast_block_cost_s
from core.geometry import SafeBand, exclusion_mask
from core.model.held_out import HeldOut
from core.plan import Decision
from core.policies.variance import median_noise_var, nearest_lattice, posterior

if TYPE_CHECKING:
    from core.policies.base import PlanContext
    from core.policies.parts import PolicyParts
    from core.policies.scattered import ScatteredPlanner

# a fast cell is this many array pitches on a side (core.model.two_fidelity.CELL_SPACINGS; its bounds too):
# the planner prices an array by the cells the model will bin it into
CELL_SPACINGS = 3.0
CELL_UV_BOUNDS = (0.005, 0.1)


class FidelityView(Protocol):
    """What a measurement would teach the CSM map (y-free, every hyperparameter held), in GPa²."""

    @property
    def mode(self) -> str: ...

    def variance(self, uv: np.ndarray) -> np.ndarray:
        """The CSM map's latent variance now."""
        ...

    def variance_after_csm(self, uv: np.ndarray, sites_uv: np.ndarray, noise_var: np.ndarray) -> np.ndarray:
        """... after CSM values at ``sites_uv`` with these noise variances."""
        ...

    def variance_after_fast(self, uv: np.ndarray, cells_uv: np.ndarray, noise_var: np.ndarray) -> np.ndarray:
        """... after fast cells (medians of fast indents) at ``cells_uv`` with these noise variances."""
        ...

    def fast_noise_var(self, uv: np.ndarray) -> np.ndarray:
        """One fast indent's noise variance."""
        ...


class HeldOutView:
    """The fast channel is measured, but its map predicts held-out CSM values worse than the CSM-only GP."""

    mode = "held out"

    def __init__(self, held_out: HeldOut) -> None:
        self.held_out = held_out


@dataclass(frozen=True)
class FastArrays:
    """Which fast arrays the planner prices against the CSM block at each decision."""

    pitches_um: tuple[float, ...] = (50.0, 100.0)  # ≥ 2·r_excl apart, so CSM indents still fit between
    extent_fractions: tuple[float, ...] = (1.0, 0.5)  # of the profile's fast.max_extent_um (and the sample)
    scored: int = 4  # arrays priced exactly per decision; the others are ranked by a cheap proxy first
    # ASSUMPTIONS to check, used only before the first fast data (then the two-fidelity model's own):
    prior_noise_ratio: float = 2.5  # a fast indent's sd over a CSM indent's (SPEC §9 and issue 36: 2–3×)
    prior_bias_share: float = 0.25  # the share of the CSM map's variance the fast channel does not explain


class PriorFidelityView:
    """Before any fast data: the CSM-only GP's posterior, a fast cell reading the CSM map plus a bias GP (the
    same kernel, ``prior_bias_share`` of its variance) with ``prior_noise_ratio`` × the CSM noise."""

    mode = "prior"

    def __init__(self, ctx: PlanContext, design: FastArrays) -> None:
        gp, pred, noise = ctx.gp, ctx.prediction, ctx.tested_noise_var_gpa2
        if gp is None or pred is None or noise is None:
            raise ValueError("a prior fidelity view needs a fitted CSM model")
        u, v = ctx.calibration.to_uv(ctx.tested_xy_um[:, 0], ctx.tested_xy_um[:, 1])
        self.post = posterior(gp, np.column_stack([u, v]), noise)
        self.design = design
        self.lattice_uv = ctx.lattice.uv
        self.csm_noise_var = pred.noise_sd**2

    def variance(self, uv: np.ndarray) -> np.ndarray:
        return np.maximum(self.post.var(self.post.factor(uv)), 0.0)

    def _after(self, uv: np.ndarray, pts: np.ndarray, noise_var: np.ndarray, bias_share: float) -> np.ndarray:
        fu, fp = self.post.factor(uv), self.post.factor(pts)
        c_up = self.post.cov(uv, fu, pts, fp)
        s = self.post.cov(pts, fp, pts, fp) + np.diag(np.asarray(noise_var, dtype=float))
        if bias_share > 0:
            s = s + bias_share * self.post.kernel(pts, pts)
        s[np.diag_indices_from(s)] += 1e-10 * self.post.os
        red = np.einsum("ij,ji->i", c_up, cho_solve(cho_factor(s, lower=True), c_up.T))
        return np.maximum(self.variance(uv) - red, 0.0)

    def variance_after_csm(self, uv: np.ndarray, sites_uv: np.ndarray, noise_var: np.ndarray) -> np.ndarray:
        return self._after(uv, sites_uv, noise_var, 0.0)

    def variance_after_fast(self, uv: np.ndarray, cells_uv: np.ndarray, noise_var: np.ndarray) -> np.ndarray:
        return self._after(uv, cells_uv, noise_var, self.design.prior_bias_share)

    def fast_noise_var(self, uv: np.ndarray) -> np.ndarray:
        at = nearest_lattice(self.lattice_uv, uv)
        return np.asarray(self.design.prior_noise_ratio**2 * self.csm_noise_var[at], dtype=float)


@dataclass(frozen=True)
class PricedArray:
    array: FastArray
    keep: np.ndarray  # the sites the sample allows
    gain: float  # the drop of the CSM map's weighted error variance (the design's IVR units)
    cost_s: float

    @property
    def rate(self) -> float:
        return self.gain / self.cost_s if self.cost_s > 0 else 0.0


def array_cells(uv: np.ndarray, pitch_uv: float) -> tuple[np.ndarray, np.ndarray]:
    """The cells the model bins an array's sites into (centres, indents per cell)."""
    side = float(np.clip(CELL_SPACINGS * pitch_uv, *CELL_UV_BOUNDS))
    ij = np.floor(uv / side).astype(np.int64)
    _, inverse, counts = np.unique(ij, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.ravel()
    centres = np.zeros((len(counts), 2))
    np.add.at(centres, inverse, uv)
    return centres / counts[:, None], counts


def candidate_arrays(ctx: PlanContext, design: FastArrays) -> list[tuple[FastArray, np.ndarray]]:
    """Square arrays tiling the sample at each extent and pitch the profile allows, with their allowed sites
    (inside the sample, off its exclusions, ``r_excl`` from every earlier indent); none without a site."""
    fast = ctx.profile.fast
    if fast is None:
        return []
    x0, x1, y0, y1 = ctx.calibration.bounds_um
    out: list[tuple[FastArray, np.ndarray]] = []
    for frac in design.extent_fractions:
        # below the safety hop: a left-out site never makes two kept neighbours a hop that needs a
        # reconfiguration (which an array cannot make)
        reach = ctx.profile.reconfig_threshold_um - 1e-6
        extent = min(frac * fast.max_extent_um, x1 - x0, y1 - y0, reach)
        for pitch in design.pitches_um:
            if pitch < fast.min_pitch_um or pitch > extent:
                continue
            n = math.floor(extent / pitch + 1e-9) + 1
            side = (n - 1) * pitch
            nx = max(1, math.ceil((x1 - x0) / max(side, pitch) - 1e-9))
            ny = max(1, math.ceil((y1 - y0) / max(side, pitch) - 1e-9))
            # each tiling twice: on its lattice and shifted half a pitch, between the sites of an earlier array
            for shift in (0.0, pitch / 2.0):
                for cx, cy in itertools.product(_centres(x0, x1, side, nx), _centres(y0, y1, side, ny)):
                    array = check_fast_array(ctx.profile, FastArray(cx + shift, cy + shift, n, n, pitch))
                    sites = array.sites_um()
                    keep = (
                        ctx.sample.allowed(sites)
                        if ctx.sample is not None
                        else ctx.calibration.contains_stage(sites[:, 0], sites[:, 1])
                    )
                    # the array is one program: every site in the safe band around its centre
                    band = SafeBand(
                        ctx.calibration.plane, array.center_x_um, array.center_y_um, ctx.dz_safe_um
                    )
                    keep &= band.contains(sites[:, 0], sites[:, 1])
                    if len(ctx.indents_xy_um):
                        keep &= exclusion_mask(sites, ctx.indents_xy_um, ctx.r_excl_um)
                    if keep.any():
                        out.append((array, keep))
    return out


def _centres(lo: float, hi: float, side: float, n: int) -> list[float]:
    if n == 1:
        return [(lo + hi) / 2.0]
    return [lo + side / 2.0 + i * (hi - lo - side) / (n - 1) for i in range(n)]


class TwoFidelityPlanner:
    """The design's CSM block or a fast array, by the expected reduction of the CSM map's error per second."""

    def __init__(self, name: str, parts: PolicyParts, inner: ScatteredPlanner, design: FastArrays) -> None:
        self.name = name
        self.parts = parts
        self.inner = inner
        self.design = design

    def propose_stretch(self, ctx: PlanContext) -> list[Decision] | None:
        """A stretch is the design's CSM arrays (fast arrays are priced block by block)."""
        return self.inner.propose_stretch(ctx)

    def view(self, ctx: PlanContext) -> FidelityView | HeldOutView | None:
        if ctx.fidelity is not None:
            return ctx.fidelity
        if ctx.gp is None or ctx.prediction is None or ctx.tested_noise_var_gpa2 is None:
            return None
        return PriorFidelityView(ctx, self.design)

    def propose(self, ctx: PlanContext) -> Decision | None:
        csm = self.inner.propose(ctx)
        if ctx.profile.fast is None or ctx.prefer_xy_um is not None or ctx.prediction is None:
            return csm  # no fast mode, a veto's alternative, or no model yet: the design's own block
        if len(ctx.learnt_xy_um) < self.inner.design.space_filling_indents:
            return csm
        view = self.view(ctx)
        if view is None:
            return csm
        if isinstance(view, HeldOutView):
            return None if csm is None else _noted(csm, f"; no fast array: {view.held_out.words()}")
        ref_uv, w = self.inner.ivr.weights(ctx, ctx.prediction)
        w = w / float(np.mean(w))
        var_now = view.variance(ref_uv)
        csm_rate = -math.inf
        if csm is not None:
            csm_rate = self.csm_gain(ctx, view, csm, ref_uv, w, var_now) / max(csm.predicted_cost_s, 1e-9)
        best = self.best_array(ctx, view, ref_uv, w, var_now)
        if best is None or best.rate <= csm_rate:
            if csm is not None and best is not None:
                csm = _noted(
                    csm,
                    f"; two-fidelity IVR/cost {csm_rate:.3g}/s ≥ the best fast array's {best.rate:.3g}/s ({view.mode})",
                )
            return csm
        block = fast_block(ctx.block_id, best.array, best.keep)
        a = best.array
        extent = a.extent_um[0]
        versus = f"CSM {csm_rate:.3g}/s" if csm is not None else "no CSM block left"
        return Decision(
            block=block,
            policy=self.name,
            acquisition=best.gain,
            score=best.rate,
            predicted_cost_s=best.cost_s,
            alternatives=() if csm is None else csm.alternatives,
            reason=(
                f"fast array: {block.n_indents} indents, {extent:g} µm at {a.pitch_um:g} µm pitch, "
                f"IVR/cost {best.rate:.3g}/s > {versus} ({view.mode})"
            ),
            phase="fast",
            hold_mode="fast array",
        )

    def csm_gain(
        self,
        ctx: PlanContext,
        view: FidelityView,
        decision: Decision,
        ref_uv: np.ndarray,
        w: np.ndarray,
        var_now: np.ndarray,
    ) -> float:
        """The CSM block's reduction of the weighted error variance under the view."""
        assert ctx.prediction is not None
        xy = np.array([(s.x_um, s.y_um) for s in decision.block.indents])
        u, v = ctx.calibration.to_uv(xy[:, 0], xy[:, 1])
        sites = np.column_stack([u, v])
        at = nearest_lattice(ctx.lattice.uv, sites)
        site_var = ctx.gp.site_var_gpa2 if ctx.gp is not None else 0.0
        noise = ctx.prediction.noise_sd[at] ** 2 + site_var
        after = view.variance_after_csm(ref_uv, sites, np.maximum(noise, 1e-12))
        return float(np.mean(w * (var_now - after)))

    def best_array(
        self, ctx: PlanContext, view: FidelityView, ref_uv: np.ndarray, w: np.ndarray, var_now: np.ndarray
    ) -> PricedArray | None:
        """The candidate array of the largest gain per second (the ``scored`` best by a proxy priced exactly)."""
        cands = candidate_arrays(ctx, self.design)
        if not cands:
            return None
        ref_xy = np.column_stack(ctx.calibration.to_stage(ref_uv[:, 0], ref_uv[:, 1]))
        proxies: list[tuple[float, int, float]] = []
        for k, (array, keep) in enumerate(cands):
            block = fast_block(ctx.block_id, array, keep)
            cost = fast_block_cost_s(ctx.profile, block, ctx.position_um, ctx.program_open)
            ex, ey = array.extent_um
            inside = (np.abs(ref_xy[:, 0] - array.center_x_um) <= ex / 2 + array.pitch_um) & (
                np.abs(ref_xy[:, 1] - array.center_y_um) <= ey / 2 + array.pitch_um
            )
            proxies.append((float(np.sum(w * var_now * inside)) * keep.mean() / cost, k, cost))
        proxies.sort(key=lambda t: -t[0])
        best: PricedArray | None = None
        for _, k, cost in proxies[: self.design.scored]:
            array, keep = cands[k]
            sites = array.sites_um()[keep]
            u, v = ctx.calibration.to_uv(sites[:, 0], sites[:, 1])
            uv = np.column_stack([u, v])
            pu, _ = ctx.calibration.to_uv(
                np.array([0.0, array.pitch_um]) + array.center_x_um, np.full(2, array.center_y_um)
            )
            cells, counts = array_cells(uv, float(abs(pu[1] - pu[0])))
            noise = median_noise_var(np.sqrt(view.fast_noise_var(cells)), counts)
            after = view.variance_after_fast(ref_uv, cells, np.maximum(noise, 1e-12))
            priced = PricedArray(array, keep, float(np.mean(w * (var_now - after))), cost)
            if best is None or priced.rate > best.rate:
                best = priced
        return best


def _noted(decision: Decision, note: str) -> Decision:
    return replace(decision, reason=decision.reason + note)

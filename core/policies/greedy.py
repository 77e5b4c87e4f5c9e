"""Greedy batch values: what one more single indent adds given the picks already planned (y-free).

A block of scattered singles (``core.policies.scattered``) and a stretch of arrays (``core.policies.stretch``)
are planned as q-batches, greedily: each pick is the candidate of highest value, then ``take`` conditions the
value on it, so the next pick sees what the earlier ones will already have taught. ``Maximin`` is the
space-filling start (no model yet); ``GreedyIvr`` is the design's ``IntegratedVarianceReduction``
(``core.policies.acquisition``) conditioned pick by pick, over one map or the hardness and modulus maps.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from core.policies.variance import PosteriorCov

if TYPE_CHECKING:
    from core.policies.acquisition import IntegratedVarianceReduction
    from core.policies.base import PlanContext


class GreedyValue:
    """What one more single indent at candidate j adds; ``take`` commits it so the next pick sees it.

    ``take`` rebinds its state instead of changing it in place, so ``copy.copy`` gives an independent
    branch: the stay and the jump options are each picked against the same posterior."""

    def best(self, mask: np.ndarray) -> int | None:
        raise NotImplementedError

    def gains(self) -> np.ndarray:
        raise NotImplementedError

    def take(self, j: int) -> float:
        raise NotImplementedError


class Maximin(GreedyValue):
    """Distance (in u, v) to the nearest indent the map learnt from: the greedy space-filling design."""

    def __init__(self, ctx: PlanContext, cand: np.ndarray) -> None:
        self.uv = ctx.lattice.uv[cand]
        done = ctx.learnt_xy_um
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


class GreedyIvr(GreedyValue):
    """Integrated variance reduction of the relative map error under the fitted kernel (y-free but for
    the weights, which the fitted mean sets).

    With a modulus view (``map_weights``) the value is what a pick takes off the weighted sum of the maps'
    RMS relative errors, Σ weight · (√V_before − √V_after), V a map's mean relative error variance under its
    own GP: the sum of the maps' expected relative errors, in the units the bench scores each map in (MAPE).
    Both maps are already relative, so neither is starved for being small in GPa; a unit of V counts for
    1/(2√V), so the map with the larger remaining error leads, and the lead passes as it closes. (The product
    of the Vs, Σ log V, the first version, weighs a unit of V by 1/V: it led with the map already closer, the
    modulus, and cost the hardness +5.4 % median, +92 % worst, against a hardness-only plan on the ternary.)
    The greedy picks update each V, so a map's gain shrinks as the block already covers it. A weight of 0
    drops that map; one map alone keeps its plain reduction (a monotone transform of it would rank the
    same, and the default path stays bit for bit)."""

    def __init__(self, ctx: PlanContext, cand: np.ndarray, ivr: IntegratedVarianceReduction) -> None:
        pred, gp = ctx.prediction, ctx.gp
        assert pred is not None and gp is not None and ctx.tested_noise_var_gpa2 is not None
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
            model = ivr.covariance(ctx, p, g, xy, nv, cand)
            # one indent: no estimator loss
            self.parts.append((weight, model, p.noise_sd[cand] ** 2 + g.site_var_gpa2))
            if several:
                self.remaining.append(ivr.remaining(ctx, p, g, xy, nv))

    def _gain(self) -> np.ndarray:
        if len(self.parts) == 1:
            w, model, noise_var = self.parts[0]
            gain = model.gain(noise_var)
            return gain if w == 1.0 else w * gain
        return np.asarray(
            sum(
                w * _error_reduction(model.gain(nv), v)
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


def _error_reduction(gain: np.ndarray, remaining: float) -> np.ndarray:
    """√V − √(V − gain): what a pick takes off a map's RMS relative error."""
    v = max(remaining, 1e-300)
    left = 1.0 - np.minimum(gain / v, 1.0 - _MIN_LEFT)
    return np.asarray(np.sqrt(v) * (1.0 - np.sqrt(left)), dtype=float)

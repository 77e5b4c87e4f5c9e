"""Acquisition objects: what a candidate is worth, read off the model's posterior (BoTorch's separation).

The surrogate gives a posterior (``PlanContext.prediction``: mean, epistemic and noise sd on the lattice;
``PlanContext.gp``: the fitted kernel, for covariances). An acquisition scores candidates from it; a block
design (``core.policies.planner``, ``core.policies.scattered``) decides what a block is and asks the
acquisition what it is worth. Cost-awareness and the edge penalty are wrappers over an acquisition, as
BoTorch's ``InverseCostWeightedUtility`` wraps a utility, not flags read in if-chains:

- marginal acquisitions, one value per lattice candidate: ``UncertaintyExploration`` (UE = σ, the paper),
  ``UpperConfidenceBound``, ``ExpectedImprovement``; ``EdgePenalised`` multiplies one by the operator's edge
  penalty (SPEC §6.5);
- ``IntegratedVarianceReduction``: the drop in the map's integrated relative error variance that a planned
  measurement brings (y-free), on a ``ReferencePoints`` set; it hands the block design a ``PosteriorCov``
  that it conditions greedily on its own picks;
- ``CostWeighted``: an acquisition per second of instrument time (the block time the candidate implies from
  the current stage position). Only a cost-weighted acquisition can compare staying in a program with a
  jump, so only it lets a design stay.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

import numpy as np

from core.acquisition import ei, ucb, ue
from core.geometry import edge_penalty
from core.policies.bends import bend_factor, relative_curvature
from core.policies.variance import PosteriorCov, design_rel_error, nearest_lattice, reference_lattice

if TYPE_CHECKING:
    from core.geometry import CandidateLattice
    from core.model import Prediction
    from core.policies.base import GPSummary, PlanContext

FULL_WEIGHT_REL_SLOPE = 2.0  # a relative slope (per side of the area) that gets the full structure weight


class Acquisition(Protocol):
    """What a block design asks: the value of each lattice candidate, and its utility for a block cost."""

    @property
    def cost_weighted(self) -> bool:
        """The utility is per second of instrument time (a stay and a jump are comparable)."""
        ...

    @property
    def needs_covariance(self) -> bool:
        """The acquisition reads the fitted kernel and the tested centres' noise, not only the marginals."""
        ...

    def values(self, ctx: PlanContext) -> np.ndarray:
        """One value per lattice candidate (``ctx.lattice``), higher is better."""
        ...

    def utility(self, value: np.ndarray, cost_s: np.ndarray) -> np.ndarray:
        """What a design ranks candidates by, given their values and their blocks' seconds."""
        ...


class _Marginal:
    """An acquisition of the posterior's marginals at each candidate: cost ignored."""

    cost_weighted = False
    needs_covariance = False

    def utility(self, value: np.ndarray, cost_s: np.ndarray) -> np.ndarray:
        return value

    @staticmethod
    def _prediction(ctx: PlanContext) -> Prediction:
        if ctx.prediction is None:
            raise ValueError("an acquisition needs a fitted model (ctx.prediction is None)")
        return ctx.prediction


@dataclass(frozen=True)
class UncertaintyExploration(_Marginal):
    """UE: the epistemic sd (where the map, not the indent, is uncertain; the noise sd sizes grids)."""

    def values(self, ctx: PlanContext) -> np.ndarray:
        return ue(self._prediction(ctx))


@dataclass(frozen=True)
class UpperConfidenceBound(_Marginal):
    """UCB μ + √β·σ with the operator's β, shifted positive so that a value per second ranks sensibly."""

    def values(self, ctx: PlanContext) -> np.ndarray:
        acq = ucb(self._prediction(ctx), ctx.settings.beta)
        return np.asarray(acq - float(np.min(acq)) + 1e-9, dtype=float)


@dataclass(frozen=True)
class ExpectedImprovement(_Marginal):
    """EI over the best hardness observed (the fitted maximum before any), kept above 0 for a ratio."""

    def values(self, ctx: PlanContext) -> np.ndarray:
        pred = self._prediction(ctx)
        best = ctx.best_observed_gpa if ctx.best_observed_gpa is not None else float(np.max(pred.mean))
        return np.asarray(ei(pred, best) + 1e-12, dtype=float)


@dataclass(frozen=True)
class EdgePenalised:
    """An acquisition damped near the sample's edges by the operator's edge penalty (SPEC §6.5)."""

    base: Acquisition

    @property
    def cost_weighted(self) -> bool:
        return self.base.cost_weighted

    @property
    def needs_covariance(self) -> bool:
        return self.base.needs_covariance

    def values(self, ctx: PlanContext) -> np.ndarray:
        acq = self.base.values(ctx)
        if ctx.settings.edge_penalty > 0:
            acq = acq * edge_penalty(ctx.lattice.uv, strength=ctx.settings.edge_penalty)
        return np.asarray(acq, dtype=float)

    def utility(self, value: np.ndarray, cost_s: np.ndarray) -> np.ndarray:
        return self.base.utility(value, cost_s)


@dataclass(frozen=True)
class CostWeighted:
    """An acquisition per second of the block it implies (SPEC §6: acquisition / cost)."""

    base: Acquisition
    cost_weighted = True

    @property
    def needs_covariance(self) -> bool:
        return self.base.needs_covariance

    def values(self, ctx: PlanContext) -> np.ndarray:
        return self.base.values(ctx)

    def utility(self, value: np.ndarray, cost_s: np.ndarray) -> np.ndarray:
        return np.asarray(value / cost_s, dtype=float)


# -- integrated variance reduction ---------------------------------------------------------------------


class ReferencePoints(Protocol):
    """Where the map's error is integrated: points in (u, v), and the lattice index nearest each."""

    def points(self, lattice: CandidateLattice) -> tuple[np.ndarray, np.ndarray]: ...


@dataclass(frozen=True)
class CellCentres:
    """The cell centres of an n×n partition of the unit square (the replicate-grid planner's)."""

    n: int = 12

    def points(self, lattice: CandidateLattice) -> tuple[np.ndarray, np.ndarray]:
        ref = reference_lattice(self.n)
        return ref, nearest_lattice(lattice.uv, ref)


@dataclass(frozen=True)
class LatticeSubset:
    """About n×n of the candidate lattice's own points, evenly strided (the scattered singles')."""

    n: int = 24

    def points(self, lattice: CandidateLattice) -> tuple[np.ndarray, np.ndarray]:
        side = lattice.n
        step = max(1, side // self.n)
        rows = np.arange(step // 2, side, step)
        idx = (rows[:, None] * side + rows[None, :]).ravel()
        return lattice.uv[idx], idx


@dataclass(frozen=True)
class IntegratedVarianceReduction:
    """IVR of the relative map error (what MAPE counts) under the fitted kernel (``core.policies.variance``):
    the reference points weigh 1/μ², times up to ``1 + structure_weight`` where the fitted mean is steep and
    ``bend_factor(κ, bend_weight)`` where it bends (``core.policies.bends``: the bias a stationary GP leaves
    there). ``values`` is the gain of one noiseless-but-for-the-site-scatter measurement; designs that plan
    several measurements condition the ``covariance`` on their picks."""

    reference: ReferencePoints = field(default_factory=CellCentres)
    structure_weight: float = 0.0
    bend_weight: float = 0.0
    cost_weighted = False
    needs_covariance = True

    def weights(self, ctx: PlanContext, pred: Prediction) -> tuple[np.ndarray, np.ndarray]:
        """The reference points (u, v) and their weights under the fitted mean ``pred`` (on the lattice)."""
        lat = ctx.lattice
        ref_uv, at = self.reference.points(lat)
        mu = np.maximum(np.abs(pred.mean[at]), 1e-6)
        w = 1.0 / mu**2
        if self.structure_weight > 0:
            # relative slope of the fitted mean per unit of (u, v): 0 on a flat map, ≥ 1 where it bends hard
            grad_v, grad_u = np.gradient(pred.mean.reshape(lat.n, lat.n), lat.pitch_uv[0])
            rel = np.hypot(grad_u, grad_v).ravel()[at] / mu
            w = w * (1.0 + self.structure_weight * np.minimum(rel / FULL_WEIGHT_REL_SLOPE, 1.0))
        if self.bend_weight > 0:
            kappa = relative_curvature(pred.mean.reshape(lat.n, lat.n), lat.pitch_uv).ravel()[at]
            w = w * bend_factor(kappa, self.bend_weight)
        return ref_uv, w

    def covariance(
        self,
        ctx: PlanContext,
        pred: Prediction,
        gp: GPSummary,
        tested_xy_um: np.ndarray,
        tested_noise_var_gpa2: np.ndarray,
        cand: np.ndarray,
    ) -> PosteriorCov:
        """The weighted posterior covariance between the candidates ``cand`` (lattice indices) and the
        reference points, given the tested centres and their noise: ``gain(noise_var)`` is the IVR."""
        ref_uv, w = self.weights(ctx, pred)
        return PosteriorCov.build(
            gp, self._train_uv(ctx, tested_xy_um), tested_noise_var_gpa2, ctx.lattice.uv[cand], ref_uv, w
        )

    def remaining(
        self,
        ctx: PlanContext,
        pred: Prediction,
        gp: GPSummary,
        tested_xy_um: np.ndarray,
        tested_noise_var_gpa2: np.ndarray,
    ) -> float:
        """The map's weighted error variance now, in the gains' units (GPa², weights normalised): what its
        gains use up. mean(var·w) over the reference points (design_rel_error's mean(var/μ²), μ = 1/√w)."""
        ref_uv, w = self.weights(ctx, pred)
        train_uv = self._train_uv(ctx, tested_xy_um)
        rms = design_rel_error(gp, train_uv, tested_noise_var_gpa2, ref_uv, 1.0 / np.sqrt(w))
        return rms**2 / float(np.mean(w))

    def values(self, ctx: PlanContext) -> np.ndarray:
        pred, gp = ctx.prediction, ctx.gp
        if pred is None or gp is None or ctx.tested_noise_var_gpa2 is None:
            raise ValueError("integrated variance reduction needs a fitted model and its tested centres")
        cand = np.arange(ctx.lattice.n * ctx.lattice.n)
        model = self.covariance(ctx, pred, gp, ctx.tested_xy_um, ctx.tested_noise_var_gpa2, cand)
        return model.gain(pred.noise_sd**2 + gp.site_var_gpa2)

    def utility(self, value: np.ndarray, cost_s: np.ndarray) -> np.ndarray:
        return value

    @staticmethod
    def _train_uv(ctx: PlanContext, tested_xy_um: np.ndarray) -> np.ndarray:
        u, v = ctx.calibration.to_uv(tested_xy_um[:, 0], tested_xy_um[:, 1])
        return np.column_stack([u, v])


def variance_reduction(acquisition: Acquisition) -> IntegratedVarianceReduction | None:
    """The IVR inside a stack of wrappers, or None: a design that plans picks jointly needs its covariance."""
    inner: object = acquisition
    while isinstance(inner, CostWeighted | EdgePenalised):
        inner = inner.base
    return inner if isinstance(inner, IntegratedVarianceReduction) else None


__all__ = [
    "Acquisition",
    "CellCentres",
    "CostWeighted",
    "EdgePenalised",
    "ExpectedImprovement",
    "IntegratedVarianceReduction",
    "LatticeSubset",
    "ReferencePoints",
    "UncertaintyExploration",
    "UpperConfidenceBound",
    "variance_reduction",
]

"""The noise model: per-indent noise variance σ²(x) from the within-grid spreads.

With three or more spreads, a GP on their unbiased log sample variances (each with its known sampling
variance); with fewer, their pooled variance; with none (single indents), a homoskedastic variance the mean
GP learns. The mean GP's fixed per-centre noise is eff·σ²(x_i)/n_i (SPEC §5).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from core.model.hyper import NoiseKind
from core.model.kernels import DTYPE, MIN_NOISE_STD
from core.model.observations import Observations, log_spread_targets, spread_mask, standardise
from core.model.problem import Predictor

MIN_SPREADS_FOR_GP = 3  # fewer spreads than this: pooled constant variance instead of a noise GP


def noise_kind_for(obs: Observations, heteroskedastic: bool) -> NoiseKind:
    n_spreads = int(np.sum(spread_mask(obs)))
    if not heteroskedastic or n_spreads == 0:
        return "learned"
    return "gp" if n_spreads >= MIN_SPREADS_FOR_GP else "pooled"


@dataclass(frozen=True)
class NoiseData:
    """The noise GP's data: standardised log-variance targets and their (standardised) sampling variances."""

    x: torch.Tensor
    target: torch.Tensor
    target_var: torch.Tensor
    loc: float
    scale: float


def noise_data(obs: Observations) -> NoiseData:
    mask = spread_mask(obs)
    assert obs.spread_dof is not None
    target, tvar = log_spread_targets(obs.spread_var_gpa2[mask], obs.spread_dof[mask])
    loc, scale = standardise(target)
    x = torch.as_tensor(obs.uv[mask], dtype=DTYPE)
    t = torch.as_tensor((target - loc) / scale, dtype=DTYPE)
    v = torch.as_tensor(np.maximum(tvar / scale**2, MIN_NOISE_STD), dtype=DTYPE)
    return NoiseData(x, t, v, loc, scale)


@dataclass(frozen=True)
class NoiseField:
    """σ²(x) in GPa²: the noise GP's log-variance mean, or one constant (pooled or learned)."""

    gp: Predictor | None
    loc: float = 0.0
    scale: float = 1.0
    constant_var_gpa2: float = 1.0

    def var_at(self, xs: torch.Tensor) -> torch.Tensor:
        if self.gp is not None:
            return torch.exp(self.gp.mean_f32(xs) * self.scale + self.loc)
        return torch.full((xs.shape[0],), self.constant_var_gpa2, dtype=DTYPE)

    @property
    def lengthscales_uv(self) -> tuple[float, float] | None:
        if self.gp is None:
            return None
        nl = self.gp.lengthscale
        return (float(nl[0]), float(nl[1]))

"""One GP's data as its likelihood sees it, and what a conditioned GP offers prediction.

The exact GP (``core.model.exact``) and the inducing-point GP (``core.model.ski``) both take a
``Problem`` and give a ``Predictor``; the fitting, the noise model and the guard do not know which.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import torch

from core.model.kernels import MIN_NOISE_STD, KernelName, Unpacked


@dataclass(frozen=True, eq=False)
class Problem:
    """Inputs, standardised targets and the noise of one GP (mean or noise GP), in standardised units."""

    kernel: KernelName
    floor_uv: float
    with_prior: bool
    x: torch.Tensor  # (n, 2) in the unit square
    y: torch.Tensor  # (n,)
    noise_fixed: torch.Tensor | None  # per-point noise, or None when it is learned
    noise_scale: torch.Tensor  # per-point multiplier of the learned noise variance
    nugget: bool = False  # fixed noise plus one learned variance shared by every point (site-to-site scatter)

    @property
    def n(self) -> int:
        return int(self.y.shape[0])

    @property
    def learn_noise(self) -> bool:
        return self.noise_fixed is None or self.nugget

    def noise(self, u: Unpacked) -> torch.Tensor:
        if self.noise_fixed is not None:
            if not self.nugget:
                return self.noise_fixed
            assert u.noise_var is not None
            return self.noise_fixed + u.noise_var
        assert u.noise_var is not None
        return (self.noise_scale * u.noise_var).clamp_min(MIN_NOISE_STD)

    # -- what each model provides ------------------------------------------------------------------

    def objective(self, theta: torch.Tensor) -> float:
        """−(log marginal likelihood (or its bound) + log prior)/n: what the fit minimises."""
        raise NotImplementedError

    def loss(self, theta: torch.Tensor) -> tuple[torch.Tensor, float]:
        """(a tensor whose gradient w.r.t. ``theta`` is the objective's, the objective's value)."""
        raise NotImplementedError

    def condition(self, theta: torch.Tensor) -> Predictor:
        raise NotImplementedError


class Predictor(Protocol):
    """A GP conditioned on its data, in standardised units."""

    outputscale: float
    constant: float
    lengthscale: torch.Tensor

    def mean(self, xs: torch.Tensor) -> torch.Tensor: ...

    def mean_f32(self, xs: torch.Tensor) -> torch.Tensor: ...

    def mean_var(self, xs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]: ...

"""Kernel math: the ARD Matérn-5/2 / RBF kernels in closed form, their parameters, and gpytorch's model of record.

The closed forms are the hot paths (checked against gpytorch in the tests); ``GPModel`` is the same GP as a
gpytorch ``ExactGP`` with ``FixedNoiseGaussianLikelihood`` (constraints and prior are gpytorch's), the
reference the tests compare with.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import gpytorch
import torch
from gpytorch.constraints import GreaterThan
from gpytorch.distributions import MultivariateNormal
from gpytorch.kernels import MaternKernel, RBFKernel, ScaleKernel
from gpytorch.likelihoods import FixedNoiseGaussianLikelihood
from gpytorch.means import ConstantMean
from gpytorch.priors import GammaPrior

KernelName = Literal["matern52", "rbf"]
DTYPE = torch.float64
MIN_NOISE_STD = 1e-8  # numerical floor on a point's noise, in standardised units
OUTPUTSCALE_FLOOR = 1e-6
NOISE_VAR_FLOOR = 1e-6
PRIOR_CONCENTRATION, PRIOR_RATE = 3.0, 6.0  # weak Gamma prior on length-scales, mode ≈ 1/3 of the side


def lengthscale_prior() -> GammaPrior:
    """A fresh float64 prior per use: a prior registered in a model is converted in place by ``model.to``."""
    return GammaPrior(torch.tensor(PRIOR_CONCENTRATION, dtype=DTYPE), torch.tensor(PRIOR_RATE, dtype=DTYPE))


PRIOR = lengthscale_prior()  # the objective's own copy, never registered in a model


class GPModel(gpytorch.models.ExactGP):
    """The GP of record: constant mean, scaled ARD kernel, per-point fixed noise (gpytorch's own classes)."""

    def __init__(
        self, x: torch.Tensor, y: torch.Tensor, kernel: KernelName, floor_uv: float, with_prior: bool
    ) -> None:
        likelihood = FixedNoiseGaussianLikelihood(
            noise=torch.full_like(y, 1e-4), learn_additional_noise=False
        )
        super().__init__(x, y, likelihood)
        self.mean_module = ConstantMean()
        prior = lengthscale_prior() if with_prior else None
        base: gpytorch.kernels.Kernel
        if kernel == "matern52":
            base = MaternKernel(
                nu=2.5, ard_num_dims=2, lengthscale_constraint=GreaterThan(floor_uv), lengthscale_prior=prior
            )
        else:
            base = RBFKernel(
                ard_num_dims=2, lengthscale_constraint=GreaterThan(floor_uv), lengthscale_prior=prior
            )
        self.covar_module = ScaleKernel(base, outputscale_constraint=GreaterThan(OUTPUTSCALE_FLOOR))
        self.to(DTYPE)

    def forward(self, x: torch.Tensor) -> MultivariateNormal:
        return MultivariateNormal(self.mean_module(x), self.covar_module(x))

    def load_theta(self, theta: torch.Tensor) -> None:
        """Raw vector [constant, outputscale, ℓu, ℓv, ...] into gpytorch's raw parameters."""
        with torch.no_grad():
            self.mean_module.raw_constant.copy_(theta[0])
            self.covar_module.raw_outputscale.copy_(theta[1])
            self.covar_module.base_kernel.raw_lengthscale.copy_(theta[2:4].reshape(1, 2))


def pair_sq_diffs(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Squared coordinate differences between training points, per axis (exact: no cancellation)."""
    d0 = (x[:, 0:1] - x[:, 0]).square_()
    d1 = (x[:, 1:2] - x[:, 1]).square_()
    return d0, d1


def unit_kernel(kernel: KernelName, r2: torch.Tensor) -> torch.Tensor:
    """k(r²) with unit outputscale from the squared scaled distance (in place on ``r2``)."""
    if kernel == "rbf":
        return r2.mul_(-0.5).exp_()
    r = r2.mul(5.0).sqrt_()
    e = torch.neg(r).exp_()
    return r2.mul_(5.0 / 3.0).add_(r).add_(1.0).mul_(e)


def cross_kernel(
    kernel: KernelName, xs: torch.Tensor, x: torch.Tensor, lengthscale: torch.Tensor, outputscale: float
) -> torch.Tensor:
    """outputscale · k(xs, x) for a chunk of candidates: one GEMM for the distances, the rest in place.

    The kernel's constant (√5 for Matérn-5/2, 1/√2 for RBF) is folded into the scaling, to save passes over
    the (chunk × n) matrix, which is what the prediction time is made of.
    """
    centre = x.mean(dim=0)
    scale = (math.sqrt(5.0) if kernel == "matern52" else math.sqrt(0.5)) / lengthscale
    a = (xs - centre) * scale
    b = (x - centre) * scale
    s2 = torch.addmm((b * b).sum(dim=1).unsqueeze(0), a, b.T, alpha=-2.0)
    s2.add_((a * a).sum(dim=1).unsqueeze(1)).clamp_min_(0.0)
    if kernel == "rbf":
        return s2.neg_().exp_().mul_(outputscale)  # exp(−r²/2)
    s = s2.sqrt()  # √5·r
    k = s2.div_(3.0).add_(s).add_(1.0)  # 1 + √5r + 5r²/3
    return k.mul_(s.neg_().exp_()).mul_(outputscale)


@dataclass(frozen=True)
class Unpacked:
    constant: torch.Tensor
    outputscale: torch.Tensor
    lengthscale: torch.Tensor  # (2,)
    noise_var: torch.Tensor | None  # learned homoskedastic per-indent variance (standardised), or None


def unpack(theta: torch.Tensor, floor_uv: float, learn_noise: bool) -> Unpacked:
    """Raw vector [constant, outputscale, ℓu, ℓv(, noise)] → constrained values, as gpytorch's GreaterThan does."""
    sp = torch.nn.functional.softplus
    return Unpacked(
        constant=theta[0],
        outputscale=sp(theta[1]) + OUTPUTSCALE_FLOOR,
        lengthscale=sp(theta[2:4]) + floor_uv,
        noise_var=sp(theta[4]) + NOISE_VAR_FLOOR if learn_noise else None,
    )


def inv_softplus(value: float) -> float:
    return value + math.log(-math.expm1(-value))


def lengthscales_of(raw: Sequence[float], floor_uv: float) -> tuple[float, float]:
    ls = torch.nn.functional.softplus(torch.tensor(list(raw[2:4]), dtype=DTYPE)) + floor_uv
    return (float(ls[0]), float(ls[1]))

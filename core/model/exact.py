"""The exact GP: its marginal likelihood with the analytic gradient, and the GP conditioned on its data.

Closed-form torch on the Cholesky factor (checked against gpytorch in the tests): the gradient is
½ Σ (ααᵀ − K⁻¹) ∘ ∂K/∂θ with no autograd through the Cholesky, and prediction forms only the diagonal of
the predictive covariance (gpytorch's default forms the joint covariance of all 10,000 candidates, about
10 s here). Cost grows as n³ in the fit and n² per candidate: the interpolated GP (``core.model.ski``)
takes over for large designs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch

from core.model.kernels import (
    DTYPE,
    PRIOR,
    GPModel,
    KernelName,
    Unpacked,
    cross_kernel,
    pair_sq_diffs,
    unit_kernel,
    unpack,
)
from core.model.problem import Problem


@dataclass(frozen=True, eq=False)
class ExactProblem(Problem):
    """The exact GP's problem: the pairwise squared differences are computed once per data set."""

    def __post_init__(self) -> None:
        d0, d1 = pair_sq_diffs(self.x)
        object.__setattr__(self, "d0", d0)
        object.__setattr__(self, "d1", d1)

    d0: torch.Tensor = field(init=False, repr=False)
    d1: torch.Tensor = field(init=False, repr=False)

    def objective(self, theta: torch.Tensor) -> float:
        return objective(self, theta)

    def loss(self, theta: torch.Tensor) -> tuple[torch.Tensor, float]:
        """The matrix work is closed form; autograd only carries the gradient through the constraint
        transforms and the prior."""
        u = unpack(theta, self.floor_uv, self.learn_noise)
        with torch.no_grad():
            mll, g = mll_and_grads(self, u)
        values = [u.constant, u.outputscale, u.lengthscale[0], u.lengthscale[1]]
        if u.noise_var is not None:
            values.append(u.noise_var)
        prior = log_prior(self, u)
        surrogate = -(torch.stack(values) @ g + prior) / self.n
        return surrogate, -(mll + float(prior.detach())) / self.n

    def condition(self, theta: torch.Tensor) -> Conditioned:
        return condition(self, theta)


def mll_and_grads(p: ExactProblem, u: Unpacked) -> tuple[float, torch.Tensor]:
    """Exact log marginal likelihood and its gradient w.r.t. the constrained values (no autograd):
    ∂/∂θ = ½ Σ (ααᵀ − K⁻¹) ∘ ∂K/∂θ, with α = K⁻¹(y − c)."""
    n = p.y.shape[0]
    ls = u.lengthscale.detach()
    os = float(u.outputscale.detach())
    q0 = p.d0 / float(ls[0]) ** 2
    q1 = p.d1 / float(ls[1]) ** 2
    r2 = q0 + q1
    if p.kernel == "rbf":
        k0 = torch.exp(-0.5 * r2)
        dk_dr2 = -0.5 * k0  # ∂k/∂(r²)
    else:
        r = torch.sqrt(5.0 * r2)
        e = torch.exp(-r)
        k0 = (1.0 + r + (5.0 / 3.0) * r2) * e
        dk_dr2 = -(5.0 / 6.0) * (1.0 + r) * e
    noise = p.noise(u)
    k = os * k0
    k.diagonal().add_(noise)
    chol, info = torch.linalg.cholesky_ex(k)
    if int(info) != 0:
        k.diagonal().add_(1e-6 * float(k.diagonal().mean()))
        chol = torch.linalg.cholesky(k)
    resid = (p.y - u.constant.detach()).unsqueeze(-1)
    alpha = torch.cholesky_solve(resid, chol)
    mll = float(-0.5 * (resid * alpha).sum() - chol.diagonal().log().sum()) - 0.5 * n * math.log(2 * math.pi)
    w = torch.cholesky_inverse(chol)
    w.neg_().addmm_(alpha, alpha.T)  # ααᵀ − K⁻¹
    wd = w * dk_dr2
    grads = [
        float(alpha.sum()),
        0.5 * float((w * k0).sum()),
        # ∂(r²)/∂ℓ_d = −2 q_d / ℓ_d
        -os * float((wd * q0).sum()) / float(ls[0]),
        -os * float((wd * q1).sum()) / float(ls[1]),
    ]
    if p.nugget and p.noise_fixed is not None:
        grads.append(0.5 * float(w.diagonal().sum()))
    elif p.learn_noise:
        grads.append(0.5 * float((w.diagonal() * p.noise_scale).sum()))
    return mll, torch.tensor(grads, dtype=DTYPE)


def log_prior(p: ExactProblem, u: Unpacked) -> torch.Tensor:
    if not p.with_prior:
        return torch.zeros((), dtype=DTYPE)
    return PRIOR.log_prob(u.lengthscale).sum()


def objective(p: ExactProblem, theta: torch.Tensor) -> float:
    """−(log marginal likelihood + log prior)/n, the quantity gpytorch's ExactMarginalLogLikelihood returns."""
    with torch.no_grad():
        u = unpack(theta, p.floor_uv, p.learn_noise)
        mll, _ = mll_and_grads(p, u)
        return -(mll + float(log_prior(p, u))) / p.y.shape[0]


@dataclass
class Conditioned:
    """A GP conditioned on its data: what prediction needs, all in standardised units."""

    kernel: KernelName
    x: torch.Tensor
    lengthscale: torch.Tensor
    outputscale: float
    constant: float
    chol: torch.Tensor  # lower Cholesky factor of K + D
    alpha: torch.Tensor  # (K + D)⁻¹ (y − c)
    model: GPModel  # the same GP as a gpytorch ExactGP: the model of record and the reference path

    def __post_init__(self) -> None:
        self.chol_t = self.chol.T.contiguous()
        self._x32 = self.x.to(torch.float32)
        self._lengthscale32 = self.lengthscale.to(torch.float32)
        self._alpha32 = self.alpha.to(torch.float32)

    def cross(self, xs: torch.Tensor) -> torch.Tensor:
        return cross_kernel(self.kernel, xs, self.x, self.lengthscale, self.outputscale)

    def mean(self, xs: torch.Tensor) -> torch.Tensor:
        return self.cross(xs) @ self.alpha + self.constant

    def mean_f32(self, xs: torch.Tensor) -> torch.Tensor:
        """The posterior mean in single precision (≈ 5× faster here, mostly the exp): for the noise GP only,
        whose log-variance needs 1e-6, not 1e-15; the mean GP stays in double (its α can be large)."""
        k = cross_kernel(self.kernel, xs.to(torch.float32), self._x32, self._lengthscale32, self.outputscale)
        return (k @ self._alpha32).to(DTYPE) + self.constant

    def mean_var(self, xs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Latent mean and the diagonal of the latent covariance, kss − ‖L⁻¹k*‖²: no joint covariance."""
        ks = self.cross(xs)
        mean = ks @ self.alpha + self.constant
        # k* L⁻ᵀ with one row per candidate: a right-sided solve works on contiguous rows of the chunk
        v = torch.linalg.solve_triangular(self.chol_t, ks, upper=True, left=False)
        var = (self.outputscale - v.square_().sum(dim=1)).clamp_min_(0.0)
        return mean, var


def data_covariance(p: Problem, u: Unpacked, d0: torch.Tensor, d1: torch.Tensor) -> torch.Tensor:
    """K + D at the data: the scaled kernel from the per-axis squared differences, each point's noise added."""
    r2 = d0 / float(u.lengthscale[0]) ** 2 + d1 / float(u.lengthscale[1]) ** 2
    k = unit_kernel(p.kernel, r2).mul_(float(u.outputscale))
    k.diagonal().add_(p.noise(u))
    return k


def condition(p: ExactProblem, theta: torch.Tensor) -> Conditioned:
    with torch.no_grad():
        u = unpack(theta, p.floor_uv, p.learn_noise)
        os = float(u.outputscale)
        noise = p.noise(u)
        k = data_covariance(p, u, p.d0, p.d1)
        chol, info = torch.linalg.cholesky_ex(k)
        if int(info) != 0:
            k.diagonal().add_(1e-6 * float(k.diagonal().mean()))
            chol = torch.linalg.cholesky(k)
        constant = float(u.constant)
        alpha = torch.cholesky_solve((p.y - constant).unsqueeze(-1), chol).squeeze(-1)
        model = GPModel(p.x, p.y, p.kernel, p.floor_uv, p.with_prior)
        model.load_theta(theta)
        model.likelihood.noise = noise.clone()
    return Conditioned(p.kernel, p.x, u.lengthscale.clone(), os, constant, chol, alpha, model)

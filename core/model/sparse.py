"""The inducing-point GP for large designs: Titsias' collapsed bound with per-point (heteroskedastic) noise.

m inducing points on a fixed regular grid over the unit square (deterministic: the same data and record give
the same model, so crash-resume stays exact). With Kmm = Lm Lmᵀ, A = Lm⁻¹ Kmn D^-½ and B = I + AAᵀ = LB LBᵀ:

    log p(y) ≥ log N(y | c, Qnn + D) − ½ Σᵢ (kᵢᵢ − qᵢᵢ)/Dᵢ,   Qnn = Knm Kmm⁻¹ Kmn

(the SGPR bound; gpytorch's ``InducingPointKernel`` optimises the same quantity). Fit and conditioning cost
O(n m²), prediction O(m²) per candidate: mean k*ᵀ Lm⁻ᵀ LB⁻ᵀ c, variance k** − ‖Lm⁻¹k*‖² + ‖LB⁻¹Lm⁻¹k*‖²,
with no n × (candidates) matrix. The same raw vector, prior and constraints as the exact GP
(``core.model.kernels``), so a warm start and the collapse guard carry over when a design outgrows it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch

from core.model.kernels import DTYPE, PRIOR, KernelName, Unpacked, cross_kernel, unpack
from core.model.problem import Problem

# more centres than this: the sparse GP (benchmarks/scale.py: where it decides faster than the exact GP)
SPARSE_ABOVE = 1_000_000  # set from benchmarks/scale.py once measured
INDUCING_PER_SIDE = 24  # m = 576 inducing points, spacing 0.043 of the side (measured in benchmarks/scale.py)
JITTER = 1e-6  # relative to the outputscale, on Kmm's diagonal


def inducing_grid(per_side: int = INDUCING_PER_SIDE) -> torch.Tensor:
    c = torch.linspace(0.0, 1.0, per_side, dtype=DTYPE)
    u, v = torch.meshgrid(c, c, indexing="ij")
    return torch.stack([u.reshape(-1), v.reshape(-1)], dim=1)


def _kernel(kernel: KernelName, a: torch.Tensor, b: torch.Tensor, lengthscale: torch.Tensor) -> torch.Tensor:
    """Unit-outputscale k(a, b), differentiable in the length-scales (the exact GP's closed form is in place)."""
    diff = a.unsqueeze(1) / lengthscale - b.unsqueeze(0) / lengthscale
    r2 = diff.square().sum(dim=-1)
    if kernel == "rbf":
        return torch.exp(-0.5 * r2)
    r = torch.sqrt(5.0 * r2.clamp_min(1e-30))
    return (1.0 + r + (5.0 / 3.0) * r2) * torch.exp(-r)


@dataclass(frozen=True)
class _Factors:
    lm: torch.Tensor  # Cholesky factor of Kmm
    lb: torch.Tensor  # Cholesky factor of B = I + AAᵀ
    a: torch.Tensor  # Lm⁻¹ Kmn D^-½
    r: torch.Tensor  # D^-½ (y − c)
    noise: torch.Tensor  # D


@dataclass(frozen=True, eq=False)
class SparseProblem(Problem):
    """The sparse GP's problem: the inducing grid is fixed, nothing of size n × n is ever formed."""

    z: torch.Tensor = field(init=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "z", inducing_grid())

    def _factors(self, u: Unpacked) -> _Factors:
        os = u.outputscale
        kmm = os * _kernel(self.kernel, self.z, self.z, u.lengthscale)
        kmm = kmm + (JITTER * os) * torch.eye(self.z.shape[0], dtype=DTYPE)
        kmn = os * _kernel(self.kernel, self.z, self.x, u.lengthscale)
        noise = self.noise(u)
        lm = torch.linalg.cholesky(kmm)
        a = torch.linalg.solve_triangular(lm, kmn, upper=False) / noise.sqrt()
        b = a @ a.T + torch.eye(a.shape[0], dtype=DTYPE)
        lb = torch.linalg.cholesky(b)
        r = (self.y - u.constant) / noise.sqrt()
        return _Factors(lm, lb, a, r, noise)

    def _neg_objective(self, theta: torch.Tensor) -> torch.Tensor:
        u = unpack(theta, self.floor_uv, self.learn_noise)
        f = self._factors(u)
        c = torch.linalg.solve_triangular(f.lb, (f.a @ f.r).unsqueeze(-1), upper=False).squeeze(-1)
        logdet = f.noise.log().sum() + 2.0 * f.lb.diagonal().log().sum()
        quad = f.r.square().sum() - c.square().sum()
        trace = (u.outputscale / f.noise).sum() - f.a.square().sum()
        bound = -0.5 * (self.n * math.log(2.0 * math.pi) + logdet + quad + trace)
        prior = PRIOR.log_prob(u.lengthscale).sum() if self.with_prior else torch.zeros((), dtype=DTYPE)
        return -(bound + prior) / self.n

    def objective(self, theta: torch.Tensor) -> float:
        with torch.no_grad():
            try:
                return float(self._neg_objective(theta))
            except (RuntimeError, torch.linalg.LinAlgError):
                return math.inf

    def loss(self, theta: torch.Tensor) -> tuple[torch.Tensor, float]:
        value = self._neg_objective(theta)
        return value, float(value.detach())

    def condition(self, theta: torch.Tensor) -> SparseConditioned:
        with torch.no_grad():
            u = unpack(theta, self.floor_uv, self.learn_noise)
            f = self._factors(u)
            c = torch.linalg.solve_triangular(f.lb, (f.a @ f.r).unsqueeze(-1), upper=False).squeeze(-1)
            # mean weights on the inducing kernel: k*ᵀ Lm⁻ᵀ LB⁻ᵀ c
            w = torch.linalg.solve_triangular(f.lb.T, c.unsqueeze(-1), upper=True)
            w = torch.linalg.solve_triangular(f.lm.T, w, upper=True).squeeze(-1)
            return SparseConditioned(
                kernel=self.kernel,
                z=self.z,
                lengthscale=u.lengthscale.clone(),
                outputscale=float(u.outputscale),
                constant=float(u.constant),
                lm_t=f.lm.T.contiguous(),
                lb_t=f.lb.T.contiguous(),
                weights=w,
            )


@dataclass
class SparseConditioned:
    """The sparse GP conditioned on its data: m × m factors and m weights, whatever n was."""

    kernel: KernelName
    z: torch.Tensor
    lengthscale: torch.Tensor
    outputscale: float
    constant: float
    lm_t: torch.Tensor  # Lmᵀ
    lb_t: torch.Tensor  # LBᵀ
    weights: torch.Tensor  # Kmm⁻¹-side weights of the mean

    def cross(self, xs: torch.Tensor) -> torch.Tensor:
        return cross_kernel(self.kernel, xs, self.z, self.lengthscale, self.outputscale)

    def mean(self, xs: torch.Tensor) -> torch.Tensor:
        return self.cross(xs) @ self.weights + self.constant

    def mean_f32(self, xs: torch.Tensor) -> torch.Tensor:
        return self.mean(xs)  # m is small: double precision costs little here

    def mean_var(self, xs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Latent mean and the diagonal of the latent covariance, one row per candidate (no joint covariance)."""
        ks = self.cross(xs)
        mean = ks @ self.weights + self.constant
        v1 = torch.linalg.solve_triangular(self.lm_t, ks, upper=True, left=False)  # k* Lm⁻ᵀ
        v2 = torch.linalg.solve_triangular(self.lb_t, v1, upper=True, left=False)  # k* Lm⁻ᵀ LB⁻ᵀ
        var = (self.outputscale - v1.square().sum(dim=1) + v2.square().sum(dim=1)).clamp_min_(0.0)
        return mean, var

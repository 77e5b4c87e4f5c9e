"""The GP for large designs: structured kernel interpolation (KISS-GP) on a 2-D grid, solved exactly.

The kernel is approximated as K ≈ W Kmm Wᵀ (Wilson & Nickisch 2015), W the cubic-convolution interpolation
weights of each point onto an m-point regular grid (16 per point, as gpytorch's ``GridInterpolationKernel``).
The variance this loses at each data point, k(x, x) − wᵀ Kmm w, is added to its noise D (a diagonal
correction, as FITC makes: see ``variance_deficit``). The marginal likelihood of N(c, W Kmm Wᵀ + D) needs only
m-sized algebra (Woodbury): with S = Wᵀ D⁻¹ W (sparse, summed once per evaluation in O(256 n)),
b = Wᵀ D⁻¹ (y − c), Kmm = Lm Lmᵀ and B = I + Lmᵀ S Lm = LB LBᵀ,

    log p(y) = −½ [n log 2π + Σ log D + 2 Σ log diag LB + (y − c)ᵀ D⁻¹ (y − c) − ‖LB⁻¹ Lmᵀ b‖²].

Where gpytorch's KISS-GP solves with conjugate gradients and estimates the log-determinant with random
Lanczos probes, a grid of at most 28 × 28 (``grid_for``: its spacing follows the fitted length-scale) is small enough for dense Cholesky factors: the same value every time, so a
resumed run fits and predicts exactly as before. The grid values' posterior is N(G c, G Gᵀ) with G = Lm LB⁻ᵀ;
a candidate's latent mean and variance read 16 and 256 of its entries (the interpolated prior's, as KISS-GP's
own predictive variance; the deficit k** − w*ᵀ Kmm w* at a candidate would add ~1 % of the prior variance as if it were
independent of the data, more than the posterior variance itself on a dense design). O(m³) per fit
whatever n is, and no matrix of size n × (candidates).
Same raw vector, prior and constraints as the exact GP (``core.model.kernels``): warm starts and the
collapse guard carry over when a design outgrows the exact GP.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import torch

from core.model.kernels import DTYPE, PRIOR, KernelName, Unpacked, unpack
from core.model.problem import Problem

# more centres than this: the interpolated GP (benchmarks/scale.py: where it decides faster than the exact GP)
SKI_ABOVE = 1000
# the grid follows the fitted length-scale: cubic interpolation of a Matérn-5/2 kernel is within the exact GP's
# map error once a length-scale spans this many grid steps (edge spot, 1,000 centres, on the exact GP's own
# hyperparameters: 2.8 steps +1.5 %, 4.1 steps −1.0 %; docs/benchmarks.md)
STEPS_PER_LENGTHSCALE = 4.0
# never coarser than 20 × 20, whatever the length-scale: the ternary (length-scale ≈ 1) mapped 7–19 % worse
# than the exact GP on 12 × 12 and within 1.1 % on 20 × 20 (1,000 centres)
MIN_PER_SIDE = 20
MAX_PER_SIDE = 28  # m = 784: a fit's cost grows as m³, so shorter length-scales get fewer steps each
GRID_PER_SIDE = MIN_PER_SIDE  # the grid before any length-scale is known (a cold fit starts on it)
GRID_MARGIN_UV = 0.02  # the grid covers [−margin, 1 + margin]: indents of a centre on the edge lie inside
JITTER = 1e-6  # relative to the outputscale, on Kmm's diagonal


def _cubic(d: torch.Tensor) -> torch.Tensor:
    """Keys' cubic convolution kernel (a = −½) at distances ``d`` in grid steps: gpytorch's KISS-GP weights."""
    a = d.abs()
    near = (1.5 * a - 2.5) * a.square() + 1.0
    far = ((-0.5 * a + 2.5) * a - 4.0) * a + 2.0
    return torch.where(a <= 1.0, near, torch.where(a < 2.0, far, torch.zeros_like(a)))


@dataclass(frozen=True)
class Grid:
    """A regular per_side × per_side grid whose cubic stencils cover [−margin, 1 + margin]² (one extra
    step outside on each side, as gpytorch pads its KISS-GP grid)."""

    per_side: int = GRID_PER_SIDE
    margin: float = GRID_MARGIN_UV

    @property
    def m(self) -> int:
        return self.per_side * self.per_side

    @property
    def step(self) -> float:
        return (1.0 + 2.0 * self.margin) / (self.per_side - 3)

    @property
    def lo(self) -> float:
        return -self.margin - self.step

    def points(self) -> torch.Tensor:
        c = self.lo + self.step * torch.arange(self.per_side, dtype=DTYPE)
        u, v = torch.meshgrid(c, c, indexing="ij")
        return torch.stack([u.reshape(-1), v.reshape(-1)], dim=1)

    def weights(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Cubic interpolation: (n, 16) grid indices and (n, 16) weights; points outside are clamped in."""
        t = ((x - self.lo) / self.step).clamp(1.0, self.per_side - 2.0)
        base = t.floor().clamp_max(self.per_side - 3)  # the stencil is base − 1 … base + 2
        offsets = torch.arange(-1, 3, dtype=DTYPE)
        node = base.unsqueeze(-1) + offsets  # (n, 2, 4)
        w1 = _cubic(t.unsqueeze(-1) - node)
        i1 = node.long()
        g = self.per_side
        idx = (i1[:, 0, :, None] * g + i1[:, 1, None, :]).reshape(-1, 16)
        w = (w1[:, 0, :, None] * w1[:, 1, None, :]).reshape(-1, 16)
        return idx, w


def grid_for(lengthscales_uv: Sequence[float] | None) -> Grid:
    """The grid for these length-scales: STEPS_PER_LENGTHSCALE steps per the shorter one, within the bounds
    (deterministic in the hyperparameters: a resumed run conditions on the same grid)."""
    if lengthscales_uv is None:
        return Grid(GRID_PER_SIDE)
    steps = math.ceil((1.0 + 2.0 * GRID_MARGIN_UV) * STEPS_PER_LENGTHSCALE / min(lengthscales_uv))
    return Grid(min(max(steps + 3, MIN_PER_SIDE), MAX_PER_SIDE))


def _kernel(kernel: KernelName, a: torch.Tensor, lengthscale: torch.Tensor) -> torch.Tensor:
    """Unit-outputscale k(a, a), differentiable in the length-scales (m × m: small)."""
    s = a / lengthscale
    r2 = (s.unsqueeze(1) - s.unsqueeze(0)).square().sum(dim=-1)
    if kernel == "rbf":
        return torch.exp(-0.5 * r2)
    r = torch.sqrt(5.0 * r2.clamp_min(1e-30))
    return (1.0 + r + (5.0 / 3.0) * r2) * torch.exp(-r)


def _quad_form(mat: torch.Tensor, idx: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """wᵢᵀ M wᵢ per row from the k × k grid entries each row touches."""
    block = mat[idx.unsqueeze(2), idx.unsqueeze(1)]  # (n, k, k)
    return torch.einsum("na,nab,nb->n", w, block, w)


@dataclass(frozen=True, eq=False)
class SkiProblem(Problem):
    """The interpolated GP's problem: interpolation weights once per data set, m-sized algebra per step."""

    grid: Grid = field(default_factory=Grid)
    idx: torch.Tensor = field(init=False, repr=False)
    w: torch.Tensor = field(init=False, repr=False)
    pair_idx: torch.Tensor = field(init=False, repr=False)
    pair_w: torch.Tensor = field(init=False, repr=False)
    z: torch.Tensor = field(init=False, repr=False)

    def __post_init__(self) -> None:
        idx, w = self.grid.weights(self.x)
        m = self.grid.m
        object.__setattr__(self, "idx", idx)
        object.__setattr__(self, "w", w)
        object.__setattr__(self, "pair_idx", (idx.unsqueeze(2) * m + idx.unsqueeze(1)).reshape(-1))
        object.__setattr__(self, "pair_w", (w.unsqueeze(2) * w.unsqueeze(1)).reshape(idx.shape[0], -1))
        object.__setattr__(self, "z", self.grid.points())

    def _solve(self, u: Unpacked) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """(−2·log p(y) without the n log 2π, Lm, LB, LB⁻¹ Lmᵀ b) at the constrained values ``u``."""
        m = self.grid.m
        kmm = u.outputscale * _kernel(self.kernel, self.z, u.lengthscale)
        kmm = kmm + (JITTER * u.outputscale) * torch.eye(m, dtype=DTYPE)
        noise = self.noise(u) + self.variance_deficit(u, kmm)
        inv_d = 1.0 / noise
        s = torch.zeros(m * m, dtype=DTYPE).index_add(
            0, self.pair_idx, (self.pair_w * inv_d[:, None]).reshape(-1)
        )
        s = s.reshape(m, m)
        resid = self.y - u.constant
        b = torch.zeros(m, dtype=DTYPE).index_add(
            0, self.idx.reshape(-1), (self.w * (resid * inv_d)[:, None]).reshape(-1)
        )
        lm = torch.linalg.cholesky(kmm)
        big_b = lm.T @ s @ lm + torch.eye(m, dtype=DTYPE)
        lb = torch.linalg.cholesky(big_b)
        c = torch.linalg.solve_triangular(lb, (lm.T @ b).unsqueeze(-1), upper=False).squeeze(-1)
        logdet = noise.log().sum() + 2.0 * lb.diagonal().log().sum()
        quad = (resid.square() * inv_d).sum() - c.square().sum()
        return logdet + quad, lm, lb, c

    def variance_deficit(self, u: Unpacked, kmm: torch.Tensor) -> torch.Tensor:
        """k(xᵢ, xᵢ) − wᵢᵀ Kmm wᵢ per point: the prior variance the interpolation loses between grid points.

        Without it the likelihood sees a kernel that is smoother than the exact one at the data, and fits a
        shorter length-scale to make up for it (edge spot, 1,000 centres: 0.17 against the exact GP's 0.19,
        +5 % map error; on the exact GP's hyperparameters the interpolated map is within 0.5 %). Added to the
        per-point noise it restores the exact prior variance at every data point, as FITC does for inducing
        points (Wilson, Dann & Nickisch 2015, "Thoughts on massively scalable GPs"), at O(256 n).
        """
        lost = u.outputscale - (self.pair_w * kmm.reshape(-1)[self.pair_idx].reshape(self.n, -1)).sum(dim=1)
        return lost.clamp_min(0.0)  # cubic weights can overshoot by rounding's worth

    def _neg_objective(self, theta: torch.Tensor) -> torch.Tensor:
        u = unpack(theta, self.floor_uv, self.learn_noise)
        two_nll, _, _, _ = self._solve(u)
        mll = -0.5 * (self.n * math.log(2.0 * math.pi) + two_nll)
        prior = PRIOR.log_prob(u.lengthscale).sum() if self.with_prior else torch.zeros((), dtype=DTYPE)
        return -(mll + prior) / self.n

    def objective(self, theta: torch.Tensor) -> float:
        with torch.no_grad():
            try:
                return float(self._neg_objective(theta))
            except (RuntimeError, torch.linalg.LinAlgError):
                return math.inf

    def loss(self, theta: torch.Tensor) -> tuple[torch.Tensor, float]:
        value = self._neg_objective(theta)
        return value, float(value.detach())

    def condition(self, theta: torch.Tensor) -> SkiConditioned:
        with torch.no_grad():
            u = unpack(theta, self.floor_uv, self.learn_noise)
            _, lm, lb, c = self._solve(u)
            g = torch.linalg.solve_triangular(lb, lm.T, upper=False).T  # Lm LB⁻ᵀ
            return SkiConditioned(
                kernel=self.kernel,
                grid=self.grid,
                z=self.z,
                lengthscale=u.lengthscale.clone(),
                outputscale=float(u.outputscale),
                constant=float(u.constant),
                grid_mean=g @ c,
                grid_cov=g @ g.T,
            )


@dataclass
class SkiConditioned:
    """The interpolated GP conditioned on its data: the grid values' posterior, whatever n was."""

    kernel: KernelName
    grid: Grid
    z: torch.Tensor
    lengthscale: torch.Tensor
    outputscale: float
    constant: float
    grid_mean: torch.Tensor  # (m,) posterior mean of the latent values at the grid points
    grid_cov: torch.Tensor  # (m, m) their posterior covariance

    def mean(self, xs: torch.Tensor) -> torch.Tensor:
        idx, w = self.grid.weights(xs)
        return (w * self.grid_mean[idx]).sum(dim=1) + self.constant

    def mean_f32(self, xs: torch.Tensor) -> torch.Tensor:
        return self.mean(xs)  # 16 terms per point: no cheaper path needed

    def mean_var(self, xs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Latent mean and variance per candidate from 16 and 256 grid entries (no joint covariance)."""
        idx, w = self.grid.weights(xs)
        mean = (w * self.grid_mean[idx]).sum(dim=1) + self.constant
        var = _quad_form(self.grid_cov, idx, w).clamp_min_(0.0)
        return mean, var

"""The CSM level of the two-fidelity model: autoregressive co-kriging on the fast channel's posterior.

Kennedy & O'Hagan (Biometrika 87 (2000) 1): H_csm(x) = ρ(x)·H_fast(x) + δ(x), with ρ(x) = b₀ + b₁(u − ½) +
b₂(v − ½) + b₃·z(x) + b₄·z(x)² and δ a GP with a plane for its mean (c₀ + c₁(u − ½) + c₂(v − ½)) and an ARD
Matérn-5/2 / RBF kernel. z is the link feature: the fast channel's own reading of what sets its bias, held
as known (a posterior mean on the fast grid, standardised); the two-fidelity model gives it the fast
channel's E/H (Nix–Gao: the size effect's h* grows as (E/H)², so the CSM/fast ratio is a function of it
that a plane in x cannot follow across a library). Without it (z ≡ 0), ρ is the plane. The fast latent field enters with its whole posterior from its own GP (the
interpolated GP of ``core.model.ski``: its grid values g ~ N(μ_g, Σ_g), H_fast(x) = wₓᵀ g), so the CSM data
update it jointly with δ: the CSM values are Gaussian with

    mean  ρᵢ·wᵢᵀμ_g + c(xᵢ),    covariance  (ρρᵀ) ∘ (W Σ_g Wᵀ) + K_δ + D,

D the CSM noise (eff·σ²(x)/n per centre, from the CSM noise model). ρ, the plane and δ's kernel are fitted by
this marginal likelihood (with the project's length-scale prior): the bias is learnt, never given. The fast
channel's hyperparameters come from the fast data alone (its thousands of indents decide them; Le Gratiet &
Garnier's recursive co-kriging, Int. J. Uncertain. Quantif. 4 (2014) 365, fits each level apart in the same
way); given all hyperparameters, the posterior is the joint one, exact in the CSM data and in the fast grid.

All in the CSM data's standardised units (both channels on the CSM's location and scale, so ρ is the physical
ratio). The algebra is n_csm-sized (a Cholesky of K) plus gathers of 16 grid weights per point: a candidate's
latent mean and variance never form an (n_fast × candidates) matrix.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch

from core.model.kernels import DTYPE, OUTPUTSCALE_FLOOR, PRIOR, KernelName, cross_kernel, inv_softplus
from core.model.problem import Problem
from core.model.ski import Grid

N_RHO = 5  # b₀ b₁ b₂ (ρ's plane), b₃ b₄ (ρ's link to the feature z: z, z²)
N_THETA = 11  # ρ's five, c₀ c₁ c₂ (δ's plane), δ's raw outputscale, raw ℓu, raw ℓv
N_LINK = 2  # z and z²
JITTER_REL = 1e-8  # on K's diagonal, relative to its mean, when a Cholesky fails


def _empty() -> torch.Tensor:
    return torch.empty(0, dtype=DTYPE)


def plane_basis(x: torch.Tensor) -> torch.Tensor:
    """(n, 3): 1, u − ½, v − ½ (ρ's and δ's mean's basis)."""
    return torch.cat([torch.ones_like(x[:, :1]), x - 0.5], dim=1)


def link_at(link_grid: torch.Tensor, idx: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """(n, N_LINK): the link features at points from their values on the grid (the cubic weights)."""
    return (link_grid[idx] * w.unsqueeze(-1)).sum(dim=1)


def rho_basis(x: torch.Tensor, link: torch.Tensor) -> torch.Tensor:
    """(n, N_RHO): ρ's basis, the plane's and the link's."""
    return torch.cat([plane_basis(x), link], dim=1)


def regression_columns(rho_b: torch.Tensor, fast_mean: torch.Tensor, plane_b: torch.Tensor) -> torch.Tensor:
    """(n, N_RHO + 3): the mean ρ·f + plane as a linear model in (b, c): ρ's basis times the fast mean, the plane."""
    return torch.cat([rho_b * fast_mean.unsqueeze(1), plane_b], dim=1)


def _kernel(kernel: KernelName, a: torch.Tensor, b: torch.Tensor, ls: torch.Tensor) -> torch.Tensor:
    """Unit-outputscale k(a, b), differentiable in the length-scales."""
    r2 = torch.cdist(a / ls, b / ls).square()
    if kernel == "rbf":
        return torch.exp(-0.5 * r2)
    r = torch.sqrt(5.0 * r2.clamp_min(1e-30))
    return (1.0 + r + (5.0 / 3.0) * r2) * torch.exp(-r)


def _sparse(idx: torch.Tensor, w: torch.Tensor, m: int) -> torch.Tensor:
    """The (n, m) interpolation weights as a sparse matrix: 16 entries a row, so products with it cost 16 per
    row and column of the other factor, with no (n × 16 × ·) gather in memory."""
    rows = torch.arange(idx.shape[0]).repeat_interleave(idx.shape[1])
    return torch.sparse_coo_tensor(
        torch.stack([rows, idx.reshape(-1)]),
        w.reshape(-1),
        (idx.shape[0], m),
        check_invariants=False,  # indices from Grid.weights: always in range
    )


def interpolation_matrix(grid: Grid, x: torch.Tensor) -> torch.Tensor:
    idx, w = grid.weights(x)
    return _sparse(idx, w, grid.m)


@dataclass(frozen=True)
class CoKrigingTheta:
    """The constrained values of a raw vector."""

    rho: torch.Tensor  # (N_RHO,) b₀ … b₄
    plane: torch.Tensor  # (3,) c₀ c₁ c₂
    outputscale: torch.Tensor
    lengthscale: torch.Tensor  # (2,)


def unpack_theta(theta: torch.Tensor, floor_uv: float) -> CoKrigingTheta:
    sp = torch.nn.functional.softplus
    return CoKrigingTheta(
        rho=theta[0:N_RHO],
        plane=theta[N_RHO : N_RHO + 3],
        outputscale=sp(theta[N_RHO + 3]) + OUTPUTSCALE_FLOOR,
        lengthscale=sp(theta[N_RHO + 4 : N_THETA]) + floor_uv,
    )


def start_theta(rho0: float, outputscale: float, lengthscale: float, floor_uv: float) -> torch.Tensor:
    """A cold start: ρ = ρ₀ everywhere, a flat δ mean, δ's scale and length-scale as given."""
    raw_ls = inv_softplus(max(lengthscale - floor_uv, 1e-3))
    values = [
        rho0,
        *[0.0] * (N_RHO - 1),
        0.0,
        0.0,
        0.0,
        inv_softplus(max(outputscale - OUTPUTSCALE_FLOOR, 1e-6)),
    ]
    return torch.tensor([*values, raw_ls, raw_ls], dtype=DTYPE)


@dataclass(frozen=True, eq=False)
class CoKrigingProblem(Problem):
    """The CSM level's data: ``x``, ``y`` (standardised CSM values), ``noise_fixed`` (D), and the fast
    channel's grid posterior (standardised like y) seen from the CSM points, and ρ's link features on the
    same grid (``link_grid`` (m, N_LINK); empty: none, ρ the plane)."""

    grid: Grid = field(default_factory=Grid)
    fast_grid_mean: torch.Tensor = field(default_factory=_empty)  # (m,) μ_g
    fast_grid_cov: torch.Tensor = field(default_factory=_empty)  # (m, m) Σ_g
    link_grid: torch.Tensor = field(default_factory=_empty)  # (m, N_LINK) z, z² on the grid
    fast_mean: torch.Tensor = field(init=False, repr=False)  # (n,) Wμ_g at the CSM points
    fast_cross: torch.Tensor = field(init=False, repr=False)  # (m, n) Σ_g Wᵀ
    fast_cov: torch.Tensor = field(init=False, repr=False)  # (n, n) W Σ_g Wᵀ
    basis: torch.Tensor = field(init=False, repr=False)  # (n, 3)
    rho_basis: torch.Tensor = field(init=False, repr=False)  # (n, N_RHO)

    def __post_init__(self) -> None:
        if self.link_grid.numel() == 0:
            object.__setattr__(self, "link_grid", torch.zeros(self.grid.m, N_LINK, dtype=DTYPE))
        idx, w = self.grid.weights(self.x)
        weights = _sparse(idx, w, self.grid.m)
        cross = torch.sparse.mm(weights, self.fast_grid_cov).T  # (m, n): Σ_g is symmetric
        cov = torch.sparse.mm(weights, cross)  # (n, n)
        object.__setattr__(
            self, "fast_mean", torch.sparse.mm(weights, self.fast_grid_mean.unsqueeze(1))[:, 0]
        )
        object.__setattr__(self, "fast_cross", cross)
        object.__setattr__(self, "fast_cov", 0.5 * (cov + cov.T))
        object.__setattr__(self, "basis", plane_basis(self.x))
        object.__setattr__(self, "rho_basis", rho_basis(self.x, link_at(self.link_grid, idx, w)))

    def _moments(self, t: CoKrigingTheta) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(ρ at the points, the CSM values' mean, their covariance K)."""
        rho = self.rho_basis @ t.rho
        mean = rho * self.fast_mean + self.basis @ t.plane
        k = (rho.unsqueeze(1) * rho.unsqueeze(0)) * self.fast_cov
        k = k + t.outputscale * _kernel(self.kernel, self.x, self.x, t.lengthscale)
        assert self.noise_fixed is not None
        k = k + torch.diag(self.noise_fixed)
        return rho, mean, k

    def data_covariance(self, theta: torch.Tensor) -> torch.Tensor:
        """K: the CSM values' covariance (noise included) under ``theta``."""
        with torch.no_grad():
            return self._moments(unpack_theta(theta, self.floor_uv))[2]

    def _neg(self, theta: torch.Tensor) -> torch.Tensor:
        t = unpack_theta(theta, self.floor_uv)
        _, mean, k = self._moments(t)
        chol, info = torch.linalg.cholesky_ex(k)
        if int(info) != 0:
            k = k + JITTER_REL * float(k.diagonal().mean()) * torch.eye(self.n, dtype=DTYPE)
            chol = torch.linalg.cholesky(k)
        resid = (self.y - mean).unsqueeze(-1)
        z = torch.linalg.solve_triangular(chol, resid, upper=False)
        mll = -0.5 * z.square().sum() - chol.diagonal().log().sum() - 0.5 * self.n * math.log(2 * math.pi)
        prior = PRIOR.log_prob(t.lengthscale).sum() if self.with_prior else torch.zeros((), dtype=DTYPE)
        return -(mll + prior) / self.n

    def objective(self, theta: torch.Tensor) -> float:
        with torch.no_grad():
            try:
                value = float(self._neg(theta))
            except (RuntimeError, torch.linalg.LinAlgError):
                return math.inf
        return value if math.isfinite(value) else math.inf

    def loss(self, theta: torch.Tensor) -> tuple[torch.Tensor, float]:
        value = self._neg(theta)
        return value, float(value.detach())

    def condition(self, theta: torch.Tensor) -> CoKrigingConditioned:
        with torch.no_grad():
            t = unpack_theta(theta, self.floor_uv)
            rho, mean, k = self._moments(t)
            chol, info = torch.linalg.cholesky_ex(k)
            if int(info) != 0:
                k = k + JITTER_REL * float(k.diagonal().mean()) * torch.eye(self.n, dtype=DTYPE)
                chol = torch.linalg.cholesky(k)
            alpha = torch.cholesky_solve((self.y - mean).unsqueeze(-1), chol).squeeze(-1)
            # the mean's regression (ρ's and δ's planes, the link): its columns at the CSM points, those in use
            reg = regression_columns(self.rho_basis, self.fast_mean, self.basis)
            used = reg.abs().sum(dim=0) > 0
            z = torch.linalg.solve_triangular(chol, reg[:, used], upper=False)
            a_chol, a_info = torch.linalg.cholesky_ex(z.T @ z)
            return CoKrigingConditioned(
                kernel=self.kernel,
                grid=self.grid,
                x=self.x,
                rho_coef=t.rho.clone(),
                plane=t.plane.clone(),
                outputscale=float(t.outputscale),
                lengthscale=t.lengthscale.clone(),
                constant=float(t.plane[0]),
                fast_grid_mean=self.fast_grid_mean,
                fast_grid_cov=self.fast_grid_cov,
                link_grid=self.link_grid,
                cross_rho=self.fast_cross * rho.unsqueeze(0),
                chol_t=chol.T.contiguous(),
                alpha=alpha,
                reg_used=used,
                reg_z=z,
                reg_a_chol=a_chol if int(a_info) == 0 else None,
            )


@dataclass
class CoKrigingConditioned:
    """The CSM level conditioned on its data: the CSM latent map's posterior at any candidates."""

    kernel: KernelName
    grid: Grid
    x: torch.Tensor
    rho_coef: torch.Tensor
    plane: torch.Tensor
    outputscale: float  # δ's
    lengthscale: torch.Tensor  # δ's
    constant: float  # δ's mean at the centre of the square
    fast_grid_mean: torch.Tensor
    fast_grid_cov: torch.Tensor
    link_grid: torch.Tensor  # (m, N_LINK)
    cross_rho: torch.Tensor  # (m, n) Σ_g Wᵀ diag(ρ)
    chol_t: torch.Tensor  # upper factor of K
    alpha: torch.Tensor  # K⁻¹ (y − mean)
    # universal kriging: the mean's coefficients are estimated from the same CSM data, and their uncertainty
    # is the map's too: + rᵀ(FᵀK⁻¹F)⁻¹r, r = f(x) − FᵀK⁻¹k(x) (Cressie 1993, §3.4; Santner et al. 2003,
    # §3.3). Without it the posterior says a map read through ρ is known once the fast map is, while the
    # calibration of ρ from noisy CSM values is what limits it (the film: 6 numbers from indents of 10 % noise)
    reg_used: torch.Tensor  # (N_RHO + 3,) bool: the regression columns in use (the link's, only when on)
    reg_z: torch.Tensor  # (n, p) L⁻¹F
    reg_a_chol: torch.Tensor | None  # Cholesky of FᵀK⁻¹F (None: not positive definite, no correction)

    def rho(self, xs: torch.Tensor) -> torch.Tensor:
        idx, w = self.grid.weights(xs)
        return rho_basis(xs, link_at(self.link_grid, idx, w)) @ self.rho_coef

    def _parts(
        self, xs: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """(prior mean, cross-covariance with the CSM data, ρ at xs, the 16 grid indices and weights)."""
        basis = plane_basis(xs)
        idx, w = self.grid.weights(xs)
        rho = rho_basis(xs, link_at(self.link_grid, idx, w)) @ self.rho_coef
        fast = (self.fast_grid_mean[idx] * w).sum(dim=1)
        prior_mean = rho * fast + basis @ self.plane
        weights = _sparse(idx, w, self.grid.m)
        cross = rho.unsqueeze(1) * torch.sparse.mm(weights, self.cross_rho)
        cross = cross + cross_kernel(self.kernel, xs, self.x, self.lengthscale, self.outputscale)
        return prior_mean, cross, rho, idx, w

    def mean(self, xs: torch.Tensor) -> torch.Tensor:
        prior_mean, cross, _, _, _ = self._parts(xs)
        return prior_mean + cross @ self.alpha

    def mean_f32(self, xs: torch.Tensor) -> torch.Tensor:
        return self.mean(xs)

    def mean_var(self, xs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Latent mean and variance of the CSM map: prior ρ²·wᵀΣ_g w + σ_δ² less what the CSM data explain."""
        prior_mean, cross, rho, idx, w = self._parts(xs)
        block = self.fast_grid_cov[idx.unsqueeze(2), idx.unsqueeze(1)]
        fast_var = torch.einsum("ca,cab,cb->c", w, block, w)
        prior_var = rho.square() * fast_var + self.outputscale
        v = torch.linalg.solve_triangular(self.chol_t, cross, upper=True, left=False)
        var = prior_var - v.square().sum(dim=1)
        if self.reg_a_chol is not None:
            fast = (self.fast_grid_mean[idx] * w).sum(dim=1)
            f = regression_columns(rho_basis(xs, link_at(self.link_grid, idx, w)), fast, plane_basis(xs))
            r = f[:, self.reg_used] - v @ self.reg_z
            g = torch.linalg.solve_triangular(self.reg_a_chol, r.T, upper=False)
            var = var + g.square().sum(dim=0)
        return prior_mean + cross @ self.alpha, var.clamp_min(0.0)

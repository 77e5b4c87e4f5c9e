"""The heteroskedastic GP surrogate: hardness medians per tested centre, with a second GP for the noise.

The mean GP sees one robust value per executed local grid (the median of its g² indents) with a fixed
per-point noise 1.57·σ²(x)/n, where σ²(x) comes from a GP on the log within-grid variances. Both are
gpytorch ``ExactGP`` models with ``FixedNoiseGaussianLikelihood`` (constraints and prior are gpytorch's);
the hot paths are closed-form torch on the Cholesky factor, checked against gpytorch in the tests: the
marginal likelihood with its analytic gradient (no autograd through the Cholesky), and only the diagonal
of the predictive covariance (gpytorch's default forms the joint covariance of all 10,000 candidates,
about 10 s here). Decisions take 0.05 s at 100 centres and 0.2 s at 400 (benchmarks/decision_latency.py).
"""

from __future__ import annotations

import copy
import math
import time
import warnings
from dataclasses import dataclass
from typing import Any, Literal, get_args

import gpytorch
import numpy as np
import torch
from gpytorch.constraints import GreaterThan
from gpytorch.distributions import MultivariateNormal
from gpytorch.kernels import MaternKernel, RBFKernel, ScaleKernel
from gpytorch.likelihoods import FixedNoiseGaussianLikelihood
from gpytorch.means import ConstantMean
from gpytorch.priors import GammaPrior
from scipy.special import digamma, polygamma

from core.errors import InputError
from core.estimators import estimator_efficiency

KernelName = Literal["matern52", "rbf"]
# keep-last-good: a fit whose length-scales collapse keeps the last good kernel (SPEC §5);
# keep-last-good-unless-confirmed: ... except where a cold search on 1.5× more data lands where the warm fit
# slid and both beat the kept kernel by more than COLD_WIN_NATS (a real short scale, not a slide);
# off: a plain maximum-likelihood GP (the unguarded ablation)
GuardName = Literal["keep-last-good", "keep-last-good-unless-confirmed", "off"]
GUARDS: tuple[GuardName, ...] = get_args(GuardName)

HYPER_VERSION = 1
MIN_NOISE_STD = 1e-8  # numerical floor on a point's noise, in standardised units
MIN_SPREAD_GPA2 = 1e-8  # floor on a within-grid variance before its log is taken
MIN_SPREADS_FOR_GP = 3  # fewer spreads than this: pooled constant variance instead of a noise GP
FLOOR_MARGIN = 1.05  # a length-scale within 5 % of its floor counts as collapsed
MAX_THREADS = 2  # torch intra-op threads; 1 is the default: on a busy 2-core machine a second thread
# mostly waits for a core (measured 3–5× slower decisions under load, no gain when idle)
PREDICT_CHUNK = 4096  # candidates per block of the predictive diagonal (fastest measured at n = 100–400)
_DTYPE = torch.float64
OUTPUTSCALE_FLOOR = 1e-6
NOISE_VAR_FLOOR = 1e-6
PRIOR_CONCENTRATION, PRIOR_RATE = 3.0, 6.0  # weak Gamma prior on length-scales, mode ≈ 1/3 of the side
COLD_LENGTHSCALES_UV = (0.15, 0.4)  # deterministic starts of a cold fit
# a warm-started refit follows its own optimum as data arrive and can stay in it after the data favour
# another (the grains: texture read as noise at a long length-scale); whenever the data have grown by this
# factor since the last cold fit, the refit also runs the cold starts and keeps the better likelihood
COLD_REFIT_GROWTH = 1.5
# ... and only by more than this (log marginal likelihood + prior): on smooth maps the cold starts land in
# the warm optimum and would win by rounding, replacing a settled model with an equivalent one (measured:
# 0.00–0.01 nats on the ternary, 19.6 nats on the grains once their texture is in the data)
COLD_WIN_NATS = 2.0
WARM_MIN_OUTPUTSCALE = 0.05  # standardised: a warm start never begins below this
WARM_MIN_LENGTHSCALE_EXCESS_UV = 0.005  # ... nor with a length-scale closer than this to its floor
WARM_MIN_NOISE_VAR = 1e-3  # ... nor with a learned noise variance (standardised) below this
COLD_NOISE_VAR = 0.1  # initial learned noise (standardised) of a cold homoskedastic fit
TOL_GRAD = 1e-4  # on −mll/n per raw parameter: warm and cold fits agree to < 0.3 % in length-scale
TOL_CHANGE = 1e-8  # absolute, on −mll/n and on the raw step


@dataclass(frozen=True)
class Observations:
    """One row per tested centre: each executed g×g grid collapsed to one robust value and its spread."""

    uv: np.ndarray  # (n, 2) in the unit square
    median_gpa: np.ndarray  # (n,) median of the centre's indents
    spread_var_gpa2: np.ndarray  # (n,) within-grid sample variance (or detrended), NaN where there is none
    n_indents: np.ndarray  # (n,) ints
    spread_dof: np.ndarray | None = None  # (n,) degrees of freedom of each spread; None: n_indents − 1
    # (n,) var(centre value)·n/σ²: how much the robust value wastes; None: the median's (SPEC §5)
    efficiency: np.ndarray | None = None

    def __post_init__(self) -> None:
        uv = np.asarray(self.uv, dtype=float)
        med = np.asarray(self.median_gpa, dtype=float)
        spread = np.asarray(self.spread_var_gpa2, dtype=float)
        n_ind = np.asarray(self.n_indents)
        if uv.ndim != 2 or uv.shape[1] != 2:
            raise InputError("observations.uv", f"expected shape (n, 2), got {uv.shape}")
        n = uv.shape[0]
        for name, arr in (("median_gpa", med), ("spread_var_gpa2", spread), ("n_indents", n_ind)):
            if arr.shape != (n,):
                raise InputError(f"observations.{name}", f"expected shape ({n},), got {arr.shape}")
        if not np.all(np.isfinite(uv)):
            raise InputError("observations.uv", "non-finite coordinates")
        if not np.all(np.isfinite(med)):
            raise InputError("observations.median_gpa", "non-finite hardness")
        if n and (not np.all(np.isfinite(n_ind)) or np.any(n_ind < 1) or np.any(n_ind != np.round(n_ind))):
            raise InputError("observations.n_indents", "every centre needs a whole number >= 1 of indents")
        if np.any(spread[np.isfinite(spread)] < 0):
            raise InputError("observations.spread_var_gpa2", "negative variance")
        object.__setattr__(self, "uv", uv)
        object.__setattr__(self, "median_gpa", med)
        object.__setattr__(self, "spread_var_gpa2", spread)
        object.__setattr__(self, "n_indents", n_ind.astype(np.int64))
        dof = (
            (n_ind - 1).astype(float) if self.spread_dof is None else np.asarray(self.spread_dof, dtype=float)
        )
        if dof.shape != (n,):
            raise InputError("observations.spread_dof", f"expected shape ({n},), got {dof.shape}")
        object.__setattr__(self, "spread_dof", dof)
        eff = (
            estimator_efficiency("median", n_ind)
            if self.efficiency is None
            else np.asarray(self.efficiency, dtype=float)
        )
        if eff.shape != (n,) or not np.all(np.isfinite(eff)) or np.any(eff < 1.0):
            raise InputError("observations.efficiency", f"expected ({n},) values ≥ 1, got {eff!r}")
        object.__setattr__(self, "efficiency", eff)

    @property
    def n(self) -> int:
        return int(self.uv.shape[0])

    @classmethod
    def from_indents(
        cls, uv_per_indent: np.ndarray, hardness: np.ndarray, centre_ids: np.ndarray, detrend: bool = False
    ) -> Observations:
        """Group indents by centre id (in order of first appearance): centre = mean position of its indents.

        ``detrend``: the spread is the residual variance about a plane fitted to the grid (n − 3 degrees of
        freedom), so a steep hardness gradient across the grid is not mistaken for indent noise.
        """
        uv_i = np.asarray(uv_per_indent, dtype=float)
        h = np.asarray(hardness, dtype=float)
        ids = np.asarray(centre_ids)
        if uv_i.ndim != 2 or uv_i.shape[1] != 2 or h.shape != (uv_i.shape[0],) or ids.shape != h.shape:
            raise InputError(
                "indents", f"shapes disagree: uv {uv_i.shape}, hardness {h.shape}, ids {ids.shape}"
            )
        _, first, inverse = np.unique(ids, return_index=True, return_inverse=True)
        order = np.argsort(first, kind="stable")
        uv, med, spread, count, dof = [], [], [], [], []
        for group in order:
            mask = inverse == group
            vals = h[mask]
            pos = uv_i[mask]
            uv.append(pos.mean(axis=0))
            med.append(float(np.median(vals)))
            count.append(int(vals.size))
            var, k = _grid_spread(pos, vals, detrend)
            spread.append(var)
            dof.append(k)
        return cls(
            uv=np.asarray(uv, dtype=float).reshape(-1, 2),
            median_gpa=np.asarray(med, dtype=float),
            spread_var_gpa2=np.asarray(spread, dtype=float),
            n_indents=np.asarray(count, dtype=np.int64),
            spread_dof=np.asarray(dof, dtype=float),
        )


def _grid_spread(pos: np.ndarray, vals: np.ndarray, detrend: bool) -> tuple[float, float]:
    """(variance, degrees of freedom) of one grid's indents; NaN variance when there are too few."""
    n = vals.size
    if detrend and n >= 4:
        design = np.column_stack([np.ones(n), pos - pos.mean(axis=0)])
        coef, _, rank, _ = np.linalg.lstsq(design, vals, rcond=None)
        if rank == 3:
            resid = vals - design @ coef
            return float(resid @ resid) / (n - 3), float(n - 3)
    if n >= 2:
        return float(np.var(vals, ddof=1)), float(n - 1)
    return math.nan, 0.0


@dataclass(frozen=True)
class Prediction:
    """The four fields of the paper's Figure 8, in GPa."""

    mean: np.ndarray
    epistemic_sd: np.ndarray  # sd of the latent hardness f
    noise_sd: np.ndarray  # per-indent noise sd σ(x) (what grid sizing uses)
    total_sd: np.ndarray  # sqrt(epistemic² + noise²)


@dataclass(frozen=True)
class FitReport:
    lengthscales_uv: tuple[float, float]
    noise_lengthscales_uv: tuple[float, float] | None
    outputscale: float  # prior variance of the latent field, GPa²
    mean_const: float  # GPa
    collapse: bool
    collapse_reason: str
    used_last_good: bool
    n_points: int
    iterations: int  # L-BFGS iterations, mean GP + noise GP
    seconds: float
    hyper: dict[str, Any]  # the hyperparameters in use (JSON-able): warm start, journal, resume


def _lengthscale_prior() -> GammaPrior:
    """A fresh float64 prior per use: a prior registered in a model is converted in place by ``model.to``."""
    return GammaPrior(torch.tensor(PRIOR_CONCENTRATION, dtype=_DTYPE), torch.tensor(PRIOR_RATE, dtype=_DTYPE))


_PRIOR = _lengthscale_prior()  # the objective's own copy, never registered in a model


class _GPModel(gpytorch.models.ExactGP):
    """The GP of record: constant mean, scaled ARD kernel, per-point fixed noise (gpytorch's own classes)."""

    def __init__(
        self, x: torch.Tensor, y: torch.Tensor, kernel: KernelName, floor_uv: float, with_prior: bool
    ) -> None:
        likelihood = FixedNoiseGaussianLikelihood(
            noise=torch.full_like(y, 1e-4), learn_additional_noise=False
        )
        super().__init__(x, y, likelihood)
        self.mean_module = ConstantMean()
        prior = _lengthscale_prior() if with_prior else None
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
        self.to(_DTYPE)

    def forward(self, x: torch.Tensor) -> MultivariateNormal:
        return MultivariateNormal(self.mean_module(x), self.covar_module(x))

    def load_theta(self, theta: torch.Tensor) -> None:
        """Raw vector [constant, outputscale, ℓu, ℓv, ...] into gpytorch's raw parameters."""
        with torch.no_grad():
            self.mean_module.raw_constant.copy_(theta[0])
            self.covar_module.raw_outputscale.copy_(theta[1])
            self.covar_module.base_kernel.raw_lengthscale.copy_(theta[2:4].reshape(1, 2))


# -- closed-form kernels and likelihood (the hot paths; checked against gpytorch in the tests) ----------


def _pair_sq_diffs(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Squared coordinate differences between training points, per axis (exact: no cancellation)."""
    d0 = (x[:, 0:1] - x[:, 0]).square_()
    d1 = (x[:, 1:2] - x[:, 1]).square_()
    return d0, d1


def _unit_kernel(kernel: KernelName, r2: torch.Tensor) -> torch.Tensor:
    """k(r²) with unit outputscale from the squared scaled distance (in place on ``r2``)."""
    if kernel == "rbf":
        return r2.mul_(-0.5).exp_()
    r = r2.mul(5.0).sqrt_()
    e = torch.neg(r).exp_()
    return r2.mul_(5.0 / 3.0).add_(r).add_(1.0).mul_(e)


def _cross_kernel(
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
class _Unpacked:
    constant: torch.Tensor
    outputscale: torch.Tensor
    lengthscale: torch.Tensor  # (2,)
    noise_var: torch.Tensor | None  # learned homoskedastic per-indent variance (standardised), or None


def _unpack(theta: torch.Tensor, floor_uv: float, learn_noise: bool) -> _Unpacked:
    """Raw vector [constant, outputscale, ℓu, ℓv(, noise)] → constrained values, as gpytorch's GreaterThan does."""
    sp = torch.nn.functional.softplus
    return _Unpacked(
        constant=theta[0],
        outputscale=sp(theta[1]) + OUTPUTSCALE_FLOOR,
        lengthscale=sp(theta[2:4]) + floor_uv,
        noise_var=sp(theta[4]) + NOISE_VAR_FLOOR if learn_noise else None,
    )


@dataclass(frozen=True)
class _Problem:
    """One GP's data for the likelihood: the fixed part of its noise and the pairwise differences."""

    kernel: KernelName
    floor_uv: float
    with_prior: bool
    y: torch.Tensor
    d0: torch.Tensor
    d1: torch.Tensor
    noise_fixed: torch.Tensor | None  # per-point noise, or None when it is learned
    noise_scale: torch.Tensor  # per-point multiplier of the learned noise variance
    nugget: bool = False  # fixed noise plus one learned variance shared by every point (site-to-site scatter)

    @property
    def learn_noise(self) -> bool:
        return self.noise_fixed is None or self.nugget

    def noise(self, u: _Unpacked) -> torch.Tensor:
        if self.noise_fixed is not None:
            if not self.nugget:
                return self.noise_fixed
            assert u.noise_var is not None
            return self.noise_fixed + u.noise_var
        assert u.noise_var is not None
        return (self.noise_scale * u.noise_var).clamp_min(MIN_NOISE_STD)


def _mll_and_grads(p: _Problem, u: _Unpacked) -> tuple[float, torch.Tensor]:
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
    return mll, torch.tensor(grads, dtype=_DTYPE)


def _log_prior(p: _Problem, u: _Unpacked) -> torch.Tensor:
    if not p.with_prior:
        return torch.zeros((), dtype=_DTYPE)
    return _PRIOR.log_prob(u.lengthscale).sum()


def _objective(p: _Problem, theta: torch.Tensor) -> float:
    """−(log marginal likelihood + log prior)/n, the quantity gpytorch's ExactMarginalLogLikelihood returns."""
    with torch.no_grad():
        u = _unpack(theta, p.floor_uv, p.learn_noise)
        mll, _ = _mll_and_grads(p, u)
        return -(mll + float(_log_prior(p, u))) / p.y.shape[0]


def _optimise(p: _Problem, theta0: torch.Tensor, max_iter: int) -> tuple[torch.Tensor, int]:
    """Deterministic L-BFGS (strong Wolfe) on the raw vector; the matrix work is closed form, autograd only
    carries the gradient through the constraint transforms and the prior."""
    theta = theta0.detach().clone().requires_grad_(True)
    n = p.y.shape[0]
    opt = torch.optim.LBFGS(
        [theta],
        lr=1.0,
        max_iter=max_iter,
        max_eval=int(max_iter * 1.5) + 1,
        tolerance_grad=TOL_GRAD,
        tolerance_change=TOL_CHANGE,
        history_size=10,
        line_search_fn="strong_wolfe",
    )

    def closure() -> torch.Tensor:
        opt.zero_grad()
        u = _unpack(theta, p.floor_uv, p.learn_noise)
        with torch.no_grad():
            mll, g = _mll_and_grads(p, u)
        values = [u.constant, u.outputscale, u.lengthscale[0], u.lengthscale[1]]
        if u.noise_var is not None:
            values.append(u.noise_var)
        prior = _log_prior(p, u)
        surrogate = -(torch.stack(values) @ g + prior) / n
        surrogate.backward()
        return torch.tensor(-(mll + float(prior.detach())) / n, dtype=_DTYPE)

    try:
        opt.step(closure)
    except (RuntimeError, torch.linalg.LinAlgError):
        return theta0.detach().clone(), 0
    result = theta.detach()
    if not bool(torch.isfinite(result).all()):
        return theta0.detach().clone(), 0
    return result, int(opt.state[theta].get("n_iter", 0))


@dataclass
class _Conditioned:
    """A GP conditioned on its data: what prediction needs, all in standardised units."""

    kernel: KernelName
    x: torch.Tensor
    lengthscale: torch.Tensor
    outputscale: float
    constant: float
    chol: torch.Tensor  # lower Cholesky factor of K + D
    alpha: torch.Tensor  # (K + D)⁻¹ (y − c)
    model: _GPModel  # the same GP as a gpytorch ExactGP: the model of record and the reference path

    def __post_init__(self) -> None:
        self.chol_t = self.chol.T.contiguous()
        self._x32 = self.x.to(torch.float32)
        self._lengthscale32 = self.lengthscale.to(torch.float32)
        self._alpha32 = self.alpha.to(torch.float32)

    def cross(self, xs: torch.Tensor) -> torch.Tensor:
        return _cross_kernel(self.kernel, xs, self.x, self.lengthscale, self.outputscale)

    def mean(self, xs: torch.Tensor) -> torch.Tensor:
        return self.cross(xs) @ self.alpha + self.constant

    def mean_f32(self, xs: torch.Tensor) -> torch.Tensor:
        """The posterior mean in single precision (≈ 5× faster here, mostly the exp): for the noise GP only,
        whose log-variance needs 1e-6, not 1e-15; the mean GP stays in double (its α can be large)."""
        k = _cross_kernel(self.kernel, xs.to(torch.float32), self._x32, self._lengthscale32, self.outputscale)
        return (k @ self._alpha32).to(_DTYPE) + self.constant

    def mean_var(self, xs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Latent mean and the diagonal of the latent covariance, kss − ‖L⁻¹k*‖²: no joint covariance."""
        ks = self.cross(xs)
        mean = ks @ self.alpha + self.constant
        # k* L⁻ᵀ with one row per candidate: a right-sided solve works on contiguous rows of the chunk
        v = torch.linalg.solve_triangular(self.chol_t, ks, upper=True, left=False)
        var = (self.outputscale - v.square_().sum(dim=1)).clamp_min_(0.0)
        return mean, var


def _condition(p: _Problem, theta: torch.Tensor, x: torch.Tensor) -> _Conditioned:
    with torch.no_grad():
        u = _unpack(theta, p.floor_uv, p.learn_noise)
        os = float(u.outputscale)
        r2 = p.d0 / float(u.lengthscale[0]) ** 2 + p.d1 / float(u.lengthscale[1]) ** 2
        k = _unit_kernel(p.kernel, r2).mul_(os)
        noise = p.noise(u)
        k.diagonal().add_(noise)
        chol, info = torch.linalg.cholesky_ex(k)
        if int(info) != 0:
            k.diagonal().add_(1e-6 * float(k.diagonal().mean()))
            chol = torch.linalg.cholesky(k)
        constant = float(u.constant)
        alpha = torch.cholesky_solve((p.y - constant).unsqueeze(-1), chol).squeeze(-1)
        model = _GPModel(x, p.y, p.kernel, p.floor_uv, p.with_prior)
        model.load_theta(theta)
        model.likelihood.noise = noise.clone()
    return _Conditioned(p.kernel, x, u.lengthscale.clone(), os, constant, chol, alpha, model)


def _standardise(values: np.ndarray) -> tuple[float, float]:
    loc = float(np.mean(values))
    scale = float(np.std(values, ddof=1)) if values.size > 1 else 1.0
    if not math.isfinite(scale) or scale < 1e-9 * max(1.0, abs(loc)):
        scale = 1.0
    return loc, scale


def _log_spread_targets(spread: np.ndarray, dof: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unbiased log-variance targets and their sampling variances for chi-square variances with k dof:
    E[log s²] = log σ² + ψ(k/2) − log(k/2), var[log s²] = ψ′(k/2)."""
    half_k = dof / 2.0
    target = np.log(np.maximum(spread, MIN_SPREAD_GPA2)) - (digamma(half_k) - np.log(half_k))
    return target, polygamma(1, half_k)


def _inv_softplus(value: float) -> float:
    return value + math.log(-math.expm1(-value))


def _cold_theta(lengthscale: float, floor_uv: float, learn_noise: bool) -> torch.Tensor:
    raw_ls = _inv_softplus(max(lengthscale - floor_uv, 1e-3))
    values = [0.0, _inv_softplus(1.0 - OUTPUTSCALE_FLOOR), raw_ls, raw_ls]
    if learn_noise:
        values.append(_inv_softplus(COLD_NOISE_VAR - NOISE_VAR_FLOOR))
    return torch.tensor(values, dtype=_DTYPE)


def _raw_for(p: _Problem, raw: list[float]) -> list[float]:
    """A recorded raw vector sized to the problem: a learned noise added at its cold value where the record
    had none (a fit on spreads), dropped where the problem learns none."""
    size = 5 if p.learn_noise else 4
    values = list(raw[:size])
    if len(values) < size:
        values.append(_inv_softplus(COLD_NOISE_VAR - NOISE_VAR_FLOOR))
    return values


def _fit_problem(
    p: _Problem, warm: list[float] | None, max_iter: int, warm_max_iter: int
) -> tuple[torch.Tensor, int]:
    """Warm: one short L-BFGS run from the previous raw vector. Cold: a few deterministic starts, best kept."""
    if warm is not None:
        values = _raw_for(p, warm)
        # an outputscale that went to ~0 on a few points has a vanishing gradient (softplus' tail): lift it,
        # or every later warm fit stays trapped in the "constant function" corner
        values[1] = max(values[1], _inv_softplus(WARM_MIN_OUTPUTSCALE))
        values[2] = max(values[2], _inv_softplus(WARM_MIN_LENGTHSCALE_EXCESS_UV))  # same at the floor
        values[3] = max(values[3], _inv_softplus(WARM_MIN_LENGTHSCALE_EXCESS_UV))
        if p.learn_noise:
            values[4] = max(values[4], _inv_softplus(WARM_MIN_NOISE_VAR))
        return _optimise(p, torch.tensor(values, dtype=_DTYPE), warm_max_iter)
    best: tuple[float, torch.Tensor] | None = None
    iterations = 0
    for lengthscale in COLD_LENGTHSCALES_UV:
        theta, it = _optimise(p, _cold_theta(lengthscale, p.floor_uv, p.learn_noise), max_iter)
        iterations += it
        value = _objective(p, theta)
        if math.isfinite(value) and (best is None or value < best[0]):
            best = (value, theta)
    assert best is not None, "every start of the GP fit failed"
    return best[1], iterations


def _lengthscales_of(raw: list[float], floor_uv: float) -> tuple[float, float]:
    ls = torch.nn.functional.softplus(torch.tensor(raw[2:4], dtype=_DTYPE)) + floor_uv
    return (float(ls[0]), float(ls[1]))


class HeteroskedasticGP:
    """Mean GP on grid medians + noise GP on log within-grid variances, with a length-scale collapse guard."""

    def __init__(
        self,
        kernel: KernelName = "matern52",
        heteroskedastic: bool = True,
        lengthscale_floor_uv: float = 0.02,
        collapse_drop_ratio: float = 0.35,
        guard: GuardName = "keep-last-good",
        max_iter: int = 60,
        seed: int = 0,
        warm_max_iter: int | None = None,
        lengthscale_prior: bool = True,
        collapse_min_points: int = 8,
        threads: int = 1,
        nugget: bool = False,
    ) -> None:
        if kernel not in ("matern52", "rbf"):
            raise InputError("surrogate.kernel", f"unknown kernel {kernel!r}; allowed: matern52, rbf")
        if guard not in GUARDS:
            raise InputError("surrogate.guard", f"unknown guard {guard!r}; allowed: {', '.join(GUARDS)}")
        if not 0.0 < lengthscale_floor_uv < 1.0:
            raise InputError(
                "surrogate.lengthscale_floor_uv", f"must be in (0, 1), got {lengthscale_floor_uv}"
            )
        if not 0.0 < collapse_drop_ratio < 1.0:
            raise InputError("surrogate.collapse_drop_ratio", f"must be in (0, 1), got {collapse_drop_ratio}")
        if max_iter < 1:
            raise InputError("surrogate.max_iter", f"must be >= 1, got {max_iter}")
        self.kernel: KernelName = kernel
        self.heteroskedastic = heteroskedastic
        self.floor_uv = float(lengthscale_floor_uv)
        self.collapse_drop_ratio = float(collapse_drop_ratio)
        self.guard: GuardName = guard
        self.max_iter = int(max_iter)
        self.warm_max_iter = int(warm_max_iter) if warm_max_iter is not None else max(10, self.max_iter // 3)
        self.seed = seed  # the fit draws no random numbers: kept for the record
        self.lengthscale_prior = bool(lengthscale_prior)
        self.collapse_min_points = int(collapse_min_points)
        # learn a site-to-site variance on top of the within-grid noise: scatter between centres that the
        # spreads of tight grids cannot see (indent-scale heterogeneity) then needs no short length-scale
        self.nugget = bool(nugget)
        if not 1 <= threads <= MAX_THREADS:
            raise InputError("surrogate.threads", f"must be 1..{MAX_THREADS}, got {threads}")
        if torch.get_num_threads() != threads:
            torch.set_num_threads(threads)  # process-wide; the only torch user is this module
        self._hyper: dict[str, Any] | None = None
        self._last_good: dict[str, Any] | None = None
        self._mean: _Conditioned | None = None
        self._mean_problem: _Problem | None = None
        self._noise: _Conditioned | None = None
        self._noise_kind = "learned"
        self._noise_var_gpa2 = 1.0  # pooled or learned per-indent variance when there is no noise GP
        self._site_var_gpa2 = 0.0  # the learned site-to-site variance (nugget), GPa²
        self._y_loc = 0.0
        self._y_scale = 1.0
        self._t_loc = 0.0
        self._t_scale = 1.0

    # -- public -----------------------------------------------------------------------------------

    @property
    def hyper(self) -> dict[str, Any] | None:
        return copy.deepcopy(self._hyper)

    def fit(self, obs: Observations) -> FitReport:
        """Fit both GPs by (MAP) marginal likelihood, warm-started from the previous fit's hyperparameters."""
        t0 = time.perf_counter()
        if obs.n == 0:
            raise InputError("observations", "no tested centres to fit")
        prev = self._hyper
        compatible = prev is not None and prev["kernel"] == self.kernel
        kind = self._noise_kind_for(obs)
        iterations = 0
        noise_raw: list[float] | None = None
        if kind == "gp":
            warm_noise = prev["noise"].get("raw") if compatible and prev is not None else None
            pn, _xn = self._noise_problem(obs)
            theta_n, it = _fit_problem(pn, warm_noise, self.max_iter, self.warm_max_iter)
            iterations += it
            noise_raw = theta_n.tolist()
        pm, _ = self._mean_problem_for(obs, kind, noise_raw)
        warm_mean = prev["mean"]["raw"] if compatible and prev is not None else None
        cold_n = int(prev.get("cold_n", 0)) if compatible and prev is not None else 0
        cold_won = False
        theta_m, it = _fit_problem(pm, warm_mean, self.max_iter, self.warm_max_iter)
        iterations += it
        if warm_mean is None:
            cold_n = obs.n
        elif obs.n >= COLD_REFIT_GROWTH * max(cold_n, 1):
            # deterministic in (obs, previous record): a resumed run makes the same choice
            theta_c, it = _fit_problem(pm, None, self.max_iter, self.warm_max_iter)
            iterations += it
            warm_value, cold_value = _objective(pm, theta_m), _objective(pm, theta_c)
            if (warm_value - cold_value) * obs.n > COLD_WIN_NATS:
                theta_m = theta_c
                cold_won = True
            elif self.guard == "keep-last-good-unless-confirmed" and self._confirms(
                pm, warm_mean, warm_value, cold_value, obs.n
            ):
                # the warm fit's slide is where the cold search lands too, and the data prefer it by more
                # than the margin to the kernel in use: the data's own choice (the grains' texture),
                # which keep-last-good would otherwise veto at every refit
                cold_won = True
            cold_n = obs.n
        hyper = self._make_hyper(kind, theta_m.tolist(), noise_raw, obs)
        hyper["cold_n"] = cold_n
        # a drop against the previous fit is a slide of the warm optimum; a cold start that wins on the
        # likelihood over 1.5× more data is the data's own choice, held only to the floor
        collapse, reason = self._collapse_check(hyper, None if cold_won or not compatible else prev)
        used_last_good = False
        if collapse and self.guard != "off":
            if self._last_good is not None and self._last_good["kernel"] == self.kernel:
                hyper = self._restore(hyper, self._last_good)
                used_last_good = True
                reason += "; kept the last good hyperparameters"
            else:
                reason += "; no earlier good fit to fall back to"
        self._install(hyper, obs)
        if not collapse:
            self._last_good = hyper
        return self._report(
            hyper, obs, collapse, reason, used_last_good, iterations, time.perf_counter() - t0
        )

    def set_hyper(self, hyper: dict[str, Any], obs: Observations) -> None:
        """Condition on ``obs`` with the given hyperparameters, no optimisation: crash-resume."""
        if not isinstance(hyper, dict) or hyper.get("version") != HYPER_VERSION:
            raise InputError("surrogate.hyper", f"not a version-{HYPER_VERSION} hyperparameter record")
        if hyper.get("kernel") != self.kernel or hyper.get("lengthscale_floor_uv") != self.floor_uv:
            raise InputError(
                "surrogate.hyper",
                f"recorded for kernel {hyper.get('kernel')} / floor {hyper.get('lengthscale_floor_uv')}, "
                f"this model is {self.kernel} / {self.floor_uv}",
            )
        if bool(hyper.get("nugget", False)) != self.nugget:
            raise InputError(
                "surrogate.hyper",
                f"recorded with nugget={hyper.get('nugget', False)}, this model has {self.nugget}",
            )
        if obs.n == 0:
            raise InputError("observations", "no tested centres to condition on")
        if hyper["noise"]["kind"] == "gp" and int(np.sum(_spread_mask(obs))) < MIN_SPREADS_FOR_GP:
            raise InputError(
                "surrogate.hyper", "has a noise GP but the observations have fewer than 3 spreads"
            )
        hyper = copy.deepcopy(hyper)
        self._install(hyper, obs)
        self._last_good = hyper

    def predict(self, uv: np.ndarray) -> Prediction:
        """Mean, epistemic, noise and total sd at ``uv`` (m, 2): the predictive diagonal only, in chunks."""
        if self._mean is None:
            raise RuntimeError("HeteroskedasticGP.predict before fit() or set_hyper()")
        pts = np.array(uv, dtype=float)  # a private, writable copy for torch
        if pts.ndim != 2 or pts.shape[1] != 2:
            raise InputError("uv", f"expected shape (m, 2), got {pts.shape}")
        m = pts.shape[0]
        mean = torch.empty(m, dtype=_DTYPE)
        var = torch.empty(m, dtype=_DTYPE)
        noise_var = torch.empty(m, dtype=_DTYPE)
        xs_all = torch.as_tensor(pts, dtype=_DTYPE)
        with torch.no_grad():
            for start in range(0, m, PREDICT_CHUNK):
                xs = xs_all[start : start + PREDICT_CHUNK]
                mu, v = self._mean.mean_var(xs)
                mean[start : start + xs.shape[0]] = mu
                var[start : start + xs.shape[0]] = v
                noise_var[start : start + xs.shape[0]] = self._noise_var_at(xs)
        mean_gpa = mean.numpy() * self._y_scale + self._y_loc
        epi = np.sqrt(var.numpy()) * self._y_scale
        noise = np.sqrt(noise_var.numpy())
        return Prediction(
            mean=mean_gpa, epistemic_sd=epi, noise_sd=noise, total_sd=np.sqrt(epi**2 + noise**2)
        )

    def predict_mean(self, uv: np.ndarray) -> np.ndarray:
        """The posterior mean only (GPa): one kernel product, no variances (metrics on large lattices)."""
        if self._mean is None:
            raise RuntimeError("HeteroskedasticGP.predict_mean before fit() or set_hyper()")
        xs = torch.as_tensor(np.array(uv, dtype=float).reshape(-1, 2), dtype=_DTYPE)
        parts = []
        with torch.no_grad():
            for start in range(0, len(xs), PREDICT_CHUNK):
                parts.append(self._mean.mean(xs[start : start + PREDICT_CHUNK]).numpy())
        mean = np.concatenate(parts) if parts else np.empty(0)
        return np.asarray(mean * self._y_scale + self._y_loc, dtype=float)

    @property
    def site_var_gpa2(self) -> float:
        return self._site_var_gpa2

    @property
    def site_sd_gpa(self) -> float:
        """Scatter between centres beyond their indents' noise (0 without a nugget): more indents per
        centre do not average it away, so grid sizing ignores it."""
        return math.sqrt(self._site_var_gpa2)

    @property
    def outputscale_gpa2(self) -> float | None:
        """Prior variance of the latent map in GPa² (None before a fit): planners that need covariances."""
        return None if self._mean is None else float(self._mean.outputscale * self._y_scale**2)

    def reference_latent(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Latent mean and variance (GPa, GPa²) by gpytorch's default predictive path: slow; tests and benchmarks."""
        if self._mean is None:
            raise RuntimeError("HeteroskedasticGP.reference_latent before fit() or set_hyper()")
        model = self._mean.model
        model.eval()
        xs = torch.as_tensor(np.asarray(uv, dtype=float), dtype=_DTYPE)
        try:
            with torch.no_grad(), warnings.catch_warnings():
                warnings.simplefilter("ignore")
                post = model(xs)
                mean = post.mean.numpy() * self._y_scale + self._y_loc
                var = post.variance.numpy() * self._y_scale**2
        finally:
            model.train()
        return mean, var

    def reference_neg_mll(self) -> tuple[float, float]:
        """(this module's objective, gpytorch's −ExactMarginalLogLikelihood) at the hyperparameters in use."""
        if self._mean is None or self._mean_problem is None or self._hyper is None:
            raise RuntimeError("HeteroskedasticGP.reference_neg_mll before fit() or set_hyper()")
        model = self._mean.model
        x, y = model.train_inputs[0], model.train_targets
        ours = _objective(self._mean_problem, torch.tensor(self._hyper["mean"]["raw"], dtype=_DTYPE))
        model.train()
        mll = gpytorch.mlls.ExactMarginalLogLikelihood(model.likelihood, model)
        with torch.no_grad(), gpytorch.settings.max_cholesky_size(100_000):
            theirs = float(-mll(model(x), y))
        return ours, theirs

    # -- data and noise model ---------------------------------------------------------------------

    def _noise_kind_for(self, obs: Observations) -> str:
        n_spreads = int(np.sum(_spread_mask(obs)))
        if not self.heteroskedastic or n_spreads == 0:
            return "learned"
        return "gp" if n_spreads >= MIN_SPREADS_FOR_GP else "pooled"

    def _noise_problem(self, obs: Observations) -> tuple[_Problem, torch.Tensor]:
        """The noise GP's data: unbiased log sample variances, standardised, with their sampling variances."""
        mask = _spread_mask(obs)
        assert obs.spread_dof is not None
        target, tvar = _log_spread_targets(obs.spread_var_gpa2[mask], obs.spread_dof[mask])
        self._t_loc, self._t_scale = _standardise(target)
        x = torch.as_tensor(obs.uv[mask], dtype=_DTYPE)
        t = torch.as_tensor((target - self._t_loc) / self._t_scale, dtype=_DTYPE)
        v = torch.as_tensor(np.maximum(tvar / self._t_scale**2, MIN_NOISE_STD), dtype=_DTYPE)
        d0, d1 = _pair_sq_diffs(x)
        return _Problem(
            self.kernel, self.floor_uv, self.lengthscale_prior, t, d0, d1, v, torch.ones_like(t)
        ), x

    def _mean_problem_for(
        self, obs: Observations, kind: str, noise_raw: list[float] | None
    ) -> tuple[_Problem, torch.Tensor]:
        """The mean GP's data; its fixed per-centre noise 1.57·σ²(x_i)/n_i comes from the noise model."""
        self._y_loc, self._y_scale = _standardise(obs.median_gpa)
        y = torch.as_tensor((obs.median_gpa - self._y_loc) / self._y_scale, dtype=_DTYPE)
        x = torch.as_tensor(obs.uv, dtype=_DTYPE)
        assert obs.efficiency is not None
        scale = torch.as_tensor(obs.efficiency / obs.n_indents, dtype=_DTYPE)
        fixed: torch.Tensor | None = None
        self._noise = None
        if kind == "gp":
            assert noise_raw is not None
            pn, xn = self._noise_problem(obs)
            self._noise = _condition(pn, torch.tensor(noise_raw, dtype=_DTYPE), xn)
            with torch.no_grad():
                var_gpa2 = self._noise_var_at(x)
            fixed = scale * var_gpa2 / self._y_scale**2
        elif kind == "pooled":
            fixed = scale * _pooled_var(obs) / self._y_scale**2
        if fixed is not None:
            fixed = fixed.clamp_min(MIN_NOISE_STD)
        d0, d1 = _pair_sq_diffs(x)
        problem = _Problem(
            self.kernel, self.floor_uv, self.lengthscale_prior, y, d0, d1, fixed, scale, self.nugget
        )
        return problem, x

    def _noise_var_at(self, xs: torch.Tensor) -> torch.Tensor:
        """Per-indent noise variance (GPa²) at ``xs``."""
        if self._noise is not None:
            return torch.exp(self._noise.mean_f32(xs) * self._t_scale + self._t_loc)
        return torch.full((xs.shape[0],), self._noise_var_gpa2, dtype=_DTYPE)

    def _install(self, hyper: dict[str, Any], obs: Observations) -> None:
        """Condition on ``obs`` with ``hyper``: the one path shared by fit and set_hyper (resume is bit-identical)."""
        kind = hyper["noise"]["kind"]
        pm, x = self._mean_problem_for(obs, kind, hyper["noise"].get("raw"))
        theta = torch.tensor(hyper["mean"]["raw"], dtype=_DTYPE)
        self._mean = _condition(pm, theta, x)
        self._mean_problem = pm
        self._noise_kind = kind
        if kind == "pooled":
            self._noise_var_gpa2 = _pooled_var(obs)
        elif kind == "learned":
            u = _unpack(theta, self.floor_uv, True)
            assert u.noise_var is not None
            self._noise_var_gpa2 = float(u.noise_var) * self._y_scale**2
        self._site_var_gpa2 = 0.0
        if pm.nugget and pm.noise_fixed is not None:
            u = _unpack(theta, self.floor_uv, True)
            assert u.noise_var is not None
            self._site_var_gpa2 = float(u.noise_var) * self._y_scale**2
        self._hyper = hyper

    # -- hyperparameter records and the collapse guard --------------------------------------------

    def _make_hyper(
        self, kind: str, mean_raw: list[float], noise_raw: list[float] | None, obs: Observations
    ) -> dict[str, Any]:
        noise: dict[str, Any] = {"kind": kind}
        if noise_raw is not None:
            noise["raw"] = noise_raw
        return {
            "version": HYPER_VERSION,
            "kernel": self.kernel,
            "lengthscale_floor_uv": self.floor_uv,
            "mean": {"raw": mean_raw},  # [constant, outputscale, ℓu, ℓv(, noise)] raw, standardised units
            "noise": noise,
            "nugget": self.nugget,
            "lengthscales_uv": list(_lengthscales_of(mean_raw, self.floor_uv)),
            "n_points": obs.n,
        }

    @staticmethod
    def _confirms(p: _Problem, kept_raw: list[float], warm: float, cold: float, n: int) -> bool:
        """Does a cold search confirm the warm fit against the kept kernel (objectives per point)?"""
        if (cold - warm) * n > COLD_WIN_NATS:
            return False  # the cold starts found nothing as good: the slide is the warm path's own
        kept = _objective(p, torch.tensor(_raw_for(p, kept_raw), dtype=_DTYPE))
        return math.isfinite(kept) and (kept - min(warm, cold)) * n > COLD_WIN_NATS

    def _collapse_check(self, hyper: dict[str, Any], prev: dict[str, Any] | None) -> tuple[bool, str]:
        ls = hyper["lengthscales_uv"]
        reasons = []
        for axis, value in zip("uv", ls, strict=True):
            if value <= self.floor_uv * FLOOR_MARGIN:
                reasons.append(f"length-scale {axis} = {value:.4f} at its floor {self.floor_uv:.4f}")
        if prev is not None and int(prev.get("n_points", 0)) >= self.collapse_min_points:
            for axis, value, old in zip("uv", ls, prev["lengthscales_uv"], strict=True):
                if value < self.collapse_drop_ratio * old:
                    reasons.append(
                        f"length-scale {axis} dropped from {old:.4f} to {value:.4f} "
                        f"(< {self.collapse_drop_ratio:g}× the previous fit)"
                    )
        return bool(reasons), "; ".join(reasons)

    def _restore(self, new: dict[str, Any], good: dict[str, Any]) -> dict[str, Any]:
        """The new record with the mean GP's kernel from the last good fit; the noise model stays fresh."""
        restored = copy.deepcopy(new)
        raw = list(good["mean"]["raw"][:4]) + list(new["mean"]["raw"][4:])
        restored["mean"] = {"raw": raw}
        restored["lengthscales_uv"] = list(_lengthscales_of(raw, self.floor_uv))
        restored["restored_from_n_points"] = good.get("n_points")
        return restored

    def _report(
        self,
        hyper: dict[str, Any],
        obs: Observations,
        collapse: bool,
        reason: str,
        used_last_good: bool,
        iterations: int,
        seconds: float,
    ) -> FitReport:
        assert self._mean is not None
        ls = hyper["lengthscales_uv"]
        noise_ls = None
        if self._noise is not None:
            nl = self._noise.lengthscale
            noise_ls = (float(nl[0]), float(nl[1]))
        return FitReport(
            lengthscales_uv=(float(ls[0]), float(ls[1])),
            noise_lengthscales_uv=noise_ls,
            outputscale=self._mean.outputscale * self._y_scale**2,
            mean_const=self._mean.constant * self._y_scale + self._y_loc,
            collapse=collapse,
            collapse_reason=reason,
            used_last_good=used_last_good,
            n_points=obs.n,
            iterations=iterations,
            seconds=seconds,
            hyper=copy.deepcopy(hyper),
        )


def _spread_mask(obs: Observations) -> np.ndarray:
    assert obs.spread_dof is not None
    return (obs.spread_dof >= 1) & np.isfinite(obs.spread_var_gpa2)


def _pooled_var(obs: Observations) -> float:
    """Pooled within-grid variance (GPa²), weighted by degrees of freedom."""
    mask = _spread_mask(obs)
    assert obs.spread_dof is not None
    dof = obs.spread_dof[mask]
    return max(float(np.sum(dof * obs.spread_var_gpa2[mask]) / np.sum(dof)), MIN_SPREAD_GPA2)

"""Where the map is learned fastest per second: integrated variance reduction (IVR) from the fitted kernel.

A GP's posterior covariance does not depend on the measured values, only on where and how precisely one
measures, so the gain of a planned grid (and of several grids planned together) is known before it runs.
The gain of a candidate c measured with noise variance r is the drop in the latent variance summed over a
reference lattice, weighted by 1/μ² so that it counts relative error, the way MAPE does:

    IVR(c) = Σ_x w(x) · C(x, c)² / (C(c, c) + r)

``PosteriorCov`` rebuilds C from the surrogate's fitted kernel (``GPSummary``), the tested centres and their
noise; greedy conditioning (``condition_on``) plans a program's sub-grids jointly without any refit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from scipy import sparse

from core.estimators import CentreEstimator, estimator_efficiency
from core.model.ski import JITTER, SKI_ABOVE, grid_for
from core.policies.base import GPSummary

if TYPE_CHECKING:
    from core.policies.base import PlanContext

REFERENCE_N = 12  # reference lattice per side on which the variance is integrated


def median_noise_var(
    noise_sd_gpa: np.ndarray, n_indents: np.ndarray | int, estimator: CentreEstimator = "median"
) -> np.ndarray:
    """Noise variance of the centre value of n indents with per-indent sd σ (GPa²)."""
    n = np.asarray(n_indents, dtype=float)
    eff = estimator_efficiency(estimator, n)
    return np.asarray(eff * np.asarray(noise_sd_gpa, dtype=float) ** 2 / n, dtype=float)


def _kernel(kind: str, a: np.ndarray, b: np.ndarray, ls: np.ndarray, os: float) -> np.ndarray:
    d = (a[:, None, :] - b[None, :, :]) / ls
    r2 = np.einsum("ijk,ijk->ij", d, d)
    if kind == "rbf":
        return np.asarray(os * np.exp(-0.5 * r2))
    r = np.sqrt(5.0 * r2)
    return np.asarray(os * (1.0 + r + r * r / 3.0) * np.exp(-r))


class _ExactPosterior:
    """The fitted kernel on the tested centres, factored once: C(a, b) = k(a, b) − F(a)ᵀF(b), F = L⁻¹k(X, ·)."""

    def __init__(self, summary: GPSummary, uv: np.ndarray, noise_var: np.ndarray) -> None:
        self.kind = summary.kernel
        self.ls = np.asarray(summary.lengthscales_uv, dtype=float)
        self.os = float(summary.outputscale_gpa2)
        self.uv = uv
        self._factor(np.maximum(noise_var, 1e-10 * self.os))

    def _factor(self, noise_var: np.ndarray) -> None:
        k = self.kernel(self.uv, self.uv)
        k[np.diag_indices_from(k)] += noise_var
        self._chol = np.linalg.cholesky(k)

    def kernel(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return _kernel(self.kind, a, b, self.ls, self.os)

    def factor(self, pts: np.ndarray) -> np.ndarray:
        from scipy.linalg import solve_triangular

        return np.asarray(solve_triangular(self._chol, self.kernel(self.uv, pts), lower=True))

    def cov(self, a: np.ndarray, fa: np.ndarray, b: np.ndarray, fb: np.ndarray) -> np.ndarray:
        """C(a, b) from the points and their factors."""
        return np.asarray(self.kernel(a, b) - fa.T @ fb)

    def cov_row(self, a: np.ndarray, fa: np.ndarray, b: np.ndarray, fb: np.ndarray) -> np.ndarray:
        """C(a, b) for one point a (fa its factor, 1-D) and many b."""
        return np.asarray(self.kernel(a, b)[0] - fa @ fb)

    def var(self, f: np.ndarray) -> np.ndarray:
        return np.asarray(self.os - np.einsum("ij,ij->j", f, f))


class _GridPosterior(_ExactPosterior):
    """The posterior as the surrogate's interpolated GP has it above SKI_ABOVE centres (KISS-GP): the grid
    values' posterior N(·, G Gᵀ), G Gᵀ = (Kmm⁻¹ + Wᵀ D⁻¹ W)⁻¹, read at any point through its 16 cubic
    weights, so C(a, b) = F(a)ᵀF(b) with F = Gᵀ W(·)ᵀ of m rows whatever n is: no n × n factor and no
    n × candidates matrix. D carries the variance the interpolation loses at each centre, as in the fit
    (``core.model.ski``); the interpolated prior, not k, is what the data are taken off, as in its predictions
    (on a 1,000-centre design the exact-prior form misjudged the posterior variance by 6–27 % (median), this
    one by 1–4 %).
    """

    def _factor(self, noise_var: np.ndarray) -> None:
        from scipy.linalg import solve_triangular

        self._grid = grid_for(tuple(self.ls))
        z = self._grid.points().numpy()
        kmm = self.kernel(z, z)
        kmm[np.diag_indices_from(kmm)] += JITTER * self.os
        w = self._weights(self.uv)
        lost = self.os - np.asarray(w.multiply(w @ kmm).sum(axis=1)).ravel()  # k(x, x) − wᵀ Kmm w
        inv_d = 1.0 / (noise_var + np.maximum(lost, 0.0))
        s = (w.T.multiply(inv_d) @ w).toarray()
        lm = np.linalg.cholesky(kmm)
        lb = np.linalg.cholesky(lm.T @ s @ lm + np.eye(len(kmm)))
        self._g = solve_triangular(lb, lm.T, lower=True).T  # Lm LB⁻ᵀ

    def _weights(self, pts: np.ndarray) -> sparse.csr_matrix:
        import torch

        idx, w = self._grid.weights(torch.as_tensor(pts, dtype=torch.float64))
        rows = np.repeat(np.arange(len(pts)), idx.shape[1])
        return sparse.csr_matrix(
            (w.numpy().ravel(), (rows, idx.numpy().ravel())), shape=(len(pts), self._grid.m)
        )

    def factor(self, pts: np.ndarray) -> np.ndarray:
        return np.asarray((self._weights(pts) @ self._g).T)

    def cov(self, a: np.ndarray, fa: np.ndarray, b: np.ndarray, fb: np.ndarray) -> np.ndarray:
        return np.asarray(fa.T @ fb)

    def cov_row(self, a: np.ndarray, fa: np.ndarray, b: np.ndarray, fb: np.ndarray) -> np.ndarray:
        return np.asarray(fa @ fb)

    def var(self, f: np.ndarray) -> np.ndarray:
        return np.asarray(np.einsum("ij,ij->j", f, f))


def posterior(summary: GPSummary, uv: np.ndarray, noise_var: np.ndarray) -> _ExactPosterior:
    """The posterior the planner prices with: the model's own (exact up to SKI_ABOVE centres, interpolated
    above, where the exact one's n × n factor took 14 s of CPU and 1.4 GB at 5,000 centres)."""

    cls = _GridPosterior if len(uv) > SKI_ABOVE else _ExactPosterior
    return cls(summary, uv, noise_var)


@dataclass
class PosteriorCov:
    """Posterior covariance of the latent map between a reference lattice R and candidate centres C.

    Holds C(R, cand) and the candidates' variances; ``condition_on`` folds in a planned (not yet measured)
    grid, so the next pick sees what the earlier picks will already have taught. Each planned pick is a
    rank-one downdate kept as its two factors (over R and over the candidates) rather than applied to the
    m × k matrix: a greedy block of b picks then costs b matrix-vector products instead of b rewrites and
    squarings of C(R, cand), and the integrated reduction (``spread``) is updated exactly from the factors.
    """

    post: _ExactPosterior
    ref_uv: np.ndarray  # (m, 2)
    ref_w: np.ndarray  # (m,) weights, summing to 1
    cand_uv: np.ndarray  # (k, 2)
    f_cand: np.ndarray  # (r, k) the candidates' factors (``_ExactPosterior.factor``)
    cov_rc0: np.ndarray  # (m, k) before any planned pick
    var_c: np.ndarray  # (k,)
    downdates: list[np.ndarray] = field(
        default_factory=list
    )  # planned picks, as rank-1 updates over candidates
    ref_downdates: list[np.ndarray] = field(default_factory=list)  # the same picks' factors over R, (m,)
    spread_c: np.ndarray | None = None  # Σ_x w(x)·C(x, c)² once computed (kept through conditioning)

    @classmethod
    def build(
        cls,
        summary: GPSummary,
        train_uv: np.ndarray,
        train_noise_var: np.ndarray,
        cand_uv: np.ndarray,
        ref_uv: np.ndarray,
        ref_w: np.ndarray,
    ) -> PosteriorCov:
        return cls.of(posterior(summary, train_uv, train_noise_var), cand_uv, ref_uv, ref_w)

    @classmethod
    def of(
        cls, post: _ExactPosterior, cand_uv: np.ndarray, ref_uv: np.ndarray, ref_w: np.ndarray
    ) -> PosteriorCov:
        f_cand, f_ref = post.factor(cand_uv), post.factor(ref_uv)
        cov_rc = post.cov(ref_uv, f_ref, cand_uv, f_cand)
        var_c = np.maximum(post.var(f_cand), 1e-12 * post.os)
        return cls(post, ref_uv, ref_w / ref_w.sum(), cand_uv, f_cand, cov_rc, var_c)

    @property
    def cov_rc(self) -> np.ndarray:
        """C(R, cand) with the planned picks folded in (materialised: for tests and inspection)."""
        out = self.cov_rc0.copy()
        for a, u in zip(self.ref_downdates, self.downdates, strict=True):
            out -= np.outer(a, u)
        return out

    @property
    def spread(self) -> np.ndarray:
        """Σ_x w(x)·C(x, c)² per candidate: how much of the map each candidate is correlated with."""
        if self.spread_c is None:
            c = self.cov_rc
            self.spread_c = np.asarray(self.ref_w @ (c * c), dtype=float)
        return self.spread_c

    def gain(self, noise_var: np.ndarray | float) -> np.ndarray:
        """IVR of every candidate measured with the given noise variance (GPa², per candidate)."""
        return np.asarray(self.spread / (self.var_c + noise_var), dtype=float)

    def subset(self, cols: np.ndarray) -> PosteriorCov:
        """The same posterior restricted to some candidates (cheaper to condition and score)."""
        return PosteriorCov(
            self.post,
            self.ref_uv,
            self.ref_w,
            self.cand_uv[cols],
            self.f_cand[:, cols],
            self.cov_rc0[:, cols],
            self.var_c[cols],
            [u[cols] for u in self.downdates],
            list(self.ref_downdates),
            None if self.spread_c is None else self.spread_c[cols],
        )

    def cov_with(self, j: int) -> np.ndarray:
        """Posterior covariance between candidate j and every candidate (planned picks included)."""
        row = self.post.cov_row(self.cand_uv[j : j + 1], self.f_cand[:, j], self.cand_uv, self.f_cand)
        for u in self.downdates:
            row = row - u[j] * u
        return np.asarray(row, dtype=float)

    def _ref_column(self, j: int) -> np.ndarray:
        """C(R, candidate j) with the planned picks folded in."""
        col = self.cov_rc0[:, j].copy()
        for a, u in zip(self.ref_downdates, self.downdates, strict=True):
            col -= u[j] * a
        return col

    def condition_on(self, j: int, noise_var: float) -> PosteriorCov:
        """The covariance after candidate j is measured with ``noise_var`` (a new object; self is unchanged).

        With C' = C − a uᵀ (a = C(R, j)/√d, u = C(cand, j)/√d): Σ w C'² = Σ w C² − 2u·((w a)ᵀC) + u²·Σ w a²."""
        cj = self.cov_with(j)
        root = math.sqrt(float(self.var_c[j] + noise_var))
        u = cj / root
        a = self._ref_column(j) / root
        var_c = np.maximum(self.var_c - u * u, 1e-12 * self.post.os)
        spread = None
        if self.spread_c is not None:
            wa = self.ref_w * a
            cross = wa @ self.cov_rc0
            for a_i, u_i in zip(self.ref_downdates, self.downdates, strict=True):
                cross -= float(wa @ a_i) * u_i
            spread = np.maximum(self.spread_c - 2.0 * u * cross + u * u * float(wa @ a), 0.0)
        return PosteriorCov(
            self.post,
            self.ref_uv,
            self.ref_w,
            self.cand_uv,
            self.f_cand,
            self.cov_rc0,
            var_c,
            [*self.downdates, u],
            [*self.ref_downdates, a],
            spread,
        )


def reference_lattice(n: int = REFERENCE_N) -> np.ndarray:
    """Cell centres of an n×n lattice over the unit square: where the map's error is counted."""
    c = (np.arange(n) + 0.5) / n
    u, v = np.meshgrid(c, c)
    return np.column_stack([u.ravel(), v.ravel()])


def design_rel_error(
    summary: GPSummary,
    design_uv: np.ndarray,
    design_noise_var: np.ndarray,
    ref_uv: np.ndarray,
    ref_mu: np.ndarray,
) -> float:
    """RMS relative error of the map that a design alone would give (y-free): a precision to aim for.

    The planner compares biases with it, e.g. a fast hold's drift bias with what the 9×9 grid baseline
    would reach on this sample under the current kernel.
    """
    post = posterior(summary, design_uv, design_noise_var)
    var = np.maximum(post.var(post.factor(ref_uv)), 0.0)
    return float(np.sqrt(np.mean(var / np.maximum(ref_mu, 1e-6) ** 2)))


def nearest_lattice(lattice_uv: np.ndarray, pts_uv: np.ndarray) -> np.ndarray:
    """The index of the lattice point nearest each point (u, v)."""
    from scipy.spatial import cKDTree

    _, nearest = cKDTree(lattice_uv).query(pts_uv)
    return np.asarray(nearest, dtype=int)


def aim_rel_error(ctx: PlanContext) -> float | None:
    """The map precision aimed at: the operator's σ target if set, else what the 9×9 grid of 5×5
    baseline would reach on this sample (relative RMS error, from the fitted kernel and noise)."""
    pred = ctx.prediction
    if pred is None:
        return None
    ref = reference_lattice()
    near = nearest_lattice(ctx.lattice.uv, ref)
    mu = np.abs(pred.mean[near])
    if ctx.settings.sigma_target_gpa is not None:
        return float(ctx.settings.sigma_target_gpa / max(float(np.mean(mu)), 1e-6))
    if ctx.gp is None:
        return None
    axis = np.arange(1, 10) / 10.0
    du, dv = np.meshgrid(axis, axis)
    design = np.column_stack([du.ravel(), dv.ravel()])
    noise = median_noise_var(pred.noise_sd[nearest_lattice(ctx.lattice.uv, design)], 25)
    noise = noise + ctx.gp.site_var_gpa2  # the grid's medians carry the site scatter too
    return design_rel_error(ctx.gp, design, noise, ref, mu)

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

import numpy as np

from core.estimators import CentreEstimator, estimator_efficiency
from core.policies.base import GPSummary

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


class _Whitener:
    """The fitted kernel on some measured (or planned) centres, factored once: L⁻¹k(X, ·) for any points."""

    def __init__(self, summary: GPSummary, uv: np.ndarray, noise_var: np.ndarray) -> None:
        from scipy.linalg import solve_triangular

        self.kind = summary.kernel
        self.ls = np.asarray(summary.lengthscales_uv, dtype=float)
        self.os = float(summary.outputscale_gpa2)
        self.uv = uv
        k = _kernel(self.kind, uv, uv, self.ls, self.os)
        k[np.diag_indices_from(k)] += np.maximum(noise_var, 1e-10 * self.os)
        self._chol = np.linalg.cholesky(k)
        self._solve = solve_triangular

    def kernel(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return _kernel(self.kind, a, b, self.ls, self.os)

    def whiten(self, pts: np.ndarray) -> np.ndarray:
        return np.asarray(self._solve(self._chol, self.kernel(self.uv, pts), lower=True))


@dataclass
class PosteriorCov:
    """Posterior covariance of the latent map between a reference lattice R and candidate centres C.

    Holds C(R, cand) and the candidates' variances; ``condition_on`` folds in a planned (not yet measured)
    grid, so the next pick sees what the earlier picks will already have taught.
    """

    summary: GPSummary
    ref_uv: np.ndarray  # (m, 2)
    ref_w: np.ndarray  # (m,) weights, summing to 1
    cand_uv: np.ndarray  # (k, 2)
    train_uv: np.ndarray  # (n, 2)
    a_cand: np.ndarray  # (n, k) L⁻¹ k(X, cand)
    cov_rc: np.ndarray  # (m, k)
    var_c: np.ndarray  # (k,)
    downdates: list[np.ndarray] = field(
        default_factory=list
    )  # planned picks, as rank-1 updates over candidates

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
        w = _Whitener(summary, train_uv, train_noise_var)
        os = w.os
        a_cand, a_ref = w.whiten(cand_uv), w.whiten(ref_uv)
        cov_rc = w.kernel(ref_uv, cand_uv) - a_ref.T @ a_cand
        var_c = np.maximum(os - np.einsum("ij,ij->j", a_cand, a_cand), 1e-12 * os)
        return cls(summary, ref_uv, ref_w / ref_w.sum(), cand_uv, train_uv, a_cand, cov_rc, var_c)

    def __post_init__(self) -> None:
        self._spread: np.ndarray | None = None

    @property
    def spread(self) -> np.ndarray:
        """Σ_x w(x)·C(x, c)² per candidate: how much of the map each candidate is correlated with."""
        if self._spread is None:
            self._spread = np.asarray(self.ref_w @ (self.cov_rc * self.cov_rc), dtype=float)
        return self._spread

    def gain(self, noise_var: np.ndarray | float) -> np.ndarray:
        """IVR of every candidate measured with the given noise variance (GPa², per candidate)."""
        return np.asarray(self.spread / (self.var_c + noise_var), dtype=float)

    def subset(self, cols: np.ndarray) -> PosteriorCov:
        """The same posterior restricted to some candidates (cheaper to condition and score)."""
        return PosteriorCov(
            self.summary,
            self.ref_uv,
            self.ref_w,
            self.cand_uv[cols],
            self.train_uv,
            self.a_cand[:, cols],
            self.cov_rc[:, cols],
            self.var_c[cols],
            [u[cols] for u in self.downdates],
        )

    def cov_with(self, j: int) -> np.ndarray:
        """Posterior covariance between candidate j and every candidate (planned picks included)."""
        s = self.summary
        ls = np.asarray(s.lengthscales_uv, dtype=float)
        prior = _kernel(s.kernel, self.cand_uv[j : j + 1], self.cand_uv, ls, float(s.outputscale_gpa2))[0]
        row = prior - self.a_cand[:, j] @ self.a_cand
        for u in self.downdates:
            row = row - u[j] * u
        return np.asarray(row, dtype=float)

    def condition_on(self, j: int, noise_var: float) -> PosteriorCov:
        """The covariance after candidate j is measured with ``noise_var`` (a new object; self is unchanged)."""
        cj = self.cov_with(j)
        denom = float(self.var_c[j] + noise_var)
        u = cj / math.sqrt(denom)
        cov_rc = self.cov_rc - np.outer(self.cov_rc[:, j] / math.sqrt(denom), u)
        var_c = np.maximum(self.var_c - u * u, 1e-12 * float(self.summary.outputscale_gpa2))
        return PosteriorCov(
            self.summary,
            self.ref_uv,
            self.ref_w,
            self.cand_uv,
            self.train_uv,
            self.a_cand,
            cov_rc,
            var_c,
            [*self.downdates, u],
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
    w = _Whitener(summary, design_uv, design_noise_var)
    a = w.whiten(ref_uv)
    var = np.maximum(w.os - np.einsum("ij,ij->j", a, a), 0.0)
    return float(np.sqrt(np.mean(var / np.maximum(ref_mu, 1e-6) ** 2)))

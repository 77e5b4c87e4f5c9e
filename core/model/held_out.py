"""Leave-one-out residuals of a GP at its own data: how well a map predicts a CSM value it has not seen.

A run with a fast channel has two maps of the same CSM data, the CSM-only GP's and the two-fidelity one, and
the likelihoods of the two are not comparable (the two-fidelity level conditions on the fast channel, and
fixes its noise where the CSM-only GP learns its own). Their predictions of held-out CSM values are: each
centre's value predicted from all the others, in closed form from one inverse of the data's covariance
(Dubrule, Math. Geol. 15 (1983) 687), the mean's regression coefficients estimated again without the centre
(universal kriging: the projector P = K⁻¹ − K⁻¹F(FᵀK⁻¹F)⁻¹FᵀK⁻¹, residual (Py)ᵢ/Pᵢᵢ). Hyperparameters are
held, as in Rasmussen & Williams (2006) §5.4.2.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from core.model.kernels import DTYPE

JITTER_REL = 1e-8  # on K's diagonal, relative to its mean, when a Cholesky fails


def loo_residuals(k: torch.Tensor, y: torch.Tensor, basis: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
    """(residual yᵢ − E[yᵢ | y₋ᵢ], its predictive variance) per point, in y's units: K the data's covariance
    (noise included), ``basis`` (n, p) the mean's regression columns (p = 0: a known zero mean)."""
    n = int(y.shape[0])
    with torch.no_grad():
        k = 0.5 * (k + k.T)
        chol, info = torch.linalg.cholesky_ex(k)
        if int(info) != 0:
            chol = torch.linalg.cholesky(k + JITTER_REL * float(k.diagonal().mean()) * torch.eye(n, dtype=DTYPE))
        p = torch.cholesky_inverse(chol)
        if basis.numel():
            kf = p @ basis
            a = basis.T @ kf
            p = p - kf @ torch.linalg.solve(a + 1e-12 * torch.eye(a.shape[0], dtype=DTYPE), kf.T)
        d = p.diagonal().clamp_min(1e-300)
        return (p @ y / d).numpy(), (1.0 / d).numpy()


@dataclass(frozen=True)
class HeldOut:
    """The two maps' leave-one-out errors at the CSM centres, relative to each centre's value (%), and which
    map the run keeps: the two-fidelity one only where it predicts the held-out values better."""

    two_fidelity_pct: float  # root mean square of the relative LOO residuals, two-fidelity map
    csm_only_pct: float  # ... CSM-only GP
    centres: int

    @property
    def two_fidelity_wins(self) -> bool:
        return self.two_fidelity_pct < self.csm_only_pct

    def words(self) -> str:
        kept = "two-fidelity" if self.two_fidelity_wins else "CSM-only"
        return (
            f"held-out CSM values ({self.centres}): two-fidelity {self.two_fidelity_pct:.3g} %, "
            f"CSM-only {self.csm_only_pct:.3g} % → {kept} map"
        )


def compare(values_gpa: np.ndarray, two_fidelity_resid: np.ndarray, csm_only_resid: np.ndarray) -> HeldOut:
    """The relative RMS of each map's LOO residuals at the same centres (values ≤ 0 or not finite: left out)."""
    v = np.asarray(values_gpa, dtype=float)
    a, b = np.asarray(two_fidelity_resid, dtype=float), np.asarray(csm_only_resid, dtype=float)
    ok = np.isfinite(v) & (v > 0) & np.isfinite(a) & np.isfinite(b)
    if not ok.any():
        return HeldOut(math.inf, math.inf, 0)
    ra, rb = a[ok] / v[ok], b[ok] / v[ok]
    return HeldOut(
        float(100.0 * np.sqrt(np.mean(ra**2))), float(100.0 * np.sqrt(np.mean(rb**2))), int(ok.sum())
    )

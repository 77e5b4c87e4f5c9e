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

from core.model.cokriging import JITTER_REL
from core.model.kernels import DTYPE


def loo_residuals(k: torch.Tensor, y: torch.Tensor, basis: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
    """(residual yᵢ − E[yᵢ | y₋ᵢ], its predictive variance) per point, in y's units: K the data's covariance
    (noise included), ``basis`` (n, p) the mean's regression columns (p = 0: a known zero mean)."""
    n = int(y.shape[0])
    with torch.no_grad():
        k = 0.5 * (k + k.T)
        chol, info = torch.linalg.cholesky_ex(k)
        if int(info) != 0:
            chol = torch.linalg.cholesky(
                k + JITTER_REL * float(k.diagonal().mean()) * torch.eye(n, dtype=DTYPE)
            )
        p = torch.cholesky_inverse(chol)
        if basis.numel():
            kf = p @ basis
            a = basis.T @ kf
            p = p - kf @ torch.linalg.solve(a + 1e-12 * torch.eye(a.shape[0], dtype=DTYPE), kf.T)
        d = p.diagonal().clamp_min(1e-300)
        return (p @ y / d).numpy(), (1.0 / d).numpy()


EVIDENCE_Z = 2.0  # the two-fidelity map must beat the CSM-only GP by this many standard errors (one-sided)


@dataclass(frozen=True)
class HeldOut:
    """The two maps' leave-one-out errors at the CSM centres, relative to each centre's value (%), and which
    map the run keeps. The CSM-only GP is the default: the two-fidelity map is kept only when its squared
    held-out errors are smaller, centre by centre, by ``EVIDENCE_Z`` standard errors of their mean difference.
    Both residuals carry the same CSM noise, so the paired difference cancels most of it; a single mean, where
    noise of 10 % hides map errors of 0.5 %, flips between the two maps on chance alone."""

    two_fidelity_pct: float  # root mean square of the relative LOO residuals, two-fidelity map
    csm_only_pct: float  # ... CSM-only GP
    centres: int
    z: float = (
        0.0  # the mean paired difference (CSM-only − two-fidelity squared errors) over its standard error
    )

    @property
    def two_fidelity_wins(self) -> bool:
        return self.z > EVIDENCE_Z

    def words(self) -> str:
        kept = "two-fidelity" if self.two_fidelity_wins else "CSM-only"
        return (
            f"held-out CSM values ({self.centres}): two-fidelity {self.two_fidelity_pct:.3g} %, "
            f"CSM-only {self.csm_only_pct:.3g} % (z {self.z:+.2g}) → {kept} map"
        )


def compare(values_gpa: np.ndarray, two_fidelity_resid: np.ndarray, csm_only_resid: np.ndarray) -> HeldOut:
    """Each map's relative RMS LOO residual at the same centres and the paired z of their squared errors
    (values ≤ 0 or not finite: left out)."""
    v = np.asarray(values_gpa, dtype=float)
    a, b = np.asarray(two_fidelity_resid, dtype=float), np.asarray(csm_only_resid, dtype=float)
    ok = np.isfinite(v) & (v > 0) & np.isfinite(a) & np.isfinite(b)
    n = int(ok.sum())
    if n == 0:
        return HeldOut(math.inf, math.inf, 0)
    ra, rb = a[ok] / v[ok], b[ok] / v[ok]
    d = rb**2 - ra**2
    se = float(np.std(d, ddof=1)) / math.sqrt(n) if n > 1 else math.inf
    z = float(np.mean(d)) / se if se > 0 else (math.inf if float(np.mean(d)) > 0 else 0.0)
    return HeldOut(float(100.0 * np.sqrt(np.mean(ra**2))), float(100.0 * np.sqrt(np.mean(rb**2))), n, z)

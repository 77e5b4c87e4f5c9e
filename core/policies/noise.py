"""The noise model part: how a block's indents become the values the GP learns from, and how much to trust them.

- the centre estimator collapses a replicate grid to one value (the median, SPEC §5, or Huber's estimate);
- drift correction applies Eq. 7 with each fast indent's own drift reading before that;
- the outlier rule (Student-t weights) lets a value far off the fitted map count as a noisier one instead of
  bending the map: a cracked indent or one on a pore reads far low, and a single indent has no grid median
  to protect it. A Gaussian model ("none") trusts every value as its noise model says.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from core.estimators import MAD_TO_SD, CentreEstimator, centre_value, estimator_efficiency

OutlierRule = Literal["none", "student-t"]
NEIGHBOURS = 16  # residuals whose spread is the local yardstick
CORE_Z = 3.0  # within 3 local sd a value is trusted fully (no efficiency lost on well-behaved films)


@dataclass(frozen=True)
class NoiseModel:
    centre_estimator: CentreEstimator = "median"
    # fast indents corrected with the measured drift rate by Eq. 7 before the centre value (the journal keeps
    # what the instrument reported)
    drift_correction: bool = False
    outliers: OutlierRule = "none"
    dof: float = 4.0  # Student-t degrees of freedom: few enough that a wild value barely pulls the map

    def centre(self, hardness_gpa: np.ndarray) -> tuple[float, float]:
        """(value the GP sees, var(value)·n/σ²) for one centre's indents."""
        h = np.asarray(hardness_gpa, dtype=float)
        return centre_value(h, self.centre_estimator), float(
            estimator_efficiency(self.centre_estimator, h.size)
        )

    def efficiency(self, n_indents: np.ndarray | int) -> np.ndarray:
        return estimator_efficiency(self.centre_estimator, n_indents)

    def noise_inflation(self, residual_gpa: np.ndarray, uv: np.ndarray) -> np.ndarray:
        """Per-centre factor (≥ 1) on the noise variance: the Student-t's weights as an iteratively reweighted
        Gaussian. Each residual is scaled by the normalised MAD of its neighbours' residuals: the outliers do
        not set their own yardstick, and a film that scatters more in one phase is not read as outliers."""
        r = np.asarray(residual_gpa, dtype=float)
        if self.outliers == "none" or r.size < NEIGHBOURS:
            return np.ones_like(r)
        from scipy.spatial import cKDTree

        _, near = cKDTree(np.asarray(uv, dtype=float)).query(uv, k=NEIGHBOURS)
        local = r[near]
        scale = MAD_TO_SD * np.median(np.abs(local - np.median(local, axis=1, keepdims=True)), axis=1)
        ok = np.isfinite(scale) & (scale > 0.0)
        z2 = np.where(ok, (r / np.where(ok, scale, 1.0)) ** 2, 0.0)
        return np.asarray(np.maximum((self.dof + z2) / (self.dof + CORE_Z**2), 1.0), dtype=float)

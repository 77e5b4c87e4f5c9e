"""A truth field laid onto a sample: any field fits any sample's (u, v) chart."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from core.geometry import Calibration
from drivers.sim.truth import Bounds, FloatArray, TruthField, truth_modulus_gpa, truth_modulus_noise_sd_gpa


class LaidTruth:
    """A truth field whose area is stretched onto a sample's (u, v) chart, so any field fits any sample."""

    def __init__(self, base: TruthField, calibration: Calibration) -> None:
        self.base = base
        self.calibration = calibration
        self.name = f"{base.name}@sample"
        x0, x1, y0, y1 = calibration.bounds_um
        self.bounds_um: Bounds = (x0, x1, y0, y1)

    def _field_xy(self, x_um: ArrayLike, y_um: ArrayLike) -> tuple[FloatArray, FloatArray]:
        u, v = self.calibration.to_uv(x_um, y_um)
        fx0, fx1, fy0, fy1 = self.base.bounds_um
        u = np.clip(u, 0.0, 1.0)
        v = np.clip(v, 0.0, 1.0)
        return fx0 + u * (fx1 - fx0), fy0 + v * (fy1 - fy0)

    def hardness_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        return self.base.hardness_gpa(*self._field_xy(x_um, y_um))

    def noise_sd_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        return self.base.noise_sd_gpa(*self._field_xy(x_um, y_um))

    def modulus_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        return truth_modulus_gpa(self.base, *self._field_xy(x_um, y_um))

    def modulus_noise_sd_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        return truth_modulus_noise_sd_gpa(self.base, *self._field_xy(x_um, y_um))

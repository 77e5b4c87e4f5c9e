"""The simulated instrument's physics: ground-truth hardness fields, vertical drift, and what an indent reports.

The emulator stands in for the sample and the nanoindenter during planning studies (SPEC §4). A truth field
gives the hardness and the per-indent scatter at any stage point; a drift model gives the vertical drift rate
on the instrument clock; the ``Emulator`` turns a commanded indent into a measurement. Every random draw is
a pure function of (seed, block_id, indent_index), so a crashed and resumed campaign measures exactly what an
uninterrupted one would have.

The truth fields are in ``drivers.sim.truth`` (the protocol, noise modes), ``drivers.sim.fields`` (analytic)
and ``drivers.sim.truth_csv`` (from a file); the drift model in ``drivers.sim.drift``. This module is the
measurement: what one commanded indent reports. The names below stay importable from here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from core.drift import area_error_pct
from core.errors import InputError
from core.profile import InstrumentProfile
from drivers.sim.drift import DRIFT_SCENARIOS, DriftModel
from drivers.sim.fields import (
    EdgeSpotField,
    PhaseBoundaryField,
    QuaternaryFilm,
    RotatedQuaternaryField,
    RoughField,
    SiteTexture,
    TernaryField,
)
from drivers.sim.truth import (
    NOISE_MODES,
    Bounds,
    FloatArray,
    ModulusTruth,
    NoiseOverride,
    TruthField,
    broadcast_xy,
    check_seed,
    field_extrema,
    modulus_from_hardness_gpa,
    modulus_on_lattice,
    truth_modulus_gpa,
    truth_modulus_noise_sd_gpa,
    truth_on_lattice,
)
from drivers.sim.truth_csv import CsvTruth

__all__ = [
    "DRIFT_SCENARIOS",
    "NOISE_MODES",
    "Bounds",
    "CsvTruth",
    "DriftModel",
    "EdgeSpotField",
    "Emulator",
    "FloatArray",
    "Measurement",
    "ModulusTruth",
    "NoiseOverride",
    "PhaseBoundaryField",
    "QuaternaryFilm",
    "RotatedQuaternaryField",
    "RoughField",
    "SiteTexture",
    "TernaryField",
    "TruthField",
    "area_error_pct",
    "field_extrema",
    "modulus_from_hardness_gpa",
    "modulus_on_lattice",
    "truth_modulus_gpa",
    "truth_modulus_noise_sd_gpa",
    "truth_on_lattice",
]


@dataclass(frozen=True)
class Measurement:
    actual_x_um: float
    actual_y_um: float
    hardness_gpa: float
    modulus_gpa: float
    drift_rate_nm_s: float
    depth_at_max_load_nm: float  # the test runs to its nominal depth, as measured (drift included)


# stream numbers k in default_rng([seed, block_id, indent_index, k]): one per physical effect, so turning one
# effect on or off never changes the draws of the others
_K_LATERAL, _K_HARDNESS, _K_MODULUS, _K_DRIFT = 0, 1, 2, 3


class Emulator:
    """Turns a commanded indent into what the instrument would report.

    Depth bias from vertical drift is DR(t)·t_measure·r(hold), r = max(0, 1 − hold/full_correction_hold_s):
    the post-hold drift measurement corrects the depth fully after the profile's longest hold (80 s on the
    iMicro) and barely after 5 s. The test runs
    to its nominal depth as measured (drift included), so the true depth is shallower by the uncorrected
    bias: the instrument overestimates the contact area (∝ depth²) and hardness reads low. This is the
    convention of the paper's Eq. 7 (h_true = h_meas − DR·t), which the hold rule and the correction use.
    """

    def __init__(
        self,
        truth: TruthField,
        drift: DriftModel,
        seed: int,
        lateral_sd_um: float = 0.0,
        nominal_depth_nm: float = 100.0,
        t_measure_s: float = 40.0,
        full_correction_hold_s: float = max(InstrumentProfile.allowed_holds_s),
        site_texture: SiteTexture | None = None,
    ) -> None:
        self.truth = truth
        self.site_texture = site_texture
        self.drift = drift
        self.seed = check_seed(seed)
        for key, value in (
            ("lateral_sd_um", lateral_sd_um),
            ("nominal_depth_nm", nominal_depth_nm),
            ("t_measure_s", t_measure_s),
            ("full_correction_hold_s", full_correction_hold_s),
        ):
            if not math.isfinite(value) or value < 0 or (key != "lateral_sd_um" and value == 0):
                raise InputError(key, f"must be a finite number {'≥' if key == 'lateral_sd_um' else '>'} 0")
        self.lateral_sd_um = float(lateral_sd_um)
        self.nominal_depth_nm = float(nominal_depth_nm)
        self.t_measure_s = float(t_measure_s)
        self.full_correction_hold_s = float(full_correction_hold_s)

    def residual_fraction(self, hold_s: float) -> float:
        """The share of the drift bias a hold leaves uncorrected."""
        return max(0.0, 1.0 - hold_s / self.full_correction_hold_s)

    def depth_bias_nm(self, t_s: float, hold_s: float) -> float:
        return float(self.drift.rate_nm_s(t_s)) * self.t_measure_s * self.residual_fraction(hold_s)

    def true_modulus_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        """The modulus truth at stage points, clamped to the field's area as the hardness."""
        x_min, x_max, y_min, y_max = self.truth.bounds_um
        x, y = broadcast_xy(x_um, y_um)
        return truth_modulus_gpa(self.truth, np.clip(x, x_min, x_max), np.clip(y, y_min, y_max))

    def true_hardness_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        """Truth at stage points, clamped to the field's area (an indent that lands off it sees the edge)."""
        x_min, x_max, y_min, y_max = self.truth.bounds_um
        x, y = broadcast_xy(x_um, y_um)
        return self.truth.hardness_gpa(np.clip(x, x_min, x_max), np.clip(y, y_min, y_max))

    def _rng(self, block_id: int, indent_index: int, k: int) -> np.random.Generator:
        return np.random.default_rng([self.seed, block_id, indent_index, k])

    def measure(
        self, x_um: float, y_um: float, hold_s: float, t_s: float, block_id: int, indent_index: int
    ) -> Measurement:
        """One indent: a pure function of (seed, block_id, indent_index) and the arguments."""
        if block_id < 0 or indent_index < 0:
            raise ValueError(f"block_id and indent_index must be ≥ 0, got {block_id}, {indent_index}")
        if not (math.isfinite(hold_s) and hold_s >= 0 and math.isfinite(t_s)):
            raise ValueError(f"hold_s must be ≥ 0 and t_s finite, got {hold_s!r}, {t_s!r}")
        ax, ay = float(x_um), float(y_um)
        if self.lateral_sd_um > 0:
            dx, dy = self._rng(block_id, indent_index, _K_LATERAL).normal(0.0, self.lateral_sd_um, 2)
            ax, ay = ax + float(dx), ay + float(dy)
        x_min, x_max, y_min, y_max = self.truth.bounds_um
        cx, cy = min(max(ax, x_min), x_max), min(max(ay, y_min), y_max)
        h_true = float(self.truth.hardness_gpa(cx, cy))
        sd = float(self.truth.noise_sd_gpa(cx, cy))
        h_noisy = h_true + sd * float(self._rng(block_id, indent_index, _K_HARDNESS).standard_normal())
        if self.site_texture is not None:
            h_noisy += float(self.site_texture.offset_gpa(cx, cy))
        h_noisy = max(h_noisy, 1e-3)
        depth = self.nominal_depth_nm
        # true / measured depth; a drift displacement of the whole depth would leave no indent to read
        shrink = max(depth - self.depth_bias_nm(t_s, hold_s), 0.01 * depth) / depth
        # the same contact-area error drives both: H ∝ 1/A, E ∝ 1/√A, so E carries half of H's relative error,
        # and the film's own modulus scatter on top (its own stream: the hardness draws never change)
        e_true = float(truth_modulus_gpa(self.truth, cx, cy))
        e_sd = float(truth_modulus_noise_sd_gpa(self.truth, cx, cy))
        rel = 0.5 * (h_noisy - h_true) / h_true + e_sd / e_true * float(
            self._rng(block_id, indent_index, _K_MODULUS).standard_normal()
        )
        rate = float(self.drift.rate_nm_s(t_s))
        reading = rate + (0.1 * rate + 0.002) * float(
            self._rng(block_id, indent_index, _K_DRIFT).standard_normal()
        )
        return Measurement(
            actual_x_um=ax,
            actual_y_um=ay,
            hardness_gpa=h_noisy * shrink**2,
            modulus_gpa=max(e_true * (1.0 + rel), 1e-3) * shrink,
            drift_rate_nm_s=max(reading, 0.0),
            depth_at_max_load_nm=depth,
        )

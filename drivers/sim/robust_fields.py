"""Truth fields of other characters than the built-in ones, for the bench's robustness suite.

No policy was tuned on these. Each is a ground-truth map on the 1000 µm square (hardness and per-indent
scatter, GPa) as the simulated instrument sees it; ``robust_scenario`` wraps one in a Scenario with the
ternary library's stage, profile and (no) drift, so the only thing that changes is the film.

- ``grains``: a multiphase grain texture, Voronoi grains 20–60 µm across in three phases;
- ``step``: a straight step discontinuity (+1.5 GPa) across the area at an angle;
- ``stripe``: a nearly flat film with one narrow hard stripe (30 µm wide) along a diagonal;
- ``phase-noise``: two smooth phases where one scatters eight times more than the other;
- ``outliers``: the ternary library where 5 % of the surface is pores: an indent there reads 50 % low.

Each field has a modulus truth too (``modulus_gpa``, ``modulus_noise_sd_gpa``): the grains, step and
phase-noise change both maps together, but their hardest phase is not their stiffest; the stripe's stiff
stripe runs elsewhere than its hard one.

The sharp curved phase boundary, the hot spot near an edge and the rotated quaternary spread are the
emulator's own ``phase-boundary``, ``edge-spot`` and ``rotated-quaternary`` scenarios.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numpy.typing import ArrayLike

from core.errors import InputError
from drivers.sim.fields import SiteTexture, TernaryField
from drivers.sim.scenarios import Scenario, make_scenario
from drivers.sim.truth import FloatArray, TruthField

SIDE_UM = 1000.0

ROBUST_FIELDS: dict[str, str] = {
    "grains": "multiphase grain texture: Voronoi grains 20–60 µm across in three phases (4.5, 5.5, 7 GPa)",
    "step": "a straight step discontinuity of +1.5 GPa across the area, 20° off the stage axes",
    "stripe": "a nearly flat film (6 GPa ± 2 %) with one narrow hard stripe (+1 GPa, 30 µm wide)",
    "phase-noise": "two smooth phases; the hard one scatters 8× more per indent (8 % against 1 %)",
    "outliers": "the ternary library with pores over 5 % of the surface: indents there read 50 % low",
}


def _xy(x_um: ArrayLike, y_um: ArrayLike) -> tuple[FloatArray, FloatArray]:
    x, y = np.broadcast_arrays(np.asarray(x_um, dtype=float), np.asarray(y_um, dtype=float))
    return x, y


class GrainField:
    """Voronoi grains (seeded, ~40 µm mean size) in three phases over a gentle trend."""

    _PHASE_GPA = (4.5, 5.5, 7.0)
    _PHASE_MODULUS_GPA = (150.0, 200.0, 160.0)  # the hardest phase is not the stiffest

    def __init__(self, seed: int = 0, mean_grain_um: float = 40.0) -> None:
        self.name = "grains"
        self.bounds_um = (0.0, SIDE_UM, 0.0, SIDE_UM)
        rng = np.random.default_rng([seed, 0x475241494E])
        n = int((SIDE_UM / mean_grain_um) ** 2)
        self._sites = rng.uniform(-mean_grain_um, SIDE_UM + mean_grain_um, (n, 2))
        self._phase = rng.choice(len(self._PHASE_GPA), size=n, p=(0.5, 0.35, 0.15))
        from scipy.spatial import cKDTree

        self._tree = cKDTree(self._sites)

    def hardness_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        x, y = _xy(x_um, y_um)
        _, idx = self._tree.query(np.column_stack([x.ravel(), y.ravel()]))
        h = np.asarray(self._PHASE_GPA)[self._phase[idx]].reshape(x.shape)
        return np.asarray(h + 0.3 * x / SIDE_UM, dtype=float)

    def noise_sd_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        return 0.02 * self.hardness_gpa(x_um, y_um)

    def modulus_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        x, y = _xy(x_um, y_um)
        _, idx = self._tree.query(np.column_stack([x.ravel(), y.ravel()]))
        e = np.asarray(self._PHASE_MODULUS_GPA)[self._phase[idx]].reshape(x.shape)
        return np.asarray(e - 10.0 * y / SIDE_UM, dtype=float)

    def modulus_noise_sd_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        return 0.02 * self.modulus_gpa(x_um, y_um)


class StepField:
    """A smooth trend with a sharp step (+1.5 GPa over ~2 µm) along a straight line 20° off the y axis."""

    def __init__(self) -> None:
        self.name = "step"
        self.bounds_um = (0.0, SIDE_UM, 0.0, SIDE_UM)
        theta = math.radians(20.0)
        self._n = (math.cos(theta), -math.sin(theta))
        self._offset = 0.55 * SIDE_UM * self._n[0] + 0.5 * SIDE_UM * self._n[1]

    def hardness_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        x, y = _xy(x_um, y_um)
        d = x * self._n[0] + y * self._n[1] - self._offset
        trend = 5.0 + 0.6 * y / SIDE_UM - 0.4 * x / SIDE_UM
        return np.asarray(trend + 1.5 * 0.5 * (1.0 + np.tanh(d / 1.0)), dtype=float)

    def noise_sd_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        return 0.015 * self.hardness_gpa(x_um, y_um)

    def modulus_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        """The same step (+12 GPa, the composition changes both), over a trend of its own."""
        x, y = _xy(x_um, y_um)
        d = x * self._n[0] + y * self._n[1] - self._offset
        trend = 150.0 - 10.0 * y / SIDE_UM + 15.0 * x / SIDE_UM
        return np.asarray(trend + 12.0 * 0.5 * (1.0 + np.tanh(d / 1.0)), dtype=float)

    def modulus_noise_sd_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        return 0.015 * self.modulus_gpa(x_um, y_um)


class StripeField:
    """Nearly flat (6 GPa with a ±2 % trend) but for one narrow hard stripe along a diagonal."""

    def __init__(self, width_um: float = 30.0) -> None:
        self.name = "stripe"
        self.bounds_um = (0.0, SIDE_UM, 0.0, SIDE_UM)
        self.width_um = float(width_um)

    def hardness_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        x, y = _xy(x_um, y_um)
        u, v = x / SIDE_UM, y / SIDE_UM
        flat = 6.0 + 0.12 * (u - 0.5) - 0.08 * (v - 0.5)
        d = 0.8 * x - 0.6 * y - 0.15 * SIDE_UM  # distance to the line 0.8x − 0.6y = 150 µm
        return np.asarray(flat + 1.0 * np.exp(-0.5 * (d / (self.width_um / 2.355)) ** 2), dtype=float)

    def noise_sd_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        return 0.015 * self.hardness_gpa(x_um, y_um)

    def modulus_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        """Flat too, but its stiff stripe runs along the other diagonal: the hard stripe is not stiff."""
        x, y = _xy(x_um, y_um)
        u, v = x / SIDE_UM, y / SIDE_UM
        flat = 170.0 + 3.0 * (u - 0.5) + 2.0 * (v - 0.5)
        d = 0.6 * x + 0.8 * y - 0.7 * SIDE_UM
        return np.asarray(flat + 15.0 * np.exp(-0.5 * (d / (self.width_um / 2.355)) ** 2), dtype=float)

    def modulus_noise_sd_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        return 0.015 * self.modulus_gpa(x_um, y_um)


class PhaseNoiseField:
    """Two smooth phases across a soft boundary; the hard phase scatters 8 % per indent, the soft one 1 %."""

    def __init__(self) -> None:
        self.name = "phase-noise"
        self.bounds_um = (0.0, SIDE_UM, 0.0, SIDE_UM)

    def _hard_fraction(self, x: FloatArray, y: FloatArray) -> FloatArray:
        r = np.hypot(x - 0.3 * SIDE_UM, y - 0.7 * SIDE_UM)
        return np.asarray(0.5 * (1.0 - np.tanh((r - 0.35 * SIDE_UM) / 40.0)), dtype=float)

    def hardness_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        x, y = _xy(x_um, y_um)
        f = self._hard_fraction(x, y)
        soft = 4.0 + 0.5 * x / SIDE_UM + 0.3 * np.sin(math.pi * y / SIDE_UM)
        return np.asarray(soft + 2.0 * f, dtype=float)

    def noise_sd_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        x, y = _xy(x_um, y_um)
        f = self._hard_fraction(x, y)
        return np.asarray(self.hardness_gpa(x, y) * (0.01 + 0.07 * f), dtype=float)

    def modulus_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        """The hard phase is compliant: 25 GPa below the soft one, which has a cosine ripple of its own."""
        x, y = _xy(x_um, y_um)
        f = self._hard_fraction(x, y)
        soft = 160.0 - 10.0 * x / SIDE_UM + 8.0 * np.cos(2.0 * math.pi * y / SIDE_UM)
        return np.asarray(soft - 25.0 * f, dtype=float)

    def modulus_noise_sd_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        x, y = _xy(x_um, y_um)
        f = self._hard_fraction(x, y)
        return np.asarray(self.modulus_gpa(x, y) * (0.01 + 0.03 * f), dtype=float)


class Pores(SiteTexture):
    """Pores over a share of the surface: an indent whose centre lands on one reads ``drop`` low.

    It is measurement error, not map: the truth (and MAPE) stays the film without pores. Pores are small
    discs (radius ~3 µm) at seeded positions, so which indents hit one depends only on where they land.
    """

    def __init__(
        self, truth: TruthField, seed: int, share: float = 0.05, drop: float = 0.5, radius_um: float = 3.0
    ) -> None:
        if not (0.0 < share < 0.5 and 0.0 < drop < 1.0):
            raise InputError("pores", f"share must be in (0, 0.5) and drop in (0, 1), got {share}, {drop}")
        self.truth = truth
        self.drop = float(drop)
        self.radius_um = float(radius_um)
        self.sd_gpa = 0.0
        self.scale_um = 2.0 * radius_um
        rng = np.random.default_rng([seed, 0x504F5245])
        # discs that may overlap: n such that the covered share is `share` (1 − exp(−n·πr²/A) = share)
        n = round(-math.log(1.0 - share) * SIDE_UM**2 / (math.pi * radius_um**2))
        from scipy.spatial import cKDTree

        self._tree = cKDTree(rng.uniform(0.0, SIDE_UM, (n, 2)))

    def offset_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        x, y = _xy(x_um, y_um)
        d, _ = self._tree.query(np.column_stack([x.ravel(), y.ravel()]))
        hit = (d <= self.radius_um).reshape(x.shape)
        return np.asarray(np.where(hit, -self.drop * self.truth.hardness_gpa(x, y), 0.0), dtype=float)


def robust_truth(key: str, seed: int) -> tuple[TruthField, SiteTexture | None]:
    if key == "grains":
        return GrainField(seed=11), None  # one fixed texture: the seeds vary the noise draws, not the film
    if key == "step":
        return StepField(), None
    if key == "stripe":
        return StripeField(), None
    if key == "phase-noise":
        return PhaseNoiseField(), None
    if key == "outliers":
        truth = TernaryField(SIDE_UM)
        return truth, Pores(truth, seed)
    raise InputError("field", f"unknown robustness field {key!r} (known: {', '.join(ROBUST_FIELDS)})")


def robust_scenario(key: str, seed: int) -> Scenario:
    """The field on the ternary library's stage: same calibration, profile, lattice and (no) drift."""
    truth, texture = robust_truth(key, seed)
    base = make_scenario("ternary", seed)
    return dataclasses.replace(
        base, name=key, truth=truth, site_texture=texture, description=ROBUST_FIELDS[key]
    )

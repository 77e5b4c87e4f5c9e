"""What a ground-truth field is: hardness and per-indent scatter (and a modulus) at any stage point.

Only the simulated instrument knows the truth (``core`` never sees it). This module holds the protocol every
field meets, the modulus a field without its own gets, the scenario noise modes that replace a field's own
scatter, and the lattices the evaluator and the scenarios read a field on. The analytic fields are in
``drivers.sim.fields``, truth from a CSV file in ``drivers.sim.truth_csv``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core.errors import InputError

FloatArray = NDArray[np.float64]
Bounds = tuple[float, float, float, float]

NOISE_MODES: tuple[str, ...] = ("hetero", "homo", "10pct")


@runtime_checkable
class TruthField(Protocol):
    """A ground-truth map: hardness and per-indent measurement scatter at stage points (µm, GPa)."""

    name: str
    bounds_um: Bounds

    def hardness_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray: ...

    def noise_sd_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray: ...


@runtime_checkable
class ModulusTruth(Protocol):
    """A truth field that also knows the film's reduced modulus and its per-indent scatter (GPa).

    A field without one gets ``modulus_from_hardness_gpa`` with a 1 % scatter (``truth_modulus_gpa``)."""

    def modulus_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray: ...

    def modulus_noise_sd_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray: ...


DEFAULT_MODULUS_REL_SD = 0.01  # a field without its own modulus: scatter of 1 % of E beyond the area error


def truth_modulus_gpa(truth: TruthField, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
    """The field's modulus at stage points, or E(H) where the field has none of its own."""
    if isinstance(truth, ModulusTruth):
        return np.asarray(truth.modulus_gpa(x_um, y_um), dtype=float)
    return modulus_from_hardness_gpa(truth.hardness_gpa(x_um, y_um))


def truth_modulus_noise_sd_gpa(truth: TruthField, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
    """Per-indent modulus scatter of the field's own (beyond the contact-area error it shares with H)."""
    if isinstance(truth, ModulusTruth):
        return np.asarray(truth.modulus_noise_sd_gpa(x_um, y_um), dtype=float)
    return DEFAULT_MODULUS_REL_SD * truth_modulus_gpa(truth, x_um, y_um)


def modulus_from_hardness_gpa(h_gpa: ArrayLike) -> FloatArray:
    """A smooth E(H) with E/H from ~24 (soft) to ~19 (hard), typical of metallic films."""
    h = np.asarray(h_gpa, dtype=float)
    return 25.0 * h * (1.0 - 0.02 * h)


def broadcast_xy(x_um: ArrayLike, y_um: ArrayLike) -> tuple[FloatArray, FloatArray]:
    x, y = np.broadcast_arrays(np.asarray(x_um, dtype=float), np.asarray(y_um, dtype=float))
    return x, y


def inclusive_lattice(bounds: Bounds, n: int) -> tuple[FloatArray, FloatArray]:
    """An n×n lattice that includes the edges and corners, where the extremes of these fields sit."""
    x_min, x_max, y_min, y_max = bounds
    return np.meshgrid(np.linspace(x_min, x_max, n), np.linspace(y_min, y_max, n))


def centred_lattice(bounds: Bounds, n: int) -> tuple[FloatArray, FloatArray]:
    x_min, x_max, y_min, y_max = bounds
    x = x_min + (np.arange(n) + 0.5) * (x_max - x_min) / n
    y = y_min + (np.arange(n) + 0.5) * (y_max - y_min) / n
    return x, y


def field_extrema(truth: TruthField, n: int = 201) -> tuple[float, float, float, float]:
    """(min H, max H, max σ, mean σ) over the field's area: edges included for extremes, cell centres for the mean."""
    gx, gy = inclusive_lattice(truth.bounds_um, n)
    h = truth.hardness_gpa(gx, gy)
    sd = truth.noise_sd_gpa(gx, gy)
    cx, cy = centred_lattice(truth.bounds_um, n)
    mx, my = np.meshgrid(cx, cy)
    return float(h.min()), float(h.max()), float(sd.max()), float(truth.noise_sd_gpa(mx, my).mean())


def check_noise_mode(noise: str, source: str = "noise") -> str:
    if noise not in NOISE_MODES:
        raise InputError(source, f"unknown noise model {noise!r} (known: {', '.join(NOISE_MODES)})")
    return noise


def noise_transform(
    hardness: Callable[[FloatArray, FloatArray], FloatArray],
    sd: Callable[[FloatArray, FloatArray], FloatArray],
    bounds: Bounds,
    mode: str,
) -> tuple[float, float | None]:
    """(scale, constant) that turn a field's own noise into the requested mode.

    ``homo`` is a constant equal to the mean of the field's own σ (same average noise, no structure);
    ``10pct`` keeps the shape and scales it so that max σ is 10 % of max H (the real film's level).
    """
    if mode == "hetero":
        return 1.0, None
    gx, gy = inclusive_lattice(bounds, 201)
    if mode == "homo":
        cx, cy = centred_lattice(bounds, 200)
        mx, my = np.meshgrid(cx, cy)
        return 1.0, float(sd(mx, my).mean())
    max_sd = float(sd(gx, gy).max())
    max_h = float(hardness(gx, gy).max())
    if max_sd <= 0.0:
        return 1.0, 0.1 * max_h
    return 0.1 * max_h / max_sd, None


class NoiseOverride:
    """Any truth field with its noise replaced by one of the scenario noise modes (hetero keeps its own)."""

    def __init__(self, base: TruthField, mode: str) -> None:
        self.base = base
        self.mode = check_noise_mode(mode)
        self.name = base.name if mode == "hetero" else f"{base.name}+{mode}"
        self.bounds_um: Bounds = base.bounds_um
        self._scale, self._const = noise_transform(
            base.hardness_gpa, base.noise_sd_gpa, base.bounds_um, self.mode
        )
        self._e_scale, self._e_const = noise_transform(
            lambda x, y: truth_modulus_gpa(base, x, y),
            lambda x, y: truth_modulus_noise_sd_gpa(base, x, y),
            base.bounds_um,
            self.mode,
        )

    def hardness_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        return self.base.hardness_gpa(x_um, y_um)

    def modulus_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        return truth_modulus_gpa(self.base, x_um, y_um)

    def modulus_noise_sd_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        if self._e_const is not None:
            x, _ = broadcast_xy(x_um, y_um)
            return np.full(x.shape, self._e_const)
        return self._e_scale * truth_modulus_noise_sd_gpa(self.base, x_um, y_um)

    def noise_sd_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        if self._const is not None:
            x, _ = broadcast_xy(x_um, y_um)
            return np.full(x.shape, self._const)
        return self._scale * self.base.noise_sd_gpa(x_um, y_um)


def check_seed(value: int, source: str = "seed") -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 0:
        raise InputError(source, f"must be a non-negative integer, got {value!r}")
    return int(value)


def truth_on_lattice(truth: TruthField, n: int = 100) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(x (n,), y (n,), H (n, n)) at the cell centres of an n×n lattice over the area; H[j, i] = H(x[i], y[j])."""
    if n < 1:
        raise InputError("lattice_n", f"must be ≥ 1, got {n}")
    x, y = centred_lattice(truth.bounds_um, n)
    gx, gy = np.meshgrid(x, y)
    return x, y, np.asarray(truth.hardness_gpa(gx, gy), dtype=float)


def modulus_on_lattice(truth: TruthField, n: int = 100) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(x, y, E (n, n)) on the same lattice as ``truth_on_lattice``."""
    if n < 1:
        raise InputError("lattice_n", f"must be ≥ 1, got {n}")
    x, y = centred_lattice(truth.bounds_um, n)
    gx, gy = np.meshgrid(x, y)
    return x, y, truth_modulus_gpa(truth, gx, gy)

"""The analytic truth fields: the paper's ternary library and quaternary film, the robustness suite's
provocations (a curved phase boundary, a hot spot near an edge, a rotated gradient, a rough map) and the
indent-scale site texture. Each meets ``drivers.sim.truth.TruthField``."""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np
from numpy.typing import ArrayLike

from core.errors import InputError
from drivers.sim.truth import (
    Bounds,
    FloatArray,
    broadcast_xy,
    check_noise_mode,
    check_seed,
    inclusive_lattice,
    noise_transform,
)


class TernaryField:
    """The paper's emulated ternary library (SPEC §4): maximum 7.0 GPa in the bottom-left corner.

    Modulus: a rule of mixtures (A 110, B 190, C 140 GPa) with mixing terms shaped like the hardness's, so
    the composition drives both; but C, the hardest corner, is compliant (H/E ≈ 0.05 against ≈ 0.026 at B),
    and a stiff bump near (A, B) = (0.3, 0.5) that the hardness does not have gives E a structure of its own.
    Its scatter has its own shape too (largest towards C, where the hardness's is smallest).
    """

    def __init__(
        self, side_um: float = 1000.0, noise: str = "hetero", origin_um: tuple[float, float] = (0.0, 0.0)
    ) -> None:
        if not (math.isfinite(side_um) and side_um > 0):
            raise InputError("side_um", f"must be a positive length, got {side_um!r}")
        self.side_um = float(side_um)
        self.noise = check_noise_mode(noise)
        self.origin_um = (float(origin_um[0]), float(origin_um[1]))
        x0, y0 = self.origin_um
        self.name = "ternary" if noise == "hetero" else f"ternary+{noise}"
        self.bounds_um: Bounds = (x0, x0 + self.side_um, y0, y0 + self.side_um)
        self._scale, self._const = noise_transform(
            self._hardness, self._hetero_sd, self.bounds_um, self.noise
        )
        self._e_scale, self._e_const = noise_transform(
            self.modulus_gpa, self._hetero_modulus_sd, self.bounds_um, self.noise
        )

    def composition(self, x_um: ArrayLike, y_um: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Fractions (A, B, C): A grows with x, B with y, C is the rest (at least 0.01 before renormalising)."""
        x, y = broadcast_xy(x_um, y_um)
        a = (x - self.origin_um[0]) / self.side_um
        b = (y - self.origin_um[1]) / self.side_um
        c = np.maximum(1.0 - a - b, 0.01)
        total = a + b + c
        return a / total, b / total, c / total

    def _hardness(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        a, b, c = self.composition(x_um, y_um)
        return 3 * a + 5 * b + 7 * c - 4 * a * b - 3 * b * c - 2 * c * a - 6 * c**2 * (1 - c)

    def _hetero_sd(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        a, b, c = self.composition(x_um, y_um)
        return 0.005 + 0.1 * a + 0.05 * b + 0.025 * c

    def hardness_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        return self._hardness(x_um, y_um)

    def noise_sd_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        if self._const is not None:
            x, _ = broadcast_xy(x_um, y_um)
            return np.full(x.shape, self._const)
        return self._scale * self._hetero_sd(x_um, y_um)

    def modulus_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        a, b, c = self.composition(x_um, y_um)
        bump = 25.0 * np.exp(-((a - 0.3) ** 2 + (b - 0.5) ** 2) / (2.0 * 0.12**2))
        return np.asarray(110 * a + 190 * b + 140 * c - 60 * a * b - 45 * b * c - 30 * c * a + bump, float)

    def _hetero_modulus_sd(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        a, b, c = self.composition(x_um, y_um)
        return 0.5 + 0.5 * a + 1.0 * b + 3.0 * c

    def modulus_noise_sd_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        if self._e_const is not None:
            x, _ = broadcast_xy(x_um, y_um)
            return np.full(x.shape, self._e_const)
        return self._e_scale * self._hetero_modulus_sd(x_um, y_um)


class QuaternaryFilm:
    """A Ta–Ti–Hf–Zr-like co-sputtered film on a millimetre-sized stage area away from the stage origin.

    Composition model: four sputter guns aim at the library from outside the measured area. Each element's
    deposition rate at a point falls off with distance d from its gun's footprint centre as
    w / (1 + (d/D)²)^1.5 (the shape of a point source over a plane); the local fraction of an element is its
    rate over the sum of the four. Ta (narrow footprint, strongest gradient) and Ti sit beyond the upper-left
    corner, Hf and Zr (broad footprint, weakest gradient) beyond the lower-right, so the film runs from
    Ta/Ti-rich at the upper left to Hf/Zr-rich at the lower right, as in the paper's film (Fig. 8, S10).

    Hardness: a rule of mixtures over nominal film hardnesses (Ta 14.5, Ti 9.5, Hf 6.5, Zr 5.0 GPa) plus two
    small solid-solution terms (2.0·c_Ta·c_Hf + 1.5·c_Ti·c_Zr). Over the default 5 × 3 mm area this gives
    about 6.7–10.8 GPa, falling monotonically from the upper-left corner to the lower-right one.

    Noise: smooth and shaped like the hardness itself, slightly raised within ~250 µm of the edges (as the
    paper's Fig. 8c), scaled so that its maximum is ``noise_max_frac`` (10 %) of the maximum hardness.
    """

    # nominal film moduli (GPa): Hf is stiffer than its hardness ranks it, Ta–Hf mixing softens E while it
    # hardens H (a hard but compliant region between them)
    _MODULUS_GPA: ClassVar[dict[str, float]] = {"Ta": 185.0, "Ti": 120.0, "Hf": 150.0, "Zr": 95.0}

    _GUNS: tuple[tuple[str, float, float, float, float, float], ...] = (
        # element, gun x, gun y (mm from the area's bottom-left corner), weight, footprint D (mm), film H (GPa)
        ("Ta", -1.0, 4.0, 1.1, 2.5, 14.5),
        ("Ti", 1.5, 7.0, 1.2, 5.0, 9.5),
        ("Hf", 6.5, -1.5, 1.0, 3.5, 6.5),
        ("Zr", 14.0, -12.0, 1.0, 20.0, 5.0),
    )
    ELEMENTS: tuple[str, ...] = tuple(g[0] for g in _GUNS)

    def __init__(
        self,
        x0_um: float = 10_000.0,
        y0_um: float = 20_000.0,
        width_um: float = 5_000.0,
        height_um: float = 3_000.0,
        noise_max_frac: float = 0.10,
    ) -> None:
        if not (width_um > 0 and height_um > 0):
            raise InputError("film", f"width and height must be positive, got {width_um!r} × {height_um!r}")
        if not (0 < noise_max_frac < 1):
            raise InputError("film", f"noise_max_frac must be in (0, 1), got {noise_max_frac!r}")
        self.name = "quaternary-film"
        self.x0_um, self.y0_um = float(x0_um), float(y0_um)
        # the guns were placed for a 5 × 3 mm area; other sizes stretch the layout with it
        self._sx, self._sy = width_um / 5_000.0, height_um / 3_000.0
        self.bounds_um: Bounds = (self.x0_um, self.x0_um + width_um, self.y0_um, self.y0_um + height_um)
        self.noise_max_frac = float(noise_max_frac)
        gx, gy = inclusive_lattice(self.bounds_um, 201)
        h = self.hardness_gpa(gx, gy)
        self._h_min, self._h_max = float(h.min()), float(h.max())
        shape = self._noise_shape(gx, gy)
        self._noise_scale = self.noise_max_frac * self._h_max / float(shape.max())

    def composition(self, x_um: ArrayLike, y_um: ArrayLike) -> dict[str, FloatArray]:
        x, y = broadcast_xy(x_um, y_um)
        xi = (x - self.x0_um) / (1000.0 * self._sx)
        eta = (y - self.y0_um) / (1000.0 * self._sy)
        rates = {}
        for element, gx, gy, weight, footprint, _ in self._GUNS:
            d2 = ((xi - gx) ** 2 + (eta - gy) ** 2) / footprint**2
            rates[element] = weight / (1.0 + d2) ** 1.5
        total = sum(rates.values())
        return {k: v / total for k, v in rates.items()}

    def hardness_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        c = self.composition(x_um, y_um)
        h = sum(c[element] * h_el for element, *_, h_el in self._GUNS)
        return np.asarray(h + 2.0 * c["Ta"] * c["Hf"] + 1.5 * c["Ti"] * c["Zr"], dtype=float)

    def modulus_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        c = self.composition(x_um, y_um)
        e = sum(c[element] * self._MODULUS_GPA[element] for element in self.ELEMENTS)
        return np.asarray(e - 60.0 * c["Ta"] * c["Hf"] + 20.0 * c["Ti"] * c["Zr"], dtype=float)

    def modulus_noise_sd_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        """2 % of E, raised by half near the edges (as the hardness's), but not shaped like the hardness."""
        x, y = broadcast_xy(x_um, y_um)
        x_min, x_max, y_min, y_max = self.bounds_um
        edge = np.minimum.reduce([x - x_min, x_max - x, y - y_min, y_max - y])
        return 0.02 * self.modulus_gpa(x, y) * (1.0 + 0.5 * np.exp(-np.maximum(edge, 0.0) / 250.0))

    def _noise_shape(self, x: FloatArray, y: FloatArray) -> FloatArray:
        h = self.hardness_gpa(x, y)
        x_min, x_max, y_min, y_max = self.bounds_um
        edge = np.minimum.reduce([x - x_min, x_max - x, y - y_min, y_max - y])
        rel = (h - self._h_min) / max(self._h_max - self._h_min, 1e-12)
        return 0.5 + 0.5 * rel + 0.2 * np.exp(-np.maximum(edge, 0.0) / 250.0)

    def noise_sd_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        x, y = broadcast_xy(x_um, y_um)
        return self._noise_scale * self._noise_shape(x, y)


class PhaseBoundaryField:
    """Two smooth phases split by a sharp curved boundary (~2 GPa over ~10 µm): a GP with one length-scale
    cannot fit both the step and the smooth parts, which is what this field is for."""

    def __init__(self, side_um: float = 1000.0, width_um: float = 10.0) -> None:
        self.name = "phase-boundary"
        self.side_um = float(side_um)
        self.bounds_um: Bounds = (0.0, self.side_um, 0.0, self.side_um)
        # boundary: an arc of a circle centred beyond the lower-right corner; 10–90 % rise over width_um
        self._centre = (1.15 * self.side_um, -0.15 * self.side_um)
        self._radius = 0.75 * self.side_um
        self._w = width_um / (2.0 * math.atanh(0.8))

    def signed_distance_um(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        """Positive inside the hard phase (towards the lower-right corner)."""
        x, y = broadcast_xy(x_um, y_um)
        return self._radius - np.hypot(x - self._centre[0], y - self._centre[1])

    def hardness_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        x, y = broadcast_xy(x_um, y_um)
        u, v = x / self.side_um, y / self.side_um
        soft = 4.0 + 0.8 * u - 0.6 * v + 0.3 * np.sin(math.pi * v)
        hard = 6.0 + 0.5 * u - 0.3 * v + 0.3 * np.sin(math.pi * v)  # ~2 GPa above soft along the arc
        frac = 0.5 * (1.0 + np.tanh(self.signed_distance_um(x, y) / self._w))
        return soft + (hard - soft) * frac

    def noise_sd_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        # indents that straddle the boundary scatter more
        h = self.hardness_gpa(x_um, y_um)
        d = self.signed_distance_um(x_um, y_um)
        return 0.01 + 0.012 * h + 0.08 * np.exp(-((d / 15.0) ** 2))

    def modulus_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        """The hard phase is compliant: E drops by ~20 GPa across the boundary where H rises by 2."""
        x, y = broadcast_xy(x_um, y_um)
        u, v = x / self.side_um, y / self.side_um
        soft = 150.0 + 20.0 * u - 10.0 * v
        hard = 130.0 + 10.0 * u + 15.0 * v
        frac = 0.5 * (1.0 + np.tanh(self.signed_distance_um(x, y) / self._w))
        return np.asarray(soft + (hard - soft) * frac, dtype=float)

    def modulus_noise_sd_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        d = self.signed_distance_um(x_um, y_um)
        return np.asarray(0.01 * self.modulus_gpa(x_um, y_um) + 4.0 * np.exp(-((d / 15.0) ** 2)), float)


class EdgeSpotField:
    """The ternary field plus a small hard spot close to one edge, where an edge penalty may hide it."""

    def __init__(
        self,
        side_um: float = 1000.0,
        noise: str = "hetero",
        spot_um: tuple[float, float] | None = None,
        radius_um: float = 60.0,
        height_gpa: float = 2.0,
    ) -> None:
        self.name = "edge-spot"
        self._ternary = TernaryField(side_um, noise)
        self.bounds_um: Bounds = self._ternary.bounds_um
        self.spot_um = spot_um if spot_um is not None else (0.93 * side_um, 0.38 * side_um)
        self.radius_um = float(radius_um)
        self.height_gpa = float(height_gpa)

    def spot_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        """A flat-topped bump: full height in the middle, half of it at ``radius_um``."""
        x, y = broadcast_xy(x_um, y_um)
        r = np.hypot(x - self.spot_um[0], y - self.spot_um[1]) / self.radius_um
        return self.height_gpa * np.exp(-math.log(2.0) * r**4)

    def hardness_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        return self._ternary.hardness_gpa(x_um, y_um) + self.spot_gpa(x_um, y_um)

    def noise_sd_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        return self._ternary.noise_sd_gpa(x_um, y_um)

    def modulus_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        """The spot is hard but barely stiffer: +50 % H, about +5 % E."""
        return self._ternary.modulus_gpa(x_um, y_um) + 4.0 * self.spot_gpa(x_um, y_um)

    def modulus_noise_sd_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        return self._ternary.modulus_noise_sd_gpa(x_um, y_um)


class RotatedQuaternaryField:
    """A four-component spread whose composition axes are rotated against the stage axes.

    Fractions are the bilinear weights of the four corners of a square rotated by ``angle_deg`` about the
    area's centre, so the gradients run neither along x nor y (a per-axis kernel cannot align with them).
    """

    _H_CORNERS = (8.0, 5.5, 3.5, 6.0)

    def __init__(self, side_um: float = 1000.0, angle_deg: float = 30.0) -> None:
        self.name = "rotated-quaternary"
        self.side_um = float(side_um)
        self.bounds_um: Bounds = (0.0, self.side_um, 0.0, self.side_um)
        theta = math.radians(angle_deg)
        self._cos, self._sin = math.cos(theta), math.sin(theta)
        self._extent = self.side_um * (abs(self._cos) + abs(self._sin))

    def composition(self, x_um: ArrayLike, y_um: ArrayLike) -> tuple[FloatArray, ...]:
        x, y = broadcast_xy(x_um, y_um)
        dx, dy = x - 0.5 * self.side_um, y - 0.5 * self.side_um
        xi = np.clip(0.5 + (dx * self._cos + dy * self._sin) / self._extent, 0.0, 1.0)
        eta = np.clip(0.5 + (-dx * self._sin + dy * self._cos) / self._extent, 0.0, 1.0)
        return ((1 - xi) * (1 - eta), xi * (1 - eta), xi * eta, (1 - xi) * eta)

    def hardness_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        c1, c2, c3, c4 = self.composition(x_um, y_um)
        h1, h2, h3, h4 = self._H_CORNERS
        return h1 * c1 + h2 * c2 + h3 * c3 + h4 * c4 + 6.0 * c1 * c3 - 3.0 * c2 * c4

    def noise_sd_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        c1, c2, c3, c4 = self.composition(x_um, y_um)
        return 0.02 + 0.1 * c2 + 0.06 * c3 + 0.03 * c4 + 0.01 * c1

    def modulus_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        """Corners 150, 120, 140, 200 GPa: the hardest corner (1) is not the stiffest (4)."""
        c1, c2, c3, c4 = self.composition(x_um, y_um)
        e = 150.0 * c1 + 120.0 * c2 + 140.0 * c3 + 200.0 * c4
        return np.asarray(e + 40.0 * c1 * c3 - 20.0 * c2 * c4 + 50.0 * c2 * c3, dtype=float)

    def modulus_noise_sd_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        c1, c2, c3, c4 = self.composition(x_um, y_um)
        return np.asarray(1.0 + 1.0 * c1 + 1.5 * c2 + 0.5 * c3 + 3.0 * c4, dtype=float)


class RoughField:
    """A real-looking rough map: a smooth trend plus multi-scale correlated roughness, fixed by its seed.

    The roughness is a sum of random plane waves at three scales (≈300, 120, 50 µm) with falling amplitude,
    evaluated in closed form, so the field is exact and identical wherever and in whatever order it is asked.
    """

    _SCALES_UM = (300.0, 120.0, 50.0)
    _AMPS_GPA = (0.45, 0.2, 0.08)
    _MODES = 12

    def __init__(self, side_um: float = 1000.0, seed: int = 0) -> None:
        self.name = f"rough-{seed}"
        self.side_um = float(side_um)
        self.seed = int(seed)
        self.bounds_um: Bounds = (0.0, self.side_um, 0.0, self.side_um)
        rng = np.random.default_rng([check_seed(seed), 0x524F55474B])
        kx, ky, phase, amp = [], [], [], []
        for scale, a in zip(self._SCALES_UM, self._AMPS_GPA, strict=True):
            direction = rng.uniform(0.0, 2.0 * math.pi, self._MODES)
            k = 2.0 * math.pi / (scale * rng.uniform(0.8, 1.25, self._MODES))
            kx.append(k * np.cos(direction))
            ky.append(k * np.sin(direction))
            phase.append(rng.uniform(0.0, 2.0 * math.pi, self._MODES))
            amp.append(np.full(self._MODES, a * math.sqrt(2.0 / self._MODES)))
        self._kx, self._ky = np.concatenate(kx), np.concatenate(ky)
        self._phase, self._amp = np.concatenate(phase), np.concatenate(amp)
        # the modulus shares the roughness (×15 GPa per GPa) and adds its own, from a stream of its own
        rng_e = np.random.default_rng([check_seed(seed), 0x4D4F44554C])
        direction = rng_e.uniform(0.0, 2.0 * math.pi, self._MODES)
        k = 2.0 * math.pi / (200.0 * rng_e.uniform(0.8, 1.25, self._MODES))
        self._e_kx, self._e_ky = k * np.cos(direction), k * np.sin(direction)
        self._e_phase = rng_e.uniform(0.0, 2.0 * math.pi, self._MODES)
        self._e_amp = 4.0 * math.sqrt(2.0 / self._MODES)

    def trend_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        x, y = broadcast_xy(x_um, y_um)
        u, v = x / self.side_um - 0.5, y / self.side_um - 0.5
        return 5.0 + 1.2 * u - 0.8 * v + 1.0 * u * v - 0.6 * u**2

    def roughness_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        x, y = broadcast_xy(x_um, y_um)
        arg = x[..., None] * self._kx + y[..., None] * self._ky + self._phase
        return np.asarray(np.cos(arg) @ self._amp, dtype=float)

    def hardness_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        return self.trend_gpa(x_um, y_um) + self.roughness_gpa(x_um, y_um)

    def noise_sd_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        return 0.01 + 0.012 * self.trend_gpa(x_um, y_um)

    def modulus_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        x, y = broadcast_xy(x_um, y_um)
        u, v = x / self.side_um - 0.5, y / self.side_um - 0.5
        trend = 140.0 + 15.0 * u + 20.0 * v - 10.0 * u * v
        own = np.cos(x[..., None] * self._e_kx + y[..., None] * self._e_ky + self._e_phase).sum(-1)
        return np.asarray(trend + 15.0 * self.roughness_gpa(x, y) + self._e_amp * own, dtype=float)

    def modulus_noise_sd_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        x, _ = broadcast_xy(x_um, y_um)
        return np.full(x.shape, 1.5)


class SiteTexture:
    """Indent-scale heterogeneity (grain clusters, roughness, thickness ripple) that a tight grid shares.

    A seeded sum of random plane waves of ~``scale_um`` wavelength with standard deviation ``sd_gpa``:
    indents 5 µm apart see nearly the same offset, centres 100 µm apart independent ones. It is measurement
    error, not map: the truth (and MAPE) stays the smooth field. A within-grid spread cannot see it, so a
    GP that takes its noise from those spreads alone has to explain it with short length-scales.
    """

    _MODES = 64

    def __init__(self, sd_gpa: float, scale_um: float = 40.0, seed: int = 0) -> None:
        for key, value in (("site_sd_gpa", sd_gpa), ("site_scale_um", scale_um)):
            if not (math.isfinite(value) and value > 0):
                raise InputError(key, f"must be a positive finite number, got {value!r}")
        self.sd_gpa = float(sd_gpa)
        self.scale_um = float(scale_um)
        rng = np.random.default_rng([check_seed(seed), 0x53495445])
        direction = rng.uniform(0.0, 2.0 * math.pi, self._MODES)
        k = 2.0 * math.pi / (self.scale_um * rng.uniform(0.7, 1.4, self._MODES))
        self._kx, self._ky = k * np.cos(direction), k * np.sin(direction)
        self._phase = rng.uniform(0.0, 2.0 * math.pi, self._MODES)
        self._amp = self.sd_gpa * math.sqrt(2.0 / self._MODES)

    def offset_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        x, y = broadcast_xy(x_um, y_um)
        arg = x[..., None] * self._kx + y[..., None] * self._ky + self._phase
        return np.asarray(self._amp * np.cos(arg).sum(axis=-1), dtype=float)

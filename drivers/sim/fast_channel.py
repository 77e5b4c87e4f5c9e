"""What a fast (NanoBlitz-class) indent reads, given the CSM truth at its site (SPEC §9).

A fast indent goes to a fixed peak load P with no continuous stiffness signal and no hold: H and E come from
its unloading curve (Oliver–Pharr). Here, from the CSM hardness H0 and modulus E at the site:

- depth: the Berkovich ideal area A = 24.5·h_c² (Oliver & Pharr, J. Mater. Res. 7 (1992) 1564) with the
  hardness the indent itself sees, H(h_c) = P / A, so h_c solves h_c⁴ + h*·h_c³ = (P / (24.5·H0))²;
- size effect: Nix & Gao (J. Mech. Phys. Solids 46 (1998) 411), H(h) = H0·√(1 + h*/h), with
  h* = (81/2)·b·α²·tan²θ·(μ/H0)²: h* grows as (μ/H0)², so it is tied to the local material through the
  truth's own E/H0 (μ ∝ E at a fixed Poisson ratio): h* = H_STAR_REF_NM·((E/H0)/EH_REF)², clamped to
  [H_STAR_MIN_NM, H_STAR_MAX_NM] ("tens to hundreds of nm", SPEC §9). It varies as smoothly as the
  composition does, and jumps where the material does (a phase boundary);
- roughness: a relative scatter of the contact area Ra/h_c: ISO 14577-1 asks for h ≥ 20·Ra for the roughness
  to stay within ~5 % of the result, so a relative sd of Ra/h_c (5 % at h = 20·Ra) grows at shallow depth;
- scatter: FAST_NOISE_FACTOR × the CSM per-indent sd in quadrature with the roughness term, 2–3× the CSM
  scatter in all (issue 36; "more scatter than a CSM average", SPEC §9);
- failures: FAILURE_RATE of the indents fail (no surface detected, a broken unloading fit): they come back
  as failed, with no numbers (NaN and ``failed``), never as values a model could learn;
- an optional surface layer (oxide, contamination) of thickness t and hardness H_L over part of the sample,
  read through Korsunsky's composite law H = H_sub + (H_L − H_sub)/(1 + k·(h/t)²) (Korsunsky et al., Surf.
  Coat. Technol. 99 (1998) 171; k = 1 an ASSUMPTION): what a shallow fast indent sees and a deeper CSM
  average does not (a layer that hides a feature).

A truth CSV may say what a fast indent reads at each point (``fast_hardness_gpa``, ``fast_noise_sd_gpa``,
``fast_modulus_gpa``, ``fast_modulus_noise_sd_gpa``): ``read_fast_table`` reads those columns and the table
replaces the physics' expected reading and scatter where it speaks (failures still happen).

Every draw is a pure function of (seed, array_id, index in the array): a resumed run reads the same values.
This module takes the CSM values at the sites as arrays, so the emulator calls it with its truth field's.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from core.errors import InputError
from drivers.sim.csv_points import check_point, number_rows, read_header

FloatArray = NDArray[np.float64]

BERKOVICH_AREA_COEFF = 24.5  # A = 24.5·h_c², the ideal Berkovich area function (Oliver & Pharr 1992)
# Nix–Gao's h* at E/H0 = EH_REF: 100 nm is mid-range of "tens to hundreds of nm" (SPEC §9); ASSUMPTION
H_STAR_REF_NM = 100.0
EH_REF = 25.0  # E/H of a typical hard film (the ternary spans ≈ 20–38): where h* = H_STAR_REF_NM
H_STAR_MIN_NM, H_STAR_MAX_NM = 20.0, 400.0  # "tens to hundreds of nm" (SPEC §9)
# surface roughness Ra of a sputtered library: 1 nm is an ASSUMPTION to check against the lab's AFM
ROUGHNESS_RA_NM = 1.0
# fast scatter / CSM per-indent scatter before the roughness: with it, 2.0–2.7× on the ternary and the
# phase boundary (tests/test_fast_channel.py), the 2–3× (issue 36)
FAST_NOISE_FACTOR = 2.0
# a fast indent fails as often as any real indent: 1–2 % (drivers.sim.failures.REALISTIC_FAILURE_RATE)
FAILURE_RATE = 0.015
LAYER_K = 1.0  # Korsunsky's k (film/substrate mixing): ASSUMPTION
MIN_READING_GPA = 1e-3  # a reading never goes to or below zero (as the CSM emulator's)

_K_NOISE, _K_MODULUS, _K_AREA, _K_FAIL = 11, 12, 13, 14  # draw streams, apart from the CSM emulator's (0–3)


@dataclass(frozen=True)
class SurfaceLayer:
    """A layer of ``thickness_nm`` and ``hardness_gpa`` over a disc of the sample (stage µm)."""

    centre_um: tuple[float, float]
    radius_um: float
    thickness_nm: float
    hardness_gpa: float

    def weight(self, x_um: FloatArray, y_um: FloatArray, depth_nm: FloatArray) -> FloatArray:
        """The layer's share of what an indent at ``depth_nm`` reads (0 outside the disc)."""
        inside = np.hypot(x_um - self.centre_um[0], y_um - self.centre_um[1]) <= self.radius_um
        share = 1.0 / (1.0 + LAYER_K * (depth_nm / self.thickness_nm) ** 2)
        return np.where(inside, share, 0.0)


@dataclass(frozen=True)
class FastPhysics:
    """The fast channel's parameters; the defaults are the sourced constants above."""

    peak_load_mn: float
    h_star_ref_nm: float = H_STAR_REF_NM
    roughness_ra_nm: float = ROUGHNESS_RA_NM
    noise_factor: float = FAST_NOISE_FACTOR
    failure_rate: float = FAILURE_RATE
    layer: SurfaceLayer | None = None

    def __post_init__(self) -> None:
        for name in ("peak_load_mn", "h_star_ref_nm", "noise_factor"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise InputError(f"fast_channel.{name}", f"must be a finite number > 0, got {value!r}")
        if not (math.isfinite(self.roughness_ra_nm) and self.roughness_ra_nm >= 0):
            raise InputError("fast_channel.roughness_ra_nm", f"must be ≥ 0, got {self.roughness_ra_nm!r}")
        if not 0.0 <= self.failure_rate < 1.0:
            raise InputError("fast_channel.failure_rate", f"must be in [0, 1), got {self.failure_rate!r}")


@dataclass(frozen=True)
class CsmAtSites:
    """The CSM truth at the sites: hardness and modulus and their per-indent sds (GPa), one per site."""

    hardness_gpa: FloatArray
    noise_sd_gpa: FloatArray
    modulus_gpa: FloatArray
    modulus_noise_sd_gpa: FloatArray


@dataclass(frozen=True)
class FastReadings:
    """What an array of fast indents reports: NaN hardness, modulus and depth where an indent failed."""

    x_um: FloatArray
    y_um: FloatArray
    hardness_gpa: FloatArray
    modulus_gpa: FloatArray
    depth_nm: FloatArray
    failed: NDArray[np.bool_]


def h_star_nm(physics: FastPhysics, h0_gpa: FloatArray, e_gpa: FloatArray) -> FloatArray:
    """Nix–Gao's characteristic depth from the local E/H0 (μ ∝ E): h* ∝ (μ/H0)²."""
    ratio = np.asarray(e_gpa, float) / np.asarray(h0_gpa, float)
    return np.clip(physics.h_star_ref_nm * (ratio / EH_REF) ** 2, H_STAR_MIN_NM, H_STAR_MAX_NM)


def contact_depth_nm(peak_load_mn: float, h0_gpa: FloatArray, h_star: FloatArray) -> FloatArray:
    """h_c at the peak load where the size-affected hardness H0·√(1 + h*/h) carries it on 24.5·h_c²:
    the root of h⁴ + h*·h³ − a² = 0, a = P/(24.5·H0), by Newton from √a (monotone, a few steps)."""
    # P in mN, H in GPa: P/(24.5 H) in mN/GPa = 1e-3 N / 1e9 Pa = 1e-12 m² = 1e6 nm²
    a = peak_load_mn / (BERKOVICH_AREA_COEFF * np.asarray(h0_gpa, float)) * 1e6
    h = np.sqrt(a)
    for _ in range(30):
        f = h**4 + h_star * h**3 - a**2
        step = f / (4.0 * h**3 + 3.0 * h_star * h**2)
        h = np.maximum(h - step, 1e-3 * np.sqrt(a))
        if np.all(np.abs(step) <= 1e-9 * h):
            break
    return np.asarray(h, float)


@dataclass(frozen=True)
class Expected:
    """The noiseless fast reading at the sites and its scatter."""

    hardness_gpa: FloatArray
    noise_sd_gpa: FloatArray
    modulus_gpa: FloatArray
    modulus_noise_sd_gpa: FloatArray
    depth_nm: FloatArray
    h_star_nm: FloatArray
    area_rel_sd: FloatArray  # relative sd of the contact area from roughness


def expected_reading(
    physics: FastPhysics,
    x_um: FloatArray,
    y_um: FloatArray,
    csm: CsmAtSites,
    table: FastTable | None = None,
) -> Expected:
    """What a fast indent reads on average at the sites, and how much it scatters."""
    h0 = np.asarray(csm.hardness_gpa, float)
    e = np.asarray(csm.modulus_gpa, float)
    hs = h_star_nm(physics, h0, e)
    depth = contact_depth_nm(physics.peak_load_mn, h0, hs)
    h_fast = h0 * np.sqrt(1.0 + hs / depth)
    if physics.layer is not None:
        # the layer changes what the indent sees, and so how deep it goes: two fixed-point passes (the
        # weight changes slowly with depth)
        for _ in range(2):
            w = physics.layer.weight(x_um, y_um, depth)
            mixed = h0 + (physics.layer.hardness_gpa - h0) * w
            depth = contact_depth_nm(physics.peak_load_mn, mixed, hs)
        w = physics.layer.weight(x_um, y_um, depth)
        h_fast = (h0 + (physics.layer.hardness_gpa - h0) * w) * np.sqrt(1.0 + hs / depth)
    area_rel = physics.roughness_ra_nm / depth
    sd = np.hypot(physics.noise_factor * np.asarray(csm.noise_sd_gpa, float), area_rel * h_fast)
    # E ∝ 1/√A: half the area's relative error, plus the modulus's own scatter times the same factor
    e_sd = np.hypot(physics.noise_factor * np.asarray(csm.modulus_noise_sd_gpa, float), 0.5 * area_rel * e)
    e_fast = e
    if table is not None:
        h_fast, sd, e_fast, e_sd = table.at(x_um, y_um, h_fast, sd, e_fast, e_sd)
        # the file's reading is what the indent sees (its size effect included): the depth follows it
        depth = contact_depth_nm(physics.peak_load_mn, h_fast, np.zeros_like(h_fast))
        if "fast_noise_sd_gpa" in table.columns:
            area_rel = np.zeros_like(h_fast)  # the file's scatter is the whole scatter
    return Expected(h_fast, sd, e_fast, e_sd, depth, hs, area_rel)


def read_array(
    physics: FastPhysics,
    seed: int,
    array_id: int,
    x_um: FloatArray,
    y_um: FloatArray,
    csm: CsmAtSites,
    table: FastTable | None = None,
    indices: NDArray[np.int64] | None = None,
) -> FastReadings:
    """One fast array's readings at its sites (``indices``: their places in the array, default 0..n−1).

    A reading is a pure function of (seed, array_id, index): part of an array read again reads the same.
    """
    x = np.asarray(x_um, float).ravel()
    y = np.asarray(y_um, float).ravel()
    n = x.size
    idx = np.arange(n) if indices is None else np.asarray(indices, np.int64).ravel()
    if idx.size != n or (n and idx.min() < 0):
        raise ValueError("indices must be one non-negative index per site")
    if seed < 0 or array_id < 0:
        raise ValueError(f"seed and array_id must be ≥ 0, got {seed}, {array_id}")
    exp = expected_reading(physics, x, y, csm, table)
    size = int(idx.max()) + 1 if n else 0

    def draws(k: int) -> FloatArray:
        # sequential draws of one stream: the i-th value does not depend on how many follow
        return np.random.default_rng([seed, array_id, k]).standard_normal(size)[idx]

    area = draws(_K_AREA)
    noise = draws(_K_NOISE)
    e_noise = draws(_K_MODULUS)
    fail = np.random.default_rng([seed, array_id, _K_FAIL]).random(size)[idx] < physics.failure_rate
    # the roughness's area error is shared by H (∝ 1/A) and E (∝ 1/√A); the rest is independent scatter
    rough_sd = exp.area_rel_sd * exp.hardness_gpa
    own_sd = np.sqrt(np.maximum(exp.noise_sd_gpa**2 - rough_sd**2, 0.0))
    h = exp.hardness_gpa * (1.0 + exp.area_rel_sd * area) + own_sd * noise
    e_rough = 0.5 * exp.area_rel_sd * exp.modulus_gpa
    e_own = np.sqrt(np.maximum(exp.modulus_noise_sd_gpa**2 - e_rough**2, 0.0))
    e = exp.modulus_gpa * (1.0 + 0.5 * exp.area_rel_sd * area) + e_own * e_noise
    nan = np.full(n, np.nan)
    return FastReadings(
        x_um=x,
        y_um=y,
        hardness_gpa=np.where(fail, nan, np.maximum(h, MIN_READING_GPA)),
        modulus_gpa=np.where(fail, nan, np.maximum(e, MIN_READING_GPA)),
        depth_nm=np.where(fail, nan, exp.depth_nm),
        failed=fail,
    )


# --------------------------------------------------------------------------------------------- from a file

FAST_CSV_COLUMNS = ("fast_hardness_gpa", "fast_noise_sd_gpa", "fast_modulus_gpa", "fast_modulus_noise_sd_gpa")


class FastTable:
    """A truth file's fast columns, interpolated as the file's CSM columns are (linear; nearest outside)."""

    def __init__(self, x_um: FloatArray, y_um: FloatArray, columns: dict[str, FloatArray], name: str) -> None:
        self.name = name
        self.columns = tuple(columns)
        self._fn: dict[str, Callable[[FloatArray, FloatArray], FloatArray]] = {}
        from scipy.interpolate import LinearNDInterpolator, NearestNDInterpolator

        pts = np.column_stack([x_um, y_um])
        for key, values in columns.items():
            lin = LinearNDInterpolator(pts, values)
            near = NearestNDInterpolator(pts, values)

            def interp(
                x: FloatArray,
                y: FloatArray,
                lin: LinearNDInterpolator = lin,
                near: NearestNDInterpolator = near,
            ) -> FloatArray:
                out = np.asarray(lin(x, y), dtype=float)
                gap = np.isnan(out)
                if gap.any():
                    out[gap] = near(x[gap], y[gap])
                return out

            self._fn[key] = interp

    def at(
        self,
        x_um: FloatArray,
        y_um: FloatArray,
        hardness_gpa: FloatArray,
        noise_sd_gpa: FloatArray,
        modulus_gpa: FloatArray,
        modulus_noise_sd_gpa: FloatArray,
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """The physics' expected reading and scatter, replaced where the file says them."""
        out = [hardness_gpa, noise_sd_gpa, modulus_gpa, modulus_noise_sd_gpa]
        for i, key in enumerate(FAST_CSV_COLUMNS):
            if key in self._fn:
                out[i] = self._fn[key](x_um, y_um)
        return out[0], out[1], out[2], out[3]


def read_fast_table(path: str | Path) -> FastTable | None:
    """The fast columns of a truth CSV (None when it has none); any problem is one line naming the file.

    Only ``x_um``, ``y_um`` and the fast columns are read here; the CSM columns are the truth reader's.
    """
    source = str(path)
    header, reader = read_header(path)
    present = [c for c in FAST_CSV_COLUMNS if c in header]
    if not present:
        return None
    for col in ("x_um", "y_um"):
        if col not in header:
            raise InputError(source, f"missing column {col}")
    if "fast_noise_sd_gpa" in present and "fast_hardness_gpa" not in present:
        raise InputError(source, "has fast_noise_sd_gpa but no fast_hardness_gpa column")
    if "fast_modulus_noise_sd_gpa" in present and "fast_modulus_gpa" not in present:
        raise InputError(source, "has fast_modulus_noise_sd_gpa but no fast_modulus_gpa column")
    where = ("x_um", "y_um", *present)
    rows: list[list[float]] = []
    for line, values in number_rows(source, header, reader, where):
        check_point(source, line, values, prefix="fast_")
        rows.append([values[c] for c in where])
    if len(rows) < 4:
        raise InputError(source, f"needs at least 4 points, found {len(rows)}")
    data = np.array(rows)
    columns = {c: data[:, k + 2] for k, c in enumerate(present)}
    return FastTable(data[:, 0], data[:, 1], columns, name=f"csv:{Path(path).name}")

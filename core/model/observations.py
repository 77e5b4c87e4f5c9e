"""What the surrogate learns from: one robust value per tested centre, its spread and how many indents.

Each executed g×g grid collapses to its median (or another robust value, whose efficiency relative to the
mean the caller gives) and its within-grid variance; the noise model reads the variances, the mean GP the
values (SPEC §5).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.special import digamma, polygamma

from core.errors import InputError
from core.estimators import estimator_efficiency

MIN_SPREAD_GPA2 = 1e-8  # floor on a within-grid variance before its log is taken


@dataclass(frozen=True)
class Observations:
    """One row per tested centre: each executed g×g grid collapsed to one robust value and its spread."""

    uv: np.ndarray  # (n, 2) in the unit square
    median_gpa: np.ndarray  # (n,) median of the centre's indents
    spread_var_gpa2: np.ndarray  # (n,) within-grid sample variance (or detrended), NaN where there is none
    n_indents: np.ndarray  # (n,) ints
    spread_dof: np.ndarray | None = None  # (n,) degrees of freedom of each spread; None: n_indents − 1
    # (n,) var(centre value)·n/σ²: how much the robust value wastes; None: the median's (SPEC §5)
    efficiency: np.ndarray | None = None

    @classmethod
    def of_centres(
        cls,
        centres: Sequence[Any],
        noise_inflation: Sequence[float],
        to_uv: Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]],
    ) -> Observations:
        """The rows of tested centres (anything with ``x_um``, ``y_um``, ``value_gpa``, ``spread_var_gpa2``,
        ``n_indents`` and ``efficiency``), each centre's noise inflated by its factor: one home for the
        hardness map and the modulus map alike."""
        xy = np.array([(c.x_um, c.y_um) for c in centres], dtype=float).reshape(-1, 2)
        u, v = to_uv(xy[:, 0], xy[:, 1])
        return cls(
            uv=np.column_stack([u, v]),
            median_gpa=np.array([c.value_gpa for c in centres]),
            spread_var_gpa2=np.array([c.spread_var_gpa2 for c in centres]),
            n_indents=np.array([c.n_indents for c in centres]),
            efficiency=np.array([c.efficiency for c in centres], dtype=float) * np.array(noise_inflation),
        )

    def __post_init__(self) -> None:
        uv = np.asarray(self.uv, dtype=float)
        med = np.asarray(self.median_gpa, dtype=float)
        spread = np.asarray(self.spread_var_gpa2, dtype=float)
        n_ind = np.asarray(self.n_indents)
        if uv.ndim != 2 or uv.shape[1] != 2:
            raise InputError("observations.uv", f"expected shape (n, 2), got {uv.shape}")
        n = uv.shape[0]
        for name, arr in (("median_gpa", med), ("spread_var_gpa2", spread), ("n_indents", n_ind)):
            if arr.shape != (n,):
                raise InputError(f"observations.{name}", f"expected shape ({n},), got {arr.shape}")
        if not np.all(np.isfinite(uv)):
            raise InputError("observations.uv", "non-finite coordinates")
        if not np.all(np.isfinite(med)):
            raise InputError("observations.median_gpa", "non-finite hardness")
        if n and (not np.all(np.isfinite(n_ind)) or np.any(n_ind < 1) or np.any(n_ind != np.round(n_ind))):
            raise InputError("observations.n_indents", "every centre needs a whole number >= 1 of indents")
        if np.any(spread[np.isfinite(spread)] < 0):
            raise InputError("observations.spread_var_gpa2", "negative variance")
        object.__setattr__(self, "uv", uv)
        object.__setattr__(self, "median_gpa", med)
        object.__setattr__(self, "spread_var_gpa2", spread)
        object.__setattr__(self, "n_indents", n_ind.astype(np.int64))
        dof = (
            (n_ind - 1).astype(float) if self.spread_dof is None else np.asarray(self.spread_dof, dtype=float)
        )
        if dof.shape != (n,):
            raise InputError("observations.spread_dof", f"expected shape ({n},), got {dof.shape}")
        object.__setattr__(self, "spread_dof", dof)
        eff = (
            estimator_efficiency("median", n_ind)
            if self.efficiency is None
            else np.asarray(self.efficiency, dtype=float)
        )
        if eff.shape != (n,) or not np.all(np.isfinite(eff)) or np.any(eff < 1.0):
            raise InputError("observations.efficiency", f"expected ({n},) values ≥ 1, got {eff!r}")
        object.__setattr__(self, "efficiency", eff)

    @property
    def n(self) -> int:
        return int(self.uv.shape[0])

    @classmethod
    def from_indents(
        cls, uv_per_indent: np.ndarray, hardness: np.ndarray, centre_ids: np.ndarray, detrend: bool = False
    ) -> Observations:
        """Group indents by centre id (in order of first appearance): centre = mean position of its indents.

        ``detrend``: the spread is the residual variance about a plane fitted to the grid (n − 3 degrees of
        freedom), so a steep hardness gradient across the grid is not mistaken for indent noise.
        """
        uv_i = np.asarray(uv_per_indent, dtype=float)
        h = np.asarray(hardness, dtype=float)
        ids = np.asarray(centre_ids)
        if uv_i.ndim != 2 or uv_i.shape[1] != 2 or h.shape != (uv_i.shape[0],) or ids.shape != h.shape:
            raise InputError(
                "indents", f"shapes disagree: uv {uv_i.shape}, hardness {h.shape}, ids {ids.shape}"
            )
        _, first, inverse = np.unique(ids, return_index=True, return_inverse=True)
        order = np.argsort(first, kind="stable")
        # each group's indents in their original order, by one stable sort (not a mask per group: fast
        # arrays bring thousands of cells)
        by_group = np.argsort(inverse.ravel(), kind="stable")
        starts = np.searchsorted(inverse.ravel()[by_group], np.arange(first.size + 1))
        uv, med, spread, count, dof = [], [], [], [], []
        for group in order:
            members = by_group[starts[group] : starts[group + 1]]
            vals = h[members]
            pos = uv_i[members]
            uv.append(pos.mean(axis=0))
            med.append(float(np.median(vals)))
            count.append(int(vals.size))
            var, k = _grid_spread(pos, vals, detrend)
            spread.append(var)
            dof.append(k)
        return cls(
            uv=np.asarray(uv, dtype=float).reshape(-1, 2),
            median_gpa=np.asarray(med, dtype=float),
            spread_var_gpa2=np.asarray(spread, dtype=float),
            n_indents=np.asarray(count, dtype=np.int64),
            spread_dof=np.asarray(dof, dtype=float),
        )


def _grid_spread(pos: np.ndarray, vals: np.ndarray, detrend: bool) -> tuple[float, float]:
    """(variance, degrees of freedom) of one grid's indents; NaN variance when there are too few."""
    n = vals.size
    if detrend and n >= 4:
        design = np.column_stack([np.ones(n), pos - pos.mean(axis=0)])
        coef, _, rank, _ = np.linalg.lstsq(design, vals, rcond=None)
        if rank == 3:
            resid = vals - design @ coef
            return float(resid @ resid) / (n - 3), float(n - 3)
    if n >= 2:
        return float(np.var(vals, ddof=1)), float(n - 1)
    return math.nan, 0.0


def spread_mask(obs: Observations) -> np.ndarray:
    assert obs.spread_dof is not None
    return (obs.spread_dof >= 1) & np.isfinite(obs.spread_var_gpa2)


def pooled_var(obs: Observations) -> float:
    """Pooled within-grid variance (GPa²), weighted by degrees of freedom."""
    mask = spread_mask(obs)
    assert obs.spread_dof is not None
    dof = obs.spread_dof[mask]
    return max(float(np.sum(dof * obs.spread_var_gpa2[mask]) / np.sum(dof)), MIN_SPREAD_GPA2)


def standardise(values: np.ndarray) -> tuple[float, float]:
    loc = float(np.mean(values))
    scale = float(np.std(values, ddof=1)) if values.size > 1 else 1.0
    if not math.isfinite(scale) or scale < 1e-9 * max(1.0, abs(loc)):
        scale = 1.0
    return loc, scale


def log_spread_targets(spread: np.ndarray, dof: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unbiased log-variance targets and their sampling variances for chi-square variances with k dof:
    E[log s²] = log σ² + ψ(k/2) − log(k/2), var[log s²] = ψ′(k/2)."""
    half_k = dof / 2.0
    target = np.log(np.maximum(spread, MIN_SPREAD_GPA2)) - (digamma(half_k) - np.log(half_k))
    return target, polygamma(1, half_k)

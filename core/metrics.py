"""Map-quality and speed metrics (SPEC §7)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np


def mape_pct(predicted: np.ndarray, truth: np.ndarray) -> float:
    """Mean absolute percentage error of a predicted map against the truth (finite cells only)."""
    p = np.asarray(predicted, dtype=float).ravel()
    t = np.asarray(truth, dtype=float).ravel()
    ok = np.isfinite(p) & np.isfinite(t) & (t != 0)
    if not ok.any():
        raise ValueError("no finite cells to compare")
    return float(np.mean(np.abs(p[ok] - t[ok]) / np.abs(t[ok])) * 100.0)


def time_to_mape(trajectory: Sequence[tuple[float, float]], target_pct: float) -> float | None:
    """First instrument time at which the MAPE is at or below ``target_pct`` (None if never)."""
    for t_s, mape in trajectory:
        if mape <= target_pct:
            return float(t_s)
    return None


def speedup(baseline_s: float | None, policy_s: float | None) -> float | None:
    """baseline time / policy time to reach the same MAPE (None when either never got there)."""
    if baseline_s is None or policy_s is None or policy_s <= 0:
        return None
    return baseline_s / policy_s


@dataclass(frozen=True)
class MapScore:
    """How good a map is against the truth (simulated runs only): None where it cannot be said yet."""

    mape_pct: float | None
    max_found_gpa: float | None


class ScoredMap(Protocol):
    """What an evaluator may ask a campaign: its map's mean and where it indented, nothing else."""

    def has_map(self) -> bool: ...

    def predict_mean_stage(self, x_um: np.ndarray, y_um: np.ndarray) -> np.ndarray: ...

    def indented_xy_um(self) -> np.ndarray: ...


class ScoredModulusMap(Protocol):
    """What a modulus evaluator may ask: whether there is a modulus map (fitting it if need be), its mean."""

    def has_modulus_map(self) -> bool: ...

    def predict_modulus_mean_stage(self, x_um: np.ndarray, y_um: np.ndarray) -> np.ndarray: ...


class MapEvaluator(Protocol):
    """Scores a map against a truth the campaign never sees (the simulated instrument's evaluator)."""

    def score(self, campaign: ScoredMap) -> MapScore: ...

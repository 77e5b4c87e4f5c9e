"""Acquisition functions over a surrogate ``Prediction`` (SPEC §6), vectorised over all candidates.

All of them use the epistemic sd: the planner asks where the *map* is uncertain, not where indents scatter
(the noise sd sizes the grid instead). Cost awareness is a division by the candidate's block time.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
from scipy.special import ndtr

from core.errors import InputError
from core.model import Prediction

_INV_SQRT_2PI = 1.0 / math.sqrt(2.0 * math.pi)


def ue(pred: Prediction) -> np.ndarray:
    """Uncertainty exploration: the epistemic sd itself."""
    return np.asarray(pred.epistemic_sd, dtype=float).copy()


def ucb(pred: Prediction, beta: float) -> np.ndarray:
    """Upper confidence bound μ + √β·σ_epistemic."""
    if not (math.isfinite(beta) and beta >= 0.0):
        raise InputError("beta", f"must be a finite number >= 0, got {beta!r}")
    return np.asarray(pred.mean, dtype=float) + math.sqrt(beta) * np.asarray(pred.epistemic_sd, dtype=float)


def ei(pred: Prediction, best_observed: float, xi: float = 0.0) -> np.ndarray:
    """Expected improvement over ``best_observed`` + ξ (maximisation); where σ = 0 it is max(μ − best − ξ, 0)."""
    if not math.isfinite(best_observed):
        raise InputError("best_observed", f"must be a finite hardness, got {best_observed!r}")
    mu = np.asarray(pred.mean, dtype=float)
    sd = np.asarray(pred.epistemic_sd, dtype=float)
    gain = mu - best_observed - xi
    out = np.maximum(gain, 0.0)
    pos = sd > 0
    z = gain[pos] / sd[pos]
    out[pos] = gain[pos] * ndtr(z) + sd[pos] * _INV_SQRT_2PI * np.exp(-0.5 * z * z)
    return out


def cost_aware(acq: np.ndarray, cost_s: np.ndarray) -> np.ndarray:
    """Acquisition per second of instrument time: acq / cost, every cost finite and > 0."""
    a = np.asarray(acq, dtype=float)
    c = np.asarray(cost_s, dtype=float)
    try:
        np.broadcast_shapes(a.shape, c.shape)
    except ValueError:
        raise InputError("cost_s", f"shape {c.shape} does not match the acquisition's {a.shape}") from None
    bad = ~(np.isfinite(c) & (c > 0))
    if np.any(bad):
        first = float(c.ravel()[np.flatnonzero(bad.ravel())[0]])
        raise InputError("cost_s", f"every cost must be a finite number of seconds > 0, got {first!r}")
    return a / c


ACQUISITIONS: dict[str, Callable[..., np.ndarray]] = {"ue": ue, "ucb": ucb, "ei": ei}


def score(name: str, pred: Prediction, **params: Any) -> np.ndarray:
    """The acquisition called by name, e.g. ``score("ucb", pred, beta=4.0)``."""
    fn = ACQUISITIONS.get(name)
    if fn is None:
        raise InputError("acquisition", f"unknown acquisition {name!r}; allowed: {', '.join(ACQUISITIONS)}")
    try:
        return fn(pred, **params)
    except TypeError as exc:
        raise InputError("acquisition", f"{name}: {exc}") from None

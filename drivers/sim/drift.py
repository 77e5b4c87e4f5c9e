"""Vertical thermal drift on the instrument clock (SPEC §4): decaying events, seeded, per scenario."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from core.errors import InputError
from drivers.sim.truth import FloatArray, check_seed

DRIFT_SCENARIOS: tuple[str, ...] = ("none", "good", "bad")

# (amplitude nm/s, decay τ s, mean time between events s) per scenario; a 5 s hold needs DR ≲ 0.025 nm/s
_DRIFT_PARAMS: dict[str, tuple[float, float, float]] = {
    "good": (0.3, 600.0, 3.0 * 3600.0),
    "bad": (1.0, 4000.0, 2.0 * 3600.0),
}
# SPEC §4 models drift as decaying events only, and scenario "none" must mean no drift; a steady rate is
# available for studies (``DriftModel(base_nm_s=...)``) but no named scenario has one
_DRIFT_BASE_NM_S = 0.0


@dataclass(frozen=True)
class DriftModel:
    """Vertical thermal drift on the instrument clock: decaying events over an optional steady rate.

    DR(t) = base + Σ_k A_k·exp(−(t − t0_k)/τ_k) for t ≥ t0_k. Loading the sample disturbs the enclosure, so
    the "good" and "bad" scenarios open with an event at t = 0; later events arrive as a seeded Poisson process.
    """

    name: str = "none"
    base_nm_s: float = _DRIFT_BASE_NM_S
    events: tuple[tuple[float, float, float], ...] = ()  # (t0_s, amplitude_nm_s, tau_s)
    horizon_s: float = 400_000.0

    @classmethod
    def scenario(cls, name: str, seed: int, horizon_s: float = 400_000.0) -> DriftModel:
        if name not in DRIFT_SCENARIOS:
            raise InputError(
                "drift", f"unknown drift scenario {name!r} (known: {', '.join(DRIFT_SCENARIOS)})"
            )
        if name == "none":
            return cls(name="none", horizon_s=horizon_s)
        amp, tau, interval = _DRIFT_PARAMS[name]
        rng = np.random.default_rng([check_seed(seed), 0x44524946, DRIFT_SCENARIOS.index(name)])
        events: list[tuple[float, float, float]] = []
        t = 0.0
        while t <= horizon_s:
            events.append((t, float(amp * rng.uniform(0.7, 1.3)), float(tau * rng.uniform(0.7, 1.3))))
            t += float(rng.exponential(interval))
        return cls(name=name, events=tuple(events), horizon_s=horizon_s)

    def rate_nm_s(self, t_s: ArrayLike) -> FloatArray:
        t = np.asarray(t_s, dtype=float)
        rate = np.full(t.shape, self.base_nm_s)
        if self.events:
            ev = np.asarray(self.events, dtype=float)
            dt = t[..., None] - ev[:, 0]
            active = dt >= 0
            rate = rate + np.sum(
                np.where(active, ev[:, 1] * np.exp(-np.where(active, dt, 0.0) / ev[:, 2]), 0.0), -1
            )
        return rate

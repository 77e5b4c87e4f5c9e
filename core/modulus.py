"""The modulus map a campaign learns beside the hardness map (issue 27).

Every indent reports a modulus as well; the materials scientist reports both maps and ratios such as H/E.
The modulus gets a heteroskedastic GP of its own, built exactly as the hardness one (same kernel, guard,
length-scale floor, robust centre value and outlier rule, its own noise GP): two independent GPs over
the same indents rather than one coregionalised GP, so the hardness map, its decisions and its journal are
those of a hardness-only run whatever happens to the modulus. A failed or not-run indent, and a measured one
whose modulus the instrument did not report (NaN), stay out of it.

The campaign keeps it fitted after every refit when the planner aims at the modulus (``map_weights``);
otherwise it is fitted only when something asks for the modulus map (a report, an export, a score).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from core.model import FitReport, HeteroskedasticGP, Observations, Prediction
from core.policies.noise import NoiseModel

MIN_CENTRES = 2  # a map needs at least two centres with a modulus


@dataclass(frozen=True)
class ModulusCentre:
    """One tested centre's modulus: its robust value and spread (the modulus GP's training row)."""

    block_id: int
    x_um: float
    y_um: float
    value_gpa: float
    spread_var_gpa2: float
    n_indents: int
    efficiency: float


def drift_corrected_modulus_gpa(
    modulus_gpa: np.ndarray, hardness_raw_gpa: np.ndarray, hardness_corrected_gpa: np.ndarray
) -> np.ndarray:
    """E ∝ 1/√A and H ∝ 1/A: the contact-area correction that moved H by a factor moves E by its root."""
    ratio = np.asarray(hardness_corrected_gpa, float) / np.asarray(hardness_raw_gpa, float)
    return np.asarray(modulus_gpa, float) * np.sqrt(np.where(np.isfinite(ratio) & (ratio > 0), ratio, 1.0))


class ModulusMap:
    """The modulus GP, its training rows and its prediction on the campaign's lattice."""

    def __init__(self, surrogate: HeteroskedasticGP, noise: NoiseModel, lattice_uv: np.ndarray) -> None:
        self.surrogate = surrogate
        self.noise = noise
        self.lattice_uv = lattice_uv
        self.centres: list[ModulusCentre] = []
        self.noise_inflation: list[float] = []
        self.prediction: Prediction | None = None
        self.last_fit: FitReport | None = None
        self._fitted_n = 0  # centres the installed GP was conditioned on (0: none)

    def add(self, block_id: int, x_um: float, y_um: float, modulus_gpa: np.ndarray) -> None:
        """One tested centre's moduli; NaN (not reported) are left out, a centre with none adds nothing."""
        e = np.asarray(modulus_gpa, dtype=float)
        e = e[np.isfinite(e) & (e > 0)]
        if e.size == 0:
            return
        value, efficiency = self.noise.centre(e)
        self.centres.append(
            ModulusCentre(
                block_id=block_id,
                x_um=x_um,
                y_um=y_um,
                value_gpa=value,
                spread_var_gpa2=float(np.var(e, ddof=1)) if e.size >= 2 else math.nan,
                n_indents=int(e.size),
                efficiency=efficiency,
            )
        )
        self.noise_inflation.append(1.0)

    @property
    def n(self) -> int:
        return len(self.centres)

    def xy_um(self) -> np.ndarray:
        return np.array([(c.x_um, c.y_um) for c in self.centres], dtype=float).reshape(-1, 2)

    def observations(self, to_uv: Any) -> Observations:
        return Observations.of_centres(self.centres, self.noise_inflation, to_uv)

    @property
    def stale(self) -> bool:
        """There are centres the installed GP has not seen (or none is installed yet)."""
        return self.n >= MIN_CENTRES and self._fitted_n != self.n

    def fit(self, to_uv: Any) -> FitReport | None:
        """Refit (warm start) with the hardness map's outlier rule, and predict on the lattice."""
        if self.n < MIN_CENTRES:
            return None
        report = self.surrogate.fit(self.observations(to_uv))
        if self.noise.outliers != "none":
            obs = self.observations(to_uv)
            resid = obs.median_gpa - self.surrogate.predict_mean(obs.uv)
            new = self.noise.noise_inflation(resid, obs.uv)
            if not np.array_equal(new, np.array(self.noise_inflation)):
                self.noise_inflation = new.tolist()
                report = self.surrogate.fit(self.observations(to_uv))
        self.last_fit = report
        self._fitted_n = self.n
        self.prediction = self.surrogate.predict(self.lattice_uv)
        return report

    def ensure_fitted(self, to_uv: Any) -> bool:
        """Fit once if new centres came in since the last fit; True when there is a map."""
        if self.stale:
            self.fit(to_uv)
        return self._fitted_n > 0

    # -- persistence ------------------------------------------------------------------------------
    def export_state(self) -> dict[str, Any]:
        return {"gp": self.surrogate.hyper, "noise_inflation": list(self.noise_inflation)}

    def restore(self, state: dict[str, Any] | None, to_uv: Any) -> None:
        """Condition on the recorded hyperparameters without refitting (crash-resume decides the same)."""
        if not state:
            return
        inflation = state.get("noise_inflation")
        if isinstance(inflation, list) and len(inflation) == self.n:
            self.noise_inflation = [float(v) for v in inflation]
        hyper = state.get("gp")
        if hyper is not None and self.n >= MIN_CENTRES:
            self.surrogate.set_hyper(hyper, self.observations(to_uv))
            self._fitted_n = self.n
            self.prediction = self.surrogate.predict(self.lattice_uv)


def modulus_values_of(results: Sequence[Any]) -> np.ndarray:
    """The reported moduli of measured indents (NaN where none was reported)."""
    return np.array([getattr(r, "modulus_gpa", math.nan) for r in results], dtype=float)

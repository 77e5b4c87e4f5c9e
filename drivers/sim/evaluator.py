"""The truth evaluator: scores a campaign's map against the simulated instrument's ground truth.

The campaign never sees the truth. ``aeni simulate``, the demo and the bench hand one of these to
whatever reports the map error (the engine, the headless loop), which asks it after each refit.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from core.geometry import Calibration
from core.metrics import MapScore, ScoredMap, ScoredModulusMap, mape_pct
from drivers.sim.laid import LaidTruth
from drivers.sim.truth import FloatArray, TruthField, truth_modulus_gpa, truth_on_lattice


@dataclass
class TruthEvaluator:
    """MAPE of the map's mean on a fixed lattice of truth points, and the hardest truth indented so far."""

    truth: TruthField
    xy_um: FloatArray  # (N, 2) where the map is scored
    truth_gpa: FloatArray  # (N,) the truth there
    modulus_truth_gpa: FloatArray | None = None  # (N,) the modulus truth there (None: computed when asked)
    _max_found: float | None = field(default=None, repr=False)
    _seen: int = field(default=0, repr=False)

    @classmethod
    def for_truth(cls, truth: TruthField, calibration: Calibration, n: int = 100) -> TruthEvaluator:
        """An n×n lattice of cell centres: over the field's own rectangle when the field is the sample's own,
        else over the sample's (u, v) square (a field laid onto a sample)."""
        if isinstance(truth, LaidTruth):
            c = (np.arange(n) + 0.5) / n
            gu, gv = np.meshgrid(c, c)
            x, y = calibration.to_stage(gu.ravel(), gv.ravel())
            xy = np.column_stack([x, y])
            return cls(truth, xy, np.asarray(truth.hardness_gpa(xy[:, 0], xy[:, 1]), dtype=float))
        xs, ys, h = truth_on_lattice(truth, n)
        gx, gy = np.meshgrid(xs, ys)
        return cls(truth, np.column_stack([gx.ravel(), gy.ravel()]), h.ravel())

    def flat_mape_pct(self) -> float:
        """MAPE of the best constant map (the weighted median of the truth, weights 1/H): what a map that
        resolves nothing of the field scores. A design whose error is near it has not mapped the field."""
        t = np.asarray(self.truth_gpa, dtype=float)
        t = t[np.isfinite(t) & (t > 0)]
        order = np.argsort(t)
        w = np.cumsum(1.0 / t[order])
        c = float(t[order][np.searchsorted(w, 0.5 * w[-1])])
        return mape_pct(np.full_like(t, c), t)

    def modulus_truth(self) -> FloatArray:
        """The modulus truth on the scoring lattice (computed once)."""
        if self.modulus_truth_gpa is None:
            self.modulus_truth_gpa = truth_modulus_gpa(self.truth, self.xy_um[:, 0], self.xy_um[:, 1])
        return self.modulus_truth_gpa

    def score_modulus(self, campaign: ScoredModulusMap) -> float | None:
        """MAPE (%) of the modulus map's mean on the same lattice; None while there is no modulus map.

        Asking fits the modulus map if the planner did not keep it fitted (a hardness-only run)."""
        if not campaign.has_modulus_map():
            return None
        pred = campaign.predict_modulus_mean_stage(self.xy_um[:, 0], self.xy_um[:, 1])
        return mape_pct(pred, self.modulus_truth())

    def score(self, campaign: ScoredMap) -> MapScore:
        indents = campaign.indented_xy_um()
        if len(indents) > self._seen:
            new = indents[self._seen :]
            top = float(np.max(self.truth.hardness_gpa(new[:, 0], new[:, 1])))
            self._max_found = top if self._max_found is None else max(self._max_found, top)
            self._seen = len(indents)
        if not campaign.has_map():
            return MapScore(None, self._max_found)
        pred = campaign.predict_mean_stage(self.xy_um[:, 0], self.xy_um[:, 1])
        return MapScore(mape_pct(pred, self.truth_gpa), self._max_found)

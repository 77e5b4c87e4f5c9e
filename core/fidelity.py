"""A run's fast channel: its fast indents and the two-fidelity model that learns the CSM map from both.

The campaign keeps its CSM-only GP (its noise rules, its guard, its journal record) and, where the policy
prices fast arrays (``PolicyParts.fast``), one ``FastChannel``: the measured fast indents (failed ones are
kept apart, never learnt from) and a ``TwoFidelityGP`` built on the campaign's own GP, so the CSM level is
fitted on the same CSM fit. Once the fast data are enough (``MIN_FAST_CELLS`` cells), the map the run shows,
scores and plans on is the two-fidelity one, as long as it predicts the CSM values it has not seen better
than the CSM-only GP does (leave-one-out at every CSM centre, ``core.model.held_out``): a fast channel that
misleads (a bias the model's ρ and δ do not follow) is caught by the CSM indents themselves, and the run maps
and plans on the CSM-only GP until the evidence turns. The collapse guard covers both channels (the fast GP's
own guard; the same rule on δ's length-scales).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from core.model import FitReport, HeteroskedasticGP, Observations, Prediction
from core.model.held_out import HeldOut, compare
from core.model.two_fidelity import (
    TwoFidelityGP,
    TwoFidelityReport,
    fast_link_observations,
    fast_observations,
)
from core.plan import IndentResult
from core.policies.fidelity import HeldOutView

ToUv = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]


class TwoFidelityView:
    """The planner's ``FidelityView`` of a fitted two-fidelity model (``core.policies.fidelity``)."""

    mode = "two-fidelity"

    def __init__(self, model: TwoFidelityGP) -> None:
        self.model = model

    def variance(self, uv: np.ndarray) -> np.ndarray:
        return np.asarray(self.model.predict(uv).epistemic_sd ** 2, dtype=float)

    def variance_after_csm(self, uv: np.ndarray, sites_uv: np.ndarray, noise_var: np.ndarray) -> np.ndarray:
        return self.model.csm_variance_after_csm(uv, sites_uv, noise_var)

    def variance_after_fast(self, uv: np.ndarray, cells_uv: np.ndarray, noise_var: np.ndarray) -> np.ndarray:
        return self.model.csm_variance_after_fast(uv, cells_uv, noise_var)

    def fast_noise_var(self, uv: np.ndarray) -> np.ndarray:
        return np.asarray(self.model.fast_gp.predict_noise_sd(uv) ** 2, dtype=float)


class FastChannel:
    """The fast indents of a run and the two-fidelity model over them and the campaign's CSM GP."""

    def __init__(self, csm_gp: HeteroskedasticGP) -> None:
        self.model = TwoFidelityGP(
            kernel=csm_gp.kernel,
            lengthscale_floor_uv=csm_gp.floor_uv,
            collapse_drop_ratio=csm_gp.collapse_drop_ratio,
            guard=csm_gp.guard,
            csm_gp=csm_gp,
        )
        self.xy_um: list[tuple[float, float]] = []  # measured fast indents (actual positions)
        self.hardness_gpa: list[float] = []
        self.modulus_gpa: list[float] = []
        self.failed = 0  # fast indents the instrument made without a value (recorded, never learnt)
        self.last_report: TwoFidelityReport | None = None
        self.held_out: HeldOut | None = None  # the two maps' held-out errors at the last fit (None: no fit)
        self._cells_cache: tuple[tuple[int, ToUv], tuple[Observations, Observations | None]] | None = None

    @property
    def n(self) -> int:
        return len(self.hardness_gpa)

    @property
    def fitted(self) -> bool:
        """The two-fidelity model has a fit (enough fast cells and CSM centres to learn a bias)."""
        return self.model.mode == "two-fidelity"

    @property
    def active(self) -> bool:
        """The two-fidelity map is the run's map: fitted, and better than the CSM-only GP on held-out values."""
        return self.fitted and self.held_out is not None and self.held_out.two_fidelity_wins

    def _judge(self, csm: Observations) -> None:
        """Both maps' leave-one-out errors at the CSM centres (deterministic in the data and the fits: a
        resumed run judges the same)."""
        if not self.fitted:
            self.held_out = None
            return
        two, _ = self.model.loo_residuals()
        only, _ = self.model.csm_gp.loo_residuals()
        self.held_out = compare(csm.median_gpa, two, only)

    def record(self, results: Sequence[IndentResult]) -> None:
        for r in results:
            if not r.measured:
                self.failed += 1
                continue
            self.xy_um.append((r.actual_x_um, r.actual_y_um))
            self.hardness_gpa.append(r.hardness_gpa)
            self.modulus_gpa.append(r.modulus_gpa)

    def _cells(self, to_uv: ToUv) -> tuple[Observations, Observations | None] | None:
        """The fast cells (hardness, and E/H for ρ's link), binned again only when fast indents arrive: at
        10,000 fast indents the binning is a tenth of a second a decision (docs/two-fidelity.md, "Scale")."""
        if not self.hardness_gpa:
            return None
        key = (self.n, to_uv)
        if self._cells_cache is not None and self._cells_cache[0] == key:
            return self._cells_cache[1]
        xy = np.array(self.xy_um, dtype=float)
        u, v = to_uv(xy[:, 0], xy[:, 1])
        uv, h = np.column_stack([u, v]), np.array(self.hardness_gpa)
        cells = (fast_observations(uv, h), fast_link_observations(uv, h, np.array(self.modulus_gpa)))
        self._cells_cache = (key, cells)
        return cells

    def observations(self, to_uv: ToUv) -> Observations | None:
        cells = self._cells(to_uv)
        return None if cells is None else cells[0]

    def link_observations(self, to_uv: ToUv) -> Observations | None:
        """The fast cells' E/H (ρ's link in the two-fidelity model), None without a measured modulus."""
        cells = self._cells(to_uv)
        return None if cells is None else cells[1]

    def fit(self, csm: Observations, csm_report: FitReport, to_uv: ToUv) -> TwoFidelityReport:
        """The fast GP, its E/H link and the CSM level on the campaign's CSM fit (``csm_report``)."""
        fast, link = self.observations(to_uv), self.link_observations(to_uv)
        # a new array's re-optimisation runs beside the next block (core.model.deferred): the decision
        # after the array waits for conditioning only
        self.last_report = self.model.fit_levels(csm, fast, csm_report, link=link, defer=True)
        self._judge(csm)
        return self.last_report

    def restore(self, record: object, csm: Observations, to_uv: ToUv) -> None:
        """Condition on the data with the journaled record (a resumed run maps and plans as before)."""
        self.model.set_hyper(record, csm, self.observations(to_uv), self.link_observations(to_uv))
        self._judge(csm)

    def predict(self, uv: np.ndarray) -> Prediction:
        return self.model.predict(uv)

    def predict_mean(self, uv: np.ndarray) -> np.ndarray:
        return self.model.predict_mean(uv)

    def bias_gpa(self, uv: np.ndarray) -> np.ndarray:
        """The learnt bias E[H_csm − H_fast] (GPa) at ``uv``; NaN where the model has no fast channel yet."""
        if not self.active:
            return np.full(len(np.asarray(uv).reshape(-1, 2)), np.nan)
        return self.model.bias_gpa(uv)

    def view(self) -> TwoFidelityView | HeldOutView | None:
        """The planner's view: the two-fidelity model's where it is the run's map; where the held-out values
        reject it, a view that buys no more fast data; None before any fit (the planner's prior)."""
        if self.active:
            return TwoFidelityView(self.model)
        if self.fitted and self.held_out is not None:
            return HeldOutView(self.held_out)
        return None

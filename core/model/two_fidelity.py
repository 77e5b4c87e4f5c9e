"""The two-fidelity surrogate: the CSM map and the fast (NanoBlitz-class) channel in one model (issue 36).

Three parts, each the project's own:
- the fast channel: the heteroskedastic GP (``core.model.surrogate``) on cells of fast indents (each cell's
  median and detrended spread: the noise model of SPEC §5 learns the fast channel's own noise), always the
  interpolated GP (``core.model.ski``): thousands of indents, and a grid posterior the CSM level can carry;
- the CSM noise: the heteroskedastic GP on the CSM centres alone (its noise model, and the CSM-only map
  where there is no fast channel to learn from);
- the CSM level: co-kriging on the fast channel's posterior (``core.model.cokriging``), H_csm = ρ(x)·H_fast
  + δ(x), ρ a plane plus a quadratic link in the fast channel's E/H and δ a GP, all fitted to the CSM data,
  the CSM noise fixed from the CSM noise model;
- the link: where the fast indents report a modulus, a third interpolated GP on the cells' E/H gives ρ its
  feature. Nix–Gao's h* grows as (E/H)², so the fast channel's size effect (and its ratio to the CSM value)
  follows E/H, which varies across a library independently of H: on the emulator's ternary the best plane ρ
  leaves a 0.12 GPa residual (1.7× the CSM noise) for δ, a ρ linked to E/H leaves 0.005 GPa
  (docs/two-fidelity.md).

The collapse guard covers both channels: the fast GP's own, and the same rule on δ's length-scales. The CSM
channel's posterior has the surrogate's four fields (``Prediction``), so a planner reads it as it reads the
CSM-only GP's.
"""

from __future__ import annotations

import copy
import math
import time
from dataclasses import dataclass, replace
from typing import Any, Literal

import numpy as np
import torch

from core.errors import InputError
from core.model.cokriging import (
    N_LINK,
    N_RHO,
    N_THETA,
    CoKrigingConditioned,
    CoKrigingProblem,
    interpolation_matrix,
    regression_columns,
    start_theta,
    unpack_theta,
)
from core.model.deferred import Deferred
from core.model.fitting import COLD_WIN_NATS, cold_search_due, optimisation_due, optimise
from core.model.guard import GUARDS, CollapseRule, GuardName
from core.model.held_out import loo_residuals
from core.model.kernels import DTYPE, MIN_NOISE_STD, KernelName
from core.model.observations import Observations, standardise
from core.model.surrogate import FitReport, HeteroskedasticGP, Prediction

FidelityMode = Literal["two-fidelity", "csm-only"]
MIN_FAST_CELLS = 20  # fewer fast cells than this: the CSM-only map (nothing to learn a bias from)
MIN_CSM_CENTRES = 4  # ... and fewer CSM centres: ρ's plane and δ's plane need more than six numbers' worth
# a fast cell is this many fast-indent spacings on a side (3 × 3 indents in a regular array): enough for a
# detrended spread (n − 3 ≥ 6 degrees of freedom) at a resolution still finer than the length-scale floor
CELL_SPACINGS = 3.0
CELL_UV_BOUNDS = (0.005, 0.1)
DELTA_COLD_STARTS = ((0.3, 0.3), (0.1, 0.15))  # δ's (outputscale, length-scale) of the cold starts
PREDICT_CHUNK = 1024  # candidates per block of the predictive diagonal
HYPER_VERSION = 2  # 1: ρ a plane (9 numbers; read as version 2 with no link)
LINK_Z_CLIP = 4.0  # the standardised link feature, clipped off the data (the grid's margin)
_FIELD = "surrogate.two_fidelity"


def _raw(values: object, version: int = HYPER_VERSION) -> torch.Tensor:
    n = N_THETA if version == HYPER_VERSION else N_THETA - N_LINK
    if (
        not isinstance(values, list)
        or len(values) != n
        or not all(isinstance(v, int | float) and math.isfinite(v) for v in values)
    ):
        raise ValueError(f"expected {n} finite numbers, got {values!r}")
    raw = [float(v) for v in values]
    if n != N_THETA:  # a version-1 record: ρ the plane, no link
        raw = raw[:3] + [0.0] * N_LINK + raw[3:]
    return torch.tensor(raw, dtype=DTYPE)


def fast_observations(uv: np.ndarray, hardness_gpa: np.ndarray, cell_uv: float | None = None) -> Observations:
    """Fast indents as the surrogate's observations: one row per occupied square cell of side ``cell_uv``
    (default CELL_SPACINGS × the indents' median nearest-neighbour spacing), its median and detrended spread.

    Failed indents (NaN) are left out: they are recorded elsewhere, never learnt from.
    """
    pts = np.asarray(uv, dtype=float).reshape(-1, 2)
    h = np.asarray(hardness_gpa, dtype=float).ravel()
    if h.shape[0] != pts.shape[0]:
        raise InputError("fast indents", f"{pts.shape[0]} positions but {h.shape[0]} values")
    ok = np.isfinite(h) & np.all(np.isfinite(pts), axis=1)
    pts, h = pts[ok], h[ok]
    if pts.shape[0] == 0:
        raise InputError("fast indents", "no measured fast indent to learn from")
    if cell_uv is None:
        cell_uv = CELL_SPACINGS * _median_spacing(pts)
    cell_uv = float(np.clip(cell_uv, *CELL_UV_BOUNDS))
    ij = np.floor(pts / cell_uv).astype(np.int64)
    ids = ij[:, 0] * 1_000_003 + ij[:, 1]
    return Observations.from_indents(pts, h, ids, detrend=True)


def fast_link_observations(
    uv: np.ndarray, hardness_gpa: np.ndarray, modulus_gpa: np.ndarray, cell_uv: float | None = None
) -> Observations | None:
    """The fast indents' E/H in the cells ``fast_observations`` makes (None where no indent has both)."""
    h = np.asarray(hardness_gpa, dtype=float).ravel()
    e = np.asarray(modulus_gpa, dtype=float).ravel()
    ok = np.isfinite(h) & np.isfinite(e) & (h > 0)
    if not ok.any():
        return None
    pts = np.asarray(uv, dtype=float).reshape(-1, 2)
    if cell_uv is None:
        cell_uv = CELL_SPACINGS * _median_spacing(pts[np.isfinite(h)])
    return fast_observations(pts[ok], e[ok] / h[ok], cell_uv)


def _median_spacing(pts: np.ndarray) -> float:
    if pts.shape[0] < 2:
        return CELL_UV_BOUNDS[1]
    from scipy.spatial import cKDTree

    d, _ = cKDTree(pts).query(pts, k=2)
    return float(np.median(d[:, 1]))


@dataclass(frozen=True)
class TwoFidelityReport:
    mode: FidelityMode
    csm: FitReport  # the CSM-only GP: the CSM noise model (and the map in csm-only mode)
    fast: FitReport | None
    rho_coef: tuple[float, float, float] | None  # ρ's plane: b₀ + b₁(u − ½) + b₂(v − ½)
    rho_link_coef: tuple[float, float] | None  # ρ's link: + b₃·z + b₄·z², z the standardised fast E/H
    delta_lengthscales_uv: tuple[float, float] | None
    delta_outputscale_gpa2: float | None  # δ's prior variance: what the fast channel does not explain
    delta_share: (
        float | None
    )  # ... as a share of the CSM values' variance (near 0: the fast channel explains them)
    collapse: bool  # δ's length-scales (the fast GP's guard reports in ``fast``)
    collapse_reason: str
    used_last_good: bool
    iterations: int
    seconds: float


@dataclass(frozen=True)
class _FitInputs:
    """What a fit of the levels reads: the data, and the CSM-only GP's report and noise taken in the caller's
    thread (so the fit never touches that GP and may run on another)."""

    csm: Observations
    fast: Observations
    link: Observations | None
    csm_report: FitReport
    noise_var: np.ndarray
    t0: float


@dataclass
class _Reoptimisation:
    """The fit ``TwoFidelityGP._fit_levels`` would have made at an array's landing, on a copy of the model:
    an object, not a closure, so a deep copy of the model copies it."""

    shadow: TwoFidelityGP
    inputs: _FitInputs

    def run(self) -> tuple[TwoFidelityGP, TwoFidelityReport]:
        return self.shadow, self.shadow._fit_levels(self.inputs)


class TwoFidelityGP:
    """The CSM map learnt from CSM centres and fast cells together; ``predict`` is the CSM channel's."""

    def __init__(
        self,
        kernel: KernelName = "matern52",
        lengthscale_floor_uv: float = 0.02,
        collapse_drop_ratio: float = 0.35,
        guard: GuardName = "keep-last-good",
        max_iter: int = 60,
        warm_max_iter: int | None = None,
        collapse_min_points: int = 8,
        min_fast_cells: int = MIN_FAST_CELLS,
        lengthscale_prior: bool = True,
        threads: int = 1,
        csm_gp: HeteroskedasticGP | None = None,
    ) -> None:
        """``csm_gp``: a CSM-only GP fitted elsewhere (a campaign's own surrogate, with its noise rules): the
        model then reads it and ``fit_levels`` fits only the fast channel and the CSM level."""
        if guard not in GUARDS:
            raise InputError("surrogate.guard", f"unknown guard {guard!r}; allowed: {', '.join(GUARDS)}")
        if min_fast_cells < 1:
            raise InputError("surrogate.min_fast_cells", f"must be ≥ 1, got {min_fast_cells}")
        common: dict[str, Any] = {
            "kernel": kernel,
            "lengthscale_floor_uv": lengthscale_floor_uv,
            "collapse_drop_ratio": collapse_drop_ratio,
            "guard": guard,
            "max_iter": max_iter,
            "warm_max_iter": warm_max_iter,
            "collapse_min_points": collapse_min_points,
            "lengthscale_prior": lengthscale_prior,
            "threads": threads,
        }
        self.csm_gp = HeteroskedasticGP(**common) if csm_gp is None else csm_gp
        self.fast_gp = HeteroskedasticGP(**common, ski_above=1)  # always the interpolated GP
        self.link_gp = HeteroskedasticGP(**common, ski_above=1)  # the fast channel's E/H: ρ's link
        self._link: Observations | None = None  # the link's cells in the current fit
        self._link_on = False  # ρ's link in use: chosen at each optimisation, by the evidence (BIC)
        self.kernel: KernelName = kernel
        self.floor_uv = float(lengthscale_floor_uv)
        self.guard: GuardName = guard
        self.max_iter = self.csm_gp.max_iter
        self.warm_max_iter = self.csm_gp.warm_max_iter
        self.with_prior = bool(lengthscale_prior)
        self.min_fast_cells = int(min_fast_cells)
        self.rule = CollapseRule(self.floor_uv, float(collapse_drop_ratio), int(collapse_min_points))
        self._theta: torch.Tensor | None = None
        self._last_good: torch.Tensor | None = None
        self._prev_n = 0
        self._cold_n = 0
        self._fit_n = 0  # CSM centres at the CSM level's last optimisation
        self._fast_n = 0  # fast cells then
        self._cond: CoKrigingConditioned | None = None
        self._p: CoKrigingProblem | None = None  # the CSM level's data, kept for what-if variances
        self._loc = 0.0
        self._scale = 1.0
        self._pending: Deferred[tuple[TwoFidelityGP, TwoFidelityReport]] | None = None

    @property
    def mode(self) -> FidelityMode:
        return "csm-only" if self._cond is None else "two-fidelity"

    @property
    def theta(self) -> tuple[float, ...] | None:
        """The CSM level's raw vector in use (None in csm-only mode): for the journal and a warm start."""
        return None if self._theta is None or self._cond is None else tuple(self._theta.tolist())

    @property
    def hyper(self) -> dict[str, Any] | None:
        """The journal's record (JSON-able): both GPs' records and the CSM level's state; None before a fit."""
        csm = self.csm_gp.hyper
        if csm is None:
            return None
        record: dict[str, Any] = {"version": HYPER_VERSION, "csm": csm}
        if self._cond is not None and self._theta is not None:
            record["fast"] = self.fast_gp.hyper
            if self._link is not None:
                record["link"] = self.link_gp.hyper
            record["cokriging"] = {
                "raw": self._theta.tolist(),
                "last_good": None if self._last_good is None else self._last_good.tolist(),
                "prev_n": self._prev_n,
                "cold_n": self._cold_n,
                "fit_n": self._fit_n,
                "fast_n": self._fast_n,
                "link_on": self._link_on,
            }
        return record

    def set_hyper(
        self,
        record: object,
        csm: Observations,
        fast: Observations | None,
        link: Observations | None = None,
    ) -> None:
        """Condition on the data with a recorded fit, no optimisation (crash-resume: the same model as before).
        ``link``: the fast cells' E/H (``fast_link_observations``), as given to the fit."""
        if (
            not isinstance(record, dict)
            or record.get("version") not in (1, HYPER_VERSION)
            or "csm" not in record
        ):
            raise InputError(_FIELD, f"not a version-1 or -{HYPER_VERSION} two-fidelity record")
        version = int(record["version"])
        self._pending = None  # a re-optimisation under way is the old model's: the record is what counts
        self.csm_gp.set_hyper(record["csm"], csm)
        if "cokriging" not in record:
            self._cond = None
            return
        if fast is None or "fast" not in record:
            raise InputError(_FIELD, "records a fast channel but no fast data (or no fast record) was given")
        self.fast_gp.set_hyper(record["fast"], fast)
        self._link = None
        if "link" in record and link is not None:
            self.link_gp.set_hyper(record["link"], link)
            self._link = link
        ck = record["cokriging"]
        try:
            raw = _raw(ck["raw"], version)
            last_good = None if ck.get("last_good") is None else _raw(ck["last_good"], version)
            counters = [int(ck[k]) for k in ("prev_n", "cold_n", "fit_n", "fast_n")]
            link_on = bool(ck.get("link_on", False))
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(_FIELD, f"malformed cokriging record: {exc!r}") from None
        self._theta, self._last_good = raw, last_good
        self._prev_n, self._cold_n, self._fit_n, self._fast_n = counters
        self._link_on = link_on and self._link is not None
        noise_var = self._csm_noise_var(csm)
        self._p = self._problem(csm, noise_var)
        self._cond = self._p.condition(raw)
        if fast.n != self._fast_n:
            # recorded between an array's landing and the fit that installs its re-optimisation: prepare it
            # again from these data (the landing's, for a run resumed before its next block's refit), so
            # the resumed run installs what the uninterrupted one did
            csm_report = self.csm_gp.condition(csm)
            if csm_report is not None:
                inputs = _FitInputs(csm, fast, link, csm_report, noise_var, time.perf_counter())
                self._defer(self._shadow(), inputs)

    def fit(
        self,
        csm: Observations,
        fast: Observations | None,
        link: Observations | None = None,
        defer: bool = False,
    ) -> TwoFidelityReport:
        """Fit the CSM-only GP, the fast GP (and its E/H link) and the CSM level (warm from the previous fit)."""
        t0 = time.perf_counter()
        return self.fit_levels(csm, fast, self.csm_gp.fit(csm), t0, link, defer)

    def fit_levels(
        self,
        csm: Observations,
        fast: Observations | None,
        csm_report: FitReport,
        t0: float | None = None,
        link: Observations | None = None,
        defer: bool = False,
    ) -> TwoFidelityReport:
        """The fast GP and the CSM level on a CSM-only GP already fitted to ``csm`` (its ``csm_report``);
        ``link``: the fast cells' E/H (``fast_link_observations``; None: ρ the plane).

        ``defer``: where new fast data (an array) would re-optimise a fitted model, condition on them with
        the hyperparameters in use now and re-optimise on a thread (``core.model.deferred``) instead, once
        ``start_reoptimisation`` says the decision is made; the re-optimisation, of the data as they are
        now, is installed at the next fit."""
        t0 = time.perf_counter() if t0 is None else t0
        installed = self._collect()
        if fast is None or fast.n < self.min_fast_cells or csm.n < MIN_CSM_CENTRES:
            self._cond = None
            return TwoFidelityReport(
                "csm-only",
                csm_report,
                None,
                None,
                None,
                None,
                None,
                None,
                False,
                "",
                False,
                0,
                time.perf_counter() - t0,
            )
        inputs = _FitInputs(csm, fast, link, csm_report, self._csm_noise_var(csm), t0)
        report = None
        if defer and self._theta is not None and self._cond is not None and fast.n != self._fast_n:
            report = self._condition_and_defer(inputs)
        if report is None:
            report = self._fit_levels(inputs)
        if installed is None:
            return report
        # the re-optimisation installed at the start of this fit is part of it: its optimiser steps and its
        # guard's verdict on δ (the fast GP's guard reports in its own FitReport, ``installed.fast``)
        reasons = [r for r in (installed.collapse_reason, report.collapse_reason) if r]
        return replace(
            report,
            collapse=installed.collapse or report.collapse,
            collapse_reason="; ".join(reasons),
            used_last_good=installed.used_last_good or report.used_last_good,
            iterations=installed.iterations + report.iterations,
        )

    @property
    def reoptimising(self) -> bool:
        """A re-optimisation of the last array's data is under way (or done and not yet installed)."""
        return self._pending is not None

    def start_reoptimisation(self) -> None:
        """The decision on the conditioned model is made: the re-optimisation may take the machine now."""
        if self._pending is not None:
            self._pending.start()

    @property
    def reoptimisation_done(self) -> bool:
        """The re-optimisation under way has finished (the next fit installs it without waiting)."""
        return self._pending is not None and self._pending.done

    def _collect(self) -> TwoFidelityReport | None:
        """Install the re-optimisation started at the last array's landing (waits for it); its report."""
        pending, self._pending = self._pending, None
        if pending is None:
            return None
        shadow, report = pending.result()
        self.fast_gp, self.link_gp = shadow.fast_gp, shadow.link_gp
        self._link, self._link_on = shadow._link, shadow._link_on
        self._theta, self._last_good = shadow._theta, shadow._last_good
        self._prev_n, self._cold_n = shadow._prev_n, shadow._cold_n
        self._fit_n, self._fast_n = shadow._fit_n, shadow._fast_n
        return report

    def _condition_and_defer(self, inputs: _FitInputs) -> TwoFidelityReport | None:
        """Condition every level on the new fast data with the hyperparameters in use, and start their
        re-optimisation (the fit ``_fit_levels`` would make now) on a copy; None where a level cannot be
        conditioned (another noise model for the new cells): then the caller fits now."""
        shadow = self._shadow()  # the model as it is: the fit below starts from here
        csm, fast = inputs.csm, inputs.fast
        link = inputs.link if inputs.link is not None and inputs.link.n >= self.min_fast_cells else None
        fast_report = self.fast_gp.condition(fast)
        if fast_report is None or (
            link is not None and (self._link is None or self.link_gp.condition(link) is None)
        ):
            self.fast_gp, self.link_gp = shadow.fast_gp, shadow.link_gp  # as they were; the caller fits now
            return None
        self._link = link
        if link is None:
            self._link_on = False
        assert self._theta is not None
        p = self._problem(csm, inputs.noise_var)
        self._p, self._cond = p, p.condition(self._theta)
        self._defer(shadow, inputs)
        return self._report(inputs.csm_report, fast_report, csm, self._theta, False, "", False, 0, inputs.t0)

    def _shadow(self) -> TwoFidelityGP:
        """A copy to fit on a thread: its own fast and link GPs; the CSM-only GP shared but never touched
        (the fit reads its noise through ``noise_var``, taken now)."""
        shadow = copy.copy(self)
        shadow.fast_gp, shadow.link_gp = copy.deepcopy(self.fast_gp), copy.deepcopy(self.link_gp)
        shadow._pending = None
        return shadow

    def _defer(self, shadow: TwoFidelityGP, inputs: _FitInputs) -> None:
        """The fit ``_fit_levels`` would make now, on ``shadow``, to run once ``start_reoptimisation`` says."""
        self._pending = Deferred(_Reoptimisation(shadow, inputs).run, torch.get_num_threads())

    def _fit_levels(self, inputs: _FitInputs) -> TwoFidelityReport:
        """The fit proper: reads the CSM-only GP only through ``inputs`` (so it may run on a thread)."""
        csm, fast, link, noise_var = inputs.csm, inputs.fast, inputs.link, inputs.noise_var
        csm_report, t0 = inputs.csm_report, inputs.t0
        fast_report = self.fast_gp.fit(fast)
        self._link = link if link is not None and link.n >= self.min_fast_cells else None
        if self._link is not None:
            self.link_gp.fit(self._link)
        else:
            self._link_on = False
        p = self._problem(csm, noise_var)
        iterations = 0
        if (
            self._theta is not None
            and fast.n == self._fast_n
            and not optimisation_due(csm.n, self._fit_n)
            and not cold_search_due(csm.n, self._cold_n)
        ):
            # a few more CSM centres and no new fast data: condition with the kept hyperparameters (as the
            # interpolated GP does between optimisations; deterministic in the data sizes)
            self._p, self._cond = p, p.condition(self._theta)
            return self._report(csm_report, fast_report, csm, self._theta, False, "", False, 0, t0)
        self._fit_n, self._fast_n = csm.n, fast.n
        if self._theta is None:
            theta = self._cold(p)[0]
            iterations += self.max_iter
            self._cold_n = csm.n
        else:
            theta, iterations = optimise(p, self._theta, self.warm_max_iter)
            if cold_search_due(csm.n, self._cold_n):
                cold, _ = self._cold(p)
                if (p.objective(theta) - p.objective(cold)) * csm.n > COLD_WIN_NATS:
                    theta = cold
                self._cold_n = csm.n
        if self._link is not None:
            p, theta, more = self._choose_link(csm, p, theta, noise_var)
            iterations += more
        t = unpack_theta(theta, self.floor_uv)
        ls = (float(t.lengthscale[0]), float(t.lengthscale[1]))
        prev_ls = None
        if self._last_good is not None:
            good = unpack_theta(self._last_good, self.floor_uv).lengthscale
            prev_ls = (float(good[0]), float(good[1]))
        collapse, reason = self.rule.check_lengthscales(ls, prev_ls, self._prev_n)
        used_last_good = False
        if collapse and self.guard != "off":
            if self._last_good is not None:
                theta = torch.cat([theta[: N_RHO + 3], self._last_good[N_RHO + 3 : N_THETA]])  # δ's kernel
                used_last_good = True
                reason += "; kept the last good bias kernel"
            else:
                reason += "; no earlier good fit to fall back to"
        elif not collapse:
            self._last_good = theta.clone()
        self._prev_n = csm.n
        self._theta = theta.clone()
        self._p, self._cond = p, p.condition(theta)
        return self._report(
            csm_report, fast_report, csm, theta, collapse, reason, used_last_good, iterations, t0
        )

    def _report(
        self,
        csm_report: FitReport,
        fast_report: FitReport,
        csm: Observations,
        theta: torch.Tensor,
        collapse: bool,
        reason: str,
        used_last_good: bool,
        iterations: int,
        t0: float,
    ) -> TwoFidelityReport:
        t = unpack_theta(theta, self.floor_uv)
        delta_var = float(t.outputscale) * self._scale**2
        return TwoFidelityReport(
            mode="two-fidelity",
            csm=csm_report,
            fast=fast_report,
            rho_coef=(float(t.rho[0]), float(t.rho[1]), float(t.rho[2])),
            rho_link_coef=(float(t.rho[3]), float(t.rho[4])) if self._link_on else None,
            delta_lengthscales_uv=(float(t.lengthscale[0]), float(t.lengthscale[1])),
            delta_outputscale_gpa2=delta_var,
            delta_share=delta_var / max(float(np.var(csm.median_gpa, ddof=1)) if csm.n > 1 else 1.0, 1e-12),
            collapse=collapse,
            collapse_reason=reason,
            used_last_good=used_last_good,
            iterations=iterations,
            seconds=time.perf_counter() - t0,
        )

    def predict(self, uv: np.ndarray) -> Prediction:
        """The CSM map's four fields (GPa) at ``uv``: mean, epistemic sd, per-indent noise sd, total sd."""
        if self._cond is None:
            return self.csm_gp.predict(uv)
        pts = np.array(uv, dtype=float).reshape(-1, 2)
        xs_all = torch.as_tensor(pts, dtype=DTYPE)
        mean = np.empty(pts.shape[0])
        var = np.empty(pts.shape[0])
        with torch.no_grad():
            for start in range(0, pts.shape[0], PREDICT_CHUNK):
                mu, v = self._cond.mean_var(xs_all[start : start + PREDICT_CHUNK])
                mean[start : start + mu.shape[0]] = mu.numpy()
                var[start : start + mu.shape[0]] = v.numpy()
        epi = np.sqrt(var) * self._scale
        noise = self.csm_gp.predict_noise_sd(pts)
        return Prediction(
            mean=mean * self._scale + self._loc,
            epistemic_sd=epi,
            noise_sd=noise,
            total_sd=np.sqrt(epi**2 + noise**2),
        )

    def csm_variance_after_fast(
        self, uv: np.ndarray, cells_uv: np.ndarray, cells_noise_var_gpa2: np.ndarray
    ) -> np.ndarray:
        """The CSM map's latent variance (GPa²) at ``uv`` if fast cells at ``cells_uv`` were added, each value
        with its noise variance, every hyperparameter held: what a fast array would buy (the planner's
        integrated variance reduction). The fast grid's posterior takes the cells (an n_cells-sized update), and
        the CSM level is conditioned on its data again over it."""
        if self._cond is None or self._p is None or self._theta is None:
            raise RuntimeError("TwoFidelityGP.csm_variance_after_fast: no fast channel in this fit")
        p = self._p
        xa = torch.as_tensor(np.array(cells_uv, dtype=float).reshape(-1, 2), dtype=DTYPE)
        noise = torch.as_tensor(np.asarray(cells_noise_var_gpa2, dtype=float).ravel(), dtype=DTYPE)
        if noise.shape[0] != xa.shape[0] or not bool(torch.all(noise > 0)):
            raise InputError("cells_noise_var_gpa2", "one noise variance > 0 per cell is needed")
        with torch.no_grad():
            weights = interpolation_matrix(p.grid, xa)
            sw = torch.sparse.mm(weights, p.fast_grid_cov)  # (n_cells, m): W Σ_g
            s = torch.sparse.mm(weights, sw.T.contiguous()) + torch.diag(noise / self._scale**2)
            z = torch.linalg.solve_triangular(torch.linalg.cholesky(s), sw, upper=False)
            after = replace(p, fast_grid_cov=p.fast_grid_cov - z.T @ z).condition(self._theta)
            xs_all = torch.as_tensor(np.array(uv, dtype=float).reshape(-1, 2), dtype=DTYPE)
            var = torch.cat(
                [
                    after.mean_var(xs_all[i : i + PREDICT_CHUNK])[1]
                    for i in range(0, xs_all.shape[0], PREDICT_CHUNK)
                ]
            )
        return var.numpy() * self._scale**2

    def csm_variance_after_csm(
        self, uv: np.ndarray, sites_uv: np.ndarray, sites_noise_var_gpa2: np.ndarray
    ) -> np.ndarray:
        """The CSM map's latent variance (GPa²) at ``uv`` if CSM values at ``sites_uv`` were added, each with
        its noise variance, every hyperparameter held (y-free): what a CSM block buys, on the same scale as
        ``csm_variance_after_fast``."""
        if self._cond is None or self._p is None or self._theta is None:
            raise RuntimeError("TwoFidelityGP.csm_variance_after_csm: no fast channel in this fit")
        p = self._p
        xa = torch.as_tensor(np.array(sites_uv, dtype=float).reshape(-1, 2), dtype=DTYPE)
        noise = torch.as_tensor(np.asarray(sites_noise_var_gpa2, dtype=float).ravel(), dtype=DTYPE)
        if noise.shape[0] != xa.shape[0] or not bool(torch.all(noise > 0)):
            raise InputError("sites_noise_var_gpa2", "one noise variance > 0 per site is needed")
        assert p.noise_fixed is not None
        with torch.no_grad():
            after = replace(
                p,
                x=torch.cat([p.x, xa]),
                y=torch.cat([p.y, torch.zeros(xa.shape[0], dtype=DTYPE)]),
                noise_fixed=torch.cat([p.noise_fixed, noise / self._scale**2]),
                noise_scale=torch.ones(p.n + xa.shape[0], dtype=DTYPE),
            ).condition(self._theta)
            xs_all = torch.as_tensor(np.array(uv, dtype=float).reshape(-1, 2), dtype=DTYPE)
            var = torch.cat(
                [
                    after.mean_var(xs_all[i : i + PREDICT_CHUNK])[1]
                    for i in range(0, xs_all.shape[0], PREDICT_CHUNK)
                ]
            )
        return var.numpy() * self._scale**2

    def predict_mean(self, uv: np.ndarray) -> np.ndarray:
        """The CSM map's mean (GPa) at ``uv`` (what an evaluator scores)."""
        if self._cond is None:
            return self.csm_gp.predict_mean(uv)
        xs_all = torch.as_tensor(np.array(uv, dtype=float).reshape(-1, 2), dtype=DTYPE)
        with torch.no_grad():
            mean = torch.cat(
                [
                    self._cond.mean(xs_all[i : i + PREDICT_CHUNK])
                    for i in range(0, xs_all.shape[0], PREDICT_CHUNK)
                ]
            )
        return np.asarray(mean.numpy() * self._scale + self._loc, dtype=float)

    def loo_residuals(self) -> tuple[np.ndarray, np.ndarray]:
        """Each CSM centre's value less the two-fidelity map's prediction of it from the other centres and
        the fast data (GPa), and its variance (GPa², noise included): ρ's and δ's planes estimated again
        without the centre, every other hyperparameter held (``core.model.held_out``)."""
        if self._cond is None or self._p is None or self._theta is None:
            raise RuntimeError("TwoFidelityGP.loo_residuals: no fast channel in this fit")
        p = self._p
        with torch.no_grad():
            k = p.data_covariance(self._theta)
            reg = regression_columns(p.rho_basis, p.fast_mean, p.basis)
            resid, var = loo_residuals(k, p.y, reg[:, self._cond.reg_used])
        return resid * self._scale, var * self._scale**2

    def predict_fast(self, uv: np.ndarray) -> Prediction:
        """The fast channel's own map (what a fast indent reads), from the fast data alone."""
        if self._cond is None:
            raise RuntimeError("TwoFidelityGP.predict_fast: no fast channel in this fit")
        return self.fast_gp.predict(uv)

    def rho(self, uv: np.ndarray) -> np.ndarray:
        """ρ(x): the fitted CSM/fast ratio."""
        if self._cond is None:
            raise RuntimeError("TwoFidelityGP.rho: no fast channel in this fit")
        xs = torch.as_tensor(np.array(uv, dtype=float).reshape(-1, 2), dtype=DTYPE)
        return self._cond.rho(xs).numpy()

    def bias_gpa(self, uv: np.ndarray) -> np.ndarray:
        """The learnt bias of the fast channel, E[H_csm − H_fast] (GPa): what the console shows as the bias."""
        return self.predict(uv).mean - self.predict_fast(uv).mean

    # -- the CSM level's data and fits ---------------------------------------------------------------

    def _choose_link(
        self, csm: Observations, p: CoKrigingProblem, theta: torch.Tensor, noise_var: np.ndarray
    ) -> tuple[CoKrigingProblem, torch.Tensor, int]:
        """ρ with its E/H link or the plane alone, whichever the CSM data support: the link's two numbers
        must buy more than Schwarz's ln(n) nats of likelihood (BIC, 2 parameters), else they fit noise
        (a field whose CSM/fast ratio barely varies, as the film's 0.86–0.91, under 10 % CSM noise).
        ``p`` and ``theta``: the problem as it stands (link on or off) and its optimum."""
        was_on = self._link_on
        self._link_on = not was_on
        other = self._problem(csm, noise_var)
        start = theta.clone()
        if was_on:
            start[3:N_RHO] = 0.0  # the plane: the link's coefficients have no feature to act on
        theta_other, iterations = optimise(other, start, self.warm_max_iter)
        linked, theta_link = (p, theta) if was_on else (other, theta_other)
        plane, theta_plane = (other, theta_other) if was_on else (p, theta)
        gain_nats = (plane.objective(theta_plane) - linked.objective(theta_link)) * csm.n
        self._link_on = bool(math.isfinite(gain_nats) and gain_nats > math.log(csm.n))
        if self._link_on:
            return linked, theta_link, iterations
        theta_plane = theta_plane.clone()
        theta_plane[3:N_RHO] = 0.0
        return plane, theta_plane, iterations

    def _csm_noise_var(self, csm: Observations) -> np.ndarray:
        """The CSM values' per-indent noise variance (GPa²) from the CSM-only GP's noise model."""
        return np.asarray(self.csm_gp.predict_noise_sd(csm.uv) ** 2 + self.csm_gp.site_var_gpa2, dtype=float)

    def _problem(self, csm: Observations, noise_var: np.ndarray) -> CoKrigingProblem:
        grid, fast_mean, fast_cov = self.fast_gp.latent_grid()
        self._loc, self._scale = standardise(csm.median_gpa)
        assert csm.efficiency is not None
        fixed = np.maximum(csm.efficiency * noise_var / csm.n_indents / self._scale**2, MIN_NOISE_STD)
        x = torch.as_tensor(csm.uv, dtype=DTYPE)
        return CoKrigingProblem(
            kernel=self.kernel,
            floor_uv=self.floor_uv,
            with_prior=self.with_prior,
            x=x,
            y=torch.as_tensor((csm.median_gpa - self._loc) / self._scale, dtype=DTYPE),
            noise_fixed=torch.as_tensor(fixed, dtype=DTYPE),
            noise_scale=torch.ones(csm.n, dtype=DTYPE),
            grid=grid,
            fast_grid_mean=torch.as_tensor((fast_mean - self._loc) / self._scale, dtype=DTYPE),
            fast_grid_cov=torch.as_tensor(fast_cov / self._scale**2, dtype=DTYPE),
            link_grid=self._link_grid(grid.points().numpy(), csm.uv),
        )

    def _link_grid(self, grid_uv: np.ndarray, csm_uv: np.ndarray) -> torch.Tensor:
        """ρ's link features on the fast grid: z, z² with z the link GP's E/H standardised over the cells
        (empty without a link: ρ the plane). z is held within what the CSM centres have seen: the link is a
        regression on them, never extrapolated (a layer or a phase that reads an E/H no CSM indent has met
        keeps ρ's value at the edge of that range, and δ and the CSM indents must find it)."""
        if self._link is None or not self._link_on:
            return torch.empty(0, dtype=DTYPE)
        cells = self._link.median_gpa
        loc, spread = float(np.mean(cells)), max(float(np.std(cells)), 1e-12)
        seen = (self.link_gp.predict_mean(csm_uv) - loc) / spread
        lo, hi = max(float(seen.min()), -LINK_Z_CLIP), min(float(seen.max()), LINK_Z_CLIP)
        z = np.clip((self.link_gp.predict_mean(grid_uv) - loc) / spread, lo, hi)
        return torch.as_tensor(np.column_stack([z, z**2][:N_LINK]), dtype=DTYPE)

    def _cold(self, p: CoKrigingProblem) -> tuple[torch.Tensor, float]:
        """A few deterministic starts, ρ₀ from the least-squares slope of the CSM values on the fast map."""
        f = p.fast_mean - p.fast_mean.mean()
        slope = float((f * (p.y - p.y.mean())).sum() / f.square().sum().clamp_min(1e-12))
        best: tuple[float, torch.Tensor] | None = None
        for outputscale, lengthscale in DELTA_COLD_STARTS:
            theta, _ = optimise(p, start_theta(slope, outputscale, lengthscale, self.floor_uv), self.max_iter)
            value = p.objective(theta)
            if math.isfinite(value) and (best is None or value < best[0]):
                best = (value, theta)
        assert best is not None, "every start of the co-kriging fit failed"
        return best[1], best[0]

"""The planner loop that an engine (or a headless simulation) drives block by block.

A Campaign owns the model side of a run: the sample (calibration, exclusions, earlier indents),
candidate lattice, surrogate and policy. It proposes a block, is told what the instrument measured,
refits, and proposes again. It never touches an instrument (the driver does that, and the engine
moves data between them) and never sees a ground truth: map errors are scored outside it.
"""

from __future__ import annotations

import dataclasses
import datetime
import functools
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from core.campaign_config import CampaignConfig
from core.cost import indent_steps
from core.drift import drift_corrected_hardness_gpa, smoothed_drift_rates_nm_s
from core.errors import InputError
from core.fidelity import FastChannel
from core.geometry import CandidateLattice
from core.metrics import MapScore
from core.model import FitReport, HeteroskedasticGP, Observations, Prediction
from core.modulus import ModulusMap, drift_corrected_modulus_gpa, modulus_values_of
from core.operator import Attendance
from core.plan import Block, Decision, IndentResult, PlannerSettings, decision_from_dict
from core.policies.base import (
    DEFAULT_PITCH_UM,
    GPSummary,
    ModulusView,
    PlanContext,
    PlansStretches,
    Policy,
    base_mask,
)
from core.policies.hold_settings import check_hold_in_force
from core.policies.registry import RunFacts, make_policy
from core.policies.stretch import renumbered
from core.policies.variance import median_noise_var
from core.profile import InstrumentProfile, load_profile
from core.runview import MapFields
from core.sample import Sample, check_avoided_centres, grid_baseline_s
from core.settings import (
    adjust_settings,
    check_holds,
    settings_from_dict,
    settings_to_dict,
)
from core.taken import taken_xy_um

VETO_HOLD_BLOCKS = 3
OUTLIER_REFIT_INFLATION = 4.0  # a value whose noise the outlier rule inflates this much is refitted at once
DEFAULT_HORIZON_SLACK = 1.02  # the default time budget over the grid baseline's priced time


@dataclass(frozen=True)
class CentreRecord:
    """One executed block collapsed to a robust value (the GP's training row)."""

    block_id: int
    x_um: float
    y_um: float
    median_gpa: float
    spread_var_gpa2: float
    n_indents: int
    value_gpa: float  # what the GP sees: the policy's centre estimator (the median by default)
    efficiency: float  # var(value)·n/σ²


@dataclass
class _Veto:
    x_um: float
    y_um: float
    until_blocks_done: int


class Campaign:
    def __init__(
        self,
        config: CampaignConfig,
        sample: Sample | None = None,
        *,
        refit_every: int = 1,
        wall_s_per_instrument_s: float = 1.0,
        attendance: Attendance | None = None,
        wall_clock: Callable[[], float] = time.time,
    ) -> None:
        """``refit_every`` > 1 refits only after every so many blocks (the bench's grid, which never looks at
        the model); ``wall_s_per_instrument_s``: how much wall time an instrument second takes (1 on a real
        instrument, 1/speed on a sped-up simulation, 0 as fast as possible), for ``stop_at``; ``attendance``:
        when anyone next comes (a simulated operator, core.visits, or the run's operator as the engine
        follows them), None: the run is planned as if someone were always there; ``wall_clock``: the local
        wall clock ``stop_at`` is read on (UNIX seconds)."""
        if refit_every < 1:
            raise InputError("refit_every", f"{refit_every!r} is not allowed: expected a whole number ≥ 1")
        sample = sample or config.sample
        if sample is None:
            raise InputError(
                "sample", "a campaign needs a sample (a sample file, or a scenario's built-in one)"
            )
        if config.sample is not sample:
            config = dataclasses.replace(config, sample=sample)
        self.config = config
        self.sample: Sample = sample
        self.profile: InstrumentProfile = load_profile(config.profile or sample.profile)
        self.calibration = sample.calibration
        n = config.lattice_n or sample.lattice_n
        if n < 5:
            raise InputError("lattice_n", f"{n} is too small: expected at least 5 candidates per side")
        self.lattice = CandidateLattice.build(self.calibration, n, grid_halfwidth_um=2 * DEFAULT_PITCH_UM)
        # where a sub-grid may go at all on this sample (its one rule, Sample.allowed); the run's own indents
        # are avoided as it makes them
        self.placement_mask = sample.allowed(self.lattice.xy_um, 2 * DEFAULT_PITCH_UM)
        self.placement_mask.flags.writeable = False
        # the policy as ``aeni`` reads the run: its block design plans stretches once the run knows when its
        # operator comes (registry.run_recipe); both made now, the attendance picks (planners keep no state)
        self._policies = (
            make_policy(config.policy, RunFacts.of(self.profile, has_calendar=False)),
            make_policy(config.policy, RunFacts.of(self.profile, has_calendar=True)),
        )
        self.attendance = attendance or Attendance()
        parts = self._policies[0].parts
        self.noise = parts.noise
        self._needs_covariance = parts.needs_covariance
        self.settings = config.settings
        check_holds(self.settings, self.profile.allowed_holds_s)
        check_avoided_centres(sample, self.settings.avoid_centers_um)
        if self.settings.fixed_hold_s is None:
            self.settings = dataclasses.replace(self.settings, fixed_hold_s=self.profile.default_hold_s)
        if self.settings.budget_s is None and self.settings.indent_budget is None:
            # default horizon: the full grid baseline's time on this area, priced from its own start, plus 2 % for
            # the path from wherever the stage starts (so the grid itself runs all its indents under it)
            self.settings = dataclasses.replace(
                self.settings, budget_s=math.ceil(DEFAULT_HORIZON_SLACK * self.grid_baseline_s)
            )
        self.surrogate: HeteroskedasticGP = parts.surrogate.build(
            parts.guard, min(self.lattice.pitch_uv), config.seed
        )
        # the fast channel and the two-fidelity model, where the policy prices fast arrays (core.fidelity)
        self.fast: FastChannel | None = None
        if parts.fast is not None:
            if self.profile.fast is None:
                raise InputError(
                    "--fast", f"profile {self.profile.name} has no fast mode (no [fast] section)"
                )
            self.fast = FastChannel(self.surrogate)
        self.modulus_map = ModulusMap(
            parts.surrogate.build(parts.guard, min(self.lattice.pitch_uv), config.seed),
            parts.noise,
            self.lattice.uv,
        )
        self.centres: list[CentreRecord] = []
        self.noise_inflation: list[float] = []  # per centre, from the noise model's outlier rule (1: trusted)
        self.blocks: list[Block] = []
        self.indents_xy: list[tuple[float, float]] = []  # measured indents (what the budgets count)
        self.taken_xy: list[tuple[float, float]] = []  # every place an indent of this run took
        self.drift_rates: list[float] = []
        # measured depths at maximum load, one per learned indent (NaN where the instrument reported none)
        self.depths_nm: list[float] = []
        self.vetoes: list[_Veto] = []
        self._prefer: tuple[float, float] | None = None  # after a veto: where the next proposal goes
        self.prediction: Prediction | None = None
        self._last_fit: FitReport | None = None
        self.last_score: MapScore | None = None
        self.last_stop_reason: str | None = None
        self.budget_note = ""  # how the last block was sized to fit a budget, for the stop reason
        # stop_at runs on the local wall clock
        self.wall_clock = wall_clock
        self.wall_s_per_instrument_s = wall_s_per_instrument_s
        self.stop_at_epoch_s = self._resolve_stop_at(self.settings.stop_at)
        self.refit_every = refit_every
        self._stretch: list[Decision] = []  # a stretch's arrays still to run (loaded in one visit)
        self._stretch_clock_s = 0.0  # the instrument clock when the stretch being fitted starts

    @property
    def policy(self) -> Policy:
        """The policy the next proposal uses (with stretches once the run knows when its operator comes)."""
        return self._policies[self.attendance.known]

    # -- static facts ----------------------------------------------------------------------------
    @functools.cached_property
    def grid_baseline_s(self) -> float:
        return grid_baseline_s(self.sample, self.profile, DEFAULT_PITCH_UM)

    @property
    def stage_bounds_um(self) -> tuple[float, float, float, float]:
        return self.calibration.bounds_um

    def start_position_um(self) -> tuple[float, float]:
        """Where the stage starts: the calibrated area's centre under the lens."""
        x0, x1, y0, y1 = self.calibration.bounds_um
        return ((x0 + x1) / 2.0, (y0 + y1) / 2.0)

    # -- planning --------------------------------------------------------------------------------
    def _gp_summary(self) -> GPSummary | None:
        hyper = self.surrogate.hyperparameters
        scale = self.surrogate.outputscale_gpa2
        if hyper is None or scale is None:
            return None
        return GPSummary(hyper.kernel, hyper.lengthscales_uv, float(scale), self.surrogate.site_var_gpa2)

    def _tested_noise_var(self) -> np.ndarray | None:
        """Noise variance of each centre's value as the model sees it: eff(n)·σ²(x)/n (+ the site scatter)."""
        if self.prediction is None or not self.centres:
            return None

        xy = np.array([(c.x_um, c.y_um) for c in self.centres])
        sd = self.predict_stage(xy[:, 0], xy[:, 1]).noise_sd
        n = np.array([c.n_indents for c in self.centres])
        noise_var = median_noise_var(sd, n, self.noise.centre_estimator) * np.array(self.noise_inflation)
        return noise_var + self.surrogate.site_var_gpa2

    def _modulus_view(self) -> ModulusView | None:
        """What the planner weighs of the modulus map: only when map_weights gives it a weight."""
        w = self.settings.map_weights
        m = self.modulus_map
        if not (w.maps_modulus and self._needs_covariance) or m.prediction is None:
            return None
        hyper, scale = m.surrogate.hyperparameters, m.surrogate.outputscale_gpa2
        if hyper is None or scale is None:
            return None

        xy = m.xy_um()
        u, v = self.calibration.to_uv(xy[:, 0], xy[:, 1])
        sd = m.surrogate.predict(np.column_stack([u, v])).noise_sd
        n = np.array([c.n_indents for c in m.centres])
        noise_var = median_noise_var(sd, n, self.noise.centre_estimator) * np.array(m.noise_inflation)
        return ModulusView(
            prediction=m.prediction,
            gp=GPSummary(hyper.kernel, hyper.lengthscales_uv, float(scale), m.surrogate.site_var_gpa2),
            tested_xy_um=xy,
            tested_noise_var_gpa2=noise_var + m.surrogate.site_var_gpa2,
            weight_hardness=w.hardness,
            weight_modulus=w.modulus,
        )

    def _program_state(self) -> tuple[tuple[float, float] | None, float | None, int]:
        centre: tuple[float, float] | None = None
        hold: float | None = None
        locals_run = 0
        for b in self.blocks:
            if b.kind == "global" and b.channel == "fast":
                centre, hold, locals_run = None, None, 0  # a fast array's program serves no CSM indent
            elif b.kind == "global":
                centre, hold, locals_run = (b.center_x_um, b.center_y_um), b.hold_s, 0
            else:
                locals_run += 1
        return centre, hold, locals_run

    # -- stopping rules a real sample can use -----------------------------------------------------
    def _resolve_stop_at(self, stop_at: str | None) -> float | None:
        """The next local wall-clock time ``HH:MM`` from now, as a UNIX time (kept in the run's state)."""
        if stop_at is None:
            return None
        h, m = (int(v) for v in stop_at.split(":"))
        now = datetime.datetime.fromtimestamp(self.wall_clock()).astimezone()
        at = now.replace(hour=h, minute=m, second=0, microsecond=0)
        if at <= now:
            at += datetime.timedelta(days=1)
        return at.timestamp()

    def _stop_at_left_s(self) -> float | None:
        """Instrument seconds left before stop_at (inf when the instrument's time costs no wall time)."""
        if self.stop_at_epoch_s is None:
            return None
        wall_left = self.stop_at_epoch_s - self.wall_clock()
        if self.wall_s_per_instrument_s <= 0:
            return math.inf if wall_left > 0 else 0.0
        return wall_left / self.wall_s_per_instrument_s

    def rel_sd_p95_pct(self) -> float | None:
        """The 95th percentile of the map's relative epistemic sd (sd / |mean|, %) over the sample's
        measurable area (the lattice centres off its edge band and exclusions); None before any map."""
        pred = self.prediction
        if pred is None:
            return None
        keep = self.placement_mask if self.placement_mask.any() else np.ones(len(pred.mean), dtype=bool)
        rel = 100.0 * pred.epistemic_sd[keep] / np.maximum(np.abs(pred.mean[keep]), 1e-12)
        return float(np.percentile(rel, 95))

    def stop_reason(self, clock_s: float) -> str | None:
        s = self.settings
        note = f"; {self.budget_note}" if self.budget_note else ""
        left = self._stop_at_left_s()
        if left is not None and left <= self.profile.comeback_s:
            return f"stop_at {s.stop_at} (local time) reached{note}"
        if s.stop_rel_sd_pct is not None:
            p95 = self.rel_sd_p95_pct()
            if p95 is not None and p95 < s.stop_rel_sd_pct:
                return (
                    f"the map's relative epistemic sd is {p95:.2f} % at the 95th percentile, below "
                    f"stop_rel_sd_pct {s.stop_rel_sd_pct:g} %"
                )
        if s.budget_s is not None and clock_s >= s.budget_s:
            return f"instrument-time budget reached ({clock_s:,.0f} s of {s.budget_s:,.0f} s){note}"
        if s.indent_budget is not None and len(self.indents_xy) >= s.indent_budget:
            return f"indent budget reached ({len(self.indents_xy)} of {s.indent_budget} indents){note}"
        if s.sigma_target_gpa is not None and self.prediction is not None:
            mean_sd = float(np.mean(self.prediction.epistemic_sd))
            if mean_sd < s.sigma_target_gpa:
                return f"mean epistemic σ {mean_sd:.4f} GPa below target {s.sigma_target_gpa:g}"
        if s.mape_target_pct is not None and self.last_score is not None:
            mape = self.last_score.mape_pct
            if mape is not None and mape <= s.mape_target_pct:
                return f"MAPE {mape:.2f} % reached target {s.mape_target_pct:g} %"
        return None

    def context(
        self, clock_s: float, position_um: tuple[float, float], program_open: bool, block_id: int
    ) -> PlanContext:
        centre, hold, locals_run = self._program_state()
        blocks_done = len(self.blocks)
        avoid = tuple((v.x_um, v.y_um) for v in self.vetoes if v.until_blocks_done > blocks_done)
        best = max((c.median_gpa for c in self.centres), default=None)
        return PlanContext(
            profile=self.profile,
            calibration=self.calibration,
            lattice=self.lattice,
            prediction=self.prediction,
            settings=self.settings,
            seed=self.config.seed,
            block_id=block_id,
            blocks_done=blocks_done,
            clock_s=clock_s,
            position_um=position_um,
            program_open=program_open,
            program_center_um=centre,
            program_hold_s=hold,
            locals_in_program=locals_run,
            tested_xy_um=np.array([(c.x_um, c.y_um) for c in self.centres]).reshape(-1, 2),
            indents_xy_um=np.concatenate(
                [self.sample.earlier_xy_um, np.array(self.taken_xy, dtype=float).reshape(-1, 2)]
            ),
            best_observed_gpa=best,
            last_drift_rate_nm_s=self.drift_rates[-1] if self.drift_rates else None,
            avoid_xy_um=avoid + tuple(self.settings.avoid_centers_um),
            globals_done=sum(1 for b in self.blocks if b.kind == "global" and b.channel == "csm"),
            learnt_xy_um=np.array(self.indents_xy, dtype=float).reshape(-1, 2),
            recent_drift_rates_nm_s=tuple(self.drift_rates[-25:]),
            recent_depths_nm=tuple(self.depths_nm[-25:]),
            tested_noise_var_gpa2=self._tested_noise_var() if self._needs_covariance else None,
            gp=self._gp_summary() if self._needs_covariance else None,
            dz_safe_um=self.sample.dz_safe_um,
            r_excl_um=self.sample.r_excl_um,
            placement_mask=self.placement_mask,
            sample=self.sample,
            modulus=self._modulus_view(),
            unattended=self.attendance.window(clock_s),
            fidelity=self.fast.view() if self.fast is not None else None,
        )

    def propose(
        self, clock_s: float, position_um: tuple[float, float], program_open: bool, block_id: int
    ) -> Decision | None:
        decision = self._propose(clock_s, position_um, program_open, block_id)
        if self.fast is not None and decision is not None:
            # the decision is made: a new array's re-optimisation may take the machine while the block runs
            # (none: the run ends on the map conditioned on every indent, with no thread left to wait for)
            self.fast.model.start_reoptimisation()
        return decision

    def _propose(
        self, clock_s: float, position_um: tuple[float, float], program_open: bool, block_id: int
    ) -> Decision | None:
        if self._stretch:
            # a loaded stretch's next array runs as handed out (fitted when planned), stop rule or not: the
            # instrument runs every array the operator loaded, and its indents must be journaled, never lost
            self.last_stop_reason = None
            return renumbered(self._stretch.pop(0), block_id)
        self.last_stop_reason = self.stop_reason(clock_s)
        if self.last_stop_reason is not None:
            return None
        ctx = self.context(clock_s, position_um, program_open, block_id)
        if self._prefer is not None:  # one proposal after a veto: the alternative listed first
            ctx = dataclasses.replace(ctx, prefer_xy_um=self._prefer)
            self._prefer = None
        arrays = None
        if ctx.prefer_xy_um is None and isinstance(self.policy, PlansStretches):
            arrays = self.policy.propose_stretch(ctx)
        if arrays:
            # the arrays run one after another: their block ids are known now, so their tickets can all go
            # out with the first (the operator loads the stretch in one visit)
            fitted = self._fit_stretch(
                [renumbered(a, block_id + k) for k, a in enumerate(arrays)],
                clock_s,
                position_um,
                program_open,
            )
            self._stretch = fitted[1:]
            return fitted[0] if fitted else None
        decision = self.policy.propose(ctx)
        if decision is None:
            self.last_stop_reason = f"policy {self.policy.name} has nothing left to propose"
            if not base_mask(ctx, 0.0).any():
                n = self.lattice.n
                self.last_stop_reason += (
                    f": every candidate of the {n}×{n} lattice is indented, excluded or too near an indent"
                )
            return None
        return self._fit_budgets(decision, clock_s, position_um, program_open)

    def _fit_stretch(
        self, arrays: list[Decision], clock_s: float, position_um: tuple[float, float], program_open: bool
    ) -> list[Decision]:
        """A stretch fitted to the budgets as a whole when it is planned: all its tickets go out with the first
        and nobody is there to take an array back, so no array handed out may be cut or dropped later."""
        fitted: list[Decision] = []
        self._stretch_clock_s = clock_s
        clock, pos, is_open, taken = clock_s, position_um, program_open, len(self.indents_xy)
        for a in arrays:
            d = self._fit_budgets(a, clock, pos, is_open, indents_taken=taken)
            if d is None:
                break
            fitted.append(d)
            clock += d.predicted_cost_s
            taken += d.block.n_indents
            pos, is_open = (d.block.indents[-1].x_um, d.block.indents[-1].y_um), True
            if d.block.n_indents < a.block.n_indents:
                break  # cut to fit: nothing after it fits
        if fitted:
            self.last_stop_reason = None  # a later array that did not fit says nothing about this one
        return fitted

    def _fit_budgets(
        self,
        decision: Decision,
        clock_s: float,
        position_um: tuple[float, float],
        program_open: bool,
        indents_taken: int | None = None,
    ) -> Decision | None:
        """Budgets are never exceeded: the next block keeps only the indents that both budgets can pay for.

        The time budget pays for the block's steps and the closing comeback to the lens; when not even its
        first indent fits, the run stops here and the stop reason says so.
        """
        s = self.settings
        block = decision.block
        keep = block.n_indents
        taken = len(self.indents_xy) if indents_taken is None else indents_taken  # a stretch counts its own
        if s.indent_budget is not None:
            keep = min(keep, s.indent_budget - taken)
        # the time the block may take: the budget's, or the wall clock's before stop_at if that is less
        left_s = math.inf if s.budget_s is None else s.budget_s - clock_s - self.profile.comeback_s
        before_stop_at = self._stop_at_left_s()
        if before_stop_at is not None and indents_taken is not None:  # a stretch's later array starts later
            before_stop_at -= clock_s - self._stretch_clock_s
        by_stop_at = before_stop_at is not None and before_stop_at - self.profile.comeback_s < left_s
        if by_stop_at:
            assert before_stop_at is not None
            left_s = before_stop_at - self.profile.comeback_s
        if math.isfinite(left_s):
            spent, pos, fits = 0.0, position_um, 0
            for i in range(keep):
                spent += sum(st.seconds for st in indent_steps(self.profile, block, i, pos, program_open))
                if spent > left_s + 1e-9:
                    break
                fits, pos = i + 1, (block.indents[i].x_um, block.indents[i].y_um)
            if fits == 0 and by_stop_at:
                self.last_stop_reason = (
                    f"stop_at {s.stop_at} (local time): the next block does not end before it "
                    f"({decision.predicted_cost_s:,.0f} s of instrument time, {max(left_s, 0.0):,.0f} s left)"
                )
                return None
            if fits == 0:
                assert s.budget_s is not None
                self.last_stop_reason = (
                    f"instrument-time budget: {max(left_s, 0.0):,.0f} s left of {s.budget_s:,.0f} s after the "
                    f"comeback, not enough for one more indent (the next block needs "
                    f"{decision.predicted_cost_s:,.0f} s){'; ' + self.budget_note if self.budget_note else ''}"
                )
                return None
            keep = fits
        if keep >= block.n_indents:
            return decision
        which = (
            "indent budget"
            if s.indent_budget is not None and keep == s.indent_budget - taken
            else f"stop_at {s.stop_at}"
            if by_stop_at
            else "time budget"
        )
        self.budget_note = (
            f"the last block was cut to {keep} of its {block.n_indents} indents to stay within the {which}"
        )
        cut = dataclasses.replace(block, indents=block.indents[:keep])
        pos, cost = position_um, 0.0
        for i in range(keep):
            cost += sum(st.seconds for st in indent_steps(self.profile, cut, i, pos, program_open))
            pos = (cut.indents[i].x_um, cut.indents[i].y_um)
        return dataclasses.replace(
            decision,
            block=cut,
            predicted_cost_s=cost,
            reason=f"{decision.reason}; {self.budget_note}" if decision.reason else self.budget_note,
        )

    def veto(self, decision: Decision, hold_blocks: int = VETO_HOLD_BLOCKS) -> None:
        """Avoid the vetoed centre for a while, and make the next proposal the best alternative the vetoed
        one listed (the panel's "next best") that no veto now avoids."""
        b = decision.block
        self._stretch = []  # a refused array ends its stretch: the planner plans again
        self.vetoes.append(_Veto(b.center_x_um, b.center_y_um, len(self.blocks) + hold_blocks))
        avoided = [(v.x_um, v.y_um) for v in self.vetoes if v.until_blocks_done > len(self.blocks)]
        avoided += list(self.settings.avoid_centers_um)
        xy = self.lattice.xy_um
        near = 2.0 * float(np.hypot(xy[1, 0] - xy[0, 0], xy[1, 1] - xy[0, 1]))  # as base_mask avoids
        self._prefer = next(
            (
                (a.center_x_um, a.center_y_um)
                for a in decision.alternatives
                if all(math.hypot(a.center_x_um - x, a.center_y_um - y) > near for x, y in avoided)
            ),
            None,
        )

    def adjust(self, **changes: Any) -> PlannerSettings:
        check_hold_in_force(self.policy.name, changes, "adjust")
        before = self.settings.stop_at
        self.settings = adjust_settings(self.settings, changes, self.profile.allowed_holds_s)
        if self.settings.stop_at != before:
            self.stop_at_epoch_s = self._resolve_stop_at(self.settings.stop_at)
        return self.settings

    # -- learning --------------------------------------------------------------------------------
    def _record(self, block: Block, results: Sequence[IndentResult]) -> None:
        if not results:
            return
        # every indent the instrument made takes its place for the planner, as for the interlock (core.taken)
        self.taken_xy.extend(map(tuple, taken_xy_um(results).tolist()))
        if block.channel == "fast":
            # fast indents teach only the two-fidelity model (core.fidelity), never as CSM centres
            if self.fast is None:
                raise InputError(
                    "journal", f"block {block.block_id} is a fast array but this run has no fast mode"
                )
            self.fast.record(results)
            self.blocks.append(block)
            return
        # a failed or not-run indent carries no value: the model never sees it; a block with no measured
        # indent still ran (the program moved there) but adds no centre, and the fit goes on without it
        results = [r for r in results if r.measured]
        if not results:
            self.blocks.append(block)
            return
        h_raw = np.array([r.hardness_gpa for r in results])
        h = h_raw
        if self.noise.drift_correction:
            h = drift_corrected_hardness_gpa(
                h,
                smoothed_drift_rates_nm_s(np.array([r.drift_rate_nm_s for r in results])),
                np.array([r.hold_s for r in results]),
                full_hold_s=max(self.profile.allowed_holds_s),
                depth_nm=np.array([r.depth_nm for r in results]),
                t_measure_s=self.profile.drift_segment_s,
                floor_nm_s=self.profile.drift_noise_floor_nm_s,
            )
        xs = np.array([r.actual_x_um for r in results])
        ys = np.array([r.actual_y_um for r in results])
        e = modulus_values_of(results)
        if self.noise.drift_correction:
            e = drift_corrected_modulus_gpa(e, h_raw, h)
        # a replicate grid is one centre; a block of scattered singles (grid_g 1) is one centre per indent
        groups = [np.arange(len(h))] if block.grid_g > 1 else [np.array([i]) for i in range(len(h))]
        for idx in groups:
            value, efficiency = self.noise.centre(h[idx])
            self.centres.append(
                CentreRecord(
                    block_id=block.block_id,
                    x_um=float(xs[idx].mean()),
                    y_um=float(ys[idx].mean()),
                    median_gpa=float(np.median(h_raw[idx])),
                    spread_var_gpa2=float(np.var(h[idx], ddof=1)) if len(idx) >= 2 else math.nan,
                    n_indents=len(idx),
                    value_gpa=value,
                    efficiency=efficiency,
                )
            )
            self.noise_inflation.append(1.0)
            last = self.centres[-1]
            self.modulus_map.add(block.block_id, last.x_um, last.y_um, e[idx])
        self.blocks.append(block)
        self.indents_xy.extend(zip(xs.tolist(), ys.tolist(), strict=True))
        self.drift_rates.extend(r.drift_rate_nm_s for r in results)
        self.depths_nm.extend(r.depth_nm for r in results)

    def observations(self) -> Observations:
        return Observations.of_centres(self.centres, self.noise_inflation, self.calibration.to_uv)

    def observe_block(
        self, block: Block, results: Sequence[IndentResult], refit: bool = True
    ) -> FitReport | None:
        """Collapse the block to its centre, refit (warm start), and predict on the lattice.

        ``refit=False`` only records the block; ``refit_every`` > 1 refits only after every so many blocks
        (a policy that never looks at the model, e.g. the grid baseline in the bench, is refitted only
        where its map is measured).
        """
        self._record(block, results)
        if len(self.centres) < 2 or not refit or len(self.blocks) % self.refit_every:
            return None
        report = self.surrogate.fit(self.observations())
        reweighed = self._reweigh_outliers()
        if reweighed == "refit":
            report = self.surrogate.fit(self.observations())
        elif reweighed == "condition":
            # the same hyperparameters on the new weights: what is journaled is what the model uses
            hyper = self.surrogate.hyper
            assert hyper is not None
            self.surrogate.set_hyper(hyper, self.observations())
        self._last_fit = report
        if self.fast is not None and report is not None:
            self.fast.fit(self.observations(), report, self.calibration.to_uv)
        self.prediction = self._map_model().predict(self.lattice.uv)
        if self.settings.map_weights.maps_modulus:
            self.modulus_map.fit(self.calibration.to_uv)
        return report

    def _reweigh_outliers(self) -> str | None:
        """The noise model's outlier rule from the fitted map's residuals: "refit" when a value newly counts
        as an outlier (the map is fitted again without its pull), "condition" when the weights changed
        otherwise, None when nothing changed."""
        if self.noise.outliers == "none":
            return None
        obs = self.observations()
        resid = obs.median_gpa - self.surrogate.predict_mean(obs.uv)
        new = self.noise.noise_inflation(resid, obs.uv)
        old = np.array(self.noise_inflation)
        if np.array_equal(new, old):
            return None
        self.noise_inflation = new.tolist()
        if np.any((new > OUTLIER_REFIT_INFLATION) & (old <= OUTLIER_REFIT_INFLATION)):
            return "refit"
        return "condition"

    def fit_report(self) -> FitReport | None:
        return self._last_fit

    # -- views -----------------------------------------------------------------------------------
    def _map_model(self) -> HeteroskedasticGP | FastChannel:
        """The CSM map's model: the two-fidelity one once it has a fast channel, else the CSM-only GP."""
        return self.fast if self.fast is not None and self.fast.active else self.surrogate

    def predict_stage(self, x_um: np.ndarray, y_um: np.ndarray) -> Prediction:
        u, v = self.calibration.to_uv(x_um, y_um)
        return self._map_model().predict(np.column_stack([u, v]))

    def has_map(self) -> bool:
        return self.prediction is not None

    def predict_mean_stage(self, x_um: np.ndarray, y_um: np.ndarray) -> np.ndarray:
        """The map's mean at stage points (what an evaluator scores; cheaper than a full prediction)."""
        u, v = self.calibration.to_uv(x_um, y_um)
        return self._map_model().predict_mean(np.column_stack([u, v]))

    def has_modulus_map(self) -> bool:
        """A modulus map exists or can be fitted now (fitted on demand when the planner does not need it)."""
        return self.modulus_map.ensure_fitted(self.calibration.to_uv)

    def predict_modulus_stage(self, x_um: np.ndarray, y_um: np.ndarray) -> Prediction:
        """The modulus map at stage points (GPa); call ``has_modulus_map`` first."""
        u, v = self.calibration.to_uv(x_um, y_um)
        return self.modulus_map.surrogate.predict(np.column_stack([u, v]))

    def predict_modulus_mean_stage(self, x_um: np.ndarray, y_um: np.ndarray) -> np.ndarray:
        """The modulus map's mean at stage points (what an evaluator scores)."""
        u, v = self.calibration.to_uv(x_um, y_um)
        return self.modulus_map.surrogate.predict_mean(np.column_stack([u, v]))

    def indented_xy_um(self) -> np.ndarray:
        """Every indent of this run so far, actual positions (n, 2)."""
        return np.array(self.indents_xy, dtype=float).reshape(-1, 2)

    def note_score(self, score: MapScore | None) -> None:
        """Remember an outside evaluator's verdict (a simulated run's MAPE) for the MAPE-target stop rule."""
        self.last_score = score

    def map_fields(
        self, snapshot_id: int, display_n: int = 50, next_candidate_um: tuple[float, float] | None = None
    ) -> MapFields:
        x0, x1, y0, y1 = self.calibration.bounds_um
        xs = np.linspace(x0, x1, display_n)
        ys = np.linspace(y0, y1, display_n)
        gx, gy = np.meshgrid(xs, ys)
        shape = gx.shape
        if self.prediction is None:
            nan = np.full(shape, np.nan)
            return MapFields(snapshot_id, xs, ys, nan, nan, nan, nan, next_candidate_um)
        pred = self.predict_stage(gx.ravel(), gy.ravel())
        inside = self.calibration.contains_stage(gx.ravel(), gy.ravel())

        def grid(a: np.ndarray) -> np.ndarray:
            return np.where(inside, a, np.nan).reshape(shape).astype(np.float32)

        # the modulus map and the fast channel's bias, where the run has them
        extra: dict[str, np.ndarray] = {}
        if self.modulus_map.prediction is not None and not self.modulus_map.stale:
            # shown where the run keeps it fitted (map_weights), never fitted for the display alone
            pm = self.predict_modulus_stage(gx.ravel(), gy.ravel())
            extra = {"modulus_mean_gpa": grid(pm.mean), "modulus_sd_gpa": grid(pm.epistemic_sd)}
        if self.fast is not None and self.fast.active:  # the two-fidelity map's learnt bias, for the console
            u, v = self.calibration.to_uv(gx.ravel(), gy.ravel())
            extra["bias_gpa"] = grid(self.fast.bias_gpa(np.column_stack([u, v])))
        means = (grid(pred.mean), grid(pred.epistemic_sd), grid(pred.noise_sd), grid(pred.total_sd))
        return MapFields(snapshot_id, xs, ys, *means, next_candidate_um, **extra)

    def queued_stretch(self) -> tuple[Block, ...]:
        """The arrays of the loaded stretch still to run after the current one, in load order."""
        return tuple(d.block for d in self._stretch)

    def drop_stretch(self) -> None:
        """Forget a stretch that was planned but not loaded (a tray chose another sample's offer)."""
        self._stretch = []

    # -- persistence -----------------------------------------------------------------------------
    def export_state(self) -> dict[str, Any]:
        return {
            "gp": self.surrogate.hyper,
            **({"two_fidelity": self.fast.model.hyper} if self.fast is not None and self.fast.fitted else {}),
            "vetoes": [[v.x_um, v.y_um, v.until_blocks_done] for v in self.vetoes],
            "settings": settings_to_dict(self.settings),
            "blocks_done": len(self.blocks),
            "noise_inflation": list(self.noise_inflation),
            **({} if self.stop_at_epoch_s is None else {"stop_at_epoch_s": self.stop_at_epoch_s}),
            # a loaded stretch's arrays still to run: a resumed run runs them as planned, re-planning nothing
            **({"stretch": [dataclasses.asdict(d) for d in self._stretch]} if self._stretch else {}),
            # the modulus GP's record only where the planner uses it (a resumed run then decides the same)
            **(
                {"modulus": self.modulus_map.export_state()} if self.settings.map_weights.maps_modulus else {}
            ),
        }

    def restore(self, state: dict[str, Any], blocks: Sequence[tuple[Block, Sequence[IndentResult]]]) -> None:
        """Rebuild after a crash from the journal, without refitting: the next decision is what it would have been."""
        for block, results in blocks:
            self._record(block, results)
        self.settings = settings_from_dict(state["settings"])
        stop_at = state.get("stop_at_epoch_s")  # the time stop_at meant when the run started
        self.stop_at_epoch_s = (
            float(stop_at) if stop_at is not None else self._resolve_stop_at(self.settings.stop_at)
        )
        self.vetoes = [_Veto(float(x), float(y), int(u)) for x, y, u in state.get("vetoes", [])]
        self._stretch = [decision_from_dict(d) for d in state.get("stretch", [])]
        inflation = state.get("noise_inflation")
        if isinstance(inflation, list) and len(inflation) == len(self.centres):
            self.noise_inflation = [float(v) for v in inflation]
        hyper = state.get("gp")
        if hyper is not None and len(self.centres) >= 2:
            self.surrogate.set_hyper(hyper, self.observations())
            record = state.get("two_fidelity")
            if self.fast is not None and record is not None:
                self.fast.restore(record, self.observations(), self.calibration.to_uv)
            self.prediction = self._map_model().predict(self.lattice.uv)
        self.modulus_map.restore(state.get("modulus"), self.calibration.to_uv)

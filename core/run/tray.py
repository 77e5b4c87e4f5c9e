"""One run over a tray: each library keeps its own Campaign (model, stopping rule), one plan chooses between
them, and the reference checks the tip.

:class:`TrayCampaign` is what the engine drives (it meets ``core.run.campaign.CampaignLike``): it asks every
library that has not reached its goal for its best block and takes the one with the most information per
second (core.policies.tray), the sample change priced in. Every library's instrument time is its own: a
``budget_s`` goal counts the seconds spent on that library, the move to it included.

With an operator calendar (a simulated operator, or a real one's hours) the tray is loaded as a real tray is:
at a visit the operator loads one list of arrays that runs until someone comes again. The libraries are
ranked at the visit; the list runs the first library's stretch, then (its goal reached, or its stretch done
early) the next one's in the rest of the window, with the tip checks where they fall. Arrays after the
visit's first are ``stretch-continues`` (core.visits counts no visit for them).

The reference is indented before the first library, whenever ``check_every_h`` hours of instrument time have
passed since the last check, and after the last library reached its goal (core.tipcheck). A failed check
raises an alarm the engine turns into a pause with an alert (``take_alarm``), and the next block is a check
again: no library is indented on a tip that failed its last check.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np

from core.campaign import Campaign
from core.campaign_config import CampaignConfig
from core.cost import block_steps
from core.metrics import MapScore
from core.modulus import ModulusMap
from core.operator import Attendance, LoadWindow
from core.plan import STRETCH_CONTINUES, Block, Decision, IndentResult, PlannerSettings
from core.policies.tray import Offer, rank, relative_value
from core.profile import InstrumentProfile, load_profile
from core.runview import MapFields
from core.sample.tray import Goal, Tray, TraySample
from core.sample_change import change_s
from core.taken import is_taken, taken_xy_um
from core.tipcheck import TipCheck, check_block, check_grid_g, judge

if TYPE_CHECKING:
    from pathlib import Path

    from core.driver import Driver
    from core.metrics import MapEvaluator
    from core.run.spec import RunSpec
    from core.sample import Sample

TIP_CHECK_PHASE = "tip-check"


@runtime_checkable
class TrayDrivers(Protocol):
    """Where a tray run's instrument comes from (``drivers.registry.DRIVERS``, passed in)."""

    def tray_sample(self, spec: RunSpec, entry: TraySample) -> Sample:
        """A tray sample without a file: the driver's built-in one for it (placed by the tray)."""
        ...

    def tray_driver(self, spec: RunSpec, tray: Tray, journal: Path | None) -> Driver:
        """One instrument over the whole tray (a KLA driver keeps its exports beside ``journal``)."""
        ...

    def tray_evaluator(self, spec: RunSpec, entry: TraySample) -> MapEvaluator | None:
        """A library's map scorer where the driver knows its truth, else None."""
        ...


def _finite(v: float) -> float | None:
    return v if math.isfinite(v) else None


def tray_profiles(tray: Tray, config: CampaignConfig) -> dict[str, InstrumentProfile]:
    """The profile each sample is planned with, by name: a library's campaign's (the run's ``profile``, else
    its sample's, as ``Campaign`` loads it), the reference's own sample's. An instrument over the tray prices
    its steps with the same, so what it charges is what the planner priced."""
    return {
        s.name: load_profile(
            s.placed.profile if s.role == "reference" else config.profile or s.placed.profile
        )
        for s in tray.samples
    }


def goal_settings(settings: PlannerSettings, goal: Goal | None) -> PlannerSettings:
    """A library's stopping rule from its goal (its own instrument time for ``budget_s``)."""
    if goal is None:
        return settings
    if goal.kind == "rel_sd_pct":
        return dataclasses.replace(settings, stop_rel_sd_pct=goal.value)
    if goal.kind == "budget_s":
        return dataclasses.replace(settings, budget_s=goal.value)
    return dataclasses.replace(settings, indent_budget=int(goal.value))


def library_config(config: CampaignConfig, entry: TraySample) -> CampaignConfig:
    """A library's campaign: the run's policy, seed, lattice and settings, with its sample and goal."""
    return dataclasses.replace(
        config,
        name=f"{config.name}/{entry.name}",
        sample=entry.placed,
        settings=goal_settings(config.settings, entry.goal),
        driver_options=dict(entry.sim),
    )


@dataclass
class Lane:
    """One library on the tray: its campaign and what the tray knows of it."""

    entry: TraySample
    campaign: Campaign
    own_s: float = 0.0  # instrument seconds spent on it (its moves and changes included)
    done: str = ""  # why it is left alone (its goal), "" while it is not
    done_at_s: float | None = None  # the tray's instrument clock when it reached its goal


@dataclass
class _Load:
    """The list of arrays the operator loaded at one visit."""

    start_s: float
    window: LoadWindow
    ranking: list[str] = field(default_factory=list)
    ranked: bool = False  # the libraries were ranked for this load (at its visit, or after its first check)


def _load_to_dict(load: _Load) -> dict[str, Any]:
    w = load.window
    return {
        "start_s": load.start_s,
        "window": [w.fill_s, _finite(w.last_answer_s), _finite(w.next_answer_s)],  # inf: none (JSON null)
        "ranking": list(load.ranking),
        "ranked": load.ranked,
    }


def _load_from_dict(d: dict[str, Any]) -> _Load:
    fill, last, after = (math.inf if v is None else float(v) for v in d["window"])
    return _Load(
        float(d["start_s"]), LoadWindow(fill, last, after), [str(n) for n in d["ranking"]], bool(d["ranked"])
    )


class _LaneAttendance(Attendance):
    """A library's share of the tray's attendance: known when the tray's is; its window is the library's
    share of the tray's load; what the operator says goes to the tray's."""

    def __init__(self, tray: Attendance, share: Callable[[float], LoadWindow | None]) -> None:
        super().__init__(None)
        self._tray = tray
        self._share = share

    @property
    def known(self) -> bool:
        return self._tray.known

    def window(self, clock_s: float) -> LoadWindow | None:
        return self._share(clock_s) if self._tray.known else None

    def follow(self, window: Callable[[float], LoadWindow | None] | None) -> None:
        self._tray.follow(window)


class TrayCampaign:
    def __init__(
        self,
        tray: Tray,
        config: CampaignConfig,
        *,
        refit_every: int = 1,
        wall_s_per_instrument_s: float = 1.0,
        attendance: Attendance | None = None,
        plans_unattended: bool = False,
    ) -> None:
        self.tray = tray
        # the engine may start blocks it planned itself with nobody asked (supervision ``auto``): when a
        # load's list runs out before anyone comes again, the tray plans the rest of the absence from the
        # models the load's arrays built, instead of leaving the instrument idle until a visit
        self.plans_unattended = plans_unattended
        self.config = config
        # when anyone next comes: the engine follows the operator's word on it; each library plans its
        # stretches in its share of the tray's load
        self.attendance = attendance or Attendance()
        self.lanes: dict[str, Lane] = {}
        for entry in tray.libraries:
            campaign = Campaign(
                library_config(config, entry),
                refit_every=refit_every,
                wall_s_per_instrument_s=wall_s_per_instrument_s,
                attendance=_LaneAttendance(self.attendance, functools.partial(self._share_for, entry.name)),
            )
            self.lanes[entry.name] = Lane(entry, campaign)
        self.reference = tray.reference
        self.reference_profile: InstrumentProfile | None = (
            None if self.reference is None else tray_profiles(tray, config)[self.reference.name]
        )
        self.checks: list[TipCheck] = []
        self._ref_taken: list[np.ndarray] = []
        self._ref_avoid: list[tuple[float, float]] = []
        self._ref_s = 0.0  # instrument seconds spent on the reference
        self._load: _Load | None = None
        self._now_s = 0.0  # the tray's instrument clock at the last proposal
        self._on: str | None = None  # the sample of the last block that started (where the tip is)
        self._stretching: str | None = None  # the library whose stretch the load is running
        self._owner: dict[int, str] = {}  # proposed block id -> sample name
        self._shown: Lane = next(iter(self.lanes.values()))  # the library the console's map shows
        self._alarm: str | None = None
        self._final_check_done = False
        self.last_stop_reason: str | None = None
        self.changes = 0  # blocks that started on another sample than the block before (sample changes)

    # -- what the engine reads --------------------------------------------------------------------------
    @property
    def settings(self) -> PlannerSettings:
        return self._shown.campaign.settings

    @settings.setter
    def settings(self, value: PlannerSettings) -> None:
        self._shown.campaign.settings = value

    @property
    def modulus_map(self) -> ModulusMap:
        return self._shown.campaign.modulus_map

    @modulus_map.setter
    def modulus_map(self, value: ModulusMap) -> None:
        self._shown.campaign.modulus_map = value

    @property
    def calibration(self) -> Any:
        return self._shown.campaign.calibration

    @property
    def current(self) -> str | None:
        """The sample the tip is on (the last block's)."""
        return self._on

    @property
    def reference_s(self) -> float:
        """Instrument seconds spent on the reference (the tip checks, their sample changes included)."""
        return self._ref_s

    def take_alarm(self) -> str | None:
        """A failed tip check's words, once (the engine pauses the run and alerts)."""
        alarm, self._alarm = self._alarm, None
        return alarm

    # -- planning -----------------------------------------------------------------------------------
    def _window_for(self, _own_clock_s: float) -> LoadWindow | None:
        """What is left of the visit's load."""
        if self._load is None:
            return None
        w, gone = self._load.window, self._now_s - self._load.start_s
        return LoadWindow(max(w.fill_s - gone, 0.0), w.last_answer_s - gone, w.next_answer_s - gone)

    def _fits(self, decision: Decision) -> bool:
        """Whether the next library's block still fits the load: it ends before someone comes again, and not
        after the day's last answerable moment (else the next request waits the night: better asked now);
        once that moment has passed, whatever keeps the instrument busy until the next answer fits."""
        left = self._window_for(self._now_s)
        if left is None:
            return False
        if left.last_answer_s <= 0:
            return True
        return decision.predicted_cost_s <= min(left.fill_s, left.last_answer_s)

    def _share_for(self, name: str, own_clock_s: float) -> LoadWindow | None:
        """A library's share of what is left of the load, as its stretch planner asks for it: the rest split
        evenly with the libraries ranked after it; the last one of the load keeps the calendar's rule on when
        the load may end (the libraries before it hand over to the next, so they may end any time)."""
        left = self._window_for(own_clock_s)
        if left is None:
            return None
        if self._load is not None and self._load.ranked:
            after = [n for n in self._load.ranking if n != name and not self.lanes[n].done]
        else:  # ranking now: every active library shares
            after = [n for n, lane in self.lanes.items() if n != name and not lane.done]
        if not after:
            return left
        return LoadWindow(left.fill_s / (1 + len(after)))

    def _unattended_left(self) -> bool:
        """Whether the engine may plan the next block itself: it may (``plans_unattended``) and the load's
        absence is not over (no visit is due before the next block would start)."""
        left = self._window_for(self._now_s)
        return self.plans_unattended and left is not None and left.fill_s > 0

    def _charge(self, clock_s: float) -> None:
        """The instrument time since the last proposal belongs to the sample the tip went to."""
        spent = max(clock_s - self._now_s, 0.0)
        self._now_s = clock_s
        if self._on is None:
            return
        if self._on in self.lanes:
            self.lanes[self._on].own_s += spent
        else:
            self._ref_s += spent

    def _check_due(self) -> bool:
        if self.reference is None or self.reference.reference is None:
            return False
        if self.checks and not self.checks[-1].passed:
            return True  # the tip failed: nothing else until a check passes
        active = any(not lane.done for lane in self.lanes.values())
        if not self.checks:
            return active
        if not active:
            return not self._final_check_done
        every_s = 3600.0 * self.reference.reference.check_every_h
        return self._now_s - self.checks[-1].t_s >= every_s

    def _check_decision(
        self, position_um: tuple[float, float], program_open: bool, block_id: int
    ) -> Decision:
        assert self.reference is not None and self.reference_profile is not None
        profile = self.reference_profile
        taken = np.concatenate(self._ref_taken) if self._ref_taken else np.empty((0, 2))
        block = check_block(
            self.reference.placed, taken, self._ref_avoid, position_um, block_id, profile.default_hold_s,
            check_grid_g(self.reference.reference.tolerance_pct),  # type: ignore[union-attr]
        )  # fmt: skip
        cost = self._block_cost(profile, block, position_um, program_open)
        if self._on != self.reference.name and self._on is not None:
            cost += change_s(profile)
        why = "before the first library" if not self.checks else (
            "after the last library" if all(lane.done for lane in self.lanes.values()) else
            "the last check failed: checking again" if not self.checks[-1].passed else
            f"{self.reference.reference.check_every_h:g} h since the last check"  # type: ignore[union-attr]
        )  # fmt: skip
        return Decision(
            block, "tip-check", math.nan, math.nan, cost, reason=f"tip check on {self.reference.name}: {why}",
            phase=TIP_CHECK_PHASE,
        )  # fmt: skip

    @staticmethod
    def _block_cost(
        profile: InstrumentProfile, block: Block, position_um: tuple[float, float], program_open: bool
    ) -> float:
        return float(sum(s.seconds for s in block_steps(profile, block, position_um, program_open)))

    def _offer(
        self, lane: Lane, position_um: tuple[float, float], program_open: bool, block_id: int
    ) -> Decision | None:
        """The library's best next block from here (a global one when the tip is on another sample)."""
        here = self._on == lane.entry.name
        decision = lane.campaign.propose(lane.own_s, position_um, program_open and here, block_id)
        if decision is None:
            lane.done = lane.campaign.last_stop_reason or "its planner has nothing left"
            lane.done_at_s = self._now_s
            return None
        if not here and self._on is not None:
            # the campaign priced a block from a closed program; the tip is engaged elsewhere and must come back
            # first, then find the new surface and settle on it
            profile = lane.campaign.profile
            comes_back = program_open and profile.global_jump_s is None  # as core.cost.open_program_steps
            extra = (profile.comeback_s if comes_back else 0.0) + change_s(profile)
            decision = dataclasses.replace(decision, predicted_cost_s=decision.predicted_cost_s + extra)
        return decision

    def _scale(self, lane: Lane) -> float | None:
        pred = lane.campaign.prediction
        return None if pred is None else float(np.mean(np.abs(pred.mean)))

    def _ranked(
        self, position_um: tuple[float, float], program_open: bool, block_id: int
    ) -> tuple[list[str], dict[str, Decision]]:
        """Every active library's offer, best first (information per second)."""
        decisions: dict[str, Decision] = {}
        offers: list[Offer] = []
        for name, lane in self.lanes.items():
            if lane.done:
                continue
            d = self._offer(lane, position_um, program_open, block_id)
            if d is None:
                continue
            decisions[name] = d
            offers.append(
                Offer(
                    name,
                    relative_value(d.acquisition, self._scale(lane)),
                    d.predicted_cost_s,
                    lane.entry.priority,
                )
            )
        return [o.name for o in rank(offers)], decisions

    def propose(
        self, clock_s: float, position_um: tuple[float, float], program_open: bool, block_id: int
    ) -> Decision | None:
        self._charge(clock_s)
        for lane in self.lanes.values():
            if not lane.done:
                reason = lane.campaign.stop_reason(lane.own_s)
                if reason is not None:
                    lane.done, lane.done_at_s = reason, self._now_s
        left = self._window_for(0.0)
        in_load = self.attendance.known and left is not None and left.fill_s > 0
        if not in_load and self.attendance.known:
            window = self.attendance.window(clock_s)
            self._load = None if window is None else _Load(clock_s, window)
        decision, loaded = self._next(position_um, program_open, block_id, in_load)
        if decision is not None and in_load and not loaded and self.attendance.known:
            # nothing of this visit's list is left: what comes next is planned now, and someone must load it
            window = self.attendance.window(clock_s)
            self._load = (
                None if window is None else _Load(clock_s, window, self._load.ranking if self._load else [])
            )
        if decision is not None and in_load and loaded:
            decision = dataclasses.replace(decision, phase=STRETCH_CONTINUES)
        return decision

    def _next(
        self, position_um: tuple[float, float], program_open: bool, block_id: int, in_load: bool
    ) -> tuple[Decision | None, bool]:
        """The next block, and whether it was part of the visit's list (planned when the load was)."""
        ref = self.reference.name if self.reference is not None else ""
        if self._check_due():
            self._owner[block_id] = ref
            return self._check_decision(position_um, program_open, block_id), True
        # the library whose loaded stretch is running goes on with it (a tip check in between or not)
        on = self.lanes.get(self._stretching or "")
        if on is not None and not on.done and on.campaign.queued_stretch():
            d = self._offer(on, position_um, program_open, block_id)
            if d is not None:
                self._owner[block_id] = on.entry.name
                return d, True
        outran = False
        while in_load and self._load is not None and self._load.ranking:
            # within a visit's load: the next library in the ranking made at the visit
            lane = self.lanes[self._load.ranking.pop(0)]
            if lane.done or lane.entry.name == self._stretching:
                continue
            d = self._offer(lane, position_um, program_open, block_id)
            if d is None:
                continue
            if not self._fits(d):
                lane.campaign.drop_stretch()  # it would outrun the load: ask for a visit instead
                outran = True
                break
            self._owner[block_id] = self._stretching = lane.entry.name
            return d, True
        # the libraries learnt nothing since the visit when only the reference ran: ranked now is as ranked then;
        # and once the list ran out before anyone comes, an engine that may plan unattended ranks them again
        # and goes on in the same absence (no visit: nobody is there to load it)
        replanned = in_load and self._load is not None and self._load.ranked
        loaded = (
            in_load and self._load is not None and not outran and (not replanned or self._unattended_left())
        )
        if in_load and not loaded and self.attendance.known:
            # nothing of this visit's list is left: what comes next is planned now, and someone must load it
            window = self.attendance.window(self._now_s)
            self._load = None if window is None else _Load(self._now_s, window)
        order, decisions = self._ranked(position_um, program_open, block_id)
        for name, lane in self.lanes.items():
            if name in decisions and name != (order[0] if order else None):
                lane.campaign.drop_stretch()  # planned, not loaded
        if not order:
            if self._check_due():  # the last library just reached its goal: the final check
                self._owner[block_id] = ref
                return self._check_decision(position_um, program_open, block_id), True
            self.last_stop_reason = "every library reached its goal: " + "; ".join(
                f"{name}: {lane.done}" for name, lane in self.lanes.items()
            )
            return None, False
        if loaded and replanned and not self._fits(decisions[order[0]]):
            loaded = False  # planned unattended, it would outrun the load: ask for a visit instead
        if self._load is not None:
            self._load.ranking, self._load.ranked = order[1:], True
        self._owner[block_id] = self._stretching = order[0]
        return decisions[order[0]], loaded

    # -- what the operator does -------------------------------------------------------------------------
    def veto(self, decision: Decision, hold_blocks: int = 3) -> None:
        name = self._owner.get(decision.block.block_id)
        if name in self.lanes:
            self.lanes[name].campaign.veto(decision, hold_blocks)
        else:
            self._ref_avoid.append((decision.block.center_x_um, decision.block.center_y_um))

    def adjust(self, **changes: Any) -> PlannerSettings:
        """An adjustment applies to every library (each keeps its own goal)."""
        for lane in self.lanes.values():
            lane.campaign.adjust(**changes)
        return self.settings

    # -- learning -------------------------------------------------------------------------------------
    def observe_block(self, block: Block, results: Sequence[IndentResult]) -> Any:
        name = self._owner.pop(block.block_id, None) or self._name_at(block)
        if any(is_taken(r.status) for r in results):
            # a block of which nothing ran (its surface not found, no export by the deadline) leaves the tip
            # where it was, as the drivers charge it: no change paid, so the next block there pays it
            if self._on is not None and name != self._on:
                self.changes += 1
            self._on = name
        if name in self.lanes:
            self._shown = self.lanes[name]
            return self.lanes[name].campaign.observe_block(block, results)
        self._observe_check(block, results)
        return None

    def _observe_check(self, block: Block, results: Sequence[IndentResult]) -> None:
        assert self.reference is not None and self.reference.reference is not None
        self._ref_taken.append(taken_xy_um(results))
        check = judge(block, results, self.reference.reference)
        self.checks.append(check)
        if not any(not lane.done for lane in self.lanes.values()) and check.passed:
            self._final_check_done = True
        if not check.passed:
            self._alarm = check.text(self.reference.reference)

    def _name_at(self, block: Block) -> str | None:
        first = block.indents[0]
        entry = self.tray.sample_at(first.x_um, first.y_um)
        return None if entry is None else entry.name

    def map_fields(self, snapshot_id: int, display_n: int = 50) -> MapFields:
        return self._shown.campaign.map_fields(snapshot_id, display_n)

    def queued_stretch(self) -> tuple[Block, ...]:
        on = self.lanes.get(self._on or "")
        return () if on is None else on.campaign.queued_stretch()

    def has_map(self) -> bool:
        return self._shown.campaign.has_map()

    def predict_mean_stage(self, x_um: Any, y_um: Any) -> Any:
        return self._shown.campaign.predict_mean_stage(x_um, y_um)

    def indented_xy_um(self) -> Any:
        return self._shown.campaign.indented_xy_um()

    def note_score(self, score: MapScore | None) -> None:
        self._shown.campaign.note_score(score)

    def stop_reason(self, clock_s: float) -> str | None:
        return self.last_stop_reason

    # -- persistence ----------------------------------------------------------------------------------
    def export_state(self) -> dict[str, Any]:
        return {
            "tray": {name: lane.campaign.export_state() for name, lane in self.lanes.items()},
            "tray_run": {
                "own_s": {name: lane.own_s for name, lane in self.lanes.items()},
                "done": {name: lane.done for name, lane in self.lanes.items()},
                "reference_s": self._ref_s,
                "now_s": self._now_s,
                "on": self._on,
                "stretching": self._stretching,
                "owner": {str(k): v for k, v in self._owner.items()},
                "ref_avoid": [list(p) for p in self._ref_avoid],
                "final_check_done": self._final_check_done,
                # the visit's load (a calendar): a resumed run goes on with it, no new visit
                "load": None if self._load is None else _load_to_dict(self._load),
                # for `aeni status` and the console (core.run.tray_view); a restore recomputes them
                "indents": {name: len(lane.campaign.indents_xy) for name, lane in self.lanes.items()},
                "rel_sd_p95_pct": {name: lane.campaign.rel_sd_p95_pct() for name, lane in self.lanes.items()},
                "checks": [
                    [c.block_id, c.t_s, _finite(c.median_gpa), _finite(c.deviation_pct), c.passed]
                    for c in self.checks
                ],
            },
        }

    def restore(self, state: dict[str, Any], blocks: Sequence[tuple[Block, Sequence[IndentResult]]]) -> None:
        """Rebuild after a crash: each block goes back to the sample it ran on, the checks are judged again."""
        by_lane: dict[str, list[tuple[Block, Sequence[IndentResult]]]] = {n: [] for n in self.lanes}
        for block, results in blocks:
            name = self._name_at(block)
            if name in by_lane:
                by_lane[name].append((block, results))
            elif name is not None and self.reference is not None and self.reference.reference is not None:
                self._ref_taken.append(taken_xy_um(results))
                self.checks.append(judge(block, results, self.reference.reference))
        for name, lane in self.lanes.items():
            lane.campaign.restore(state["tray"][name], by_lane[name])
        run = state.get("tray_run", {})
        for name, lane in self.lanes.items():
            lane.own_s = float(run.get("own_s", {}).get(name, 0.0))
            lane.done = str(run.get("done", {}).get(name, ""))
        self._ref_s = float(run.get("reference_s", 0.0))
        self._now_s = float(run.get("now_s", 0.0))
        self._on = run.get("on")
        self._stretching = run.get("stretching")
        self._owner = {int(k): str(v) for k, v in run.get("owner", {}).items()}
        self._ref_avoid = [(float(x), float(y)) for x, y in run.get("ref_avoid", [])]
        self._final_check_done = bool(run.get("final_check_done", False))
        self._load = None if run.get("load") is None else _load_from_dict(run["load"])
        if self._on in self.lanes:
            self._shown = self.lanes[self._on]

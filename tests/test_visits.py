"""The simulated operator's calendar (core.visits), the run file's [operator] section, and stretches."""

from __future__ import annotations

import math
from datetime import datetime
from pathlib import Path
from typing import Any

import pytest

from core.errors import InputError
from core.journal import JournalReader
from core.operator import Attendance, LoadWindow, OperatorAvailability, OperatorHours, parse_start
from core.runconfig import parse_run_config
from core.runview import CommandKind, EngineState
from core.visits import OperatorCalendar, SimulatedOperator

WEEKDAYS = OperatorHours.parse("Mon-Fri 08:30-18:00")


def _operator(start: str = "Mon 09:00") -> SimulatedOperator:
    return SimulatedOperator(OperatorAvailability(WEEKDAYS, 600.0, 7200.0), parse_start(start))


def test_a_request_during_hours_is_answered_within_the_response() -> None:
    op = _operator()
    op.load(0.0)
    assert (op.visits, op.waited_s) == (1, 600.0)
    assert op.wall_s(3600.0) == 4200.0


def test_a_request_just_before_they_leave_waits_for_the_next_morning() -> None:
    op = _operator("Mon 17:55")
    op.load(0.0)
    # 17:55 + 10 min is after 18:00: Tuesday 08:30 + 10 min
    assert op.now(0.0) == datetime(2024, 1, 2, 8, 40)
    assert op.waited_s == pytest.approx((14 * 60 + 45) * 60)


def test_a_friday_evening_request_waits_for_monday() -> None:
    op = _operator("Fri 19:00")
    op.load(0.0)
    assert op.now(0.0) == datetime(2024, 1, 8, 8, 40)


def test_unattended_is_the_routine_visit_during_hours_and_the_whole_absence_before_it() -> None:
    op = _operator("Mon 10:00")
    assert op.unattended(0.0).fill_s == 7200.0  # loaded 10:10, next visit 12:10, before they leave
    # a load at 17:10 runs until they answer again on Tuesday at 08:40
    assert op.unattended(7 * 3600.0).fill_s == pytest.approx(15.5 * 3600)
    # a load at 15:55: the routine visit at 17:55 could not be answered (10 min) before they leave at 18:00,
    # so the load runs the night too, until Tuesday at 08:40
    assert op.unattended(5 * 3600.0 + 45 * 60.0).fill_s == pytest.approx(16.75 * 3600)  # loaded 15:55
    # at 15:45 the routine visit (17:45, answered 17:55) still comes before they leave
    assert op.unattended(5 * 3600.0 + 35 * 60.0).fill_s == 7200.0


def test_a_load_must_not_end_between_the_last_answerable_moment_and_the_next_morning() -> None:
    """Film seed 4's Tuesday: a stretch loaded at 15:14 should run 2 h, to the routine visit; a request
    after 17:50 (18:00 less the 10 min response) is answered only on Wednesday at 08:40, so a load that
    ends between the two leaves the instrument idle all night."""
    op = _operator("Tue 15:04")
    w = op.unattended(0.0)  # loaded at 15:14
    assert w.fill_s == 7200.0
    assert w.last_answer_s == pytest.approx((2 * 60 + 36) * 60)  # 17:50
    assert w.next_answer_s == pytest.approx((17 * 60 + 26) * 60)  # Wednesday 08:40
    # a load ending at 17:55 falls between the two: nobody loads the next arrays until the morning
    assert w.last_answer_s < (2 * 60 + 41) * 60 < w.next_answer_s
    # loaded at 15:55 the routine visit (17:55) comes too late: the load fills the night, same span to avoid
    late = _operator("Tue 15:45").unattended(0.0)
    assert late.fill_s == late.next_answer_s == pytest.approx((16 * 60 + 45) * 60)
    assert late.last_answer_s == pytest.approx(115 * 60)
    # always there: no absence ahead, nothing to avoid
    always = SimulatedOperator(OperatorAvailability(OperatorHours.parse("always")), parse_start("Mon 09:00"))
    assert always.unattended(0.0) == LoadWindow(7200.0)


def test_nobody_ever_comes_is_infinite_never_a_number() -> None:
    op = SimulatedOperator(OperatorAvailability(OperatorHours.parse("never")), parse_start("Mon 09:00"))
    assert math.isinf(op.unattended(0.0).fill_s)
    op.load(0.0)
    assert math.isinf(op.wall_s(10.0)) and op.visits == 1


def test_run_file_operator_section() -> None:
    cfg = parse_run_config(
        {"operator": {"hours": "Mon-Fri 08:30-18:00", "response_min": 15, "visit_every_min": 90}}
    )
    op = cfg.options.operator
    assert op is not None
    assert (op.hours.text, op.response_s, op.visit_every_s) == ("Mon-Fri 08:30-18:00", 900.0, 5400.0)
    assert parse_run_config({}).options.operator is None  # no section: planned as if always attended


@pytest.mark.parametrize(
    ("field", "value", "says"),
    [
        ("hours", "Mon-Fri 8-18", "operator.hours"),
        ("response_min", -1, "operator.response_min"),
        ("visit_every_min", 0, "operator.visit_every_min"),
        ("when", "x", "unknown field operator.when"),
    ],
)
def test_run_file_operator_section_refuses_bad_values(field: str, value: object, says: str) -> None:
    with pytest.raises(InputError, match=says.replace(".", r"\.")):
        parse_run_config({"operator": {field: value}}, "run.toml")


def _simulate(policy: str, start: str, budget_s: float) -> dict[str, object]:
    from aeni_console.cli.simulate import run_simulation

    cal = OperatorCalendar(OperatorAvailability(WEEKDAYS, 600.0, 7200.0), parse_start(start))
    return run_simulation(policy, 0, lattice_n=24, budget_s=budget_s, calendar=cal)


def test_simulate_puts_every_trajectory_point_on_the_calendar() -> None:
    out = _simulate("aeni+attended", "Mon 09:00", 3000.0)  # the ablation: no stretches
    traj = out["trajectory"]
    assert isinstance(traj, list) and traj
    visits = [p["operator_visits"] for p in traj]
    assert visits == sorted(visits) and visits[-1] <= out["operator_visits"]
    for p in traj:
        # each block waited 10 min for the operator: wall = instrument time + 10 min per visit so far
        assert p["wall_clock_h"] == pytest.approx(p["t_s"] / 3600 + p["operator_visits"] * 600 / 3600)
    assert out["operator_visits"] == out["blocks"]  # adaptive blocks: one visit each


def test_the_grid_is_loaded_once() -> None:
    out = _simulate("grid", "Mon 17:00", 4000.0)
    assert out["operator_visits"] == 1
    assert out["wall_clock_h"] == pytest.approx(out["instrument_s"] / 3600 + 10 / 60)


def test_away_until_makes_the_engine_plan_for_nobody_until_then(tmp_path: Path) -> None:
    """`away-until` is an engine command (allowed in every live state): journaled, and from then on the
    campaign is told how long the next load runs unattended."""
    from tests.test_engine import FakeCampaign, cmd, run_engine, when

    seen: list[LoadWindow | None] = []

    class Listening(FakeCampaign):
        attendance = Attendance()

        def propose(self, clock_s: float, *a: Any) -> Any:
            seen.append(self.attendance.window(clock_s))
            return super().propose(clock_s, *a)

    now = datetime(2024, 1, 1, 17, 0)  # a Monday, 17:00
    until = datetime(2024, 1, 2, 9, 0)
    eng, path = run_engine(
        tmp_path,
        Listening(n_blocks=4),
        "step",
        [
            when(EngineState.AWAITING_APPROVAL, cmd(CommandKind.AWAY_UNTIL, until=until.isoformat())),
            *[when(EngineState.AWAITING_APPROVAL, cmd(CommandKind.APPROVE)) for _ in range(4)],
        ],
        local_now=lambda: now,
    )
    assert eng.completed
    assert seen[0] is None  # no [operator] section: planned as if always attended
    # away until 09:00, then (always there) answered within the 10 min response: 16 h 10 min from 17:00
    assert seen[-1] is not None and seen[-1].fill_s == pytest.approx(16 * 3600 + 600)
    with JournalReader(path) as r:
        texts = [e.text for e in r.events()]
    assert any("away until Tue 2024-01-02 09:00" in t for t in texts)


def test_away_until_with_a_bad_time_is_rejected_by_the_engine(tmp_path: Path) -> None:
    from tests.test_engine import FakeCampaign, cmd, run_engine, when

    _, path = run_engine(
        tmp_path,
        FakeCampaign(n_blocks=2),
        "step",
        [
            when(EngineState.AWAITING_APPROVAL, cmd(CommandKind.AWAY_UNTIL, until="tomorrow")),
            when(EngineState.AWAITING_APPROVAL, cmd(CommandKind.APPROVE)),
            when(EngineState.AWAITING_APPROVAL, cmd(CommandKind.APPROVE)),
        ],
    )
    with JournalReader(path) as r:
        texts = [e.text for e in r.events()]
    assert any("away-until rejected" in t and "not an ISO" in t for t in texts)


def test_a_stretch_fills_the_evening_with_arrays_loaded_in_one_visit() -> None:
    """Started on a Monday at 17:00: the first load runs unattended until Tuesday 08:40, so the planner
    plans one stretch of arrays (each one program at one hold; here the space-filling start, which needs
    no model), loaded in one visit; every array still passes the interlock (no refusals)."""
    from aeni_console.cli.simulate import run_simulation
    from core.run.events import Decided, RunEvent

    decided: list[Decided] = []

    class Decisions:
        def emit(self, event: RunEvent) -> None:
            if isinstance(event, Decided):
                decided.append(event)

    cal = OperatorCalendar(OperatorAvailability(WEEKDAYS, 600.0, 7200.0), parse_start("Mon 17:00"))
    out = run_simulation(
        "aeni+stretch", 0, lattice_n=24, budget_s=2.5 * 3600, calendar=cal, sinks=[Decisions()]
    )
    phases = [d.decision.phase for d in decided]
    assert phases[:2] == ["stretch", "stretch-continues"], phases
    arrays = [d.decision for d in decided if d.decision.phase.startswith("stretch")]
    assert all(a.block.kind == "global" and len({i.hold_s for i in a.block.indents}) == 1 for a in arrays)
    assert "stretch array 1 of" in arrays[0].reason and "unattended" in arrays[0].reason
    assert sum(a.block.n_indents for a in arrays[:2]) == 64  # the space-filling start, no more
    assert out["interlock_refusals"] == 0
    # every decision is a visit but a stretch's later arrays
    assert out["operator_visits"] == sum(p != "stretch-continues" for p in phases)
    # the stretch was loaded at 17:10: the instrument waited 10 min for it and for every later visit
    assert out["wall_clock_h"] >= out["instrument_s"] / 3600 + 10 / 60 - 1e-9


def test_aeni_reads_the_run_its_calendar_and_its_profile() -> None:
    """One rule in one home (registry.run_recipe): a calendar makes every load a stretch to the next visit;
    a program change the profile prices above its own itemised steps is priced over the program's life.
    The modifiers stay as ablations of the same recipe."""
    from core.policies.blocks import ScatteredSingles
    from core.policies.registry import RunFacts, policy_parts
    from core.profile import load_profile

    def blocks(name: str, facts: RunFacts | None) -> ScatteredSingles:
        b = policy_parts(name, facts).blocks
        assert isinstance(b, ScatteredSingles)
        return b

    imicro, film, blitz = (load_profile(n) for n in ("kla-imicro", "kla-imicro-film", "kla-nanoblitz"))
    assert film.global_overhead_s == 520.0 and film.itemised_program_s == imicro.global_overhead_s == 470.0
    plain = blocks("aeni", RunFacts.of(imicro))
    assert plain.stretch_min_s is None and not plain.program_life
    assert not blocks("aeni", RunFacts.of(blitz)).program_life
    on_film = blocks("aeni", RunFacts.of(film, has_calendar=True))
    assert on_film.stretch_min_s == 0.0 and on_film.program_life
    assert blocks("aeni", RunFacts.of(imicro, has_calendar=True)) == blocks("aeni+stretch-visits", None)
    assert blocks("aeni", RunFacts.of(film)) == blocks("aeni+program-life", None)
    # the ablations turn each rule off again
    off = blocks("aeni+attended+first-block", RunFacts.of(film, has_calendar=True))
    assert off.stretch_min_s is None and not off.program_life
    assert blocks("aeni+stretch", RunFacts.of(imicro, has_calendar=True)).stretch_min_s == 3 * 3600


def test_a_campaign_plans_stretches_once_its_attendance_knows_a_calendar() -> None:
    from core.campaign import Campaign
    from core.runconfig import make_campaign_config
    from drivers.registry import sim_scenario

    config = make_campaign_config(scenario="ternary", policy="aeni", seed=0, lattice_n=12)
    attendance = Attendance()
    campaign = Campaign(config, sim_scenario(config.driver_options, 0, None).sample, attendance=attendance)
    assert campaign.policy.parts.blocks.stretch_min_s is None  # type: ignore[union-attr]
    cal = OperatorCalendar(OperatorAvailability(WEEKDAYS, 600.0, 7200.0), parse_start("Mon 17:00"))
    attendance.follow(cal.operator().unattended)  # what the engine does when the operator's word changes
    assert campaign.policy.parts.blocks.stretch_min_s == 0.0  # type: ignore[union-attr]
    attendance.follow(None)
    assert campaign.policy.parts.blocks.stretch_min_s is None  # type: ignore[union-attr]


def test_a_stretch_before_the_last_visit_of_the_day_does_not_leave_the_night_idle() -> None:
    """The film, the operator coming by every 30 min, a start on Monday at 17:00: the first load (17:10)
    should run to the 17:40 routine visit, but one film array (a program of singles) takes longer than the
    40 min left before 17:50, the last moment a request is still answered. The stretch ends by then or
    fills the night; either way the instrument never waits for the morning with a stretch done at 17:55."""
    from aeni_console.cli.simulate import run_simulation

    cal = OperatorCalendar(OperatorAvailability(WEEKDAYS, 600.0, 1800.0), parse_start("Mon 17:00"))
    out = run_simulation("aeni", 0, scenario="film", lattice_n=24, budget_s=3 * 3600, calendar=cal)
    idle_h = out["wall_clock_h"] - out["instrument_s"] / 3600
    # the first load waits 10 min; every later request is answered within the hours or after a full stretch
    assert idle_h < 1.0, f"{idle_h:.2f} h idle"


def test_a_stretch_is_fitted_to_the_budget_when_planned_and_runs_whole_past_it() -> None:
    """Every ticket of a stretch goes out with its first array and the instrument runs every array the operator
    loaded, engine or not (docs/kla.md). So the stretch is fitted to the budgets as a whole when planned, and
    no stop rule later cuts or drops an array already handed out: its indents would be made and never
    journaled (the soak's lost indents, issue 38)."""
    from core.campaign import Campaign
    from core.runconfig import make_campaign_config
    from drivers.registry import sim_scenario

    budget_s = 2.0 * 3600.0  # less than the evening's space-filling stretch (48 + 16 indents) needs
    config = make_campaign_config(
        scenario="ternary", policy="aeni", seed=0, lattice_n=24, settings={"budget_s": budget_s}
    )
    cal = OperatorCalendar(OperatorAvailability(WEEKDAYS, 600.0, 7200.0), parse_start("Mon 17:00"))
    campaign = Campaign(
        config,
        sim_scenario(config.driver_options, 0, None).sample,
        attendance=Attendance(cal.operator().unattended),
    )
    first = campaign.propose(0.0, (0.0, 0.0), False, 1)
    assert first is not None and first.phase == "stretch"
    queued = campaign.queued_stretch()
    assert len(queued) == 1 and queued[0].n_indents < 16  # the second array cut to the budget when planned
    # past the budget, the loaded arrays still come out, each exactly as it was handed out, then the run stops
    arrays = [first]
    for k, block in enumerate(queued, start=2):
        d = campaign.propose(budget_s + 1.0, (0.0, 0.0), True, k)
        assert d is not None and d.block.indents == block.indents
        arrays.append(d)
    # the whole stretch, as planned, fits the budget with the comeback to the lens
    assert sum(a.predicted_cost_s for a in arrays) <= budget_s - campaign.profile.comeback_s + 1e-6
    assert campaign.propose(budget_s + 1.0, (0.0, 0.0), True, len(queued) + 2) is None
    assert campaign.last_stop_reason is not None and "budget" in campaign.last_stop_reason

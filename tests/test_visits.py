"""The simulated operator's calendar (core.visits), the run file's [operator] section, and stretches."""

from __future__ import annotations

import math
from datetime import datetime

import pytest

from core.errors import InputError
from core.operator import OperatorAvailability, OperatorHours, parse_start
from core.runconfig import parse_run_config
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
    assert op.unattended_s(0.0) == 7200.0  # loaded 10:10, next visit 12:10, before they leave
    # a load at 17:10 runs until they answer again on Tuesday at 08:40
    assert op.unattended_s(7 * 3600.0) == pytest.approx(15.5 * 3600)


def test_nobody_ever_comes_is_infinite_never_a_number() -> None:
    op = SimulatedOperator(OperatorAvailability(OperatorHours.parse("never")), parse_start("Mon 09:00"))
    assert math.isinf(op.unattended_s(0.0))
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
    from aeni_console.commands.simulate import run_simulation

    cal = OperatorCalendar(OperatorAvailability(WEEKDAYS, 600.0, 7200.0), parse_start(start))
    return run_simulation(policy, 0, lattice_n=24, budget_s=budget_s, calendar=cal)


def test_simulate_puts_every_trajectory_point_on_the_calendar() -> None:
    out = _simulate("aeni", "Mon 09:00", 3000.0)
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

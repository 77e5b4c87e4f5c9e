"""The bench's report of the default (issue 37): the time to both grids' final MAPEs, paired per seed, and the
calendar's wall clock to both maps, rendered from records (no run)."""

from __future__ import annotations

from dataclasses import replace

from aeni_console.bench.catalogue import BenchConfig
from aeni_console.bench.runner import RunRecord
from aeni_console.bench.storage import records_from_json, records_to_json
from aeni_console.reports.bench import calendar_table, two_maps_table
from core.operator import OperatorAvailability, OperatorHours, parse_start
from core.visits import OperatorCalendar


def _record(policy: str, seed: int, t_h: float | None, t_e: float | None, **kw: object) -> RunRecord:
    base = RunRecord(
        scenario="ternary",
        policy=policy,
        seed=seed,
        target_mape_pct=0.5,
        t_hit_s=t_h,
        final_mape_pct=0.5,
        max_found_gpa=7.0,
        true_max_gpa=7.0,
        instrument_s=300_000.0,
        budget_s=300_000.0,
        indents=100,
        blocks=10,
        reconfigurations=0,
        ledger={},
        stop_reason="test",
        wall_s=1.0,
        trajectory=[(1.0, 1.0)],
        max_found=[(1.0, 7.0)],
        target_mape_modulus_pct=0.3,
        final_mape_modulus_pct=0.3,
        t_hit_modulus_s=t_e,
        trajectory_modulus=[(1.0, 0.5)],
    )
    return replace(base, **kw)  # type: ignore[arg-type]


def test_the_speed_up_to_both_maps_is_paired_per_seed_and_a_miss_is_the_worst() -> None:
    records = [
        _record("grid", 0, 280_000.0, 286_000.0),
        _record("grid", 1, 270_000.0, 286_000.0),
        _record("grid", 2, 286_000.0, 286_000.0),
        _record("aeni", 0, 20_000.0, 28_600.0),  # both at 28,600 s: 10.0×
        _record("aeni", 1, 20_000.0, 57_200.0),  # 5.0×
        _record("aeni", 2, 20_000.0, None),  # the modulus never: 0×, the worst
    ]
    row = next(line for line in two_maps_table(records) if line.startswith("| ternary | aeni |"))
    assert row.endswith("| 5.0× (0.0×, seed 2) |"), row
    grid = next(line for line in two_maps_table(records) if line.startswith("| ternary | grid |"))
    assert grid.endswith("| 1.0× (1.0×, seed 0) |"), grid


def test_the_calendar_table_gives_the_wall_clock_to_both_maps_and_results_json_keeps_it() -> None:
    cal = OperatorCalendar(
        OperatorAvailability(OperatorHours.parse("Mon-Fri 08:30-18:00"), 600.0, 7200.0),
        parse_start("Mon 09:00"),
    )
    config = replace(BenchConfig.make(True), calendar=cal)
    records = [
        _record(
            "aeni",
            s,
            20_000.0,
            40_000.0,
            wall_clock_h=h,
            operator_visits=v,
            wall_clock_both_h=hb,
            operator_visits_both=vb,
        )
        for s, (h, v, hb, vb) in enumerate([(10.0, 3, 20.0, 5), (12.0, 4, 30.0, 7), (14.0, 5, 25.0, 6)])
    ]
    row = next(line for line in calendar_table(records, config) if "`aeni`" in line)
    assert "| 12.0 (14.0) | 4 (5) |" in row and "| 25.0 (30.0) | 6 (7) | 3 |" in row, row
    back, _, _ = records_from_json(records_to_json(records, config, 1.0))
    assert [(r.wall_clock_both_h, r.operator_visits_both) for r in back] == [(20.0, 5), (30.0, 7), (25.0, 6)]

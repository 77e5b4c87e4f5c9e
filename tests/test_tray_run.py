"""A tray run: one engine over several samples, each indent inside its own sample, the tip checked."""

from __future__ import annotations

import json
from datetime import datetime

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from aeni_console.alerts import KINDS, Severity, event_kind
from core.campaign_config import CampaignConfig
from core.interlock_tray import TrayInterlock
from core.operator import OperatorAvailability, OperatorHours
from core.plan import STRETCH_CONTINUES, Block, local_grid
from core.policies.tray import Offer, rank
from core.run.events import Indent, Logged, RunEvent
from core.run.headless import run_headless
from core.run.spec import RunSpec
from core.runview import EngineState
from core.sample.tray import Goal, Reference, Tray, TraySample, block_sample, placed_sample
from core.visits import OperatorCalendar
from drivers.registry import DRIVERS, default_sample

STAGE = (0.0, 0.0, 100_000.0, 100_000.0)


def _tray(ref_x_um: float = 30_000.0, check_every_h: float = 2.0) -> Tray:
    tern = default_sample("sim", {"scenario": "ternary"}, 0)
    film = default_sample("sim", {"scenario": "film"}, 0)
    return Tray(
        "t",
        (
            TraySample("tern", "library", placed_sample(tern, (0.0, 0.0), STAGE), goal=Goal("indents", 60),
                       sim={"scenario": "ternary"}),
            TraySample("film", "library", placed_sample(film, (0.0, 0.0), STAGE), goal=Goal("indents", 40),
                       sim={"scenario": "film"}),
            TraySample("silica", "reference", placed_sample(block_sample("silica", "kla-imicro", 0, 0, 3000, 3000),
                       (ref_x_um, 0.0), STAGE), reference=Reference("fused-silica", 9.0, 72.0, 5.0, check_every_h)),
        ),
        STAGE,
    )  # fmt: skip


class _Events:
    def __init__(self) -> None:
        self.events: list[RunEvent] = []

    def emit(self, event: RunEvent) -> None:
        self.events.append(event)


def _run(tray: Tray, wear: float = 0.0) -> tuple[_Events, object, object]:
    spec = RunSpec(
        campaign=CampaignConfig(seed=0, lattice_n=20, driver_options={"tip_wear_pct_per_h": wear}), tray=tray
    )
    seen = _Events()
    tally, run = run_headless(spec, DRIVERS, sinks=[seen])
    return seen, tally, run


def test_a_tray_spec_round_trips_and_a_single_sample_spec_is_unchanged() -> None:
    single = RunSpec(campaign=CampaignConfig(seed=3, driver_options={"scenario": "ternary"}))
    assert "tray" not in json.loads(single.to_json())
    assert RunSpec.from_json(single.to_json()) == single
    spec = RunSpec(campaign=CampaignConfig(seed=3), tray=_tray())
    again = RunSpec.from_json(spec.to_json())
    assert again == spec and again.tray is not None and again.tray.by_name("film").goal == Goal("indents", 40)


def test_the_tray_reaches_each_goal_with_every_indent_on_its_own_sample_and_checks_the_tip() -> None:
    tray = _tray()
    seen, tally, run = _run(tray)
    tc = run.tray  # type: ignore[attr-defined]
    assert "every library reached its goal" in tally.stop_reason  # type: ignore[attr-defined]
    assert {n: len(lane.campaign.indents_xy) for n, lane in tc.lanes.items()} == {"tern": 60, "film": 40}
    by_block: dict[int, set[str]] = {}
    for e in seen.events:
        if isinstance(e, Indent):
            r = e.result
            where = tray.sample_at(r.commanded_x_um, r.commanded_y_um)
            assert where is not None, (r.commanded_x_um, r.commanded_y_um)
            ok = where.placed.allowed(np.array([[r.commanded_x_um, r.commanded_y_um]]))
            assert ok.all() or where.role == "reference"
            by_block.setdefault(r.block_id, set()).add(where.name)
    assert all(len(names) == 1 for names in by_block.values())  # no block spans two samples
    # the reference first, after the last library and in between every check_every_h
    checks = tc.checks
    first_library = min(b for b, n in by_block.items() if n != {"silica"})
    assert by_block[0] == {"silica"} and first_library > 0
    assert max(by_block) in {c.block_id for c in checks}
    assert all(c.passed for c in checks) and len(checks) >= 3
    gaps = np.diff([c.t_s for c in checks])
    assert (gaps < 2 * 3600 + 3 * 3600).all()  # due after 2 h, run before the next library block ends


def test_a_worn_tip_is_caught_before_the_next_library_block() -> None:
    seen, tally, run = _run(_tray(), wear=3.0)
    tc = run.tray  # type: ignore[attr-defined]
    failed = [c for c in tc.checks if not c.passed]
    assert len(failed) == 1 and failed[0].deviation_pct > 5.0
    after = [e for e in seen.events if isinstance(e, Indent) and e.result.block_id > failed[0].block_id]
    assert after == []  # no library indented on the worn tip
    paused = [e for e in seen.events if getattr(e, "state", None) is EngineState.PAUSED]
    assert paused, "the run paused"
    alarm = [e for e in seen.events if isinstance(e, Logged) and e.level == "error"]
    assert alarm and event_kind(alarm[0].text) == "tip"
    assert KINDS["tip"].severity is Severity.FAILURE
    assert "nobody at a console" in tally.stop_reason  # type: ignore[attr-defined]


def test_offers_rank_by_information_per_second() -> None:
    offers = [
        Offer("a", 0.02, 1000.0),
        Offer("b", 0.02, 500.0),
        Offer("c", 0.02, 1000.0, priority=3.0),
        Offer("new", float("inf"), 5000.0),
    ]
    assert [o.name for o in rank(offers)] == ["new", "c", "b", "a"]


TRAY = _tray()
INTERLOCK = TrayInterlock(TRAY)  # check() remembers nothing


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    on=st.sampled_from([s.placed.calibration.bounds_um for s in TRAY.samples]),
    fx=st.floats(-0.3, 1.3),
    fy=st.floats(-0.3, 1.3),
    g=st.integers(1, 5),
    pitch=st.sampled_from([5.0, 50.0, 400.0]),
    local=st.booleans(),
    px=st.floats(0.0, 40_000.0),
    py=st.floats(0.0, 25_000.0),
)
def test_the_interlock_passes_only_blocks_inside_one_sample(
    on: tuple[float, float, float, float],
    fx: float,
    fy: float,
    g: int,
    pitch: float,
    local: bool,
    px: float,
    py: float,
) -> None:
    x0, x1, y0, y1 = on  # near a sample, often across its edge
    x, y = x0 + fx * (x1 - x0), y0 + fy * (y1 - y0)
    block = Block(0, "local" if local else "global", x, y, g, pitch, 80.0, local_grid(x, y, g, pitch, 80.0))
    if INTERLOCK.check(block, (px, py), True) is not None:
        return
    owners = {getattr(TRAY.sample_at(s.x_um, s.y_um), "name", None) for s in block.indents}
    assert len(owners) == 1 and None not in owners  # every indent on the one sample it started on
    if local:  # an engaged move never comes from another sample
        assert getattr(TRAY.sample_at(px, py), "name", None) in owners


def test_the_interlock_refuses_a_block_across_two_samples_or_off_every_sample() -> None:
    # a row from the ternary library's right edge towards the film, and a block in the gap between samples
    across = Block(0, "global", 900.0, 500.0, 2, 9500.0, 80.0, local_grid(5650.0, 500.0, 2, 9500.0, 80.0))
    assert INTERLOCK.check(across, (0.0, 0.0), False) is not None
    gap = Block(1, "global", 5000.0, 5000.0, 1, 5.0, 80.0, local_grid(5000.0, 5000.0, 1, 5.0, 80.0))
    assert "on no sample of the tray" in (INTERLOCK.check(gap, (0.0, 0.0), False) or "")
    local = Block(2, "local", 500.0, 500.0, 1, 5.0, 80.0, local_grid(500.0, 500.0, 1, 5.0, 80.0))
    assert "needs a global block" in (INTERLOCK.check(local, (12_000.0, 21_000.0), True) or "")


def test_a_night_on_the_calendar_is_one_visit_for_the_whole_tray() -> None:
    # loaded at 18:00 (the request made at 17:50, answered within the 10 min response) and left for the night
    cal = OperatorCalendar(
        OperatorAvailability(OperatorHours.parse("Mon-Fri 08:30-18:00"), 600, 7200),
        datetime(2026, 11, 23, 17, 50),
    )
    spec = RunSpec(campaign=CampaignConfig(seed=0, lattice_n=20), calendar=cal, tray=_tray())
    tally, run = run_headless(spec, DRIVERS)
    assert "every library reached its goal" in tally.stop_reason
    assert run.visits is not None and run.visits.visits == 1 and run.visits.waited_s == 600
    phases = [d.phase for d in tally.decisions]
    assert phases[0] == "tip-check" and set(phases[1:]) == {STRETCH_CONTINUES}  # loaded with the first
    names = {run.tray.tray.sample_at(d.block.center_x_um, d.block.center_y_um).name for d in tally.decisions}  # type: ignore[union-attr]
    assert names == {"tern", "film", "silica"}

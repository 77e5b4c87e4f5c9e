"""A tray overnight: the unattended night does not run out of work, and the tip check is sized by its purpose."""

from __future__ import annotations

from datetime import datetime

import numpy as np
import pytest

from core.campaign_config import CampaignConfig
from core.operator import OperatorAvailability, OperatorHours
from core.run.headless import run_headless
from core.run.spec import RunSpec
from core.sample.tray import Goal, Reference, Tray, TraySample, block_sample, placed_sample
from core.tipcheck import REFERENCE_SCATTER_PCT, check_grid_g, check_indents
from core.visits import OperatorCalendar
from drivers.registry import DRIVERS, default_sample

STAGE = (0.0, 0.0, 100_000.0, 100_000.0)


@pytest.mark.parametrize("tolerance_pct", [2.0, 5.0, 10.0])
def test_a_check_tells_a_good_tip_from_one_worn_past_the_tolerance(tolerance_pct: float) -> None:
    n = check_grid_g(tolerance_pct) ** 2
    assert n >= check_indents(tolerance_pct)
    rng = np.random.default_rng(0)
    good = np.median(rng.normal(0.0, REFERENCE_SCATTER_PCT, (20_000, n)), axis=1)
    worn = np.median(rng.normal(-1.4 * tolerance_pct, REFERENCE_SCATTER_PCT, (20_000, n)), axis=1)
    assert np.mean(np.abs(good) > tolerance_pct) < 0.01  # a good tip does not pause the night
    assert np.mean(np.abs(worn) > tolerance_pct) >= 0.95  # a worn one is caught


def test_the_check_spends_fewer_indents_the_wider_the_tolerance() -> None:
    sizes = [check_indents(t) for t in (1.0, 2.0, 5.0, 10.0)]
    assert sizes == sorted(sizes, reverse=True) and sizes[-1] >= 3
    assert check_indents(5.0) < 9  # the fixed 3×3 grid it replaces


def test_a_night_whose_load_holds_only_space_filling_starts_does_not_stall() -> None:
    # loaded at 18:00 (the request at 17:50 answered within the 10 min response); the ternary library needs more
    # than its space-filling start (64 singles), so the night's work goes on from the models the starts built
    tern = default_sample("sim", {"scenario": "ternary"}, 0)
    film = default_sample("sim", {"scenario": "film"}, 0)
    silica = block_sample("silica", "kla-imicro", 0, 0, 3000, 3000)
    tray = Tray(
        "night",
        (
            TraySample("tern", "library", placed_sample(tern, (0.0, 0.0), STAGE), goal=Goal("indents", 80),
                       sim={"scenario": "ternary"}),
            TraySample("film", "library", placed_sample(film, (0.0, 0.0), STAGE), goal=Goal("indents", 50),
                       sim={"scenario": "film"}),
            TraySample("silica", "reference", placed_sample(silica, (30_000.0, 0.0), STAGE),
                       reference=Reference("fused-silica", 9.0, 72.0, 5.0, 4.0)),
        ),
        STAGE,
    )  # fmt: skip
    cal = OperatorCalendar(
        OperatorAvailability(OperatorHours.parse("Mon-Fri 08:30-18:00"), 600, 7200),
        datetime(2026, 11, 23, 17, 50),
    )
    spec = RunSpec(campaign=CampaignConfig(seed=0, lattice_n=20), calendar=cal, tray=tray)
    tally, run = run_headless(spec, DRIVERS)
    assert "every library reached its goal" in tally.stop_reason
    tc = run.tray
    assert tc is not None and {n: len(lane.campaign.indents_xy) for n, lane in tc.lanes.items()} == {
        "tern": 80,
        "film": 50,
    }
    assert tally.instrument_s < 14 * 3600  # all of it fits the night (18:00 to 08:30)
    # one visit, the one that loaded the night; the instrument never waited after it
    assert run.visits is not None and run.visits.visits == 1 and run.visits.waited_s == 600

"""Stopping rules a real sample can use: ``stop_at`` (the local wall clock) and ``stop_rel_sd_pct`` (the map's
relative epistemic sd), with the reason journaled."""

from __future__ import annotations

import datetime
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from core.campaign import Campaign
from core.campaign_config import CampaignConfig
from core.plan import IndentResult, PlannerSettings
from core.runconfig import parse_run_config
from drivers.registry import default_sample, make_driver


def _campaign(
    settings: PlannerSettings, seed: int = 0, wall_clock: Callable[[], float] = time.time
) -> Campaign:
    sample = default_sample("sim", {"scenario": "ternary"}, seed)
    config = CampaignConfig(policy="aeni", seed=seed, settings=settings, sample=sample)
    return Campaign(config, wall_clock=wall_clock)


def _local(hour: int, minute: int, days: int = 0) -> float:
    now = datetime.datetime.now().astimezone()
    at = now.replace(hour=hour, minute=minute, second=0, microsecond=0) + datetime.timedelta(days=days)
    return at.timestamp()


def _run_block(c: Campaign, driver: object, block_id: int) -> bool:
    d = c.propose(driver.clock_s(), driver.position_um(), driver.program_open(), block_id)  # type: ignore[attr-defined]
    if d is None:
        return False
    results = [e for e in driver.execute_block(d.block) if isinstance(e, IndentResult)]  # type: ignore[attr-defined]
    c.observe_block(d.block, results)
    return True


def test_stop_at_runs_the_last_block_that_ends_before_it_and_says_so() -> None:
    wall = [_local(7, 0)]
    settings = PlannerSettings(stop_at="07:30", budget_s=1e9)
    c = _campaign(settings, wall_clock=lambda: wall[0])  # the run starts at 07:00
    assert c.stop_at_epoch_s == _local(7, 30)
    driver = make_driver("sim", c.sample, c.profile, {"scenario": "ternary"}, seed=0)
    ends = []
    block_id = 0
    while block_id < 200:
        before = driver.clock_s()
        if not _run_block(c, driver, block_id):
            break
        wall[0] += driver.clock_s() - before  # a real instrument: an instrument second is a wall second
        ends.append(wall[0])
        block_id += 1
    assert block_id < 200 and ends
    # every block (and the comeback to the lens) ended before 07:30; the next one would not have
    assert max(ends) + c.profile.comeback_s <= _local(7, 30) + 1e-6
    reason = c.last_stop_reason or ""
    assert "stop_at 07:30" in reason, reason


def test_stop_at_means_the_next_such_time_and_a_resumed_run_keeps_it() -> None:
    c = _campaign(PlannerSettings(stop_at="08:00"), wall_clock=lambda: _local(9, 0))
    assert c.stop_at_epoch_s == _local(8, 0, days=1)  # 08:00 has passed today: tomorrow's
    state = _campaign(PlannerSettings(stop_at="08:00"), wall_clock=lambda: _local(7, 0)).export_state()
    assert state["stop_at_epoch_s"] == _local(8, 0)  # started at 07:00: today's 08:00
    again = _campaign(PlannerSettings(stop_at="08:00"), wall_clock=lambda: _local(9, 0))
    again.restore(state, [])
    assert again.stop_at_epoch_s == _local(8, 0)  # resumed after 08:00: the run is over, not tomorrow's
    assert "stop_at 08:00" in (again.stop_reason(0.0) or "")
    # a run without stop_at journals the same state as before the rule existed
    assert "stop_at_epoch_s" not in _campaign(PlannerSettings()).export_state()


def test_stop_rel_sd_stops_once_the_map_is_known_well_enough() -> None:
    c = _campaign(PlannerSettings(stop_rel_sd_pct=6.0, budget_s=1e9))
    driver = make_driver("sim", c.sample, c.profile, {"scenario": "ternary"}, seed=0)
    p95_seen = []
    block_id = 0
    while block_id < 60 and _run_block(c, driver, block_id):
        p95_seen.append(c.rel_sd_p95_pct())
        block_id += 1
    assert block_id < 60, "never reached the target"
    reason = c.last_stop_reason or ""
    assert "stop_rel_sd_pct 6 %" in reason, reason
    p95 = c.rel_sd_p95_pct()
    assert p95 is not None and p95 < 6.0
    assert all(v is None or v >= 6.0 for v in p95_seen[:-1])  # it stopped at the first block that got there
    # the percentile is over the measurable area of the map the campaign predicts
    pred = c.prediction
    assert pred is not None
    rel = 100 * pred.epistemic_sd[c.placement_mask] / np.abs(pred.mean[c.placement_mask])
    assert p95 == np.percentile(rel, 95)


def test_the_stop_reason_is_journaled(tmp_path: Path) -> None:
    from aeni_console.cli.run import run_engine
    from core.journal import JournalReader
    from core.runconfig import RunOptions

    rc = parse_run_config({"name": "sd", "planner": {"stop_rel_sd_pct": 15, "budget_s": 1e6}}, "run.toml")
    assert rc.campaign.settings.stop_rel_sd_pct == 15.0
    path = tmp_path / "sd.sqlite"
    assert run_engine(path, create=(rc.campaign, RunOptions()), quiet=True) == 0
    with JournalReader(path) as r:
        row = r.q.engine_row()
    assert row["completed"] and "stop_rel_sd_pct 15 %" in row["stop_reason"]


def test_stop_rules_are_read_and_checked_by_the_one_validator() -> None:
    rc = parse_run_config({"planner": {"stop_at": "8:05", "stop_rel_sd_pct": 2.5}}, "run.toml")
    assert rc.campaign.settings.stop_at == "08:05" and rc.campaign.settings.stop_rel_sd_pct == 2.5

"""The measured depth at maximum load and the profile's drift segment drive the adaptive hold and the drift
correction (Eq. 7), in place of the nominal 100 nm and the fixed 40 s."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from core.campaign import Campaign
from core.campaign_config import CampaignConfig
from core.drift import drift_corrected_hardness_gpa, typical_depth_nm
from core.journal import DriverState, Journal, JournalReader
from core.plan import Block, IndentResult, StepRecord, local_grid
from core.policies.planner import choose_hold
from core.profile import load_profile
from drivers.sim.scenarios import make_scenario


def _profile(tmp_path: Path, segment_s: float) -> Path:
    path = tmp_path / f"segment-{segment_s}.toml"
    path.write_text(f'extends = "kla-imicro"\n[drift]\nsegment_s = {segment_s}\n')
    return path


def test_hold_rule_prices_the_drift_at_the_measured_depth_over_the_profiles_segment(tmp_path: Path) -> None:
    profile = load_profile("kla-imicro")
    assert profile.drift_segment_s == 40.0
    # 0.03 nm/s over 40 s: 1.2 nm of a 100 nm indent is (100/98.8)² − 1 = 2.44 % (slow); of 300 nm, 0.80 %
    hold, err = choose_hold(0.03, profile)
    assert (hold, err) == (80.0, pytest.approx(((100 / 98.8) ** 2 - 1) * 100))
    hold, err = choose_hold(0.03, profile, depth_nm=300.0)
    assert (hold, err) == (5.0, pytest.approx(((300 / 298.8) ** 2 - 1) * 100))
    short = load_profile(str(_profile(tmp_path, 10.0)))
    assert short.drift_segment_s == 10.0
    assert choose_hold(0.03, short)[0] == 5.0  # 0.3 nm of 100 nm: 0.6 %


def test_a_zero_or_negative_segment_is_refused(tmp_path: Path) -> None:
    from core.errors import InputError

    with pytest.raises(InputError, match=r"drift\.segment_s must be > 0"):
        load_profile(str(_profile(tmp_path, 0.0)))


def test_correction_uses_each_indents_depth_and_the_nominal_one_where_none_was_reported() -> None:
    h = drift_corrected_hardness_gpa(
        [5.0, 5.0, 5.0, 5.0],
        [0.2, 0.2, 0.2, 0.2],
        [5.0, 5.0, 5.0, 80.0],
        full_hold_s=80.0,
        depth_nm=[200.0, math.nan, 200.0, 200.0],
        t_measure_s=20.0,
    )
    # 0.2 nm/s × 20 s = 4 nm: 200 nm → (200/196)², unknown depth → nominal (100/96)², an 80 s hold untouched
    assert h.tolist() == pytest.approx(
        [5.0 * (200 / 196) ** 2, 5.0 * (100 / 96) ** 2, 5.0 * (200 / 196) ** 2, 5.0]
    )
    assert typical_depth_nm((math.nan, 150.0, 250.0, -1.0)) == 200.0
    assert typical_depth_nm(()) == 100.0


def test_campaign_corrects_with_the_reported_depth_and_offers_it_to_the_hold_rule(tmp_path: Path) -> None:
    campaign = Campaign(
        CampaignConfig(
            policy="aeni-paper+huber+bias-hold+drift-corr",
            profile=str(_profile(tmp_path, 20.0)),
            lattice_n=20,
        ),
        make_scenario("ternary", 0).sample,
    )
    specs = local_grid(500.0, 500.0, 3, 5.0, 5.0)
    block = Block(0, "global", 500.0, 500.0, 3, 5.0, 5.0, specs)
    results = [
        IndentResult(
            0, i, s.x_um, s.y_um, s.x_um, s.y_um, 5.0, 5.0, 100.0, 0.2, 10.0 * i, depth_at_max_load_nm=250.0
        )
        for i, s in enumerate(specs)
    ]
    campaign._record(block, results)
    assert campaign.centres[-1].value_gpa == pytest.approx(5.0 * (250 / 246) ** 2)
    ctx = campaign.context(1000.0, (500.0, 500.0), True, 1)
    assert ctx.recent_depths_nm == (250.0,) * 9


def test_the_journal_keeps_the_depth_and_null_where_none_was_reported(tmp_path: Path) -> None:
    j = Journal.create(
        tmp_path / "run.sqlite",
        {"name": "j"},
        load_profile("kla-imicro"),
        {"corners": [[0, 0, 0]]},
        supervision="autonomous",
        grid_baseline_s=1.0,
        stage_bounds_um=(0.0, 1000.0, 0.0, 1000.0),
        name="j",
    )
    specs = local_grid(100.0, 100.0, 2, 5.0, 5.0)
    reported = [123.25, None, None]
    for i, depth in enumerate(reported):
        s = specs[i]
        r = (
            IndentResult(
                0,
                i,
                s.x_um,
                s.y_um,
                s.x_um,
                s.y_um,
                5.0,
                5.0,
                100.0,
                0.01,
                1.0 + i,
                depth_at_max_load_nm=depth,
            )
            if i < 2
            else IndentResult.unmeasured(0, i, s, 3.0, "failed", "surface not found")
        )
        j.record_indent(
            r,
            [(StepRecord("indent", 1.0, 0, i), 1.0 + i)],
            DriverState(1.0 + i, 1.0 + i, (0.0, 0.0), True, "x"),
        )
    j.close()
    with JournalReader(tmp_path / "run.sqlite") as reader:
        back = reader.results()
    assert [r.depth_at_max_load_nm for r in back] == reported
    assert back[2].status == "failed"

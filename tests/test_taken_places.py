"""One notion of a taken place: planners and the safety interlock agree, whatever became of the indents.

The real planners (``aeni`` and every reference policy), fed random histories of measured, failed, not-run
and unverified indents on random samples, never propose a block the interlock refuses.
benchmarks/taken_places.py runs the same case 10,000 times.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from benchmarks.taken_places import run_case
from core.interlock import Interlock
from core.plan import Block, IndentResult, IndentSpec
from core.policies.registry import policy_names
from core.profile import load_profile
from core.sample import Sample
from core.taken import is_taken, taken_xy_um
from tests.test_interlock import real_looking_sample, samples


@settings(max_examples=250, deadline=None, database=None, suppress_health_check=list(HealthCheck))
@given(
    sample=samples(),
    policy=st.sampled_from(policy_names()),
    seed=st.integers(0, 2**31 - 1),
    fit=st.booleans(),
)
def test_no_planner_proposes_a_block_the_interlock_refuses(
    sample: Sample, policy: str, seed: int, fit: bool
) -> None:
    outcome = run_case(sample, policy, seed, fit)
    assert outcome.refusal is None, f"{policy} proposed a refused block: {outcome.refusal}"


def _result(i: int, x: float, y: float, status: str, actual: bool = True) -> IndentResult:
    nan = math.nan
    ax, ay = (x + 0.3, y - 0.2) if actual else (nan, nan)
    h = 5.0 if status == "measured" else nan
    return IndentResult(0, i, x, y, ax, ay, 80.0, h, 100.0 if h == h else nan, 0.0, 1.0, status)  # type: ignore[arg-type]


def test_measured_failed_and_unverified_indents_take_their_place_and_not_run_ones_do_not() -> None:
    results = [
        _result(0, 10.0, 10.0, "measured"),
        _result(1, 20.0, 10.0, "failed", actual=False),  # no position reported: where it was sent
        _result(2, 30.0, 10.0, "failed"),
        _result(3, 40.0, 10.0, "unverified"),
        _result(4, 50.0, 10.0, "not_run", actual=False),
    ]
    assert [is_taken(r.status) for r in results] == [True, True, True, True, False]
    np.testing.assert_allclose(taken_xy_um(results), [[10.3, 9.8], [20.0, 10.0], [30.3, 9.8], [40.3, 9.8]])
    with pytest.raises(ValueError, match="unknown indent status"):
        is_taken("skipped")


def test_a_failed_indent_keeps_the_planner_and_the_interlock_off_its_spot() -> None:
    """The stall of issue 23: a failed indent's spot was offered again by the planner, refused by the interlock."""
    from core.campaign import Campaign
    from core.campaign_config import CampaignConfig

    sample = real_looking_sample()
    campaign = Campaign(CampaignConfig(policy="aeni", seed=1, sample=sample))
    lock = Interlock(sample, load_profile(sample.profile))
    first = campaign.propose(0.0, campaign.start_position_um(), False, 0)
    assert first is not None
    block = first.block
    results = [
        IndentResult.unmeasured(0, i, s, 10.0 * i, "failed", "invalid value 1.797e308")
        for i, s in enumerate(block.indents)
    ]
    lock.passed(block, results)
    campaign.observe_block(block, results)
    taken = {(s.x_um, s.y_um) for s in block.indents}
    last = block.indents[-1]
    second = campaign.propose(1000.0, (last.x_um, last.y_um), True, 1)
    assert second is not None
    assert not taken & {(s.x_um, s.y_um) for s in second.block.indents}
    assert lock.check(second.block, (last.x_um, last.y_um), True) is None


def test_an_unverified_block_is_taken_by_the_interlock() -> None:
    sample = real_looking_sample()
    lock = Interlock(sample, load_profile(sample.profile))
    spec = IndentSpec(12700.0, 8400.0, 80.0)
    block = Block(0, "global", spec.x_um, spec.y_um, 1, 5.0, 80.0, (spec,))
    lock.passed(block, [_result(0, spec.x_um, spec.y_um, "unverified")])
    again = Block(1, "global", spec.x_um, spec.y_um, 1, 5.0, 80.0, (spec,))
    assert "earlier indent" in (lock.check(again, (spec.x_um, spec.y_um), True) or "")
    lock2 = Interlock(sample, load_profile(sample.profile))
    lock2.passed(block, [_result(0, spec.x_um, spec.y_um, "not_run", actual=False)])
    assert lock2.check(again, (spec.x_um, spec.y_um), True) is None

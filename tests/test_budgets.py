"""Budgets are budgets: a run never passes its indent or time budget, and its stop reason says how it ended."""

from __future__ import annotations

import pytest

from core.campaign import Campaign
from core.campaign_config import CampaignConfig
from core.plan import PlannerSettings
from core.run.headless import run_auto
from drivers.registry import default_sample, make_driver

OPTIONS = {"scenario": "ternary"}


def _run(policy: str, **budgets: float) -> tuple[int, float, str]:
    config = CampaignConfig(
        policy=policy,
        settings=PlannerSettings(**budgets),  # type: ignore[arg-type]
        sample=default_sample("sim", OPTIONS, 0),
        driver_options=dict(OPTIONS),
    )
    campaign = Campaign(config)
    result = run_auto(campaign, make_driver("sim", campaign.sample, campaign.profile, OPTIONS))
    return result.indents, result.instrument_s, result.stop_reason


@pytest.mark.parametrize("policy", ["cost-aware", "grid"])
@pytest.mark.parametrize("indent_budget", [1, 24, 60])
def test_indent_budget_is_never_exceeded(policy: str, indent_budget: int) -> None:
    indents, _, reason = _run(policy, indent_budget=indent_budget)
    assert indents == indent_budget  # sized to the budget exactly: 60 was 75 before (issue 15)
    assert f"indent budget reached ({indent_budget} of {indent_budget} indents)" in reason
    if indent_budget % 25:
        assert f"cut to {indent_budget % 25} of its 25 indents" in reason


@pytest.mark.parametrize("budget_s", [1_000.0, 9_000.0, 20_000.0])
def test_time_budget_is_never_exceeded(budget_s: float) -> None:
    indents, instrument_s, reason = _run("cost-aware", budget_s=budget_s)
    assert instrument_s <= budget_s  # the comeback to the lens included
    assert indents >= 1
    assert "not enough for one more indent" in reason and "cut to" in reason


def test_a_budget_too_small_for_one_indent_stops_before_any() -> None:
    indents, instrument_s, reason = _run("cost-aware", budget_s=400.0)
    assert indents == 0 and instrument_s == 0.0
    assert "not enough for one more indent" in reason and "400 s" in reason


def test_both_budgets_the_tighter_wins() -> None:
    indents, instrument_s, _ = _run("cost-aware", budget_s=9_000.0, indent_budget=40)
    assert indents <= 40 and instrument_s <= 9_000.0


def test_the_default_horizon_lets_the_grid_baseline_run_all_its_indents() -> None:
    """With no budget set, the horizon is the grid baseline's time: the grid itself must not be cut short."""
    indents, instrument_s, reason = _run("grid")
    assert indents == 2025  # SPEC §3: 9×9 blocks of 5×5
    assert instrument_s == pytest.approx(286_392, rel=0.002)  # SPEC §3, from the sample's centre
    assert "nothing left to propose" in reason


def test_single_indents_that_use_up_the_lattice_say_so() -> None:
    """A run of single indents ends when no candidate is left; its reason says the lattice ran out (the
    bench's stripe seed that stopped 1 % short of its target said only "nothing left to propose")."""
    config = CampaignConfig(
        policy="aeni", lattice_n=10, sample=default_sample("sim", OPTIONS, 0), driver_options=dict(OPTIONS)
    )
    campaign = Campaign(config)
    result = run_auto(campaign, make_driver("sim", campaign.sample, campaign.profile, OPTIONS))
    assert result.stop_reason == (
        "policy aeni has nothing left to propose: every candidate of the 10×10 lattice is indented, excluded or"
        " too near an indent"
    )
    assert 0 < result.indents <= 100

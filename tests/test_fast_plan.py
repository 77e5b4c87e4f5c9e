"""Fast arrays in the plan (issue 36): priced as the fast mode says, safe by the interlock's rules, learnt
only by the two-fidelity model, journaled with their channel, and chosen only where they buy more per second."""

from __future__ import annotations

import dataclasses
import functools
import math
import sqlite3
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from aeni_console.cli.main import main as cli_main
from core.campaign import Campaign
from core.campaign_config import CampaignConfig
from core.cost import block_costs_for, block_steps
from core.fast_array import FastArray, fast_block, fast_block_cost_s, price_fast_array
from core.fidelity import TwoFidelityView
from core.interlock import Interlock
from core.journal import DriverState, Journal, JournalReader
from core.journal.schema import SCHEMA_SQL, SCHEMA_VERSION
from core.plan import Block, Decision, IndentResult, IndentSpec, PlannerSettings
from core.policies.fidelity import FastArrays, PriorFidelityView, TwoFidelityPlanner, candidate_arrays
from core.profile import load_profile
from core.sample import Sample
from drivers.sim.scenarios import make_scenario
from tests.test_interlock import samples, violations

PROFILE = load_profile("kla-imicro")


@pytest.mark.parametrize("profile", ["kla-imicro", "kla-imicro-film"])
@pytest.mark.parametrize("program_open", [False, True])
def test_a_fast_block_runs_in_the_seconds_its_array_is_priced_at(profile: str, program_open: bool) -> None:
    p = load_profile(profile)
    array = FastArray(500.0, 500.0, 10, 20, 10.0)
    steps = block_steps(p, fast_block(3, array), (0.0, 0.0), program_open)
    assert sum(s.seconds for s in steps) == pytest.approx(
        price_fast_array(p, array, (0.0, 0.0), program_open).total_s
    )
    # one indent step per fast indent (the ledger counts them), one column change per new column
    assert sum(s.category == "indent" for s in steps) == 200
    block = fast_block(3, array)
    assert fast_block_cost_s(p, block, (0.0, 0.0), program_open) == pytest.approx(
        sum(s.seconds for s in steps)
    )
    assert sum(s.seconds == p.fast.column_change_s for s in steps if s.indent_index > 0) == 19  # type: ignore[union-attr]


def _ctx_sample_campaign(sample: Sample) -> Campaign:
    config = CampaignConfig(policy="aeni+fast", seed=0, lattice_n=10, settings=PlannerSettings(budget_s=1e6))
    return Campaign(config, sample)


@settings(max_examples=10, deadline=None, database=None, suppress_health_check=list(HealthCheck))
@given(sample=samples(), seed=st.integers(0, 2**16))
def test_every_fast_array_the_planner_may_propose_passes_the_interlock(sample: Sample, seed: int) -> None:
    """Every candidate array (its kept sites): inside the sample off its edge band and exclusions, r_excl from
    earlier indents, in the safe band of its centre, no hop ≥ the safety threshold without a reconfiguration:
    the interlock lets each through, and each breaks none of its rules."""
    campaign = _ctx_sample_campaign(sample)
    rng = np.random.default_rng(seed)
    x0, x1, y0, y1 = sample.calibration.bounds_um
    position = (float(rng.uniform(x0, x1)), float(rng.uniform(y0, y1)))
    ctx = campaign.context(0.0, position, bool(rng.random() < 0.5), 0)
    lock = Interlock(sample, campaign.profile)
    arrays = candidate_arrays(ctx, FastArrays())
    for k in rng.permutation(len(arrays))[:25]:  # a large sample tiles into hundreds: 25 of them, at random
        array, keep = arrays[k]
        block = fast_block(0, array, keep)
        assert lock.check(block, position, ctx.program_open) is None
        assert (
            violations(sample, campaign.profile, block, position, sample.earlier_xy_um, None, tol=1e-5) == []
        )
        assert max(array.extent_um) < campaign.profile.reconfig_threshold_um


def _measured(block_id: int, xy: np.ndarray, h: np.ndarray, channel: str = "csm") -> list[IndentResult]:
    return [
        IndentResult(block_id, i, x, y, x, y, 0.0 if channel == "fast" else 80.0, float(v), 150.0, 0.01, 0.0,
                     channel=channel)  # type: ignore[arg-type]
        for i, ((x, y), v) in enumerate(zip(xy, h, strict=True))
    ]  # fmt: skip


@functools.cache
def _after_one_array(offset_gpa: float, faithful: bool) -> Campaign:
    """A ternary campaign after 40 CSM singles and one 19 × 19 fast array that reads the CSM map less
    ``offset_gpa`` (``faithful``) or a field unrelated to it (a misleading channel)."""
    sc = make_scenario("ternary", 0)
    campaign = Campaign(CampaignConfig(policy="aeni+fast", seed=0, lattice_n=20), sc.sample)
    rng = np.random.default_rng(0)
    truth = sc.truth
    xy = rng.uniform(50, 950, (30, 2))
    csm = _measured(0, xy, truth.hardness_gpa(xy[:, 0], xy[:, 1]) + rng.normal(0, 0.03, 30))
    b0 = Block(0, "global", 500.0, 500.0, 1, 5.0, 80.0, tuple(IndentSpec(x, y, 80.0) for x, y in xy))
    campaign.observe_block(b0, csm)
    assert campaign.fast is not None and not campaign.fast.active
    array = FastArray(505.0, 505.0, 11, 11, 80.0)
    fb = fast_block(1, array)
    sites = np.array([(s.x_um, s.y_um) for s in fb.indents])
    read = truth.hardness_gpa(sites[:, 0], sites[:, 1]) - offset_gpa
    if not faithful:
        read = 5.0 + 1.5 * np.sin(sites[:, 0] / 90.0) * np.cos(sites[:, 1] / 70.0)
    fast = _measured(1, sites, read + rng.normal(0, 0.06, len(sites)), "fast")
    campaign.observe_block(fb, fast)
    assert len(campaign.centres) == 30 and campaign.fast.n == len(sites)
    return campaign


def test_fast_indents_teach_only_the_two_fidelity_model_and_the_bias_is_learnt() -> None:
    """A fast array's readings never become CSM centres; with enough of them the map is the two-fidelity one,
    and its learnt bias is what the fast channel reads off the CSM values (here a constant 1 GPa)."""
    campaign = _after_one_array(1.0, faithful=True)
    assert campaign.fast is not None
    assert campaign.fast.active
    uv = campaign.lattice.uv
    bias = campaign.fast.bias_gpa(uv)
    assert abs(float(np.median(bias)) - 1.0) < 0.15
    # the planner's context carries the model's view; after the fast data a CSM value is worth less
    ctx = campaign.context(10_000.0, (500.0, 500.0), False, 2)
    assert ctx.fidelity is not None and ctx.fidelity.mode == "two-fidelity"
    # the array takes its places, but the design's rules count the CSM indents and programs alone
    assert len(ctx.indents_xy_um) == 30 + campaign.fast.n and len(ctx.learnt_xy_um) == 30
    assert ctx.globals_done == 1


def _rates(campaign: Campaign) -> tuple[float, float]:
    """(the CSM block's, the best fast array's) reduction of the CSM map's weighted error per second."""
    policy = campaign.policy
    assert isinstance(policy, TwoFidelityPlanner)
    ctx = campaign.context(10_000.0, (500.0, 500.0), False, 2)
    assert ctx.prediction is not None and campaign.fast is not None
    # the model's own what-ifs, whichever map the held-out values keep
    ctx = dataclasses.replace(ctx, fidelity=TwoFidelityView(campaign.fast.model))
    assert ctx.fidelity is not None
    # a CSM block of 16 singles spread over the sample (the design's own would be placed better still)
    xy = np.random.default_rng(2).uniform(100, 900, (16, 2))
    sites = tuple(IndentSpec(float(x), float(y), 80.0) for x, y in xy)
    block = Block(2, "global", float(xy[0, 0]), float(xy[0, 1]), 1, 5.0, 80.0, sites)
    csm = Decision(
        block, policy.name, 0.0, 0.0, block_costs_for(campaign.profile, block, (500.0, 500.0), False)
    )
    ref, w = policy.inner.ivr.weights(ctx, ctx.prediction)
    w = w / w.mean()
    now = ctx.fidelity.variance(ref)
    csm_rate = policy.csm_gain(ctx, ctx.fidelity, csm, ref, w, now) / csm.predicted_cost_s
    best = policy.best_array(ctx, ctx.fidelity, ref, w, now)
    assert best is not None
    return csm_rate, best.rate


def test_a_misleading_fast_channel_makes_another_array_worth_less_than_csm_indents() -> None:
    """The same array read from a channel unrelated to the CSM map (its bias jumps everywhere): the model
    learns that, and another array is worth less than half as much against CSM indents, per second, as after
    a faithful channel: the evidence moves the plan toward CSM indents."""
    csm_faithful, fast_faithful = _rates(_after_one_array(1.0, faithful=True))
    csm_misled, fast_misled = _rates(_after_one_array(1.0, faithful=False))
    assert fast_misled / csm_misled < 0.5 * fast_faithful / csm_faithful
    # and the held-out CSM values catch it first: the misleading channel's map does not beat the CSM-only
    # GP's on them, so the run keeps the CSM-only map and buys no array; the faithful one's does
    misled, faithful = _after_one_array(1.0, faithful=False).fast, _after_one_array(1.0, faithful=True).fast
    assert misled is not None and faithful is not None
    assert misled.fitted and not misled.active and faithful.active


def test_before_any_fast_data_a_cheap_fast_mode_wins_and_a_dear_one_loses() -> None:
    """The prior view prices a first array: a fast mode ten times cheaper per indent and set-up-free is chosen
    over the CSM block; one ten times dearer never is. No 'fast first' rule: the cost model decides."""
    sc = make_scenario("ternary", 0)
    rng = np.random.default_rng(1)
    xy = rng.uniform(50, 950, (70, 2))
    h = sc.truth.hardness_gpa(xy[:, 0], xy[:, 1]) + rng.normal(0, 0.03, 70)
    # dear: about a CSM indent's time, with more noise and an unknown bias (never worth it)
    block = Block(0, "global", 500.0, 500.0, 1, 5.0, 80.0, tuple(IndentSpec(x, y, 80.0) for x, y in xy))
    chosen = {}
    for name, indent_s, setup in (("cheap", 0.1, False), ("dear", 120.0, True)):
        fast = dataclasses.replace(PROFILE.fast, indent_s=indent_s, surface_find=setup, drift_settle=setup)  # type: ignore[type-var]
        campaign = Campaign(CampaignConfig(policy="aeni+fast", seed=0, lattice_n=20), sc.sample)
        campaign.profile = dataclasses.replace(campaign.profile, fast=fast)
        campaign.observe_block(block, _measured(0, xy, h))
        ctx = campaign.context(10_000.0, (500.0, 500.0), False, 1)
        assert ctx.fidelity is None and isinstance(PriorFidelityView(ctx, FastArrays()), PriorFidelityView)
        decision = campaign.policy.propose(ctx)
        assert decision is not None
        chosen[name] = decision.block.channel
    assert chosen == {"cheap": "fast", "dear": "csm"}


def test_the_journal_keeps_each_indents_channel_and_reads_older_journals_as_csm(tmp_path: Path) -> None:
    path = tmp_path / "j.sqlite"
    journal = Journal.create(
        path, {"name": "j", "policy": "aeni+fast"}, PROFILE, {"corners": [[0, 0, 0]]}, supervision="auto",
        grid_baseline_s=1.0, stage_bounds_um=(0.0, 1000.0, 0.0, 1000.0), name="j",
    )  # fmt: skip
    fb = fast_block(0, FastArray(500.0, 500.0, 2, 2, 50.0))
    state = DriverState(9.0, 9.0, (0.0, 0.0), True, "indent")
    with journal as j:
        j.record_indent(_measured(0, np.array([[475.0, 475.0]]), np.array([4.0]), "fast")[0], [], state)
        failed = IndentResult.unmeasured(0, 1, fb.indents[1], 9.0, "failed", "no curve", "fast")
        j.record_indent(failed, [], state)
    got = JournalReader(path).results()
    assert [(r.channel, r.status) for r in got] == [("fast", "measured"), ("fast", "failed")]
    assert math.isnan(got[1].hardness_gpa)
    # a journal of schema 5 (no channel column) opens read-only as all CSM, and a resume migrates it
    conn = sqlite3.connect(path)
    conn.executescript("ALTER TABLE indents DROP COLUMN channel; UPDATE schema_version SET version = 5;")
    conn.close()
    assert [r.channel for r in JournalReader(path).results()] == ["csm", "csm"]
    with Journal.open_writer(path):
        pass
    conn = sqlite3.connect(path)
    assert conn.execute("SELECT version FROM schema_version").fetchone()[0] == SCHEMA_VERSION
    assert (
        "channel" in SCHEMA_SQL
        and conn.execute("SELECT COUNT(*) FROM indents WHERE channel = 'csm'").fetchone()[0] == 2
    )
    conn.close()


def test_fast_on_with_a_profile_without_a_fast_mode_is_one_line_and_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    lab = tmp_path / "lab.toml"
    lab.write_text('extends = "kla-imicro"\nname = "lab"\n[fast]\navailable = false\n', encoding="utf-8")
    assert cli_main(["simulate", "--fast", "on", "--profile", str(lab), "--budget-s", "3000", "--json"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "aeni: error: --fast: profile lab has no fast mode (no [fast] section)"


def test_the_simulated_instrument_reads_a_fast_array_from_its_fast_channel() -> None:
    """Each site read once, as the fast channel reads it (a failed one recorded as failed, never a number),
    on the instrument clock the array is priced at; the same array reads the same again (a resume)."""
    sc = make_scenario("ternary", 3)
    array = FastArray(500.0, 500.0, 12, 12, 20.0)
    block = fast_block(5, array)

    def run() -> tuple[list[IndentResult], float]:
        driver = sc.make_driver(PROFILE, start_um=(0.0, 0.0))
        got = [e for e in driver.execute_block(block) if isinstance(e, IndentResult)]
        return got, driver.clock_s()

    results, clock = run()
    assert clock == pytest.approx(price_fast_array(PROFILE, array, (0.0, 0.0), False).total_s)
    assert len(results) == 144 and {r.channel for r in results} == {"fast"}
    measured = [r for r in results if r.measured]
    assert all(math.isfinite(r.hardness_gpa) and r.hold_s == 0.0 for r in measured)
    assert all(math.isnan(r.hardness_gpa) for r in results if not r.measured)
    # a fast indent reads the CSM map through its size effect and scatter, not as a CSM indent would
    truth = np.array([float(sc.truth.hardness_gpa(r.actual_x_um, r.actual_y_um)) for r in measured])
    read = np.array([r.hardness_gpa for r in measured])
    assert np.corrcoef(truth, read)[0, 1] > 0.5 and not np.allclose(truth, read, rtol=0.02)
    again, _ = run()
    assert [r.hardness_gpa for r in again if r.measured] == [r.hardness_gpa for r in measured]

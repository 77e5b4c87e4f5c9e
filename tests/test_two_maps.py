"""Hardness and modulus mapped together (issue 27): the modulus GP, map_weights in the planner, resume."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from core.campaign import Campaign
from core.campaign_config import CampaignConfig
from core.plan import IndentResult, MapWeights, PlannerSettings
from core.policies.acquisition import IntegratedVarianceReduction, LatticeSubset
from core.policies.base import ModulusView
from core.policies.greedy import GreedyIvr
from core.policies.variance import design_rel_error
from core.runview import Command, CommandKind
from drivers.sim.scenarios import make_scenario


def _campaign(weights: MapWeights, seed: int = 2, policy: str = "aeni") -> Campaign:
    settings = PlannerSettings(budget_s=60_000.0, map_weights=weights)
    return Campaign(
        CampaignConfig(policy=policy, seed=seed, lattice_n=30, settings=settings),
        make_scenario("ternary", seed).sample,
    )


def _run_blocks(c: Campaign, n_blocks: int) -> list[tuple[object, list[IndentResult]]]:
    """``n_blocks`` blocks of the campaign on the simulated ternary library; the blocks and what they measured."""
    driver = make_scenario("ternary", c.config.seed).make_driver(c.profile)
    done = []
    for block_id in range(n_blocks):
        d = c.propose(driver.clock_s(), driver.position_um(), driver.program_open(), block_id)
        assert d is not None
        results = [e for e in driver.execute_block(d.block) if isinstance(e, IndentResult)]
        c.observe_block(d.block, results)
        done.append((d.block, results))
    return done


def test_both_maps_learn_from_the_same_indents_and_failed_values_stay_out_of_both() -> None:
    c = _campaign(MapWeights(1.0, 1.0))
    done = _run_blocks(c, 3)
    assert c.modulus_map.prediction is not None and c.prediction is not None
    assert c.modulus_map.n == len(c.centres) > 10
    # the modulus map's centres are the hardness map's, each with its own robust value
    assert np.allclose(c.modulus_map.xy_um(), [(r.x_um, r.y_um) for r in c.centres])
    # ternary moduli are 110–215 GPa, hardnesses 3–7: the two GPs learn their own scales
    assert 100.0 < float(np.median(c.modulus_map.prediction.mean)) < 220.0
    assert 2.0 < float(np.median(c.prediction.mean)) < 8.0
    # a failed indent, and a measured one whose modulus the instrument did not report, add nothing to E
    block, results = done[-1]
    r0 = results[0]
    failed = dataclasses.replace(
        r0, block_id=99, indent_index=0, status="failed", hardness_gpa=math.nan, modulus_gpa=math.nan
    )
    no_e = dataclasses.replace(
        r0, block_id=99, indent_index=1, actual_x_um=r0.actual_x_um + 30, modulus_gpa=math.nan
    )
    with_e = dataclasses.replace(r0, block_id=99, indent_index=2, actual_x_um=r0.actual_x_um + 60)
    n_h, n_e = len(c.centres), c.modulus_map.n
    c.observe_block(dataclasses.replace(block, block_id=99), [failed, no_e, with_e])
    assert len(c.centres) == n_h + 2  # the failed one is in neither
    assert c.modulus_map.n == n_e + 1  # the one without a modulus is in the hardness map only
    assert c.modulus_map.centres[-1].value_gpa == pytest.approx(with_e.modulus_gpa)


def test_the_planner_weighs_what_each_pick_takes_off_the_sum_of_the_maps_errors() -> None:
    """With both weights a candidate's gain is Σ weight · (√V − √(V − reduction)) over the maps, V each
    map's mean relative error variance (what a pick takes off the sum of the maps' RMS relative errors);
    the V the greedy picks use up is what the design has left."""
    c = _campaign(MapWeights(1.0, 1.0))
    _run_blocks(c, 4)
    ctx = c.context(0.0, c.start_position_um(), False, 5)
    assert ctx.modulus is not None and ctx.gp is not None and ctx.prediction is not None
    cand = np.flatnonzero(c.placement_mask)[::7]

    even = IntegratedVarianceReduction(LatticeSubset())

    def ivr(w_h: float, w_e: float, modulus: ModulusView | None = None) -> GreedyIvr:
        view = dataclasses.replace(modulus or ctx.modulus, weight_hardness=w_h, weight_modulus=w_e)
        return GreedyIvr(dataclasses.replace(ctx, modulus=view), cand, even)

    hardness_only = GreedyIvr(dataclasses.replace(ctx, modulus=None), cand, even).gains()
    assert np.array_equal(ivr(1.0, 0.0).gains(), hardness_only)  # a weight of 0 drops the modulus
    modulus_only = ivr(0.0, 1.0).gains()
    both = ivr(1.0, 1.0)
    v_h, v_e = both.remaining

    def off(v: float, reduction: np.ndarray) -> np.ndarray:
        return np.sqrt(v) - np.sqrt(v - reduction)

    assert np.allclose(both.gains(), off(v_h, hardness_only) + off(v_e, modulus_only))
    assert np.allclose(ivr(2.0, 0.5).gains(), 2.0 * off(v_h, hardness_only) + 0.5 * off(v_e, modulus_only))
    # relative: a modulus map with twice the error everywhere (noise and prior) counts twice as much
    m = ctx.modulus
    noisier = dataclasses.replace(
        m,
        prediction=dataclasses.replace(m.prediction, noise_sd=2.0 * m.prediction.noise_sd),
        gp=dataclasses.replace(
            m.gp, outputscale_gpa2=4.0 * m.gp.outputscale_gpa2, site_var_gpa2=4.0 * m.gp.site_var_gpa2
        ),
        tested_noise_var_gpa2=4.0 * m.tested_noise_var_gpa2,
    )
    assert np.allclose(ivr(1.0, 1.0, noisier).gains(), off(v_h, hardness_only) + 2.0 * off(v_e, modulus_only))
    # the V a pick leaves is the error variance of the design with that pick added (y-free), per map
    j = int(np.argmax(both.gains()))
    before = both.gains()[j]
    both.take(j)
    assert both.gains()[j] < 0.5 * before
    n = c.lattice.n
    step = max(1, n // LatticeSubset().n)
    rows = np.arange(step // 2, n, step)
    ref = (rows[:, None] * n + rows[None, :]).ravel()
    for (gp, pred, xy, nv), left in zip(
        (
            (ctx.gp, ctx.prediction, ctx.tested_xy_um, ctx.tested_noise_var_gpa2),
            (m.gp, m.prediction, m.tested_xy_um, m.tested_noise_var_gpa2),
        ),
        both.remaining,
        strict=True,
    ):
        u, v = c.calibration.to_uv(xy[:, 0], xy[:, 1])
        design = np.vstack([np.column_stack([u, v]), c.lattice.uv[cand[j]]])
        noise = np.append(nv, pred.noise_sd[cand[j]] ** 2 + gp.site_var_gpa2)
        mu = np.maximum(np.abs(pred.mean[ref]), 1e-6)
        rms = design_rel_error(gp, design, noise, c.lattice.uv[ref], mu)
        assert left == pytest.approx(rms**2 / float(np.mean(1.0 / mu**2)), rel=1e-6)


def test_hardness_only_keeps_no_modulus_model_and_decides_as_before() -> None:
    c = _campaign(MapWeights(1.0, 0.0))
    _run_blocks(c, 3)
    assert c.modulus_map.prediction is None  # never fitted for planning
    assert c.context(0.0, c.start_position_um(), False, 4).modulus is None
    assert "modulus" not in c.export_state()
    # asked for (a score, a report), it is fitted once from the same indents
    assert c.has_modulus_map() and c.modulus_map.prediction is not None


def test_a_resumed_two_map_run_decides_what_the_uninterrupted_one_would() -> None:
    c = _campaign(MapWeights(1.0, 1.0), seed=5)
    done = _run_blocks(c, 4)
    state = c.export_state()
    assert state["modulus"]["gp"] is not None
    resumed = _campaign(MapWeights(1.0, 1.0), seed=5)
    resumed.restore(state, done)
    a = c.propose(1000.0, c.start_position_um(), False, 4)
    b = resumed.propose(1000.0, resumed.start_position_um(), False, 4)
    assert a is not None and b is not None
    assert a.block == b.block and a.score == b.score


def test_the_console_cycles_through_both_maps_and_the_journal_keeps_them() -> None:
    """The map fields carry the modulus mean and sd where the run learns the modulus map; `m` then cycles on
    to them and H/E; the journal's codec keeps them; a hardness-only run's fields are as before."""
    from aeni_console.console.heatmap import HARDNESS_KEYS, MODULUS_KEYS, field_array, field_keys_of
    from core.journal.codec import map_fields_from_bytes, map_fields_to_bytes

    c = _campaign(MapWeights(1.0, 1.0))
    _run_blocks(c, 3)
    fields = c.map_fields(7, display_n=20)
    assert fields.modulus_mean_gpa is not None and fields.modulus_sd_gpa is not None
    assert fields.bias_gpa is None  # a CSM-only run has no fast channel's bias to cycle to
    assert field_keys_of(fields) == HARDNESS_KEYS + MODULUS_KEYS
    e = field_array(fields, "modulus")
    ratio = field_array(fields, "h_over_e")
    assert np.nanmin(e) > 90.0 and np.allclose(
        ratio, fields.mean_gpa / fields.modulus_mean_gpa, equal_nan=True
    )
    assert np.nanmin(ratio) > 0.01 and np.nanmax(ratio) < 0.08
    back = map_fields_from_bytes(7, map_fields_to_bytes(fields))
    assert np.array_equal(back.modulus_mean_gpa, fields.modulus_mean_gpa, equal_nan=True)
    assert np.array_equal(back.modulus_sd_gpa, fields.modulus_sd_gpa, equal_nan=True)

    h = _campaign(MapWeights(1.0, 0.0))
    _run_blocks(h, 2)
    plain = h.map_fields(3, display_n=20)
    assert plain.modulus_mean_gpa is None and field_keys_of(plain) == HARDNESS_KEYS
    assert map_fields_from_bytes(3, map_fields_to_bytes(plain)).modulus_mean_gpa is None
    assert np.isnan(field_array(plain, "h_over_e")).all()


async def test_a_modulus_collapse_alarm_reaches_the_console_and_waits(tmp_path: Path) -> None:
    """A run aiming at both maps, whose modulus GP's guard trips (its length-scale floor raised above any
    length-scale it can fit): the engine raises the collapse alarm naming the modulus map, the next block
    waits for the operator in supervised mode, and the console shows the alarm (the hardness map is healthy)."""
    from aeni_console.console.app import ConsoleApp
    from aeni_console.testkit.live import LiveRun, settle, widget_text
    from core.model.guard import CollapseRule

    def strict_modulus_guard(c: Campaign) -> None:
        gp = c.modulus_map.surrogate
        gp.collapse_rule = CollapseRule(10.0, gp.collapse_rule.drop_ratio, gp.collapse_rule.min_points)

    with LiveRun(
        tmp_path,
        supervision="supervised",
        settings=PlannerSettings(map_weights=MapWeights(1.0, 1.0)),
        prepare=strict_modulus_guard,
    ) as run:
        snap = run.until_awaiting()  # the first (global) block
        for _ in range(4):  # a map needs two centres: the alarm comes with the first refit
            if snap.gp.collapse_alarm:
                break
            run.send(Command(CommandKind.APPROVE, author="tester"))
            snap = run.until_awaiting()
        assert snap.gp.collapse_alarm and snap.gp.collapse_reason.startswith("modulus map: length-scale")
        assert (
            snap.pending is not None
        )  # the proposal after the alarm waits, though it is a local block or not
        source = run.source()
        app = ConsoleApp(source, poll_s=0.02, max_rate_hz=50.0, clock=lambda: 0.0, author="tester")
        try:
            async with app.run_test(size=(100, 30)) as pilot:
                await settle(pilot)
                assert "COLLAPSE" in widget_text(app.query_one("#status"))
                decision = app.query_one("#decision")
                assert decision.has_class("-alarm") and "modulus map" in widget_text(decision)
        finally:
            source.close()


def test_two_maps_median_counts_a_seed_that_never_reached_below_the_others() -> None:
    """A seed that never reaches a map's target within the cap is the slowest, not left out of the median."""
    from benchmarks.two_maps import _median_missing_low

    assert _median_missing_low([13.1, 8.1, 9.4, None, 7.1, 13.4, 11.5, 5.6, 13.6, 7.3]) == (8.1 + 9.4) / 2
    assert _median_missing_low([3.0, 1.0, 2.0]) == 2.0
    assert _median_missing_low([5.0, None, None]) is None  # the median seed never got there
    assert _median_missing_low([None]) is None

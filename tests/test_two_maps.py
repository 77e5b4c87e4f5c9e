"""Hardness and modulus mapped together (issue 27): the modulus GP, map_weights in the planner, resume."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from core.campaign import Campaign, CampaignConfig
from core.plan import IndentResult, MapWeights, PlannerSettings
from core.policies.scattered import _Ivr
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


def test_the_planner_weighs_both_maps_relative_errors() -> None:
    """With both weights the IVR gain of a candidate is the weighted sum of each map's own gain."""
    c = _campaign(MapWeights(1.0, 1.0))
    _run_blocks(c, 4)
    ctx = c.context(0.0, c.start_position_um(), False, 5)
    assert ctx.modulus is not None and ctx.gp is not None
    cand = np.flatnonzero(c.placement_mask)[::7]

    def gains(w_h: float, w_e: float) -> np.ndarray:
        view = dataclasses.replace(ctx.modulus, weight_hardness=w_h, weight_modulus=w_e)
        return _Ivr(dataclasses.replace(ctx, modulus=view), cand, 1.0).gains()

    hardness_only = _Ivr(dataclasses.replace(ctx, modulus=None), cand, 1.0).gains()
    assert np.array_equal(gains(1.0, 0.0), hardness_only)  # a weight of 0 drops the modulus
    modulus_only = gains(0.0, 1.0)
    # together, each map's gain counts as a reduction of its mean relative error variance: GPa² over μ²
    both = _Ivr(ctx, cand, 1.0)
    (s_h, _, _), (s_e, _, _) = both.parts
    assert np.allclose(gains(1.0, 1.0), s_h * hardness_only + s_e * modulus_only)
    assert np.allclose(gains(2.0, 0.5), 2.0 * s_h * hardness_only + 0.5 * s_e * modulus_only)
    mu_h, mu_e = np.median(ctx.prediction.mean), np.median(ctx.modulus.prediction.mean)
    assert s_h == pytest.approx(1.0 / mu_h**2, rel=0.5) and s_e == pytest.approx(1.0 / mu_e**2, rel=0.5)
    # on the relative scale neither map swamps the other (in GPa² the modulus would, ~1000×)
    ratio = float(np.max(s_e * modulus_only) / np.max(s_h * hardness_only))
    assert 0.05 < ratio < 20.0
    # and conditioning on a pick lowers both maps' gains there
    value = _Ivr(ctx, cand, 1.0)
    j = int(np.argmax(value.gains()))
    before = value.gains()[j]
    value.take(j)
    assert value.gains()[j] < 0.5 * before


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
    from aeni_console.heatmap import FIELD_KEYS, HARDNESS_KEYS, field_array, field_keys_of
    from core.journal.codec import map_fields_from_bytes, map_fields_to_bytes

    c = _campaign(MapWeights(1.0, 1.0))
    _run_blocks(c, 3)
    fields = c.map_fields(7, display_n=20)
    assert fields.modulus_mean_gpa is not None and fields.modulus_sd_gpa is not None
    assert field_keys_of(fields) == FIELD_KEYS
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

"""The acquisition layer as objects over the posterior: wrappers compose, recipes hold them, one IVR."""

from __future__ import annotations

import ast
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from core.acquisition import ei, ucb, ue
from core.campaign import Campaign
from core.campaign_config import CampaignConfig
from core.geometry import edge_penalty
from core.model import Prediction
from core.plan import PlannerSettings
from core.policies.acquisition import (
    CellCentres,
    CostWeighted,
    EdgePenalised,
    ExpectedImprovement,
    IntegratedVarianceReduction,
    LatticeSubset,
    UncertaintyExploration,
    UpperConfidenceBound,
    variance_reduction,
)
from core.policies.base import GPSummary, PlanContext
from core.policies.registry import policy_parts
from core.policies.variance import PosteriorCov, nearest_lattice, reference_lattice
from drivers.sim.scenarios import make_scenario

ROOT = Path(__file__).resolve().parents[1]


def _ctx(edge: float = 0.5, beta: float = 4.0) -> PlanContext:
    """A fresh campaign's context on a 20×20 lattice with a made-up posterior (no fit needed)."""
    sc = make_scenario("ternary", 0)
    settings = PlannerSettings(edge_penalty=edge, beta=beta)
    c = Campaign(CampaignConfig(policy="cost-aware", seed=0, lattice_n=20, settings=settings), sc.sample)
    ctx = c.context(0.0, (0.0, 0.0), False, 0)
    rng = np.random.default_rng(3)
    n = len(ctx.lattice.xy_um)
    mean, epi = rng.uniform(3.0, 7.0, n), rng.uniform(0.01, 0.5, n)
    noise = rng.uniform(0.05, 0.2, n)
    pred = Prediction(mean=mean, epistemic_sd=epi, noise_sd=noise, total_sd=np.hypot(epi, noise))
    tested = ctx.lattice.xy_um[[0, 57, 210, 399]]
    return replace(
        ctx,
        prediction=pred,
        best_observed_gpa=6.5,
        gp=GPSummary("matern52", (0.3, 0.25), 1.2, 0.01),
        tested_xy_um=tested,
        tested_noise_var_gpa2=np.full(4, 0.02),
    )


def test_marginal_acquisitions_read_the_posterior() -> None:
    ctx = _ctx()
    pred = ctx.prediction
    assert pred is not None
    np.testing.assert_array_equal(UncertaintyExploration().values(ctx), ue(pred))
    u = UpperConfidenceBound().values(ctx)
    np.testing.assert_allclose(u, ucb(pred, 4.0) - np.min(ucb(pred, 4.0)) + 1e-9)
    assert u.min() > 0
    np.testing.assert_allclose(ExpectedImprovement().values(ctx), ei(pred, 6.5) + 1e-12)
    for acq in (UncertaintyExploration(), UpperConfidenceBound(), ExpectedImprovement()):
        assert not acq.cost_weighted and not acq.needs_covariance
        v = acq.values(ctx)
        np.testing.assert_array_equal(acq.utility(v, np.full(len(v), 7.0)), v)  # cost ignored


def test_cost_and_the_edge_penalty_are_wrappers() -> None:
    ctx = _ctx(edge=0.5)
    base = UncertaintyExploration()
    edged = EdgePenalised(base)
    np.testing.assert_array_equal(
        edged.values(ctx), base.values(ctx) * edge_penalty(ctx.lattice.uv, strength=0.5)
    )
    np.testing.assert_array_equal(EdgePenalised(base).values(_ctx(edge=0.0)), base.values(ctx))
    paper = CostWeighted(edged)
    assert paper.cost_weighted and not edged.cost_weighted
    cost = np.linspace(100.0, 900.0, len(ctx.lattice.xy_um))
    np.testing.assert_array_equal(paper.utility(paper.values(ctx), cost), edged.values(ctx) / cost)
    # the ranking can flip: a dear candidate with the most σ loses to a cheap one per second
    v = np.array([1.0, 0.6])
    assert int(np.argmax(CostWeighted(base).utility(v, np.array([1000.0, 100.0])))) == 1
    assert variance_reduction(paper) is None


def test_recipes_hold_acquisition_objects() -> None:
    ue_ = UncertaintyExploration()
    assert policy_parts("uncertainty").acquisition == ue_
    assert policy_parts("cost-aware").acquisition == CostWeighted(ue_)
    assert policy_parts("aeni-paper").acquisition == CostWeighted(EdgePenalised(ue_))
    ivr = IntegratedVarianceReduction(CellCentres(12))
    assert policy_parts("aeni-paper+ivr").acquisition == CostWeighted(ivr)
    aeni = policy_parts("aeni").acquisition
    assert aeni == CostWeighted(IntegratedVarianceReduction(LatticeSubset(24), structure_weight=1.0))
    assert policy_parts("aeni+even").acquisition == CostWeighted(
        IntegratedVarianceReduction(LatticeSubset(24))
    )
    assert variance_reduction(aeni) is not None and aeni.needs_covariance
    assert policy_parts("aeni").needs_covariance and not policy_parts("cost-aware").needs_covariance


@pytest.mark.parametrize("structure", [0.0, 1.0])
def test_one_ivr_on_either_reference_set(structure: float) -> None:
    """The grid planner's reference (12×12 cell centres, μ at the nearest candidate) and the singles' (every
    k-th candidate) are one IVR: 1/μ² weights (times the structure weight) on a PosteriorCov."""
    ctx = _ctx()
    pred, gp = ctx.prediction, ctx.gp
    assert pred is not None and gp is not None and ctx.tested_noise_var_gpa2 is not None
    u, v = ctx.calibration.to_uv(ctx.tested_xy_um[:, 0], ctx.tested_xy_um[:, 1])
    train = np.column_stack([u, v])
    cand = np.arange(0, 400, 3)
    ref = reference_lattice(12)
    mu = np.maximum(np.abs(pred.mean[nearest_lattice(ctx.lattice.uv, ref)]), 1e-6)
    cells = IntegratedVarianceReduction(CellCentres(12))
    got = cells.covariance(ctx, pred, gp, ctx.tested_xy_um, ctx.tested_noise_var_gpa2, cand)
    want = PosteriorCov.build(gp, train, ctx.tested_noise_var_gpa2, ctx.lattice.uv[cand], ref, 1.0 / mu**2)
    np.testing.assert_array_equal(got.gain(0.05), want.gain(0.05))
    subset = IntegratedVarianceReduction(LatticeSubset(5), structure_weight=structure)
    ref_uv, w = subset.weights(ctx, pred)
    assert len(ref_uv) == 25 and np.all(w > 0)
    plain = IntegratedVarianceReduction(LatticeSubset(5)).weights(ctx, pred)[1]
    assert np.all(w >= plain) and (structure == 0.0) == bool(np.array_equal(w, plain))
    # y-free: the gain of one indent shrinks where a planned one already measures
    model = subset.covariance(ctx, pred, gp, ctx.tested_xy_um, ctx.tested_noise_var_gpa2, cand)
    j = int(np.argmax(model.gain(0.05)))
    assert model.condition_on(j, 0.05).gain(0.05)[j] < model.gain(0.05)[j]
    assert subset.values(ctx).shape == (400,)


def test_block_designs_refuse_an_acquisition_they_cannot_place_by() -> None:
    from core.policies.scattered import ScatteredPlanner

    with pytest.raises(TypeError, match="variance reduction per second"):
        ScatteredPlanner(
            "x", replace(policy_parts("aeni"), acquisition=CostWeighted(UncertaintyExploration()))
        )


def test_stretch_imports_no_private_name_of_another_module() -> None:
    for name in ("stretch.py", "scattered.py", "planner.py"):
        tree = ast.parse((ROOT / "core" / "policies" / name).read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("core."):
                assert not [a.name for a in node.names if a.name.startswith("_")], (name, node.module)

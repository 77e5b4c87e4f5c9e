"""The two-fidelity model (core/model/two_fidelity.py, core/model/cokriging.py) on synthetic fields whose ρ and
δ are known: it learns them, beats the CSM-only GP where the fast channel is good, and does not lose to it by
more than a tolerance where the fast channel misleads."""

from __future__ import annotations

import copy
import json
from dataclasses import dataclass, replace

import gpytorch
import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from core.errors import InputError
from core.model.cokriging import unpack_theta
from core.model.observations import Observations
from core.model.two_fidelity import (
    TwoFidelityGP,
    TwoFidelityReport,
    fast_link_observations,
    fast_observations,
)

RNG_SEED = 36
N_FAST_SIDE = 60  # 3,600 fast indents
N_CSM = 40  # CSM centres of 9 indents each


def fast_truth(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return 5.0 + 1.2 * np.sin(6.0 * u) + 0.8 * np.cos(5.0 * v) + 0.6 * u * v


def rho_truth(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return 0.8 + 0.15 * (u - 0.5) - 0.1 * (v - 0.5)


def delta_truth(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return 0.3 + 0.2 * (u - 0.5) + 0.08 * np.sin(2.0 * np.pi * v)


def bump(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """A feature the fast channel does not see (a surface layer over it)."""
    return 1.0 * np.exp(-((u - 0.3) ** 2 + (v - 0.7) ** 2) / (2 * 0.08**2))


def lattice(n: int = 50) -> np.ndarray:
    c = (np.arange(n) + 0.5) / n
    gu, gv = np.meshgrid(c, c)
    return np.column_stack([gu.ravel(), gv.ravel()])


@dataclass
class Case:
    model: TwoFidelityGP
    report: TwoFidelityReport
    csm: Observations
    fast: Observations
    truth: np.ndarray  # the CSM truth on lattice()
    mape_two: float
    mape_csm: float


def _mape(pred: np.ndarray, truth: np.ndarray) -> float:
    return float(100 * np.mean(np.abs(pred - truth) / truth))


def build(misleading: bool) -> Case:
    rng = np.random.default_rng(RNG_SEED)
    uf = lattice(N_FAST_SIDE)
    hf = fast_truth(uf[:, 0], uf[:, 1]) + 0.15 * rng.standard_normal(len(uf))
    hf[rng.random(len(uf)) < 0.02] = np.nan  # failed fast indents: never learnt from

    def csm_truth(u: np.ndarray, v: np.ndarray) -> np.ndarray:
        h = rho_truth(u, v) * fast_truth(u, v) + delta_truth(u, v)
        return h + bump(u, v) if misleading else h

    uc = rng.random((N_CSM, 2))
    vals = csm_truth(uc[:, 0], uc[:, 1])[:, None] + 0.05 * rng.standard_normal((N_CSM, 9))
    csm = Observations(
        uv=uc,
        median_gpa=np.median(vals, axis=1),
        spread_var_gpa2=np.var(vals, axis=1, ddof=1),
        n_indents=np.full(N_CSM, 9),
    )
    model = TwoFidelityGP()
    fast = fast_observations(uf, hf)
    report = model.fit(csm, fast)
    grid = lattice()
    truth = csm_truth(grid[:, 0], grid[:, 1])
    return Case(
        model,
        report,
        csm,
        fast,
        truth,
        _mape(model.predict(grid).mean, truth),
        _mape(model.csm_gp.predict(grid).mean, truth),
    )


@pytest.fixture(scope="module")
def good() -> Case:
    return build(misleading=False)


@pytest.fixture(scope="module")
def misleading() -> Case:
    return build(misleading=True)


def test_learns_a_known_rho_and_bias(good: Case) -> None:
    assert good.report.mode == "two-fidelity"
    grid = lattice()
    u, v = grid[:, 0], grid[:, 1]
    rho = good.model.rho(grid)
    assert np.max(np.abs(rho - rho_truth(u, v))) < 0.06
    # the bias the console will show, E[H_csm − H_fast], against the truth (ρ − 1)·H_fast + δ
    bias_truth = (rho_truth(u, v) - 1.0) * fast_truth(u, v) + delta_truth(u, v)
    bias = good.model.bias_gpa(grid)
    assert np.sqrt(np.mean((bias - bias_truth) ** 2)) < 0.08
    assert good.report.delta_share is not None and good.report.delta_share < 0.1


def test_beats_the_csm_only_gp_with_a_good_fast_channel(good: Case) -> None:
    assert good.mape_two < 0.6 * good.mape_csm
    pred = good.model.predict(lattice())
    z = np.abs(pred.mean - good.truth) / pred.epistemic_sd
    assert np.mean(z < 2.0) > 0.85  # its uncertainty is honest where it is small
    assert np.allclose(pred.total_sd**2, pred.epistemic_sd**2 + pred.noise_sd**2)
    # the per-indent noise is the CSM noise model's (0.05 GPa), not the fast channel's
    assert np.median(pred.noise_sd) == pytest.approx(0.05, rel=0.35)


def test_a_misleading_fast_channel_costs_little(good: Case, misleading: Case) -> None:
    assert misleading.mape_two <= 1.1 * misleading.mape_csm + 0.05
    # what the fast channel cannot explain goes to δ: a larger share than with the good channel
    assert misleading.report.delta_share is not None and good.report.delta_share is not None
    assert misleading.report.delta_share > 2.0 * good.report.delta_share


def test_the_likelihood_is_gpytorchs(good: Case) -> None:
    """The CSM level's objective is the Gaussian log density of its moments, as gpytorch computes it."""
    p = good.model._problem(good.csm, good.model._csm_noise_var(good.csm))
    theta = torch.tensor(good.model.theta, dtype=torch.float64)
    t = unpack_theta(theta, p.floor_uv)
    _, mean, k = p._moments(t)
    theirs = -float(gpytorch.distributions.MultivariateNormal(mean, k).log_prob(p.y))
    prior = float(torch.distributions.Gamma(3.0, 6.0).log_prob(t.lengthscale).sum())
    assert p.objective(theta) * p.n == pytest.approx(theirs - prior, rel=1e-8)


def test_too_few_fast_cells_is_the_csm_only_map(good: Case) -> None:
    model = TwoFidelityGP()
    report = model.fit(good.csm, None)
    assert report.mode == "csm-only" and model.mode == "csm-only"
    grid = lattice(10)
    np.testing.assert_allclose(model.predict(grid).mean, model.csm_gp.predict(grid).mean)


def test_the_guard_keeps_the_last_good_bias_kernel(good: Case) -> None:
    """Scatter between centres that their spreads cannot see (0.4 GPa, spreads of 0.05) pulls δ's
    length-scale to its floor: the guard keeps the previous fit's."""
    model = copy.deepcopy(good.model)  # its fast GP already fitted: the refit only conditions it
    assert not good.report.collapse
    rng = np.random.default_rng(1)
    uc = rng.random((80, 2))
    h = rho_truth(uc[:, 0], uc[:, 1]) * fast_truth(uc[:, 0], uc[:, 1]) + 0.4 * rng.standard_normal(80)
    noisy = Observations(uv=uc, median_gpa=h, spread_var_gpa2=np.full(80, 0.05**2), n_indents=np.full(80, 9))
    second = model.fit(noisy, good.fast)
    assert second.collapse and second.used_last_good, second.collapse_reason
    assert second.delta_lengthscales_uv == pytest.approx(good.report.delta_lengthscales_uv)


def test_the_calibration_of_rho_is_part_of_the_posterior(good: Case) -> None:
    """ρ's and δ's plane coefficients come from the CSM values: their uncertainty adds to the map's variance
    (universal kriging), most where the CSM centres are fewest, and more CSM values shrink it."""
    cond = good.model._cond
    assert cond is not None and cond.reg_a_chol is not None
    xs = torch.as_tensor(lattice(20), dtype=torch.float64)
    _, with_calibration = cond.mean_var(xs)
    _, without = replace(cond, reg_a_chol=None).mean_var(xs)
    extra = (with_calibration - without).numpy()
    assert np.all(extra >= -1e-12) and extra.max() > 0.05 * without.numpy().mean()
    # more CSM values (y-free what-if) calibrate ρ better: the variance falls everywhere
    sites = lattice(6)
    after = good.model.csm_variance_after_csm(lattice(20), sites, np.full(len(sites), 1e-3))
    assert np.all(after <= good.model.predict(lattice(20)).epistemic_sd ** 2 + 1e-12)


def test_what_a_fast_array_would_buy(good: Case) -> None:
    """Precise fast cells around one place lower the CSM map's variance most there, and nowhere raise it."""
    grid = lattice(20)
    before = good.model.predict(grid).epistemic_sd ** 2
    c = np.linspace(0.65, 0.95, 8)
    cu, cv = np.meshgrid(c, c)
    cells = np.column_stack([cu.ravel(), cv.ravel()])
    after = good.model.csm_variance_after_fast(grid, cells, np.full(len(cells), 1e-4))
    drop = before - after
    assert np.all(drop >= -1e-9 * before.max())
    near = np.all((grid >= 0.65) & (grid <= 0.95), axis=1)
    assert drop[near].mean() > 3.0 * drop[~near].mean() and drop[near].mean() > 0.05 * before[near].mean()
    # no cells: nothing bought; the same call conditions as predict does
    none = good.model.csm_variance_after_fast(grid, np.array([[0.5, 0.5]]), np.array([1e9]))
    np.testing.assert_allclose(none, before, rtol=1e-6, atol=1e-12)


def test_resume_from_the_record_is_the_same_model(good: Case) -> None:
    """A journal's record (through JSON) conditions a new model on the same data to the same map, bit for bit,
    and both go on to the same next fit."""
    record = json.loads(json.dumps(good.model.hyper))
    restored = TwoFidelityGP()
    restored.set_hyper(record, good.csm, good.fast)
    assert restored.mode == "two-fidelity"
    grid = lattice(20)
    a, b = good.model.predict(grid), restored.predict(grid)
    np.testing.assert_array_equal(a.mean, b.mean)
    np.testing.assert_array_equal(a.epistemic_sd, b.epistemic_sd)
    original = copy.deepcopy(good.model)
    more = Observations(
        uv=np.vstack([good.csm.uv, [[0.5, 0.5]]]),
        median_gpa=np.append(good.csm.median_gpa, 5.5),
        spread_var_gpa2=np.append(good.csm.spread_var_gpa2, 0.003),
        n_indents=np.append(good.csm.n_indents, 9),
    )
    original.fit(more, good.fast)
    restored.fit(more, good.fast)
    np.testing.assert_array_equal(original.predict(grid).mean, restored.predict(grid).mean)
    with pytest.raises(InputError, match="fast"):
        TwoFidelityGP().set_hyper(record, good.csm, None)
    record["cokriging"]["raw"] = record["cokriging"]["raw"][:5]
    with pytest.raises(InputError, match="malformed"):
        TwoFidelityGP().set_hyper(record, good.csm, good.fast)


def modulus_truth(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """A modulus field unrelated to the hardness's shape (as across a library: E and H follow different
    compositions)."""
    return 150.0 + 25.0 * np.sin(4.0 * u + 3.0 * v) + 10.0 * np.cos(7.0 * v)


def linked_rho(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The CSM/fast ratio as Nix–Gao makes it: a smooth non-linear function of the fast E/H, no plane in x."""
    r = modulus_truth(u, v) / fast_truth(u, v)
    z = (r - 30.0) / 5.0
    return 0.75 - 0.06 * z + 0.01 * z**2


def test_rho_linked_to_the_fast_e_over_h_learns_what_a_plane_cannot() -> None:
    rng = np.random.default_rng(RNG_SEED)
    uf = lattice(40)  # 196 cells: fewer leave the link's evidence under BIC's bar
    hf = fast_truth(uf[:, 0], uf[:, 1]) + 0.15 * rng.standard_normal(len(uf))
    ef = modulus_truth(uf[:, 0], uf[:, 1]) + 3.0 * rng.standard_normal(len(uf))
    uc = rng.random((40, 2))
    csm_truth = linked_rho(uc[:, 0], uc[:, 1]) * fast_truth(uc[:, 0], uc[:, 1]) + 0.2
    vals = csm_truth[:, None] + 0.05 * rng.standard_normal((40, 9))
    csm = Observations(
        uv=uc,
        median_gpa=np.median(vals, axis=1),
        spread_var_gpa2=np.var(vals, axis=1, ddof=1),
        n_indents=np.full(40, 9),
    )
    fast, link = fast_observations(uf, hf), fast_link_observations(uf, hf, ef)
    assert link is not None and link.n == fast.n
    grid = lattice(30)
    truth = linked_rho(grid[:, 0], grid[:, 1]) * fast_truth(grid[:, 0], grid[:, 1]) + 0.2
    plane, linked = TwoFidelityGP(), TwoFidelityGP()
    plane_report, linked_report = plane.fit(csm, fast), linked.fit(csm, fast, link)
    assert plane_report.rho_link_coef is None and linked_report.rho_link_coef is not None
    mape_plane = _mape(plane.predict(grid).mean, truth)
    mape_linked = _mape(linked.predict(grid).mean, truth)
    assert mape_linked < 0.7 * mape_plane, (mape_linked, mape_plane)
    # the link is never extrapolated past the E/H the CSM centres have seen
    assert linked._p is not None
    cells = link.median_gpa
    seen = (linked.link_gp.predict_mean(csm.uv) - cells.mean()) / cells.std()
    z_grid = linked._p.link_grid[:, 0].numpy()
    assert seen.min() - 1e-9 <= z_grid.min() and z_grid.max() <= seen.max() + 1e-9
    np.testing.assert_allclose(linked._p.link_grid[:, 1].numpy(), z_grid**2)
    # the journal's record brings the link back: the same map, bit for bit
    record = json.loads(json.dumps(linked.hyper))
    restored = TwoFidelityGP()
    restored.set_hyper(record, csm, fast, link)
    np.testing.assert_array_equal(restored.predict(grid).mean, linked.predict(grid).mean)
    # a record of the first version (ρ a plane: nine numbers) reads as ρ with no link
    old = json.loads(json.dumps(plane.hyper))
    old["version"] = 1
    for key in ("raw", "last_good"):
        raw = old["cokriging"][key]
        old["cokriging"][key] = raw[:3] + raw[5:]
    again = TwoFidelityGP()
    again.set_hyper(old, csm, fast)
    np.testing.assert_allclose(again.predict(grid).mean, plane.predict(grid).mean, rtol=1e-12)


@settings(max_examples=30, deadline=None)
@given(
    n=st.integers(1, 400),
    fail=st.floats(0.0, 0.5),
    cell=st.one_of(st.none(), st.floats(0.005, 0.2)),
    seed=st.integers(0, 10_000),
)
def test_fast_cells_keep_every_measured_indent_once(
    n: int, fail: float, cell: float | None, seed: int
) -> None:
    rng = np.random.default_rng(seed)
    uv = rng.random((n, 2))
    h = 3.0 + rng.random(n)
    h[rng.random(n) < fail] = np.nan
    if not np.isfinite(h).any():
        with pytest.raises(ValueError, match="no measured fast indent"):
            fast_observations(uv, h, cell)
        return
    obs = fast_observations(uv, h, cell)
    assert int(obs.n_indents.sum()) == int(np.isfinite(h).sum())  # failed ones are not there
    ok = h[np.isfinite(h)]
    assert np.all(obs.median_gpa >= ok.min()) and np.all(obs.median_gpa <= ok.max())
    assert np.all((obs.uv >= 0) & (obs.uv <= 1))

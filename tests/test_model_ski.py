"""The interpolated (KISS-GP) surrogate for large designs, and the hyperparameter codec both models share.

Its likelihood and predictions are checked against the same model written densely (W Kmm Wᵀ + D, n × n);
the automatic choice, the crash-exact resume, the refit schedule and the collapse guard through the
public ``HeteroskedasticGP``.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from core.errors import InputError
from core.model import SKI_ABOVE, HeteroskedasticGP, Hyperparameters, Observations
from core.model.fitting import SKI_REFIT_GROWTH, cold_theta
from core.model.kernels import unpack
from core.model.ski import JITTER, SkiProblem, _kernel
from drivers.sim.emulator import TernaryField

FIELD = TernaryField(side_um=1000.0)


def _obs(n: int, seed: int = 0, g: int = 2) -> Observations:
    """n uniform centres, each a g×g grid of emulator indents (vectorised: medians and spreads)."""
    rng = np.random.default_rng(seed)
    centres = rng.uniform(0.02, 0.98, size=(n, 2))
    off = (np.arange(g) - (g - 1) / 2) * 0.005
    du, dv = (a.ravel() for a in np.meshgrid(off, off))
    uv = centres[:, None, :] + np.stack([du, dv], axis=1)[None]
    x, y = uv[..., 0] * 1000.0, uv[..., 1] * 1000.0
    h = FIELD.hardness_gpa(x, y) + FIELD.noise_sd_gpa(x, y) * rng.standard_normal(x.shape)
    return Observations(uv.mean(axis=1), np.median(h, axis=1), np.var(h, axis=1, ddof=1), np.full(n, g * g))


def _take(obs: Observations, k: int) -> Observations:
    return Observations(obs.uv[:k], obs.median_gpa[:k], obs.spread_var_gpa2[:k], obs.n_indents[:k])


def _lattice(n: int) -> np.ndarray:
    c = (np.arange(n) + 0.5) / n
    u, v = np.meshgrid(c, c)
    return np.column_stack([u.ravel(), v.ravel()])


@pytest.fixture(scope="module")
def obs300() -> Observations:
    return _obs(300)


def _problem(nugget: bool) -> SkiProblem:
    gen = torch.Generator().manual_seed(1)
    n = 120
    x = torch.rand(n, 2, generator=gen, dtype=torch.float64) * 1.04 - 0.02
    y = torch.sin(4 * x[:, 0]) + 0.1 * torch.randn(n, generator=gen, dtype=torch.float64)
    noise = 0.01 + 0.02 * torch.rand(n, generator=gen, dtype=torch.float64)
    return SkiProblem(
        kernel="matern52",
        floor_uv=0.02,
        with_prior=False,
        x=x,
        y=y,
        noise_fixed=noise,
        noise_scale=torch.ones(n, dtype=torch.float64),
        nugget=nugget,
    )


@pytest.mark.parametrize("nugget", [False, True])
def test_likelihood_and_prediction_equal_the_dense_interpolated_gp(nugget: bool) -> None:
    p = _problem(nugget)
    theta = cold_theta(0.2, p.floor_uv, p.learn_noise)
    u = unpack(theta, p.floor_uv, p.learn_noise)
    w = torch.zeros(p.n, p.grid.m, dtype=torch.float64).scatter_add_(1, p.idx, p.w)
    kmm = u.outputscale * (
        _kernel(p.kernel, p.z, u.lengthscale) + JITTER * torch.eye(p.grid.m, dtype=torch.float64)
    )
    interpolated = w @ kmm @ w.T
    # the variance the interpolation loses at each point is added to its noise (FITC-style)
    deficit = (u.outputscale - interpolated.diagonal()).clamp_min(0.0)
    assert float(deficit.max()) > 0.0
    cov = interpolated + torch.diag(p.noise(u) + deficit)
    dense = torch.distributions.MultivariateNormal(torch.full((p.n,), float(u.constant)), cov)
    assert p.objective(theta) == pytest.approx(-float(dense.log_prob(p.y)) / p.n, abs=1e-9)
    xs = torch.rand(50, 2, generator=torch.Generator().manual_seed(2), dtype=torch.float64)
    ws = torch.zeros(50, p.grid.m, dtype=torch.float64).scatter_add_(1, *p.grid.weights(xs))
    k_sn = ws @ kmm @ w.T
    mean_ref = k_sn @ torch.linalg.solve(cov, p.y - u.constant) + u.constant
    var_ref = (ws @ kmm @ ws.T).diagonal() - (k_sn @ torch.linalg.solve(cov, k_sn.T)).diagonal()
    mean, var = p.condition(theta).mean_var(xs)
    torch.testing.assert_close(mean, mean_ref, rtol=0, atol=1e-9)
    torch.testing.assert_close(var, var_ref, rtol=0, atol=1e-9)


def test_gradient_is_the_objectives() -> None:
    p = _problem(nugget=True)
    theta = cold_theta(0.2, p.floor_uv, True).requires_grad_(True)
    surrogate, value = p.loss(theta)
    surrogate.backward()
    assert theta.grad is not None
    for i in range(theta.shape[0]):
        step = torch.zeros_like(theta).detach()
        step[i] = 1e-6
        fd = (p.objective(theta.detach() + step) - p.objective(theta.detach() - step)) / 2e-6
        assert float(theta.grad[i]) == pytest.approx(fd, rel=1e-4, abs=1e-7)
    assert value == pytest.approx(p.objective(theta.detach()), abs=1e-12)


def test_the_model_is_chosen_by_size_and_maps_like_the_exact_gp(obs300: Observations) -> None:
    assert HeteroskedasticGP().model_for(SKI_ABOVE) == "exact"
    assert HeteroskedasticGP().model_for(SKI_ABOVE + 1) == "ski"
    exact, ski = HeteroskedasticGP(), HeteroskedasticGP(ski_above=200)
    exact.fit(obs300)
    report = ski.fit(obs300)
    assert exact.model == "exact" and ski.model == report.model == "ski"
    assert report.hyper["model"] == "ski" and "model" not in exact.hyper  # type: ignore[operator]
    uv = _lattice(40)
    x, y = uv[:, 0] * 1000.0, uv[:, 1] * 1000.0
    truth = FIELD.hardness_gpa(x, y)
    mape = {
        m: float(np.mean(np.abs(gp.predict_mean(uv) - truth) / truth)) for m, gp in (("e", exact), ("s", ski))
    }
    assert mape["s"] < 1.1 * mape["e"]
    pe, ps = exact.predict(uv), ski.predict(uv)
    # the same noise model and a comparable posterior: noise ranks alike, epistemic sd of the same size
    assert np.corrcoef(pe.noise_sd, ps.noise_sd)[0, 1] > 0.95
    assert 0.5 < np.median(ps.epistemic_sd) / np.median(pe.epistemic_sd) < 2.0


def test_resume_is_exact_and_conditions_between_optimisations(obs300: Observations) -> None:
    grown = _obs(340)
    gp = HeteroskedasticGP(ski_above=100)
    gp.fit(_take(grown, 300))
    record = json.loads(json.dumps(gp.hyper))  # through the journal
    resumed = HeteroskedasticGP(ski_above=100)
    resumed.set_hyper(record, _take(grown, 300))
    uv = _lattice(30)
    np.testing.assert_array_equal(resumed.predict(uv).total_sd, gp.predict(uv).total_sd)
    # one more centre: below 10 % growth the hyperparameters stay and the new data are conditioned on
    a, b = gp.fit(_take(grown, 301)), resumed.fit(_take(grown, 301))
    assert a.iterations == 0 and a.hyper == b.hyper and a.hyper["mean"] == record["mean"]
    np.testing.assert_array_equal(resumed.predict(uv).mean, gp.predict(uv).mean)
    # past the growth factor it optimises again, and the two still agree
    n_opt = math.ceil(SKI_REFIT_GROWTH * 300)
    a, b = gp.fit(_take(grown, n_opt)), resumed.fit(_take(grown, n_opt))
    assert a.iterations > 0 and a.hyper == b.hyper and a.hyper["fit_n"] == n_opt


def test_collapse_guard_holds_for_the_interpolated_gp() -> None:
    healthy = _obs(140, seed=3)
    k = 16  # 156 centres: past the 10 % growth at which the interpolated GP optimises again
    cluster = Observations(
        np.array([[0.45 + 0.012 * (i % 4), 0.45 + 0.012 * (i // 4)] for i in range(k)]),
        np.array([6.5 if (i % 2) == (i // 4) % 2 else 4.0 for i in range(k)]),
        np.full(k, 0.02**2),
        np.full(k, 25),
    )
    both = Observations(
        np.vstack([healthy.uv, cluster.uv]),
        np.concatenate([healthy.median_gpa, cluster.median_gpa]),
        np.concatenate([healthy.spread_var_gpa2, cluster.spread_var_gpa2]),
        np.concatenate([healthy.n_indents, cluster.n_indents]),
    )
    guarded, unguarded = HeteroskedasticGP(ski_above=100), HeteroskedasticGP(ski_above=100, guard="off")
    good = guarded.fit(healthy)
    # the same fit, not computed twice: the unguarded model resumes from it (exact, as tested above)
    unguarded.set_hyper(guarded.hyper, healthy)
    bad = guarded.fit(both)
    loose = unguarded.fit(both)
    assert loose.collapse and not loose.used_last_good
    assert bad.collapse and bad.used_last_good
    assert bad.lengthscales_uv == good.lengthscales_uv and bad.model == "ski"


def test_hyperparameter_records_of_before_the_package_still_load(obs300: Observations) -> None:
    record = {
        "version": 1,
        "kernel": "matern52",
        "lengthscale_floor_uv": 0.02,
        "mean": {"raw": [0.1, 0.5, -1.0, -1.2]},
        "noise": {"kind": "gp", "raw": [0.0, 0.3, -0.5, -0.5]},
        "nugget": False,
        "lengthscales_uv": [0.33, 0.28],
        "n_points": 300,
        "cold_n": 300,
    }
    hyper = Hyperparameters.from_json(record)
    assert hyper.model == "exact" and hyper.cold_n == 300 and hyper.noise_raw == (0.0, 0.3, -0.5, -0.5)
    assert Hyperparameters.from_json(hyper.to_json()) == hyper
    gp = HeteroskedasticGP()
    gp.set_hyper(record, obs300)
    assert gp.model == "exact"
    for bad, match in (
        ({**record, "mean": {"raw": [0.1, "x", 0.0, 0.0]}}, "mean.raw"),
        ({**record, "noise": {"kind": "gp"}}, "noise.raw"),
        ({**record, "model": "svgp"}, "unknown model"),
        ({k: v for k, v in record.items() if k != "kernel"}, "malformed"),
    ):
        with pytest.raises(InputError, match=match):
            gp.set_hyper(bad, obs300)

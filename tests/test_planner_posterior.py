"""The planner prices blocks with the model's own posterior: exact up to SKI_ABOVE centres, interpolated above."""

from __future__ import annotations

import numpy as np
import pytest

from core.model.ski import SKI_ABOVE, grid_for
from core.policies.base import GPSummary
from core.policies.variance import (
    PosteriorCov,
    _ExactPosterior,
    _GridPosterior,
    posterior,
    reference_lattice,
)


def _dense_interpolated(summary: GPSummary, x: np.ndarray, noise: np.ndarray, a: np.ndarray, b: np.ndarray):
    """C(a, b) of the interpolated GP by dense n × n algebra: K̃ = W Kmm Wᵀ, D = noise + k(x, x) − K̃(x, x)."""
    import torch

    from core.policies.variance import _kernel

    ls = np.asarray(summary.lengthscales_uv)
    os = summary.outputscale_gpa2
    grid = grid_for(tuple(ls))
    z = grid.points().numpy()
    kmm = _kernel(summary.kernel, z, z, ls, os) + 1e-6 * os * np.eye(grid.m)

    def w_of(p: np.ndarray) -> np.ndarray:
        idx, w = grid.weights(torch.as_tensor(p, dtype=torch.float64))
        out = np.zeros((len(p), grid.m))
        np.add.at(out, (np.repeat(np.arange(len(p)), 16), idx.numpy().ravel()), w.numpy().ravel())
        return out

    wx, wa, wb = w_of(x), w_of(a), w_of(b)
    kxx = wx @ kmm @ wx.T
    d = noise + np.maximum(os - np.diag(kxx), 0.0)
    solve = np.linalg.solve(kxx + np.diag(d), wx @ kmm @ wb.T)
    return wa @ kmm @ wb.T - (wa @ kmm @ wx.T) @ solve


@pytest.mark.parametrize("ls", [(0.5, 0.7), (0.12, 0.3)])
def test_the_grid_posterior_is_the_interpolated_gps(ls: tuple[float, float]) -> None:
    rng = np.random.default_rng(3)
    summary = GPSummary("matern52", ls, 1.7, 0.0)
    x = rng.uniform(size=(150, 2))
    noise = rng.uniform(0.01, 0.2, size=150)
    cand = rng.uniform(size=(40, 2))
    ref = reference_lattice(6)
    post = _GridPosterior(summary, x, noise)
    got = post.cov(ref, post.factor(ref), cand, post.factor(cand))
    want = _dense_interpolated(summary, x, noise, ref, cand)
    assert np.allclose(got, want, rtol=1e-7, atol=1e-9 * summary.outputscale_gpa2)
    var = post.var(post.factor(cand))
    assert np.allclose(
        var, np.diag(_dense_interpolated(summary, x, noise, cand, cand)), rtol=1e-7, atol=1e-10
    )
    # conditioning on a planned pick is the same rank-one update in both forms
    pc = PosteriorCov.of(post, cand, ref, np.ones(len(ref)))
    after = pc.condition_on(5, 0.05)
    dense_cc = _dense_interpolated(summary, x, noise, cand, cand)
    dense_rc = _dense_interpolated(summary, x, noise, ref, cand)
    want_rc = dense_rc - np.outer(dense_rc[:, 5], dense_cc[5]) / (dense_cc[5, 5] + 0.05)
    assert np.allclose(after.cov_rc, want_rc, rtol=1e-6, atol=1e-9)


def test_the_planner_switches_with_the_model() -> None:
    rng = np.random.default_rng(0)
    summary = GPSummary("matern52", (0.4, 0.4), 1.0, 0.0)
    for n, kind in ((SKI_ABOVE, _ExactPosterior), (SKI_ABOVE + 1, _GridPosterior)):
        x = rng.uniform(size=(n, 2))
        post = posterior(summary, x, np.full(n, 0.05))
        assert type(post) is kind
    # above the switch, no factor grows with the design: the candidates' factor has one row per grid node
    assert post.factor(x[:7]).shape == (grid_for((0.4, 0.4)).m, 7)


def test_the_grid_posterior_agrees_with_the_exact_one_on_a_smooth_map() -> None:
    """Where the interpolation is fine (length-scale ≫ grid step), the two price the candidates alike."""
    rng = np.random.default_rng(1)
    summary = GPSummary("matern52", (0.5, 0.65), 1.0, 0.0)
    x = rng.uniform(size=(600, 2))
    noise = np.full(600, 0.05)
    cand = rng.uniform(size=(500, 2))
    ref = reference_lattice()
    w = np.ones(len(ref))
    e = _ExactPosterior(summary, x, noise)
    g = _GridPosterior(summary, x, noise)
    fe, fg = e.factor(cand), g.factor(cand)
    ve, vg = e.var(fe), g.var(fg)
    assert np.median(np.abs(vg / ve - 1.0)) < 0.03
    ge = (w @ e.cov(ref, e.factor(ref), cand, fe) ** 2) / (ve + 0.05)
    gg = (w @ g.cov(ref, g.factor(ref), cand, fg) ** 2) / (vg + 0.05)
    assert np.corrcoef(ge, gg)[0, 1] > 0.99

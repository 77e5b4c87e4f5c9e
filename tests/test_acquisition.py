"""Acquisition functions against values computed by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest

from core.acquisition import ACQUISITIONS, cost_aware, ei, score, ucb, ue
from core.errors import InputError
from core.model import Prediction


def _pred(mean: list[float], epi: list[float], noise: list[float] | None = None) -> Prediction:
    m = np.array(mean, dtype=float)
    e = np.array(epi, dtype=float)
    n = np.array(noise if noise is not None else [0.5] * len(mean), dtype=float)
    return Prediction(mean=m, epistemic_sd=e, noise_sd=n, total_sd=np.sqrt(e**2 + n**2))


PRED = _pred([5.0, 6.0, 4.0, 7.0], [1.0, 2.0, 0.0, 0.0], noise=[0.3, 0.9, 0.1, 2.0])


def test_ue_is_the_epistemic_sd_not_the_noise() -> None:
    np.testing.assert_array_equal(ue(PRED), [1.0, 2.0, 0.0, 0.0])


def test_ucb_hand_values() -> None:
    # beta = 4: sqrt(beta) = 2 -> mu + 2 sigma
    np.testing.assert_allclose(ucb(PRED, 4.0), [7.0, 10.0, 4.0, 7.0], rtol=0, atol=1e-15)
    np.testing.assert_allclose(ucb(PRED, 0.0), [5.0, 6.0, 4.0, 7.0], rtol=0, atol=0)
    np.testing.assert_allclose(ucb(PRED, 2.25), [6.5, 9.0, 4.0, 7.0], rtol=0, atol=1e-15)


def test_ei_hand_values() -> None:
    out = ei(PRED, best_observed=5.0)
    phi0 = 1.0 / math.sqrt(2.0 * math.pi)  # 0.398942...
    # mu=6, sd=2: z=0.5, Phi(0.5)=0.6914624613, phi(0.5)=0.3520653268
    expected = [phi0, 1.0 * 0.6914624612740131 + 2.0 * 0.3520653267642995, 0.0, 2.0]
    np.testing.assert_allclose(out, expected, rtol=1e-12, atol=1e-15)
    assert out[0] == pytest.approx(0.3989422804014327, abs=1e-15)
    assert out[1] == pytest.approx(1.3955931148026121, abs=1e-12)


def test_ei_margin_and_monotonicity() -> None:
    # xi shifts the incumbent: EI(best=5, xi=1) == EI(best=6, xi=0)
    np.testing.assert_allclose(ei(PRED, 5.0, xi=1.0), ei(PRED, 6.0), rtol=0, atol=0)
    sds = _pred([5.0] * 4, [0.1, 0.5, 1.0, 3.0])
    vals = ei(sds, 5.0)
    assert np.all(np.diff(vals) > 0)  # at mu = best, EI = sigma * phi(0) grows with sigma
    np.testing.assert_allclose(vals, np.array([0.1, 0.5, 1.0, 3.0]) / math.sqrt(2 * math.pi), rtol=1e-12)


def test_cost_aware_divides_and_checks() -> None:
    np.testing.assert_allclose(
        cost_aware(np.array([1.0, 3.0, 0.5]), np.array([2.0, 600.0, 0.25])), [0.5, 0.005, 2.0]
    )
    np.testing.assert_allclose(cost_aware(np.array([1.0, 3.0]), np.array(4.0)), [0.25, 0.75])
    with pytest.raises(InputError, match="cost_s"):
        cost_aware(np.array([1.0, 2.0]), np.array([1.0, 0.0]))
    with pytest.raises(InputError, match="cost_s"):
        cost_aware(np.array([1.0, 2.0]), np.array([1.0, -5.0]))
    with pytest.raises(InputError, match="cost_s"):
        cost_aware(np.array([1.0, 2.0]), np.array([1.0, np.nan]))
    with pytest.raises(InputError, match="shape"):
        cost_aware(np.array([1.0, 2.0]), np.array([1.0, 2.0, 3.0]))


def test_cost_aware_ranking_can_flip_the_choice() -> None:
    # the most uncertain candidate is far (390 s more): sigma/cost prefers the near one
    acq = ue(_pred([5.0, 5.0], [0.30, 0.20]))
    cost = np.array([940.0, 550.0])
    assert int(np.argmax(acq)) == 0
    assert int(np.argmax(cost_aware(acq, cost))) == 1


def test_registry_and_score_by_name() -> None:
    assert set(ACQUISITIONS) == {"ue", "ucb", "ei"}
    np.testing.assert_array_equal(score("ue", PRED), ue(PRED))
    np.testing.assert_array_equal(score("ucb", PRED, beta=4.0), [7.0, 10.0, 4.0, 7.0])
    np.testing.assert_array_equal(score("ei", PRED, best_observed=5.0), ei(PRED, 5.0))
    with pytest.raises(InputError, match="unknown acquisition 'pi'"):
        score("pi", PRED)
    with pytest.raises(InputError, match="ucb"):
        score("ucb", PRED)  # beta missing


def test_bad_parameters() -> None:
    with pytest.raises(InputError, match="beta"):
        ucb(PRED, -1.0)
    with pytest.raises(InputError, match="best_observed"):
        ei(PRED, float("nan"))

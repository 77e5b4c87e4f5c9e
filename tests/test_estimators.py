"""The centre value of a grid: Huber's estimate keeps the median's robustness and most of the mean's precision."""

from __future__ import annotations

import numpy as np
import pytest

from core.estimators import (
    MEDIAN_EFFICIENCY,
    centre_value,
    estimator_efficiency,
    huber_location,
)


def test_huber_is_the_mean_on_clean_data_and_ignores_a_wild_indent() -> None:
    clean = np.array([5.0, 5.1, 4.9, 5.05, 4.95, 5.02, 4.98, 5.01, 4.99])
    assert huber_location(clean) == pytest.approx(clean.mean(), abs=0.01)
    wild = clean.copy()
    wild[0] = 50.0  # a pore or a particle under the tip
    assert abs(huber_location(wild) - clean.mean()) < 0.05
    assert abs(np.mean(wild) - clean.mean()) > 4.0
    assert centre_value(wild, "median") == float(np.median(wild))
    # degenerate grids: one or two indents are their mean; identical values are that value
    assert huber_location(np.array([3.0])) == 3.0
    assert huber_location(np.array([3.0, 4.0])) == 3.5
    assert huber_location(np.full(4, 2.5)) == 2.5
    with pytest.raises(ValueError):
        huber_location(np.array([]))


@pytest.mark.parametrize("n", [4, 25])
def test_efficiency_table_matches_monte_carlo(n: int) -> None:
    rng = np.random.default_rng(n)
    draws = rng.standard_normal((4000, n))
    huber = np.array([huber_location(row) for row in draws])
    median = np.median(draws, axis=1)
    # 4,000 draws: the variance is known to ±2.2 % (1 sd); allow 8 %
    assert huber.var() * n == pytest.approx(float(estimator_efficiency("huber", n)), rel=0.08)
    assert huber.var() < median.var()
    if n == 25:
        assert median.var() * n == pytest.approx(MEDIAN_EFFICIENCY, rel=0.08)


def test_efficiency_is_one_for_one_or_two_indents() -> None:
    for est in ("median", "huber"):
        assert np.all(estimator_efficiency(est, np.array([1, 2])) == 1.0)  # type: ignore[arg-type]
    assert float(estimator_efficiency("median", 9)) == MEDIAN_EFFICIENCY
    assert 1.0 < float(estimator_efficiency("huber", 9)) < 1.15

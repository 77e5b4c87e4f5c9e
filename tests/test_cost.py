"""SPEC §3: the cost model reproduces the authors' calibration figures."""

from __future__ import annotations

import itertools

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from core.cost import CostLedger, block_steps, grid_baseline_blocks, price_sequence
from core.plan import Block, IndentSpec, local_grid
from core.profile import load_profile

P = load_profile("kla-imicro")


def _one_block(g: int, pitch: float = 5.0) -> CostLedger:
    return price_sequence(P, grid_baseline_blocks(1000, 1000, 1, g, pitch, 80.0))


def test_single_indent_block_is_550_s_mostly_drift() -> None:
    ledger = _one_block(1)
    without_setup = ledger.total_s - ledger.seconds["setup"]
    assert without_setup == pytest.approx(550.0, abs=1.0)
    assert 0.54 <= ledger.seconds["drift"] / without_setup <= 0.60
    assert ledger.seconds["setup"] == pytest.approx(40.0)


def test_five_by_five_block_is_3496_s_plus_setup() -> None:
    ledger = _one_block(5)
    assert ledger.total_s - ledger.seconds["setup"] == pytest.approx(3496.0, abs=2.0)
    assert ledger.indents == 25
    assert ledger.seconds["hold"] == pytest.approx(25 * 80.0)


def test_grid_baseline_286392_s() -> None:
    blocks = grid_baseline_blocks(1000, 1000, 9, 5, 5.0, 80.0)
    ledger = price_sequence(P, blocks)
    assert len(blocks) == 81 and ledger.indents == 2025
    assert ledger.total_s == pytest.approx(286_392, rel=0.005)
    assert ledger.total_s / 3600 == pytest.approx(79.6, abs=0.5)
    # centres at 100 µm pitch inside the square
    xs = sorted({b.center_x_um for b in blocks})
    assert xs[0] == pytest.approx(100) and xs[1] - xs[0] == pytest.approx(100)


def test_move_model_both_branches() -> None:
    assert P.move.axis_s(5.0) == pytest.approx(4196.41 * 2.718281828 ** (4.99e-7 * 5) - 4195.05, rel=1e-9)
    assert P.move.axis_s(2000.0) == pytest.approx(1.53e-4 * 2000 + 2.60)
    assert P.move_s(0, 0) == 0.0


def test_film_profile_prices_a_global_jump_at_520_s() -> None:
    film = load_profile("kla-imicro-film")
    a = Block(0, "global", 0, 0, 1, 5, 80, (IndentSpec(0, 0, 80),))
    b = Block(1, "global", 5000, 0, 1, 5, 80, (IndentSpec(5000, 0, 80),))
    ledger = price_sequence(film, [a, b])
    assert ledger.seconds["reconfigure"] == pytest.approx(2 * 520.0)


def test_local_block_needs_open_program() -> None:
    local = Block(0, "local", 0, 0, 1, 5, 80, (IndentSpec(0, 0, 80),))
    with pytest.raises(ValueError, match="local"):
        price_sequence(P, [local])


@settings(max_examples=60, deadline=None)
@given(
    st.lists(
        st.tuples(st.floats(-5000, 5000), st.floats(-5000, 5000)),
        min_size=2,
        max_size=12,
    )
)
@example([(0.0, 0.0), (100.0, 0.0), (1090.0, 0.0)])  # a 990 µm hop: no reconfiguration
@example([(0.0, 0.0), (100.0, 0.0), (1100.0, 0.0)])  # exactly 1000 µm: one
@example([(0.0, 0.0), (0.0, -1000.0)])  # along y, from the first (lifted) indent
def test_every_long_hop_pays_a_reconfiguration(points: list[tuple[float, float]]) -> None:
    """The safety rule (SPEC §3), tested here only: a ≥ 1000 µm hop between consecutive indents while
    engaged costs lift 25 + engage 65 + drift 300 = 390 s, and no shorter hop does. Every planner and
    driver prices and executes through these steps (see test_policies and test_campaign)."""
    specs = tuple(IndentSpec(x, y, 5.0) for x, y in points)
    block = Block(0, "global", 0, 0, 0, 0, 5, specs)
    steps = block_steps(P, block, (points[0][0], points[0][1]), False)
    long_hops = sum(
        1 for (x0, y0), (x1, y1) in itertools.pairwise(points) if abs(x1 - x0) >= 1000 or abs(y1 - y0) >= 1000
    )
    reconfigurations = [s for s in steps if s.category == "reconfigure"]
    assert len(reconfigurations) == long_hops
    assert sum(s.seconds for s in reconfigurations) == pytest.approx(390.0 * long_hops)
    assert price_sequence(P, [block]).reconfigurations == long_hops


def test_local_grid_is_boustrophedon_at_pitch() -> None:
    grid = local_grid(100, 200, 3, 5, 80)
    assert len(grid) == 9
    for a, b in itertools.pairwise(grid):
        assert abs(a.x_um - b.x_um) + abs(a.y_um - b.y_um) == pytest.approx(5.0)
    assert sum(s.x_um for s in grid) / 9 == pytest.approx(100)

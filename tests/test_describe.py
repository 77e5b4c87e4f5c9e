"""A block in words: sites, extent and program, the same in the log, the decision panel and the ticket."""

from __future__ import annotations

from core.describe import block_words, describe_block, hops_needing_reconfiguration, sites_words
from core.plan import Block, IndentSpec, local_grid


def singles(kind: str, pts: list[tuple[float, float]], hold_s: float = 5.0) -> Block:
    return Block(
        block_id=7,
        kind=kind,  # type: ignore[arg-type]
        center_x_um=pts[0][0],
        center_y_um=pts[0][1],
        grid_g=1,
        pitch_um=5.0,
        hold_s=hold_s,
        indents=tuple(IndentSpec(x, y, hold_s) for x, y in pts),
    )


# sixteen singles spread over 1196 × 600 µm, as the scattered planner places them
SPREAD = [(1000.0 + 79.7 * i, 2000.0 + (i % 4) * 200.0) for i in range(16)]


def test_scattered_singles_are_named_by_sites_extent_and_program() -> None:
    text = describe_block(singles("global", SPREAD))
    assert text == "new program: 16 singles over 1196 × 600 µm around (1598, 2300) µm, hold 5 s"
    assert "1×1" not in text


def test_stay_only_without_a_reconfiguration() -> None:
    near = [(100.0 + 30 * i, 100.0) for i in range(5)]
    assert block_words(singles("local", near), 1000.0, start_um=(90.0, 100.0)).program == "stay"
    # the move from where the tip is to the first site crosses the safety threshold
    assert block_words(singles("local", near), 1000.0, start_um=(2000.0, 100.0)).program == (
        "same program, 1 reconfiguration"
    )
    # hops of 1196 µm in x between two sites, both ways
    wide = [(0.0, 0.0), (1196.0, 0.0), (0.0, 10.0)]
    assert hops_needing_reconfiguration("local", wide, 1000.0) == 2
    assert block_words(singles("local", wide), 1000.0).program == "same program, 2 reconfigurations"
    # the threshold unknown: never "stay"
    assert block_words(singles("local", near)).program == "same program"


def test_a_grid_is_a_grid() -> None:
    b = Block(3, "local", 500.0, 500.0, 3, 5.0, 10.0, local_grid(500.0, 500.0, 3, 5.0, 10.0))
    assert (
        describe_block(b, 1000.0)
        == "stay: 3×3 grid at 5 µm pitch over 10 × 10 µm around (500, 500) µm, hold 10 s"
    )


def test_a_ticket_uses_the_same_words() -> None:
    from core.profile import InViewSettings
    from drivers.kla.exchange import make_ticket, ticket_panel

    t = make_ticket("run0", singles("local", SPREAD), InViewSettings(), expected_s=100.0)
    lines = ticket_panel(t)
    assert "same program: 16 singles over 1196 × 600 µm" in lines
    assert not any("stay" in line for line in lines)
    assert sites_words("global", [(1.0, 2.0)], 1, 5.0, None).text == "new program: 1 single at (1, 2) µm"

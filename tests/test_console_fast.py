"""Issue 36, seen: the console draws fast and CSM indents apart, names a fast array as one (decision panel and
ticket) and shows the fast channel's learnt bias as a map view (`m`), all from what the run journals (the
indents' channel, the bias field beside the map fields); the console only renders."""

from __future__ import annotations

import functools
import re
from dataclasses import replace

import numpy as np
import pytest

from aeni_console.console.app import ConsoleApp
from aeni_console.console.heatmap import (
    MARK_FAST,
    MARK_MEASURED,
    MapMarks,
    field_keys_of,
    render_heatmap,
)
from aeni_console.console.widgets.ticket import ticket_renderable
from aeni_console.testkit.live import CannedSource, LiveRun, settle, wait_until, widget_text
from core.campaign import Campaign
from core.campaign_config import CampaignConfig
from core.describe import block_words
from core.driver import InstrumentWait
from core.fast_array import FastArray, fast_block
from core.journal import map_fields_from_bytes, map_fields_to_bytes
from core.plan import Block, IndentSpec
from core.runview import IndentMark, MapFields
from drivers.sim.scenarios import make_scenario
from tests.test_fast_plan import _measured

ANSI = re.compile(r"\x1b\[[0-9;]*m")
BOUNDS = (0.0, 1000.0, 0.0, 1000.0)


@functools.cache
def _campaign_after_an_array() -> Campaign:
    """30 CSM singles on the ternary, then a 19 × 19 fast array reading the CSM map less 1 GPa."""
    sc = make_scenario("ternary", 0)
    campaign = Campaign(CampaignConfig(policy="aeni+fast", seed=0, lattice_n=20), sc.sample)
    rng = np.random.default_rng(0)
    xy = rng.uniform(50, 950, (30, 2))
    csm = _measured(0, xy, sc.truth.hardness_gpa(xy[:, 0], xy[:, 1]) + rng.normal(0, 0.03, 30))
    b0 = Block(0, "global", 500.0, 500.0, 1, 5.0, 80.0, tuple(IndentSpec(x, y, 80.0) for x, y in xy))
    campaign.observe_block(b0, csm)
    fb = fast_block(1, FastArray(505.0, 505.0, 19, 19, 50.0))
    sites = np.array([(s.x_um, s.y_um) for s in fb.indents])
    read = sc.truth.hardness_gpa(sites[:, 0], sites[:, 1]) - 1.0 + rng.normal(0, 0.06, len(sites))
    campaign.observe_block(fb, _measured(1, sites, read, "fast"))
    assert campaign.fast is not None and campaign.fast.active
    return campaign


def test_the_map_fields_carry_the_learnt_bias_through_the_journal() -> None:
    campaign = _campaign_after_an_array()
    fields = campaign.map_fields(3, display_n=20)
    assert fields.bias_gpa is not None and fields.bias_gpa.shape == fields.mean_gpa.shape
    inside = np.isfinite(fields.mean_gpa)
    assert np.array_equal(np.isfinite(fields.bias_gpa), inside)  # the sample's, as every field
    assert abs(float(np.nanmedian(fields.bias_gpa)) - 1.0) < 0.15  # what the channel reads off the CSM map
    back = map_fields_from_bytes(3, map_fields_to_bytes(fields))
    assert back.bias_gpa is not None and np.allclose(back.bias_gpa, fields.bias_gpa, equal_nan=True)
    assert field_keys_of(back)[-1] == "bias"
    # a CSM-only run has none, and `m` never offers it
    plain = replace(fields, bias_gpa=None)
    assert map_fields_from_bytes(3, map_fields_to_bytes(plain)).bias_gpa is None
    assert "bias" not in field_keys_of(plain)


def test_the_bias_view_is_centred_on_zero() -> None:
    n = 30
    xs = np.linspace(0.0, 1000.0, n)
    bias = np.tile(-0.2 + 1.0 * xs / 1000.0, (n, 1))  # −0.2 … 0.8 GPa
    ones = np.ones((n, n))
    fields = MapFields(1, xs, xs.copy(), 5 * ones, ones, ones, ones, bias_gpa=bias)
    img = render_heatmap(fields, "bias", 70, 22, BOUNDS)
    assert img.cmap == "balance" and img.vmin == pytest.approx(-img.vmax) and img.vmax == pytest.approx(0.8)


@pytest.mark.parametrize("no_color", [True, False])
def test_fast_and_csm_indents_are_drawn_apart(no_color: bool) -> None:
    fast = tuple(IndentMark(float(x), 800.0, 1, "measured", "fast") for x in np.linspace(100, 400, 7))
    csm = (IndentMark(700.0, 200.0, 0, "measured", "csm"), IndentMark(250.0, 800.0, 0, "measured", "csm"))
    marks = MapMarks(indents=fast + csm, newest_block_id=1)  # the newest block is the fast array
    n = 20
    xs = np.linspace(0.0, 1000.0, n)
    ones = np.ones((n, n))
    fields = MapFields(1, xs, xs.copy(), np.tile(2.0 + 5.0 * xs / 1000.0, (n, 1)), ones, ones, ones)
    img = render_heatmap(fields, "mean", 70, 24, BOUNDS, marks=marks, no_color=no_color, scale=False)
    plain = ANSI.sub("", img.ansi)
    star, dot = (MARK_FAST[1], MARK_MEASURED[1]) if no_color else (MARK_FAST[0], MARK_MEASURED[0])
    assert plain.count(star) >= 5  # the array's indents, as fast marks (never as hundreds of "newest")
    assert plain.count(dot) == 2  # a CSM indent wins a cell it shares with the array
    assert "◉" not in plain and "@" not in plain


def test_a_fast_array_is_named_as_one() -> None:
    block = fast_block(4, FastArray(500.0, 500.0, 20, 20, 50.0))
    words = block_words(block)
    assert words.program == "new program" and words.hold == "400 indents, no hold"
    assert words.text == (
        "new program: fast array 20×20 at 50 µm pitch over 950 × 950 µm around (500, 500) µm, 400 indents, no hold"
    )
    wait = InstrumentWait(4, "ticket", "2026-01-01T00:00:00+00:00", 60.0, "no export yet", False)
    text = "\n".join(str(part) for part in ticket_renderable(wait, 0.0, block).renderables)
    assert "FAST ARRAY" in text and "FAST ARRAY  400 indents, 20×20 at 50 µm pitch over 950 × 950 µm" in text
    csm = Block(4, "global", 500.0, 500.0, 1, 5.0, 80.0, (IndentSpec(500.0, 500.0, 80.0),))
    assert "FAST ARRAY" not in "\n".join(str(p) for p in ticket_renderable(wait, 0.0, csm).renderables)


async def test_the_console_shows_a_fast_run(live_run: object) -> None:
    """Rendering only: a real engine's snapshot, its second block's indents journaled as a fast array's and
    the map fields of a run whose two-fidelity map is active: the legend names the fast marks, the decision
    panel names the array, and `m` reaches the bias view."""
    run: LiveRun = live_run(supervision="auto")  # type: ignore[operator]
    for _ in range(2):
        run.finish_block()
    source = run.source()
    real = source.snapshot()
    source.close()
    assert real.last_decision is not None
    second = max(m.block_id for m in real.indents)
    indents = tuple(replace(m, channel="fast") if m.block_id == second else m for m in real.indents)
    array = fast_block(real.last_decision.block.block_id, FastArray(505.0, 505.0, 19, 19, 50.0))
    fields = replace(_campaign_after_an_array().map_fields(41, display_n=20), snapshot_id=41)
    snap = replace(
        real,
        indents=indents,
        last_decision=replace(real.last_decision, block=array),
        gp=replace(real.gp, snapshot_id=41),
    )
    canned = CannedSource(snap, fields)
    app = ConsoleApp(canned, poll_s=0.02, max_rate_hz=50.0, clock=lambda: 0.0, author="t", cursor_blink=False)
    async with app.run_test(size=(120, 36)) as pilot:
        await settle(pilot)
        n_fast = sum(1 for m in indents if m.channel == "fast")
        assert n_fast and f"{snap.n_indents} ind │ {n_fast} fast" in widget_text(app.query_one("#status"))
        legend = widget_text(app.query_one("#map-legend"))
        assert f"{MARK_FAST[0]} fast" in legend and f"{MARK_MEASURED[0]} measured" in legend
        decision = widget_text(app.query_one("#decision"))
        assert "NEW PROGRAM fast array 19×19 at 50 µm" in decision
        panel = app.query_one("#map")
        for _ in field_keys_of(fields)[1:]:
            await pilot.press("m")
        await wait_until(pilot, lambda: "fast-channel bias" in str(panel.border_title), what="the bias view")

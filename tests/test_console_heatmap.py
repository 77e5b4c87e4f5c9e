"""Heatmap geometry and colour: orientation as the sample is seen, real µm ticks, legible without colour."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

import core.runview as rv
from aeni_console.console.heatmap import (
    LEGEND,
    MARK_EARLIER,
    MARK_EXCLUDED,
    MARK_FAILED,
    MARK_NEWEST,
    MARK_NOT_RUN,
    MARK_OUTLINE,
    MARK_PLANNED,
    MARK_UNVERIFIED,
    SHADES,
    MapMarks,
    cell_of,
    field_array,
    nice_ticks,
    normalise,
    plot_area,
    render_heatmap,
    resample,
    tick_label,
    to_rgb,
    to_shades,
    value_range,
)
from core.runview import MapFields
from core.sample.load import load_sample

ROOT = Path(__file__).resolve().parents[1]

ANSI = re.compile(r"\x1b\[[0-9;]*m")
BOUNDS = (0.0, 1000.0, 0.0, 1000.0)


def ramp_fields(n: int = 50) -> MapFields:
    """Mean rises with x only (2 → 7 GPa); sd fields are constants we can recognise."""
    xs = np.linspace(0.0, 1000.0, n)
    mean = np.tile(2.0 + 5.0 * xs / 1000.0, (n, 1))
    return MapFields(
        snapshot_id=7,
        x_um=xs,
        y_um=xs.copy(),
        mean_gpa=mean,
        epistemic_sd_gpa=np.full((n, n), 0.3),
        noise_sd_gpa=np.full((n, n), 0.1),
        total_sd_gpa=np.full((n, n), 0.5),
    )


def test_nice_ticks_are_round_and_inside() -> None:
    assert nice_ticks(0, 1000, 5) == [0, 250, 500, 750, 1000]
    assert nice_ticks(0, 1000, 3) == [0, 500, 1000]
    assert nice_ticks(12.0, 988.0, 6) == [200, 400, 600, 800]
    ticks = nice_ticks(-3.3, 47.9, 6)
    assert ticks == [0, 10, 20, 30, 40]
    assert nice_ticks(5.0, 5.0) == [5.0]
    assert tick_label(250.0) == "250" and tick_label(12.5) == "12.5"


def test_colour_map_is_monotone_and_marks_missing() -> None:
    levels = np.linspace(0, 1, 11)
    rgb = to_rgb(levels, "viridis").astype(float)
    lightness = rgb @ np.array([0.299, 0.587, 0.114])
    assert np.all(np.diff(lightness) > 0)
    assert tuple(to_rgb(np.array([0.0]))[0]) == (68, 1, 84)
    assert tuple(to_rgb(np.array([1.0]))[0]) == (253, 231, 37)
    assert tuple(to_rgb(np.array([np.nan]))[0]) == (90, 90, 90)
    shades = to_shades(np.array([0.0, 0.3, 0.5, 0.7, 1.0, np.nan]))
    assert list(shades) == [SHADES[0], SHADES[1], SHADES[2], SHADES[3], SHADES[4], " "]


def test_value_range_and_normalise() -> None:
    assert value_range(np.array([[2.0, np.nan], [7.0, 3.0]])) == (2.0, 7.0)
    lo, hi = value_range(np.full((3, 3), 4.0))
    assert lo < 4.0 < hi
    np.testing.assert_allclose(normalise(np.array([2.0, 4.5, 7.0, 9.0]), 2.0, 7.0), [0.0, 0.5, 1.0, 1.0])


@pytest.mark.parametrize("reverse_x", [False, True])
def test_resample_orientation(reverse_x: bool) -> None:
    f = ramp_fields()
    r = resample(f.mean_gpa, f.x_um, f.y_um, cols=40, rows=10, bounds_um=BOUNDS, reverse_x=reverse_x)
    assert r.values.shape == (10, 40)
    left, right = r.values[0, 0], r.values[0, -1]
    if reverse_x:  # mirrored as on the iMicro: large x on the left
        assert left > 6.8 and right < 2.2
        assert r.x_um[0] > r.x_um[-1]
    else:
        assert left < 2.2 and right > 6.8
    # bilinear: a cell centre at x = 512.5 µm shows 2 + 5·0.5125
    cols = 40
    i = int(np.argmin(np.abs(r.x_um - 512.5)))
    assert r.values[3, i] == pytest.approx(2 + 5 * r.x_um[i] / 1000, abs=1e-9)
    assert cols == len(r.x_um)


def test_resample_puts_high_y_on_top() -> None:
    n = 20
    xs = np.linspace(0, 1000, n)
    f = np.tile((xs / 1000.0)[:, None], (1, n))  # value = y / 1000
    r = resample(f, xs, xs, cols=8, rows=8, bounds_um=BOUNDS)
    assert r.values[0, 0] > 0.9 and r.values[-1, 0] < 0.1
    assert r.y_um[0] > r.y_um[-1]


def test_cell_of_matches_resample_geometry() -> None:
    assert cell_of(0.0, 0.0, 40, 10, BOUNDS) == (0, 9)
    assert cell_of(999.9, 999.9, 40, 10, BOUNDS) == (39, 0)
    assert cell_of(999.9, 0.0, 40, 10, BOUNDS, reverse_x=True) == (0, 9)
    assert cell_of(1200.0, 10.0, 40, 10, BOUNDS) is None
    # a point lands in the cell whose centre resample() evaluates nearest to it
    r = resample(
        np.zeros((2, 2)), np.array([0, 1000.0]), np.array([0, 1000.0]), 40, 10, BOUNDS, reverse_x=True
    )
    c, row = cell_of(310.0, 720.0, 40, 10, BOUNDS, reverse_x=True)
    assert abs(r.x_um[c] - 310.0) <= 12.5 and abs(r.y_um[row] - 720.0) <= 50.0


def test_plot_area_accounts_for_labels_and_frame() -> None:
    assert plot_area(50, 18, ["0", "1000"]) == (44, 14)


def test_field_array_by_key() -> None:
    f = ramp_fields()
    assert field_array(f, "total")[0, 0] == 0.5
    with pytest.raises(ValueError, match="unknown map field"):
        field_array(f, "bogus")


def test_render_heatmap_colours_every_cell_and_labels_um() -> None:
    f = ramp_fields()
    img = render_heatmap(f, "mean", 60, 20, BOUNDS, reverse_x=False, keep_aspect=False)
    plain = ANSI.sub("", img.ansi)
    lines = plain.split("\n")
    assert len(lines) == 20
    assert "1000" in lines[1] and " 0┤" in "\n".join(lines)  # real µm ticks, not bin numbers
    assert "x µm" in plain and "GPa" in lines[0]
    colours = re.findall(r"38;2;(\d+);(\d+);(\d+)m▀", img.ansi)
    cols, rows = plot_area(60 - 10, 20, ["0", "250", "500", "750", "1000"])
    assert len(colours) == cols * rows  # one RGB cell per character, no gaps
    assert img.vmin == pytest.approx(2.0) and img.vmax == pytest.approx(7.0)
    first_row = [tuple(map(int, c)) for c in colours[:cols]]
    assert first_row[0] == (68, 1, 84) or sum(first_row[0]) < sum(first_row[-1])  # low x is dark


def test_render_heatmap_mirrors_and_marks_the_newest_block_and_planned_sites() -> None:
    f = ramp_fields()
    marks = MapMarks(
        indents=(
            rv.IndentMark(100, 100, 0, "measured"),
            rv.IndentMark(500, 500, 1, "measured"),
            rv.IndentMark(900, 900, 2, "measured"),
        ),
        planned_um=(((900, 100),),),
        newest_block_id=2,
    )
    img = render_heatmap(f, "mean", 60, 20, BOUNDS, marks=marks, reverse_x=True)
    lines = ANSI.sub("", img.ansi).split("\n")
    newest = [(i, ln.index("◉")) for i, ln in enumerate(lines) if "◉" in ln]
    older = [(i, ln.index("•")) for i, ln in enumerate(lines) if "•" in ln]
    nxt = [(i, ln.index("+", 5)) for i, ln in enumerate(lines[1:-3], start=1) if "+" in ln[5:]]
    assert len(newest) == 1 and len(older) == 2
    # mirrored: x = 900 is drawn left of x = 100; y = 900 above y = 100
    (row_new, col_new) = newest[0]
    low = max(older, key=lambda p: p[0])  # (100, 100): lowest row
    assert col_new < low[1] and row_new < low[0]
    assert nxt and nxt[0][1] < low[1]
    assert "mirrored" in "\n".join(lines)


def niticu_marks() -> tuple[MapMarks, tuple[float, float, float, float]]:
    """The worked example's sample (docs/examples): its outline, two exclusions and earlier indents."""
    sample = load_sample(ROOT / "docs" / "examples" / "NiTiCu-library-07.toml")
    c = sample.calibration
    corners = [(k.x_um, k.y_um) for k in (c.tl, c.tr, c.br, c.bl)]
    xs, ys = [p[0] for p in corners], [p[1] for p in corners]
    marks = MapMarks(
        outline_um=tuple(corners),
        exclusions=sample.exclusions,
        earlier_um=sample.earlier_indents_um,
        indents=(
            rv.IndentMark(12400.0, 8900.0, 0, "measured"),
            rv.IndentMark(12900.0, 8300.0, 0, "failed"),
            rv.IndentMark(13200.0, 8900.0, 0, "not_run"),
            rv.IndentMark(12300.0, 8500.0, 0, "unverified"),
        ),
        planned_um=(((13000.0, 8600.0), (13100.0, 8600.0)),),
        newest_block_id=0,
    )
    return marks, (min(xs), max(xs), min(ys), max(ys))


def test_every_meaning_has_its_own_character_with_and_without_colour() -> None:
    chars = {i: [m[i] for m, _ in LEGEND] for i in (0, 1)}
    for shown in chars.values():
        assert len(set(shown)) == len(shown), f"two meanings share a character: {shown}"
    assert not set(chars[1]) & set(SHADES), "a no-colour marker looks like a shade of the field"


@pytest.mark.parametrize("no_color", [False, True])
def test_the_map_shows_the_sample_as_it_is(no_color: bool) -> None:
    marks, bounds = niticu_marks()
    xs = np.linspace(bounds[0], bounds[1], 30)
    ys = np.linspace(bounds[2], bounds[3], 30)
    z = np.full((30, 30), 5.0) + np.linspace(0, 1, 30)[None, :]
    f = MapFields(1, xs, ys, z, z, z, z)
    img = render_heatmap(f, "mean", 60, 22, bounds, marks=marks, reverse_x=True, no_color=no_color)
    body = "\n".join(ln[5:] for ln in ANSI.sub("", img.ansi).split("\n")[1:-3])
    i = 1 if no_color else 0
    for mark in (MARK_OUTLINE, MARK_EXCLUDED, MARK_FAILED, MARK_NOT_RUN, MARK_UNVERIFIED, MARK_PLANNED):
        assert mark[i] in body, f"{mark} not drawn"
    assert MARK_NEWEST[i] in body  # the measured indent of the newest block
    assert MARK_EARLIER[i] in body
    # the polygon exclusion sits at the bottom-left corner (BL = 12000, 8000): mirrored, that is the right
    rows = body.split("\n")
    bottom = rows[-2]
    assert bottom.rstrip().endswith(MARK_EXCLUDED[i]) or MARK_EXCLUDED[i] in bottom[len(bottom) // 2 :]


def test_render_without_fields_draws_an_empty_frame() -> None:
    img = render_heatmap(None, "mean", 40, 12, BOUNDS)
    assert img.snapshot_id is None and "┌" in img.ansi and "GPa" not in img.ansi


def test_large_panels_are_not_clipped_to_the_process_terminal() -> None:
    # plotext would clip to the size of the terminal the process runs in (a worker has none)
    img = render_heatmap(
        ramp_fields(),
        "mean",
        150,
        60,
        BOUNDS,
        marks=MapMarks(indents=(rv.IndentMark(10, 10, 0, "measured"),)),
    )
    assert len(img.ansi.split("\n")) == 60 and len(img.text.split("\n")) == 60


def test_each_character_shows_two_pixels_upper_above_lower() -> None:
    from rich.console import Console

    n = 40
    ys = np.linspace(0.0, 1000.0, n)
    rising = np.tile((2.0 + 5.0 * ys / 1000.0)[:, None], (1, n))  # hardness grows with y only
    f = MapFields(1, ys, ys.copy(), rising, rising, rising, rising)
    img = render_heatmap(f, "mean", 50, 16, BOUNDS, keep_aspect=False, scale=False)
    lines = img.text.split("\n")
    console = Console()
    x0 = lines[1].plain.index("┤") + 1
    fg_lightness, bg_lightness = [], []
    for row in (1, 6, 11):
        style = lines[row].get_style_at_offset(console, x0 + 3)
        fg, bg = style.color.get_truecolor(), style.bgcolor.get_truecolor()
        assert lines[row].plain[x0 + 3] == "▀"
        fg_lightness.append(sum(fg))
        bg_lightness.append(sum(bg))
        assert sum(fg) > sum(bg)  # the upper pixel (larger y) is the harder, lighter one
    assert fg_lightness[0] > fg_lightness[1] > fg_lightness[2]

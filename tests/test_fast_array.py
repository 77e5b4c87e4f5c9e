"""The profile's fast mode ([fast]) and the cost of a fast array, against figures worked out by hand."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from core.cost import CostLedger
from core.errors import InputError
from core.fast_array import FastArray, check_fast_array, price_fast_array
from core.profile import FastMode, load_profile, profile_from_dict, profile_to_dict

FAST_TABLE = (
    "[fast]\nindent_s = 2.0\ncolumn_change_s = 4.0\nmax_extent_um = 800.0\nmin_pitch_um = 10.0\n"
    'peak_load_mn = 10.0\nsurface_find = true\ndrift_settle = false\nmethod = "Lab NanoBlitz.nmt"\n'
)


def test_kla_imicro_declares_the_fast_mode_of_spec_9() -> None:
    fast = load_profile("kla-imicro").fast
    assert fast == FastMode(
        indent_s=1.0,
        column_change_s=3.0,
        max_extent_um=1000.0,
        min_pitch_um=5.0,
        peak_load_mn=5.0,
        surface_find=True,
        drift_settle=True,
    )
    assert load_profile("kla-imicro-film").fast == fast  # inherited


def test_profile_without_the_section_has_no_fast_mode(tmp_path: Path) -> None:
    f = tmp_path / "plain.toml"
    f.write_text('name = "plain"\n[steps]\nlift_s = 30\n', encoding="utf-8")
    assert load_profile(f).fast is None
    off = tmp_path / "off.toml"
    off.write_text('name = "off"\nextends = "kla-imicro"\n[fast]\navailable = false\n', encoding="utf-8")
    p = load_profile(off)
    assert p.fast is None
    with pytest.raises(InputError, match="has no fast mode"):
        price_fast_array(p, FastArray(500.0, 500.0, 2, 2, 10.0), (0.0, 0.0), False)


def test_own_fast_section_and_round_trip(tmp_path: Path) -> None:
    f = tmp_path / "lab.toml"
    f.write_text('name = "lab"\n' + FAST_TABLE, encoding="utf-8")
    p = load_profile(f)
    assert p.fast is not None
    assert (p.fast.indent_s, p.fast.column_change_s, p.fast.drift_settle) == (2.0, 4.0, False)
    assert p.fast.method == "Lab NanoBlitz.nmt"  # the InView method a fast array's ticket names
    assert profile_from_dict(profile_to_dict(p)) == p
    # a child overrides one field of an inherited section
    g = tmp_path / "child.toml"
    g.write_text('name = "child"\nextends = "kla-imicro"\n[fast]\nindent_s = 4.0\n', encoding="utf-8")
    child = load_profile(g).fast
    assert child is not None and child.indent_s == 4.0 and child.column_change_s == 3.0
    # journals written before the fast mode have no "fast": none
    old = profile_to_dict(load_profile("kla-imicro"))
    del old["fast"]
    assert profile_from_dict(old).fast is None


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ('name = "x"\n[fast]\nindent_s = 1.0\n', "fast.column_change_s"),  # incomplete without a parent
        ('extends = "kla-imicro"\n[fast]\nindent_s = -1\n', "fast.indent_s"),
        ('extends = "kla-imicro"\n[fast]\nindent_s = 0\n', "fast.indent_s"),
        ('extends = "kla-imicro"\n[fast]\npeak_load_mn = "5 mN"\n', "fast.peak_load_mn"),
        ('extends = "kla-imicro"\n[fast]\nsurface_find = 1\n', "fast.surface_find"),
        ('name = "x"\n' + FAST_TABLE.replace('method = "Lab NanoBlitz.nmt"\n', ""), "fast.method"),
        ('extends = "kla-imicro"\n[fast]\nmethod = " "\n', "fast.method"),
        ('extends = "kla-imicro"\n[fast]\nmethod = 3\n', "fast.method"),
        ('extends = "kla-imicro"\n[fast]\nwarp_s = 1\n', "fast.warp_s"),
        ('extends = "kla-imicro"\n[fast]\nmin_pitch_um = 2000.0\n', "fast.min_pitch_um"),
        ('extends = "kla-imicro"\n[fast]\navailable = "no"\n', "fast.available"),
        ('extends = "kla-imicro"\n[fast]\navailable = false\nindent_s = 1\n', "fast.available"),
        ('extends = "kla-imicro"\nfast = 3\n', "[fast] must be a table"),
    ],
)
def test_bad_fast_fields_are_one_line_naming_the_field(tmp_path: Path, text: str, needle: str) -> None:
    f = tmp_path / "bad.toml"
    f.write_text(text, encoding="utf-8")
    with pytest.raises(InputError) as err:
        load_profile(f)
    assert needle in str(err.value) and "\n" not in str(err.value)


def _axis_s(d: float) -> float:
    """SPEC §3's move law for d < 500 µm, written out again."""
    return 4196.41 * math.exp(4.99e-7 * d) - 4195.05


def test_fast_array_cost_by_hand() -> None:
    p = load_profile("kla-imicro")
    array = FastArray(500.0, 500.0, rows=10, cols=20, pitch_um=10.0)
    assert array.first_site_um == (405.0, 455.0)  # extent 190 × 90 µm about the centre
    cost = price_fast_array(p, array, (0.0, 0.0), program_open=False)
    # set-up 20 + lens travel 20 + lift 30; the lifted move; surface find 65; drift 300;
    # 200 indents × 1 s; 19 column changes × 3 s
    travel = _axis_s(405.0) + _axis_s(455.0)
    assert travel == pytest.approx(4.521, abs=1e-3)
    assert cost.opening_s == 70.0
    assert cost.travel_s == pytest.approx(travel)
    assert (cost.surface_find_s, cost.drift_settle_s) == (65.0, 300.0)
    assert (cost.indents_s, cost.column_changes_s) == (200.0, 57.0)
    assert cost.total_s == pytest.approx(70.0 + travel + 65.0 + 300.0 + 200.0 + 57.0)
    assert cost.total_s == pytest.approx(696.52, abs=0.01)
    ledger = CostLedger().extend(cost.steps)
    assert ledger.total_s == pytest.approx(cost.total_s)
    assert ledger.seconds["drift"] == 300.0 and ledger.reconfigurations == 0
    # with a program running: its comeback (35 s) first
    assert price_fast_array(p, array, (0.0, 0.0), program_open=True).total_s == pytest.approx(
        cost.total_s + 35.0
    )


def test_fast_array_against_a_csm_block() -> None:
    """One 1×1 CSM block is ≈ 550 s (SPEC §3); a 1 mm array of 101 × 101 fast indents (10 µm) is
    10,201 s of indents + 100 × 3 s of column changes on top of the same ≈ 435 s opening."""
    p = load_profile("kla-imicro")
    one = price_fast_array(p, FastArray(500.0, 500.0, 1, 1, 10.0), (500.0, 500.0), False)
    assert one.total_s == pytest.approx(20 + 20 + 30 + 65 + 300 + 1.0)
    big = price_fast_array(p, FastArray(500.0, 500.0, 101, 101, 10.0), (0.0, 0.0), False)
    assert big.indents_s == 10_201.0 and big.column_changes_s == 300.0
    assert big.travel_s == 0.0  # its first site is the start
    assert big.total_s == pytest.approx(70 + 365 + 10_501.0)


def test_film_profile_opens_an_array_with_its_flat_jump() -> None:
    p = load_profile("kla-imicro-film")
    cost = price_fast_array(p, FastArray(10_500.0, 20_500.0, 5, 5, 10.0), (10_000.0, 20_000.0), True)
    # 520 s holds lift, engage and settle: no surface find or settle on top
    assert cost.opening_s == 520.0 and cost.surface_find_s == 0.0 and cost.drift_settle_s == 0.0
    assert cost.total_s == pytest.approx(520.0 + cost.travel_s + 25.0 + 4 * 3.0)


@pytest.mark.parametrize(
    ("array", "needle"),
    [
        (FastArray(500.0, 500.0, 0, 3, 10.0), "fast_array.rows"),
        (FastArray(500.0, 500.0, 3, 3, 2.0), "fast_array.pitch_um"),
        (FastArray(500.0, 500.0, 3, 102, 10.0), "fast.max_extent_um"),
        (FastArray(math.nan, 500.0, 3, 3, 10.0), "fast_array.center_x_um"),
    ],
)
def test_impossible_arrays_are_refused(array: FastArray, needle: str) -> None:
    with pytest.raises(InputError, match=needle.replace(".", r"\.")):
        check_fast_array(load_profile("kla-imicro"), array)


@settings(max_examples=40, deadline=None)
@given(
    rows=st.integers(1, 30),
    cols=st.integers(1, 30),
    pitch=st.floats(5.0, 30.0),
)
def test_sites_snake_by_column_one_pitch_apart(rows: int, cols: int, pitch: float) -> None:
    array = FastArray(500.0, 500.0, rows, cols, pitch)
    sites = array.sites_um()
    assert sites.shape == (rows * cols, 2)
    assert tuple(sites[0]) == pytest.approx(array.first_site_um)
    if rows * cols > 1:
        hops = np.hypot(*np.diff(sites, axis=0).T)
        assert np.allclose(hops, pitch)  # every hop one pitch: the safety rule never fires inside
    assert len({(round(x, 6), round(y, 6)) for x, y in sites}) == rows * cols
    cost = price_fast_array(load_profile("kla-imicro"), array, (500.0, 500.0), False)
    assert cost.column_changes_s == pytest.approx(3.0 * (cols - 1))

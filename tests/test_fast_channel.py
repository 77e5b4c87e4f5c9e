"""The emulator's fast channel (drivers/sim/fast_channel.py): the physics of SPEC §9, failures, seeds, files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from core.errors import InputError
from drivers.sim.emulator import (
    PhaseBoundaryField,
    TernaryField,
    TruthField,
    truth_modulus_gpa,
    truth_modulus_noise_sd_gpa,
)
from drivers.sim.fast_channel import (
    CsmAtSites,
    FastPhysics,
    SurfaceLayer,
    contact_depth_nm,
    expected_reading,
    h_star_nm,
    read_array,
    read_fast_table,
)

PHYSICS = FastPhysics(peak_load_mn=5.0)


def _sites(n: int = 25) -> tuple[np.ndarray, np.ndarray]:
    x, y = np.meshgrid(np.linspace(5.0, 995.0, n), np.linspace(5.0, 995.0, n))
    return x.ravel(), y.ravel()


def _csm(truth: TruthField, x: np.ndarray, y: np.ndarray) -> CsmAtSites:
    return CsmAtSites(
        truth.hardness_gpa(x, y),
        truth.noise_sd_gpa(x, y),
        truth_modulus_gpa(truth, x, y),
        truth_modulus_noise_sd_gpa(truth, x, y),
    )


def _uniform(h: float, n: int = 1, e: float = 150.0, sd: float = 0.05) -> CsmAtSites:
    return CsmAtSites(np.full(n, h), np.full(n, sd), np.full(n, e), np.full(n, 0.02 * e))


def test_depth_is_berkovich_at_the_peak_load() -> None:
    # no size effect: h_c = √(P / (24.5 H)); 5 mN into 5 GPa: √(5e-3 / (24.5 × 5e9)) m = 202.03 nm
    assert contact_depth_nm(5.0, np.array([5.0]), np.array([0.0]))[0] == pytest.approx(202.03, abs=0.01)
    # with it, the hardness the indent sees carries the load on its own area: P = 24.5 h² H0 √(1 + h*/h)
    h = contact_depth_nm(5.0, np.array([5.0]), np.array([100.0]))[0]
    assert 24.5 * (h * 1e-9) ** 2 * 5e9 * np.sqrt(1 + 100.0 / h) == pytest.approx(5e-3, rel=1e-9)


@settings(max_examples=50, deadline=None)
@given(h_soft=st.floats(1.0, 20.0), factor=st.floats(1.05, 3.0), e=st.floats(50.0, 400.0))
def test_harder_is_probed_shallower(h_soft: float, factor: float, e: float) -> None:
    soft = expected_reading(PHYSICS, np.zeros(1), np.zeros(1), _uniform(h_soft, e=e))
    hard = expected_reading(PHYSICS, np.zeros(1), np.zeros(1), _uniform(h_soft * factor, e=e))
    assert hard.depth_nm[0] < soft.depth_nm[0]


def test_size_effect_raises_hardness_at_shallow_depth() -> None:
    csm = _uniform(5.0, e=125.0)
    readings = [
        expected_reading(FastPhysics(peak_load_mn=p), np.zeros(1), np.zeros(1), csm) for p in (1, 5, 50)
    ]
    depths = [r.depth_nm[0] for r in readings]
    values = [r.hardness_gpa[0] for r in readings]
    assert depths[0] < depths[1] < depths[2]
    assert values[0] > values[1] > values[2] > 5.0  # Nix–Gao: the shallower, the harder; always above H0
    r = readings[1]  # H = H0 √(1 + h*/h) at its own depth, h* = 100 nm × ((125/5)/25)² = 100 nm
    assert r.h_star_nm[0] == pytest.approx(100.0)
    assert r.hardness_gpa[0] == pytest.approx(5.0 * np.sqrt(1.0 + 100.0 / r.depth_nm[0]))


def test_h_star_varies_across_the_library_within_tens_to_hundreds_of_nm() -> None:
    x, y = _sites()
    for truth in (TernaryField(), PhaseBoundaryField()):
        hs = h_star_nm(PHYSICS, truth.hardness_gpa(x, y), truth_modulus_gpa(truth, x, y))
        assert hs.min() >= 20.0 and hs.max() <= 400.0
        assert hs.max() > 2.0 * hs.min()  # material-dependent, not one number
    # the phase boundary: h* jumps with the material (the hard phase is compliant: smaller μ/H)
    pb = PhaseBoundaryField()
    d = pb.signed_distance_um(x, y)
    hs = h_star_nm(PHYSICS, pb.hardness_gpa(x, y), truth_modulus_gpa(pb, x, y))
    assert np.median(hs[d > 50]) < 0.6 * np.median(hs[d < -50])


def test_roughness_scatter_is_worse_at_shallow_depth() -> None:
    shallow = expected_reading(FastPhysics(peak_load_mn=0.5), np.zeros(1), np.zeros(1), _uniform(5.0))
    deep = expected_reading(FastPhysics(peak_load_mn=50.0), np.zeros(1), np.zeros(1), _uniform(5.0))
    assert shallow.area_rel_sd[0] > 3.0 * deep.area_rel_sd[0]
    assert shallow.noise_sd_gpa[0] / shallow.hardness_gpa[0] > deep.noise_sd_gpa[0] / deep.hardness_gpa[0]


@pytest.mark.parametrize("truth", [TernaryField(), PhaseBoundaryField()], ids=["ternary", "phase-boundary"])
def test_fast_scatter_is_two_to_three_times_the_csm(truth: TruthField) -> None:
    x, y = _sites()
    csm = _csm(truth, x, y)
    exp = expected_reading(PHYSICS, x, y, csm)
    ratio = exp.noise_sd_gpa / csm.noise_sd_gpa
    assert ratio.min() >= 2.0 and ratio.max() <= 3.0
    # the drawn readings scatter as said: many readings at one site
    n = 4000
    site = CsmAtSites(*(np.full(n, float(getattr(csm, f)[100])) for f in CsmAtSites.__dataclass_fields__))
    r = read_array(
        FastPhysics(peak_load_mn=5.0, failure_rate=0.0), 3, 0, np.full(n, x[100]), np.full(n, y[100]), site
    )
    assert np.std(r.hardness_gpa) == pytest.approx(exp.noise_sd_gpa[100], rel=0.06)
    assert np.mean(r.hardness_gpa) == pytest.approx(
        exp.hardness_gpa[100], abs=4 * exp.noise_sd_gpa[100] / np.sqrt(n)
    )


def test_failures_are_failures_never_numbers() -> None:
    x, y = _sites(40)
    r = read_array(FastPhysics(peak_load_mn=5.0, failure_rate=0.1), 7, 2, x, y, _csm(TernaryField(), x, y))
    assert 0.07 < r.failed.mean() < 0.13
    for values in (r.hardness_gpa, r.modulus_gpa, r.depth_nm):
        assert np.all(np.isnan(values[r.failed]))
        assert np.all(np.isfinite(values[~r.failed])) and np.all(values[~r.failed] > 0)


def test_reproducible_by_seed_array_and_index() -> None:
    x, y = _sites(10)
    csm = _csm(TernaryField(), x, y)
    a = read_array(PHYSICS, 5, 1, x, y, csm)
    b = read_array(PHYSICS, 5, 1, x, y, csm)
    np.testing.assert_array_equal(a.hardness_gpa, b.hardness_gpa)
    np.testing.assert_array_equal(a.failed, b.failed)
    assert not np.allclose(a.hardness_gpa, read_array(PHYSICS, 6, 1, x, y, csm).hardness_gpa, equal_nan=True)
    assert not np.allclose(a.hardness_gpa, read_array(PHYSICS, 5, 2, x, y, csm).hardness_gpa, equal_nan=True)
    # the tail of the array read again on its own (a resumed run) reads the same values
    tail = np.arange(60, 100)
    part = CsmAtSites(*(getattr(csm, f)[tail] for f in CsmAtSites.__dataclass_fields__))
    c = read_array(PHYSICS, 5, 1, x[tail], y[tail], part, indices=tail)
    np.testing.assert_array_equal(c.hardness_gpa, a.hardness_gpa[tail])


def test_a_surface_layer_hides_what_lies_under_it_from_shallow_indents() -> None:
    layer = SurfaceLayer(centre_um=(0.0, 0.0), radius_um=100.0, thickness_nm=1000.0, hardness_gpa=4.0)
    physics = FastPhysics(peak_load_mn=5.0, layer=layer)
    xs = np.array([0.0, 0.0, 500.0, 500.0])
    csm = CsmAtSites(np.array([4.0, 7.0, 4.0, 7.0]), np.full(4, 0.05), np.full(4, 120.0), np.full(4, 2.0))
    r = expected_reading(physics, xs, np.zeros(4), csm)
    under = r.hardness_gpa[1] - r.hardness_gpa[0]  # a 3 GPa difference under the layer
    bare = r.hardness_gpa[3] - r.hardness_gpa[2]
    assert bare > 2.0 and under < 0.15 * bare


def test_truth_csv_fast_columns(tmp_path: Path) -> None:
    f = tmp_path / "truth.csv"
    lines = ["x_um,y_um,hardness_gpa,noise_sd_gpa,fast_hardness_gpa,fast_noise_sd_gpa"]
    for xv in (0.0, 100.0):
        for yv in (0.0, 100.0):
            lines.append(f"{xv},{yv},5.0,0.05,{6.0 + xv / 100.0},0.2")
    f.write_text("\n".join(lines) + "\n", encoding="utf-8")
    table = read_fast_table(f)
    assert table is not None and table.columns == ("fast_hardness_gpa", "fast_noise_sd_gpa")
    csm = _uniform(5.0, n=2)
    r = expected_reading(PHYSICS, np.array([50.0, 100.0]), np.array([50.0, 0.0]), csm, table)
    np.testing.assert_allclose(r.hardness_gpa, [6.5, 7.0])  # the file's reading, not the physics'
    np.testing.assert_allclose(r.noise_sd_gpa, [0.2, 0.2])
    assert r.depth_nm[1] < r.depth_nm[0]  # its depth follows what it reads
    plain = tmp_path / "plain.csv"
    plain.write_text("x_um,y_um,hardness_gpa\n0,0,5\n1,0,5\n0,1,5\n1,1,5\n", encoding="utf-8")
    assert read_fast_table(plain) is None


@pytest.mark.parametrize(
    ("header", "row", "needle"),
    [
        ("x_um,y_um,fast_noise_sd_gpa", "{x},{y},0.1", "no fast_hardness_gpa"),
        ("x_um,y_um,fast_modulus_noise_sd_gpa", "{x},{y},0.1", "no fast_modulus_gpa"),
        ("x_um,y_um,fast_hardness_gpa", "{x},{y},-3", "fast_hardness_gpa"),
        ("x_um,y_um,fast_hardness_gpa", "{x},{y},abc", "'abc' is not a number"),
        ("x_um,y_um,fast_hardness_gpa,fast_noise_sd_gpa", "{x},{y},5,-1", "fast_noise_sd_gpa"),
        ("y_um,fast_hardness_gpa", "{y},5", "missing column x_um"),
    ],
)
def test_bad_fast_columns_are_one_line(tmp_path: Path, header: str, row: str, needle: str) -> None:
    f = tmp_path / "bad.csv"
    rows = [row.format(x=xv, y=yv) for xv in (0, 100) for yv in (0, 100)]
    f.write_text(header + "\n" + "\n".join(rows) + "\n", encoding="utf-8")
    with pytest.raises(InputError) as err:
        read_fast_table(f)
    assert needle in str(err.value) and "bad.csv" in str(err.value) and "\n" not in str(err.value)

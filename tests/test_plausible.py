"""Plausibility bounds: impossible values are refused with the likely unit slip named (issue 15)."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from core.errors import InputError
from core.plausible import (
    MAX_HARDNESS_GPA,
    check_hardness_gpa,
    check_modulus_gpa,
    check_noise_sd_gpa,
    check_stage_um,
)


def test_mpa_under_hardness_gpa_is_named() -> None:
    with pytest.raises(
        InputError, match=r"hardness_gpa 4000 GPa is impossible .*looks like MPa \(4000 MPa = 4 GPa\)"
    ):
        check_hardness_gpa("t.csv: line 2", 4000.0)


def test_modulus_in_mpa_is_named() -> None:
    with pytest.raises(InputError, match=r"looks like MPa \(210000 MPa = 210 GPa\)"):
        check_modulus_gpa("e.csv", 210_000.0)


def test_real_values_pass() -> None:
    for h in (0.05, 2.77, 7.0, 40.0, 100.0):
        assert check_hardness_gpa("x", h) == h
    assert check_modulus_gpa("x", 1_100.0) == 1_100.0  # diamond
    assert check_noise_sd_gpa("x", 0.1, 3.0) == 0.1
    assert check_stage_um("x", "x_um", 52_000.0, 0.0, 100_000.0) == 52_000.0


def test_noise_as_large_as_the_value_is_refused() -> None:
    with pytest.raises(InputError, match=r"noise_sd_gpa 50 GPa is not below the hardness 4 GPa.*MPa"):
        check_noise_sd_gpa("t.csv: line 3", 50.0, 4.0)
    with pytest.raises(InputError, match="≥ 0"):
        check_noise_sd_gpa("t.csv", -0.1, 4.0)


def test_stage_coordinates_name_the_unit() -> None:
    with pytest.raises(InputError, match=r"x_um 5e\+07 µm is outside the reach of any stage .*looks like nm"):
        check_stage_um("p.csv: line 4", "x_um", 5e7, 0.0, 100_000.0)
    with pytest.raises(
        InputError, match=r"x_um 1e\+12 µm is outside the reach of any stage \(0 to 100000 µm\)$"
    ):
        check_stage_um("p.csv", "x_um", 1e12, 0.0, 100_000.0)
    with pytest.raises(InputError, match="not a finite number"):
        check_stage_um("p.csv", "y_um", float("nan"), 0.0, 100_000.0)


@given(st.floats(min_value=MAX_HARDNESS_GPA * 1.0001, max_value=1e30, allow_nan=False))
def test_every_impossible_hardness_is_refused(h: float) -> None:
    with pytest.raises(InputError, match="impossible"):
        check_hardness_gpa("t.csv", h)


@given(st.floats(min_value=1e-6, max_value=MAX_HARDNESS_GPA))
def test_every_possible_hardness_passes(h: float) -> None:
    assert check_hardness_gpa("t.csv", h) == h

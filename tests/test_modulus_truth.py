"""The emulator's modulus truth (issue 27): every field has one, and it never changes the hardness a run sees."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from core.errors import InputError
from drivers.sim.emulator import (
    CsvTruth,
    DriftModel,
    Emulator,
    NoiseOverride,
    TernaryField,
    TruthField,
    modulus_from_hardness_gpa,
    modulus_on_lattice,
    truth_modulus_gpa,
    truth_modulus_noise_sd_gpa,
    truth_on_lattice,
)
from drivers.sim.robust_fields import ROBUST_FIELDS, robust_scenario
from drivers.sim.scenarios import SCENARIOS, make_scenario

FIELDS = [n for n in SCENARIOS if n != "csv"] + list(ROBUST_FIELDS)


def _truth(name: str) -> TruthField:
    return make_scenario(name, 2).truth if name in SCENARIOS else robust_scenario(name, 2).truth


class _HardnessOnly:
    """A field with the hardness and noise of another but no modulus of its own."""

    def __init__(self, base: TruthField) -> None:
        self.base, self.name, self.bounds_um = base, base.name, base.bounds_um

    def hardness_gpa(self, x_um: np.ndarray, y_um: np.ndarray) -> np.ndarray:
        return self.base.hardness_gpa(x_um, y_um)

    def noise_sd_gpa(self, x_um: np.ndarray, y_um: np.ndarray) -> np.ndarray:
        return self.base.noise_sd_gpa(x_um, y_um)


@pytest.mark.parametrize("name", FIELDS)
def test_every_field_has_a_plausible_modulus_of_its_own(name: str) -> None:
    truth = _truth(name)
    _, _, h = truth_on_lattice(truth, 40)
    _, _, e = modulus_on_lattice(truth, 40)
    _, _, _ = truth_on_lattice(truth, 2)
    assert np.all(np.isfinite(e)) and np.all(e > 0)
    ratio = e / h
    assert ratio.min() > 10.0 and ratio.max() < 80.0  # E/H of metallic and ceramic films
    # its own field, not E(H): somewhere the ranking of E differs from the ranking of H
    assert not np.allclose(e, modulus_from_hardness_gpa(h), rtol=0.02)
    x0, x1, y0, y1 = truth.bounds_um
    gx, gy = np.meshgrid(np.linspace(x0, x1, 20), np.linspace(y0, y1, 20))
    sd = truth_modulus_noise_sd_gpa(truth, gx, gy)
    assert np.all(sd > 0) and np.all(sd < 0.1 * truth_modulus_gpa(truth, gx, gy))


def test_ternary_modulus_follows_the_composition_but_its_hardest_corner_is_compliant() -> None:
    truth = TernaryField()
    _, _, h = truth_on_lattice(truth, 60)
    _, _, e = modulus_on_lattice(truth, 60)
    assert np.corrcoef(h.ravel(), e.ravel())[0, 1] > 0.2  # the composition drives both
    # the C corner (bottom left) is the hardest, but not the stiffest: its H/E is about twice B's (top left)
    c_corner, b_corner = (5.0, 5.0), (5.0, 995.0)
    h_c, h_b = truth.hardness_gpa(*c_corner), truth.hardness_gpa(*b_corner)
    e_c, e_b = truth.modulus_gpa(*c_corner), truth.modulus_gpa(*b_corner)
    assert h_c > h_b and e_c < e_b
    assert (h_c / e_c) > 1.5 * (h_b / e_b)


@pytest.mark.parametrize("name", ["ternary", "film", "rough", "phase-noise", "outliers"])
def test_the_modulus_never_changes_the_hardness_a_run_sees(name: str) -> None:
    """The modulus draws come from their own stream: a field with or without a modulus gives the same
    hardness, position and drift reading for every indent."""
    sc = make_scenario(name, 4) if name in SCENARIOS else robust_scenario(name, 4)
    with_e = sc.make_emulator()
    without = Emulator(
        _HardnessOnly(sc.truth),
        sc.drift,
        sc.seed,
        lateral_sd_um=sc.lateral_sd_um,
        t_measure_s=with_e.t_measure_s,
        full_correction_hold_s=with_e.full_correction_hold_s,
        site_texture=sc.site_texture,
    )
    x0, x1, y0, y1 = sc.truth.bounds_um
    rng = np.random.default_rng(1)
    for i in range(30):
        x, y = x0 + (x1 - x0) * rng.uniform(), y0 + (y1 - y0) * rng.uniform()
        a = with_e.measure(x, y, 5.0, 60.0 * i, i // 4, i % 4)
        b = without.measure(x, y, 5.0, 60.0 * i, i // 4, i % 4)
        assert (a.hardness_gpa, a.actual_x_um, a.actual_y_um, a.drift_rate_nm_s) == (
            b.hardness_gpa,
            b.actual_x_um,
            b.actual_y_um,
            b.drift_rate_nm_s,
        )
        # the field without one gets E(H) (a pore reads low in both)
        assert sc.site_texture is not None or b.modulus_gpa == pytest.approx(
            float(modulus_from_hardness_gpa(sc.truth.hardness_gpa(*_clip(b, sc.truth)))), rel=0.2
        )


def _clip(m: object, truth: TruthField) -> tuple[float, float]:
    x0, x1, y0, y1 = truth.bounds_um
    return min(max(m.actual_x_um, x0), x1), min(max(m.actual_y_um, y0), y1)  # type: ignore[attr-defined]


def test_repeated_indents_scatter_with_the_shared_area_error_and_the_fields_own() -> None:
    truth = TernaryField()
    emu = Emulator(truth, DriftModel.scenario("none", 0), seed=3)
    x, y = 100.0, 150.0  # near C, where E scatters most and H least
    m = [emu.measure(x, y, 80.0, 0.0, 0, i) for i in range(1500)]
    e = np.array([r.modulus_gpa for r in m])
    h_rel = float(truth.noise_sd_gpa(x, y) / truth.hardness_gpa(x, y))
    e_rel = float(truth.modulus_noise_sd_gpa(x, y) / truth.modulus_gpa(x, y))
    expected = float(np.hypot(0.5 * h_rel, e_rel))
    assert np.std(e) / np.mean(e) == pytest.approx(expected, rel=0.1)
    assert np.mean(e) == pytest.approx(float(truth.modulus_gpa(x, y)), rel=0.005)


def test_noise_modes_apply_to_the_modulus_too() -> None:
    homo = NoiseOverride(TernaryField(), "homo")
    gx, gy = np.meshgrid(np.linspace(0, 1000, 7), np.linspace(0, 1000, 7))
    sd = homo.modulus_noise_sd_gpa(gx, gy)
    assert np.ptp(sd) == 0.0 and sd[0, 0] > 0
    assert np.array_equal(homo.modulus_gpa(gx, gy), TernaryField().modulus_gpa(gx, gy))
    assert np.ptp(TernaryField(noise="homo").modulus_noise_sd_gpa(gx, gy)) == 0.0


def _csv(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "truth.csv"
    path.write_text(text)
    return path


def test_a_truth_csv_may_carry_the_modulus_and_its_scatter(tmp_path: Path) -> None:
    rows = ["x_um,y_um,hardness_gpa,modulus_gpa,modulus_noise_sd_gpa"]
    for x in (0.0, 100.0):
        for y in (0.0, 100.0):
            rows.append(f"{x},{y},{4 + x / 100},{150 - 20 * y / 100},{1 + x / 100}")
    truth = CsvTruth.from_file(_csv(tmp_path, "\n".join(rows) + "\n"))
    assert truth.has_modulus
    assert float(truth.modulus_gpa(50.0, 50.0)) == pytest.approx(140.0)
    assert float(truth.modulus_noise_sd_gpa(50.0, 50.0)) == pytest.approx(1.5)
    assert float(truth.hardness_gpa(50.0, 50.0)) == pytest.approx(4.5)
    # without a scatter column: 1.5 % of the largest modulus; without a modulus: E(H)
    no_sd = CsvTruth.from_file(
        _csv(tmp_path, "x_um,y_um,hardness_gpa,modulus_gpa\n0,0,4,150\n1,0,4,150\n0,1,4,130\n1,1,4,130\n")
    )
    assert float(no_sd.modulus_noise_sd_gpa(0.5, 0.5)) == pytest.approx(0.015 * 150)
    plain = CsvTruth.from_file(_csv(tmp_path, "x_um,y_um,hardness_gpa\n0,0,4\n1,0,4\n0,1,5\n1,1,5\n"))
    assert not plain.has_modulus
    assert float(plain.modulus_gpa(0.0, 0.0)) == pytest.approx(float(modulus_from_hardness_gpa(4.0)))


@pytest.mark.parametrize(
    ("content", "problem"),
    [
        (
            "x_um,y_um,hardness_gpa,modulus_gpa\n0,0,4,150\n1,0,4,-1\n0,1,4,150\n1,1,4,150\n",
            "line 3: modulus_gpa",
        ),
        ("x_um,y_um,hardness_gpa,modulus_gpa\n0,0,4,150\n1,0,4,150000\n0,1,4,150\n1,1,4,150\n", "MPa"),
        (
            "x_um,y_um,hardness_gpa,modulus_noise_sd_gpa\n0,0,4,1\n1,0,4,1\n0,1,4,1\n1,1,4,1\n",
            "no modulus_gpa column",
        ),
        (
            "x_um,y_um,hardness_gpa,modulus_gpa,modulus_noise_sd_gpa\n0,0,4,150,1\n1,0,4,150,-2\n"
            "0,1,4,150,1\n1,1,4,150,1\n",
            "line 3: modulus_noise_sd_gpa must be",
        ),
    ],
)
def test_bad_modulus_columns_give_one_line_errors(tmp_path: Path, content: str, problem: str) -> None:
    path = _csv(tmp_path, content)
    with pytest.raises(InputError, match=problem) as info:
        CsvTruth.from_file(path)
    assert info.value.source == str(path) and "\n" not in str(info.value)

"""A truth CSV with fast columns: the simulated instrument's fast indents read the file's values there (the
CSM map, what the run is scored against, stays the file's CSM columns); a bad fast value is one line naming
the file, the line and the column."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from aeni_console.cli.main import main as cli_main
from core.errors import InputError
from core.fast_array import FastArray, fast_block
from core.plan import IndentResult
from core.profile import load_profile
from drivers.sim.scenarios import make_scenario

PROFILE = load_profile("kla-imicro")


def fast_plane_gpa(x_um: float, y_um: float) -> float:
    return 3.0 + 4.0 * x_um / 1000.0 + 0.5 * y_um / 1000.0


def write_truth(path: Path, bad: str | None = None) -> Path:
    """A 1 mm lattice: CSM hardness 5 GPa everywhere; the fast reading a plane, with almost no scatter."""
    lines = ["x_um,y_um,hardness_gpa,noise_sd_gpa,fast_hardness_gpa,fast_noise_sd_gpa"]
    for xv in range(0, 1001, 100):
        for yv in range(0, 1001, 100):
            lines.append(f"{xv},{yv},5.0,0.05,{fast_plane_gpa(xv, yv):.6f},0.001")
    if bad is not None:
        lines[4] = bad
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


@pytest.mark.parametrize("noise", [None, "homo"])
def test_fast_indents_read_the_files_fast_columns(tmp_path: Path, noise: str | None) -> None:
    truth = write_truth(tmp_path / "truth.csv")
    sc = make_scenario("csv", 1, truth_csv=str(truth), noise=noise)
    block = fast_block(3, FastArray(500.0, 500.0, 8, 8, 50.0))
    results = [e for e in sc.make_driver(PROFILE).execute_block(block) if isinstance(e, IndentResult)]
    measured = [r for r in results if r.measured]
    assert len(results) == 64 and len(measured) >= 56 and {r.channel for r in results} == {"fast"}
    read = np.array([r.hardness_gpa for r in measured])
    said = np.array([fast_plane_gpa(r.actual_x_um, r.actual_y_um) for r in measured])
    np.testing.assert_allclose(read, said, atol=0.01)  # the file's reading (3.5–7.5 GPa), not the CSM 5 GPa
    assert np.ptp(read) > 1.0
    assert all(math.isnan(r.hardness_gpa) for r in results if not r.measured)  # a failure stays a failure
    # the map is still scored against the CSM columns
    assert float(sc.truth.hardness_gpa(500.0, 500.0)) == pytest.approx(5.0)


def test_a_bad_fast_value_is_one_line_naming_file_line_and_column(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = write_truth(tmp_path / "bad.csv", bad="0,300,5.0,0.05,abc,0.001")
    with pytest.raises(InputError) as err:
        make_scenario("csv", 1, truth_csv=str(bad))
    text = str(err.value)
    assert "bad.csv" in text and "line 5" in text and "fast_hardness_gpa" in text and "\n" not in text
    unit = write_truth(tmp_path / "unit.csv", bad="0,300,5.0,0.05,5000,0.001")  # MPa under a GPa column
    assert cli_main(["simulate", "--truth", str(unit), "--budget-s", "3000", "--json"]) == 2
    err_line = capsys.readouterr().err.strip()
    assert "unit.csv" in err_line and "line 5: fast_hardness_gpa" in err_line and "\n" not in err_line

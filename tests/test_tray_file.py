"""The tray file: the template checks, every problem is one line (exit 2), a tray round-trips."""

from __future__ import annotations

from pathlib import Path

import pytest

from aeni_console.cli.main import main
from aeni_console.cli.tray import resolve_tray
from core.errors import InputError
from core.sample.tray import TRAY_TEMPLATE, parse_tray, read_tray, tray_from_dict

REF = """
[[samples]]
name = "silica"
role = "reference"
size_um = [3000.0, 3000.0]
offset_um = [{rx}, 0.0]
"""
LIB = """
[[samples]]
name = "{name}"
scenario = "ternary"
offset_um = [{x}, 0.0]
{goal}
"""


def _write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "tray.toml"
    p.write_text(text, encoding="utf-8")
    return p


def test_template_is_a_valid_sim_tray(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "tray.toml"
    assert main(["tray", "new", str(path)]) == 0
    assert path.read_text(encoding="utf-8") == TRAY_TEMPLATE
    assert main(["tray", "check", str(path), "--driver", "sim"]) == 0
    out = capsys.readouterr().out
    assert "valid (2 libraries, a reference)" in out
    assert "fused-silica → ternary-A" in out and "surface find and settle" in out
    # the same file for a real instrument: the scenarios are no sample files
    assert main(["tray", "check", str(path)]) == 2
    assert capsys.readouterr().out.count("no sample file") == 2


def test_every_problem_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    text = (
        LIB.format(name="a", x=0.0, goal="goal = { indents = 50 }")
        + LIB.format(name="b", x=500.0, goal="goal = { indents = 50 }")  # overlaps a
        + LIB.format(name="c", x=5000.0, goal="")  # no goal
        + LIB.format(name="d", x=99_500.0, goal="goal = { budget_s = 100 }")  # off the stage
        + REF.format(rx=20000.0)
    )
    path = _write(tmp_path, text)
    assert main(["tray", "check", str(path), "--driver", "sim"]) == 2
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 1 and "sample 'c': no goal" in lines[0]  # a file's own problems come first
    path = _write(
        tmp_path,
        text.replace(
            "offset_um = [5000.0, 0.0]\n\n", "offset_um = [5000.0, 0.0]\ngoal = { rel_sd_pct = 5 }\n"
        ),
    )
    assert main(["tray", "check", str(path), "--driver", "sim"]) == 2
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 2, lines
    assert any("samples 'a' and 'b' overlap" in x for x in lines)
    assert any("sample 'd': off the stage" in x for x in lines)
    assert all(x.startswith("aeni: error: ") for x in lines)


def test_bad_goal_role_and_missing_file(tmp_path: Path) -> None:
    path = _write(
        tmp_path,
        LIB.format(name="a", x=0.0, goal="goal = { rel_sd = 5 }")
        + '\n[[samples]]\nname = "b"\nrole = "shelf"\nfile = "nope.toml"\n',
    )
    _, problems = read_tray(path)
    assert len(problems) == 3
    assert "goal" in problems[0] and "role = 'shelf'" in problems[1] and "no such sample file" in problems[2]
    with pytest.raises(InputError, match="and 2 more"):
        parse_tray(path)


def test_tray_round_trips_with_its_placed_samples(tmp_path: Path) -> None:
    path = _write(
        tmp_path, LIB.format(name="a", x=2000.0, goal="goal = { indents = 50 }") + REF.format(rx=20000.0)
    )
    tray, problems = resolve_tray(parse_tray(path), "sim")
    assert problems == []
    a = tray.by_name("a").placed
    assert a.calibration.bounds_um == (2000.0, 3000.0, 0.0, 1000.0)  # the scenario's sample, placed
    assert tray.by_name("silica").reference is not None
    assert tray.by_name("silica").reference.hardness_gpa == 9.0
    again = tray_from_dict(tray.to_dict())
    assert again == tray
    assert tray.sample_at(2500.0, 500.0) is tray.by_name("a")
    assert tray.sample_at(10000.0, 500.0) is None

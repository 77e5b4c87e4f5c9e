"""`aeni cost`: the JSON contract, and one clear line with exit code 2 for every bad file and flag."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from aeni_console.cli.main import main

ROOT = Path(__file__).resolve().parents[1]


def _run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    try:
        code = main(list(argv))
    except SystemExit as exc:  # argparse errors
        code = int(exc.code or 0)
    out, err = capsys.readouterr()
    return code, out, err


def test_cost_grid_json_contract(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = _run(capsys, "cost", "grid", "--blocks", "9", "--size", "5", "--json")
    assert code == 0
    data = json.loads(out)
    assert data["total_s"] == pytest.approx(286_392, rel=0.005)
    assert set(data["ledger"]) >= {
        "setup",
        "lift",
        "move",
        "engage",
        "drift",
        "indent",
        "hold",
        "reconfigure",
        "comeback",
    }
    assert sum(data["ledger"].values()) == pytest.approx(data["total_s"])


def test_cost_path_prices_the_file_with_the_cost_model(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The CLI reads the path (default hold: the profile's) and prices it as the cost model does; the
    reconfiguration rule itself is tested once, in test_cost."""
    from core.cost import price_sequence
    from core.plan import Block, IndentSpec
    from core.profile import load_profile

    path = tmp_path / "path.csv"
    path.write_text("x_um,y_um,hold_s\n0,0,\n100,0,5\n1100,0,80\n", encoding="utf-8")
    code, out, _ = _run(capsys, "cost", "path", str(path), "--json")
    assert code == 0
    data = json.loads(out)
    profile = load_profile("kla-imicro")
    specs = (IndentSpec(0, 0, profile.default_hold_s), IndentSpec(100, 0, 5), IndentSpec(1100, 0, 80))
    ledger = price_sequence(profile, [Block(0, "global", 0, 0, 0, 0.0, specs[0].hold_s, specs)])
    assert data["total_s"] == pytest.approx(ledger.total_s)
    assert data["reconfigurations"] == ledger.reconfigurations == 1


@pytest.mark.parametrize(
    ("content", "needle"),
    [
        ("a,b\n1,2\n", "missing column"),
        ("x_um,y_um\n1,nope\n", "line 2"),
        ("x_um,y_um\n", "no indents"),
        ("x_um,y_um,hold_s\n1,2,7\n", "hold_s 7"),
        ("x_um,y_um,z\n1,2,3\n", "unknown column"),
        ("x_um,y_um\n1,inf\n", "finite"),
    ],
)
def test_cost_path_bad_files(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], content: str, needle: str
) -> None:
    f = tmp_path / "p.csv"
    f.write_text(content, encoding="utf-8")
    code, out, err = _run(capsys, "cost", "path", str(f), "--json")
    assert code == 2 and out == ""
    line = err.strip()
    assert "\n" not in line and str(f) in line and needle in line


def test_cost_path_binary_and_missing_files(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    b = tmp_path / "b.csv"
    b.write_bytes(b"\xff\xfe\x00bad")
    for path, needle in ((b, "UTF-8"), (tmp_path / "none.csv", "no such file")):
        code, _, err = _run(capsys, "cost", "path", str(path))
        assert code == 2 and needle in err and err.count("\n") == 1


@pytest.mark.parametrize(
    ("flags", "needle"),
    [
        (["--blocks", "0"], "--blocks"),
        (["--blocks", "x"], "--blocks"),
        (["--size", "11"], "--size"),
        (["--pitch-um", "-5"], "--pitch-um"),
        (["--area-um", "nan"], "--area-um"),
        (["--hold-s", "7"], "--hold-s"),
        (["--profile", "nope.toml"], "nope.toml"),
    ],
)
def test_cost_grid_bad_flags(capsys: pytest.CaptureFixture[str], flags: list[str], needle: str) -> None:
    code, out, err = _run(capsys, "cost", "grid", *flags)
    assert code == 2 and out == ""
    assert needle in err and err.count("\n") == 1


def test_bad_profile_file_via_cli(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    f = tmp_path / "p.toml"
    f.write_text("[steps]\nengage_s = -1\n", encoding="utf-8")
    code, _, err = _run(capsys, "cost", "grid", "--profile", str(f))
    assert code == 2 and "steps.engage_s" in err and err.count("\n") == 1


def test_fit_move_command(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    f = tmp_path / "m.csv"
    rows = [
        (d, 1.36 + 2.1e-3 * d if d < 500 else 2.6 + 1.53e-4 * d)
        for d in (2, 10, 50, 100, 300, 600, 5000, 20000)
    ]
    f.write_text("distance_um,seconds\n" + "\n".join(f"{a},{b}" for a, b in rows), encoding="utf-8")
    code, out, _ = _run(capsys, "cost", "fit-move", str(f), "--json")
    assert code == 0 and json.loads(out)["rmse_s"] < 0.05


def test_no_traceback_from_a_real_process(tmp_path: Path) -> None:
    f = tmp_path / "p.csv"
    f.write_text("a\n", encoding="utf-8")
    proc = subprocess.run(
        [sys.executable, "-m", "aeni_console.cli.main", "cost", "path", str(f)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr and proc.stderr.count("\n") == 1

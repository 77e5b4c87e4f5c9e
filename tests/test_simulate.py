"""``aeni simulate``: the JSON contract for every policy, a rough map loaded with --truth, bad input."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from aeni_console.cli.main import main
from core.policies.registry import policy_names

JSON_KEYS = {
    "policy",
    "scenario",
    "sample",
    "seed",
    "profile",
    "instrument_s",
    "indents",
    "fast_indents",  # NanoBlitz-class indents (issue 36): 0 with --fast off, the default
    "blocks",
    "reconfigurations",
    "ledger",
    "final_mape_pct",
    "max_found_gpa",
    "true_max_gpa",
    "grid_baseline_s",
    "stop_reason",
    "interlock_refusals",
    "wall_s",
    "trajectory",
    "final_mape_modulus_pct",
    "map_weights",
    "trajectory_modulus",
}
FAST = ["--lattice-n", "20", "--json"]


def _simulate(capsys: pytest.CaptureFixture[str], *args: str) -> dict[str, object]:
    code = main(["simulate", *args, *FAST])
    out = capsys.readouterr().out
    assert code == 0
    data = json.loads(out)
    assert isinstance(data, dict)
    return data


@pytest.mark.parametrize("policy", policy_names())
def test_every_policy_keeps_the_json_contract(policy: str, capsys: pytest.CaptureFixture[str]) -> None:
    budget = 16_000.0
    data = _simulate(capsys, "--policy", policy, "--seed", "3", "--budget-s", str(budget))
    assert set(data) == JSON_KEYS
    assert data["policy"] == policy and data["scenario"] == "ternary" and data["seed"] == 3
    ledger = data["ledger"]
    assert isinstance(ledger, dict)
    # the ledger adds up to the instrument clock, and the budget held (a block may end it by ≤ 2 %)
    assert sum(ledger.values()) == pytest.approx(data["instrument_s"], rel=1e-9)
    assert 0 < float(data["instrument_s"]) <= budget * 1.02 + 40.0
    assert int(data["indents"]) >= 4 * int(data["blocks"]) >= 8
    traj = data["trajectory"]
    assert isinstance(traj, list) and traj
    times = [p["t_s"] for p in traj]
    assert times == sorted(times) and all(math.isfinite(p["mape_pct"]) for p in traj)
    assert data["final_mape_pct"] == pytest.approx(traj[-1]["mape_pct"], rel=1e-6)
    assert 0 < float(data["max_found_gpa"]) <= float(data["true_max_gpa"]) + 1e-9
    # both maps by default (issue 37), and both read the same way for every policy, the grid included:
    # every trajectory point carries the modulus map's MAPE after the same refit
    assert data["map_weights"] == {"hardness": 1.0, "modulus": 1.0}
    assert all(math.isfinite(p["mape_modulus_pct"]) for p in traj)
    assert data["final_mape_modulus_pct"] == pytest.approx(traj[-1]["mape_modulus_pct"], rel=1e-6)
    assert 0 < float(data["final_mape_modulus_pct"]) < 10.0


def test_both_maps_are_scored_after_every_refit_when_the_planner_aims_at_both(
    capsys: pytest.CaptureFixture[str],
) -> None:
    data = _simulate(
        capsys,
        "--policy",
        "aeni",
        "--seed",
        "1",
        "--budget-s",
        "9000",
        "--map-weights",
        "hardness=1,modulus=1",
    )
    assert data["map_weights"] == {"hardness": 1.0, "modulus": 1.0}
    traj, traj_e = data["trajectory"], data["trajectory_modulus"]
    assert isinstance(traj, list) and isinstance(traj_e, list) and len(traj_e) == len(traj)
    assert [p["t_s"] for p in traj_e] == [p["t_s"] for p in traj]
    assert data["final_mape_modulus_pct"] == pytest.approx(traj_e[-1]["mape_pct"], rel=1e-6)
    # the map's error falls as indents come in
    assert traj_e[-1]["mape_pct"] < traj_e[0]["mape_pct"]
    assert main(["simulate", "--map-weights", "hardness=0,modulus=0", *FAST]) == 2
    assert "at least one map needs a weight > 0" in capsys.readouterr().err


def test_truth_from_a_rough_csv(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from aeni_console.bench.harness import write_rough_truth

    csv = write_rough_truth(tmp_path / "rough.csv", seed=4, n=41)
    data = _simulate(capsys, "--policy", "aeni", "--truth", str(csv), "--budget-s", "15000")
    assert data["scenario"] == "csv"
    assert set(data) == JSON_KEYS
    # the rough map's hardness is ≈ 3–7 GPa; the model ends within a few percent of it
    assert 3.0 < float(data["true_max_gpa"]) < 8.0
    assert 0 < float(data["final_mape_pct"]) < 15.0


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--policy", "nope"], "--policy"),
        (["--seed", "-1"], "--seed"),
        (["--budget-s", "0"], "--budget-s"),
        (["--budget-s", "soon"], "--budget-s"),
        (["--scenario", "moon"], "scenario"),
        (["--truth", "{missing}"], "no such truth file"),
        (["--truth", "{bad}"], "missing column"),
        (["--drift", "awful"], "--drift"),
    ],
)
def test_bad_input_is_one_line_exit_2_and_nothing_written(
    args: list[str], needle: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "bad.csv"
    bad.write_text("x_um,y_um\n0,0\n1,1\n", encoding="utf-8")
    args = [a.format(missing=tmp_path / "nope.csv", bad=bad) for a in args]
    before = sorted(p.name for p in tmp_path.iterdir())
    try:
        code = main(["simulate", *args, "--json"])
    except SystemExit as exc:  # argparse rejects a flag before the handler runs
        code = int(exc.code or 0)
    captured = capsys.readouterr()
    assert code == 2
    assert captured.out == ""
    err = captured.err.strip()
    assert "\n" not in err and needle in err and "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == before

"""One loop: `aeni simulate` and `aeni run` + `aeni export` drive the same Engine, so they make the same
indents (positions, holds, values), the same instrument time and the same map error."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pandas as pd
import pytest

from aeni_console.cli.main import main
from aeni_console.cli.simulate import run_simulation
from core.journal import JournalReader
from core.run.events import Indent, RunEvent

BUDGET_S = 2500.0


class Indents:
    def __init__(self) -> None:
        self.rows: list[tuple[Any, ...]] = []

    def emit(self, event: RunEvent) -> None:
        if isinstance(event, Indent):
            r = event.result
            self.rows.append(
                (r.block_id, r.indent_index, r.actual_x_um, r.actual_y_um, r.hold_s, r.hardness_gpa)
            )


@pytest.mark.parametrize("policy", ["aeni", "grid", "cost-aware"])
def test_simulate_and_run_plus_export_give_the_same_indents(
    tmp_path: Path, policy: str, capsys: pytest.CaptureFixture[str]
) -> None:
    seen = Indents()
    sim = run_simulation(policy=policy, seed=3, budget_s=BUDGET_S, sinks=[seen])
    journal = tmp_path / "run.sqlite"
    argv = ["run", "--policy", policy, "--seed", "3", "--budget-s", str(BUDGET_S), "--journal", str(journal)]
    assert main([*argv, "--quiet"]) == 0
    assert main(["export", str(journal), "--out", str(tmp_path / "out")]) == 0
    capsys.readouterr()
    exported = pd.read_csv(tmp_path / "out" / "indents.csv")
    rows = [
        (int(b), int(i), float(x), float(y), float(h), float(hv))
        for b, i, x, y, h, hv in exported[
            ["block_id", "indent_index", "x_um", "y_um", "hold_s", "hardness_gpa"]
        ].itertuples(index=False)
    ]
    assert seen.rows and len(rows) == sim["indents"] == len(seen.rows)
    for a, b in zip(rows, seen.rows, strict=True):
        assert a[:2] == b[:2]
        assert a[2:] == pytest.approx(b[2:], rel=1e-12, abs=1e-9, nan_ok=True)
    with JournalReader(journal) as r:
        snap = r.snapshot()
    assert snap.instrument_s == pytest.approx(sim["instrument_s"], abs=1e-6)
    assert snap.n_blocks == sim["blocks"]
    if sim["final_mape_pct"] is not None:
        assert snap.mape_pct == pytest.approx(sim["final_mape_pct"], abs=1e-6)
    assert sim["interlock_refusals"] == 0

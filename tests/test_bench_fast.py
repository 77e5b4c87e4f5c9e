"""The bench's fast column (issue 36): every policy's fast indents and time in fast arrays, recorded per run,
summarised per policy, kept in results.json and read back; results written before the column say 0 for a
CSM-only policy (it plans no fast arrays) and "—" for a +fast one (not recorded)."""

from __future__ import annotations

import json

from aeni_console.bench.harness import BenchConfig, RunRecord, summarise
from aeni_console.bench.storage import records_from_json, records_to_json
from aeni_console.reports.bench import scenario_table


def _rec(policy: str, seed: int, fast: int, fast_s: float) -> RunRecord:
    return RunRecord(
        scenario="ternary", policy=policy, seed=seed, target_mape_pct=0.5, t_hit_s=10_000.0, final_mape_pct=0.5,
        max_found_gpa=5.0, true_max_gpa=6.0, instrument_s=20_000.0, budget_s=30_000.0, indents=100 + fast,
        blocks=10, reconfigurations=0, ledger={"indent": 20_000.0}, stop_reason="", wall_s=1.0,
        trajectory=[(10_000.0, 0.5)], max_found=[(10.0, 5.0)], fast_indents=fast, fast_array_s=fast_s,
    )  # fmt: skip


def _rows(records: list[RunRecord]) -> dict[str, list[str]]:
    table = scenario_table(summarise(records))
    head, _, *rows = table.splitlines()
    assert head.endswith("| fast indents | time in fast arrays |")
    return {r.split("|")[1].strip(): [c.strip() for c in r.strip("|").split("|")] for r in rows}


def test_every_policy_has_the_fast_column() -> None:
    records = [_rec("grid", s, 0, 0.0) for s in range(3)]
    records += [_rec("aeni", s, 0, 0.0) for s in range(3)]
    records += [
        _rec("aeni+fast", s, n, t) for s, (n, t) in enumerate([(0, 0.0), (400, 2_000.0), (800, 5_000.0)])
    ]
    rows = _rows(records)
    assert rows["`aeni`"][-2:] == ["0", "0 s"] and rows["`grid`"][-2:] == ["0", "0 s"]
    # the median seed's: 400 fast indents, 2,000 s, 10 % of the median run's 20,000 s
    assert rows["`aeni+fast`"][-2:] == ["400", "2,000 s (10 %)"]


def test_the_column_survives_results_json_and_older_results_say_what_is_known() -> None:
    config = BenchConfig.make(quick=True, seeds=1, only="ternary")
    records = [_rec("grid", 0, 0, 0.0), _rec("aeni", 0, 0, 0.0), _rec("aeni+fast", 0, 361, 1_234.5)]
    data = json.loads(json.dumps(records_to_json(records, config, 1.0)))
    back, _, _ = records_from_json(data)
    assert [(r.fast_indents, r.fast_array_s) for r in back] == [(0, 0.0), (0, 0.0), (361, 1_234.5)]
    for run in data["runs"]:  # as a bench before the column wrote them
        del run["fast_indents"], run["fast_array_s"]
    old, _, _ = records_from_json(data)
    assert [(r.fast_indents, r.fast_array_s) for r in old] == [(0, 0.0), (0, 0.0), (None, None)]
    rows = _rows(old)
    assert rows["`aeni`"][-2:] == ["0", "0 s"] and rows["`aeni+fast`"][-2:] == ["—", "—"]

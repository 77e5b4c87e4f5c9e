"""The policy benchmark's public names in one place, for ``aeni bench``, the report and the benchmarks.

The bench is four modules, one idea each: ``catalogue`` (scenarios and the configuration), ``runner`` (the
protocol: each run composed from its RunSpec and run through the engine an operator runs), ``statistics``
(paired speed-ups, quartiles, summaries) and ``storage`` (results.json written, read back and merged).
"""

from __future__ import annotations

from aeni_console.bench.catalogue import (
    CORE,
    EXTRA_SCENARIOS,
    FULL_SCENARIOS,
    GRID_REFIT_EVERY,
    MAX_CENTRES,
    QUICK_SCENARIOS,
    SUITE_SEEDS,
    BenchConfig,
    BenchScenario,
)
from aeni_console.bench.runner import (
    BenchRun,
    RunRecord,
    bench_run_spec,
    flat_mape_pct,
    run_bench,
    run_one,
    write_rough_truth,
    write_truth_csv,
)
from aeni_console.bench.statistics import (
    ABLATION_REFERENCE,
    LEVEL_FACTORS,
    LEVEL_PAIRS,
    LOOSE_FACTOR,
    SUITE_FACTORS,
    PolicySummary,
    mape_at_equal_time,
    policy_names_in_order,
    speedup_by_level,
    summarise,
    worst_rise,
)
from aeni_console.bench.storage import merge_results, records_from_json, records_to_json

__all__ = [
    "ABLATION_REFERENCE",
    "CORE",
    "EXTRA_SCENARIOS",
    "FULL_SCENARIOS",
    "GRID_REFIT_EVERY",
    "LEVEL_FACTORS",
    "LEVEL_PAIRS",
    "LOOSE_FACTOR",
    "MAX_CENTRES",
    "QUICK_SCENARIOS",
    "SUITE_FACTORS",
    "SUITE_SEEDS",
    "BenchConfig",
    "BenchRun",
    "BenchScenario",
    "PolicySummary",
    "RunRecord",
    "bench_run_spec",
    "flat_mape_pct",
    "mape_at_equal_time",
    "merge_results",
    "policy_names_in_order",
    "records_from_json",
    "records_to_json",
    "run_bench",
    "run_one",
    "speedup_by_level",
    "summarise",
    "worst_rise",
    "write_rough_truth",
    "write_truth_csv",
]

"""Identity check for refactors: the published campaigns give the same figures before and after.

Runs ``grid``, ``cost-aware`` and ``aeni`` on the ternary library, the film and one robustness field (seeds 0 and
1, failures off) under the bench protocol (``run_one``: the grid run of a seed sets its target MAPE and budget,
as ``aeni bench`` does) and writes blocks, indents, instrument time and final MAPE per (scenario, policy, seed).
With ``--compare BASELINE.json`` it prints the largest absolute difference per metric and exits 1 if any exceeds
``--tol`` (1e-6).

    nice -n 10 .venv/bin/python benchmarks/identity_check.py --out benchmarks/results/identity_baseline.json
    nice -n 10 .venv/bin/python benchmarks/identity_check.py --scenarios ternary edge-spot \
        --compare benchmarks/results/identity_baseline.json --out /tmp/identity_after.json
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

from aeni_console.bench.harness import FULL_SCENARIOS, BenchConfig, RunSpec, run_one

SCENARIOS = ("ternary", "film", "edge-spot")
POLICIES = ("grid", "cost-aware", "aeni")
METRICS = ("blocks", "indents", "instrument_s", "final_mape_pct")


def run_case(
    scenario_key: str, seed: int, policies: tuple[str, ...], margin: float, max_blocks: int | None = None
) -> dict[str, dict[str, Any]]:
    """One scenario and seed: the grid first (its MAPE and time are the others' target and budget)."""
    sc = next(s for s in FULL_SCENARIOS if s.key == scenario_key)
    bench = BenchConfig()
    lattice_n = bench.lattice_n
    out: dict[str, dict[str, Any]] = {}
    grid = None
    for policy in ("grid", *[p for p in policies if p != "grid"]):
        kw: dict[str, Any] = {}
        if policy != "grid":
            assert grid is not None
            kw = {"budget_s": grid.instrument_s, "target_mape_pct": grid.final_mape_pct}
        start = time.monotonic()
        spec = RunSpec(
            scenario=sc,
            policy=policy,
            seed=seed,
            lattice_n=lattice_n,
            margin=margin,
            max_blocks=bench.max_blocks if max_blocks is None or policy == "grid" else max_blocks,
            max_centres=bench.max_centres,
            **kw,
        )
        rec = run_one(spec)
        if policy == "grid":
            grid = rec
        if policy not in policies:
            continue
        out[policy] = {
            "blocks": rec.blocks,
            "indents": rec.indents,
            "instrument_s": rec.instrument_s,
            "final_mape_pct": rec.final_mape_pct,
            "stop_reason": rec.stop_reason,
            "margin": margin,
            "max_blocks": spec.max_blocks,
            "wall_s": round(time.monotonic() - start, 1),
        }
        print(f"{scenario_key:10s} {policy:11s} seed {seed}: {out[policy]}", flush=True)
    return out


def compare(after: dict[str, Any], before: dict[str, Any]) -> tuple[dict[str, float], list[str]]:
    """Largest absolute difference per metric over the cases both files hold, and the cases missing from one."""
    worst = dict.fromkeys(METRICS, 0.0)
    missing: list[str] = []
    for key, b in before.items():
        a = after.get(key)
        if a is None:
            missing.append(key)
            continue
        for m in METRICS:
            if (a[m] is None) != (b[m] is None):
                worst[m] = float("inf")
            elif a[m] is not None:
                worst[m] = max(worst[m], abs(float(a[m]) - float(b[m])))
    return worst, missing


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenarios", nargs="+", default=list(SCENARIOS))
    ap.add_argument("--policies", nargs="+", default=list(POLICIES))
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--compare", type=Path, default=None)
    ap.add_argument("--tol", type=float, default=1e-6)
    ap.add_argument(
        "--margin",
        type=float,
        default=BenchConfig().margin,
        help="run-on after the target (default: the bench's); identity_baseline.json was made with 0.25",
    )
    ap.add_argument(
        "--max-blocks",
        type=int,
        default=None,
        help="stop the non-grid runs after this many blocks: a quick check of a long run's first blocks",
    )
    args = ap.parse_args(argv)
    results: dict[str, Any] = {}
    start = time.monotonic()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    for scen in args.scenarios:
        for seed in args.seeds:
            for policy, row in run_case(
                scen, seed, tuple(args.policies), args.margin, args.max_blocks
            ).items():
                results[f"{scen}/{policy}/{seed}"] = row
            # after every case: a long sweep that is stopped keeps what it measured
            tmp = args.out.with_name(f".{args.out.name}.tmp")
            tmp.write_text(json.dumps(results, indent=1, sort_keys=True) + "\n")
            tmp.replace(args.out)
    print(f"wrote {args.out} ({len(results)} runs, {time.monotonic() - start:.0f} s)")
    if args.compare is None:
        return 0
    before = json.loads(args.compare.read_text())
    worst, _ = compare(results, {k: v for k, v in before.items() if k in results})
    print("metric           max |after - before|")
    for m, d in worst.items():
        print(f"{m:16s} {d:.3g}")
    return 0 if all(d <= args.tol for d in worst.values()) else 1


if __name__ == "__main__":
    sys.exit(main())

"""The default ``aeni`` as a user gets it (issue 37), measured seed by seed under the bench's protocol.

For each seed, in turn: the grid and ``aeni`` without a calendar, then (with ``--calendar``) the grid and
``aeni`` under the operator calendar of ``docs/benchmarks.md`` (Mon-Fri 08:30-18:00, 10 min response, a
visit every 120 min, start Mon 09:00). Every campaign is ``aeni_console.bench.harness.run_one``, the bench's
own (so the same targets, budgets, failures and stopping), with the product's default map_weights (both
maps) unless ``--map-weights`` says otherwise. Each finished seed is appended to ``OUT/results.json`` (the
bench's format), so a run cut short keeps every seed it finished; ``aeni bench --render-from
OUT/results.json --out OUT`` writes RESULTS.md from it.

    nice -n 10 python benchmarks/default_recipe.py --scenario ternary --seeds 0 1 2 --out DIR [--calendar]
        [--policies aeni,aeni+attended] [--map-weights hardness=1,modulus=0]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from aeni_console.bench.harness import (  # noqa: E402
    BenchConfig,
    BenchRun,
    RunRecord,
    records_to_json,
    run_one,
)
from aeni_console.cli.common import map_weights_arg  # noqa: E402
from core.operator import OperatorAvailability, OperatorHours, parse_start  # noqa: E402
from core.visits import OperatorCalendar  # noqa: E402


def calendar() -> OperatorCalendar:
    hours = OperatorHours.parse("Mon-Fri 08:30-18:00")
    return OperatorCalendar(OperatorAvailability(hours, 600.0, 7200.0), parse_start("Mon 09:00"))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenario", default="ternary")
    ap.add_argument("--seeds", type=int, nargs="+", default=list(range(10)))
    ap.add_argument("--policies", default="aeni")
    ap.add_argument("--calendar", action="store_true", help="also run every policy under the calendar")
    ap.add_argument("--only-calendar", action="store_true", help="run only under the calendar")
    ap.add_argument("--map-weights", type=map_weights_arg, default=None)
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()

    base = BenchConfig.make(False, len(args.seeds), 1, only=args.scenario)
    sc = base.scenarios[0]
    policies = [p.strip() for p in args.policies.split(",") if p.strip()]
    modes: list[OperatorCalendar | None] = [] if args.only_calendar else [None]
    if args.calendar or args.only_calendar:
        modes.append(calendar())
    args.out.mkdir(parents=True, exist_ok=True)
    records: dict[str, list[RunRecord]] = {("cal" if m else "plain"): [] for m in modes}
    start = time.monotonic()
    for seed in args.seeds:
        for cal in modes:
            key = "cal" if cal else "plain"
            spec = BenchRun(
                sc,
                "grid",
                seed,
                lattice_n=base.lattice_n,
                margin=base.margin,
                max_blocks=base.max_blocks,
                max_centres=base.max_centres,
                failure_rate=base.failure_rate,
                map_weights=args.map_weights,
                calendar=cal,
            )
            grid = run_one(spec)
            records[key].append(grid)
            for p in policies:
                r = run_one(
                    replace(
                        spec,
                        policy=p,
                        budget_s=grid.instrument_s,
                        target_mape_pct=grid.final_mape_pct,
                        target_mape_modulus_pct=grid.final_mape_modulus_pct,
                    )
                )
                records[key].append(r)
                both = (
                    max(r.t_hit_s, r.t_hit_modulus_s)
                    if r.t_hit_s is not None and r.t_hit_modulus_s is not None
                    else None
                )
                print(
                    f"{key:5} seed {seed} {p:24} t(H) {r.t_hit_s} t(E) {r.t_hit_modulus_s} t(both) {both} "
                    f"grid {grid.t_hit_s} / {grid.t_hit_modulus_s} wall_h {r.wall_clock_h} "
                    f"visits {r.operator_visits} to both: wall_h {r.wall_clock_both_h} visits {r.operator_visits_both} "
                    f"cpu-wall {r.wall_s:.0f} s",
                    flush=True,
                )
            config = replace(
                base,
                seeds=len({r.seed for r in records[key]}),
                scenarios=(replace(sc, policies=("grid", *policies)),),
                map_weights=args.map_weights,
                calendar=cal,
            )
            out = args.out / key
            out.mkdir(exist_ok=True)
            data = records_to_json(records[key], config, time.monotonic() - start)
            (out / "results.json").write_text(json.dumps(data, separators=(",", ":")), encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

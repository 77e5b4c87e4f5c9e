"""Record the published figures' identity fields, or compare them with a recording.

The refactors of issue 35 must not move a single published number: ``aeni``, ``grid`` and ``cost-aware`` on the
ternary, the film and one robustness field (``step``), seeds 0 and 1, failures off, under the bench protocol
(the grid first: its final MAPE is the target and its instrument time the budget of the others). For each run
this records the blocks, indents, instrument time and final MAPE (and the time to the target, the stop reason
and the reconfigurations), then compares two recordings to 1e-6.

    python benchmarks/identity_check.py --record before.json       # on the code before the change
    python benchmarks/identity_check.py --compare before.json      # after: prints the table, exit 1 on a change

The film's ``aeni`` takes ~4 min a seed: run it with ``nice -n 10``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

SCENARIOS = "ternary,film,step"
POLICIES = "aeni,cost-aware"
SEEDS = 2
FIELDS = ("blocks", "indents", "instrument_s", "final_mape_pct", "t_hit_s", "reconfigurations", "stop_reason")
TOL = 1e-6


# the map weights both sides plan with: the release before the composition change plans the hardness map only
# (the both-maps default is issue 37's deliberate change), so the comparison holds them equal
HARDNESS_ONLY = {"hardness": 1.0, "modulus": 0.0}


def record(
    scenarios: str = SCENARIOS, policies: str = POLICIES, map_weights: dict[str, float] | None = None
) -> dict[str, Any]:
    from aeni_console.bench.harness import BenchConfig, run_bench

    config = BenchConfig.make(quick=False, seeds=SEEDS, jobs=1, only=scenarios, policies=policies)
    config = replace(config, failure_rate=0.0, map_weights=map_weights)
    start = time.monotonic()
    with tempfile.TemporaryDirectory() as work:
        records = run_bench(config, Path(work), progress=lambda r: print(_line(r.__dict__), flush=True))
    runs = {f"{r.scenario}/{r.policy}/{r.seed}": {name: getattr(r, name) for name in FIELDS} for r in records}
    return {"wall_s": time.monotonic() - start, "runs": runs}


def _line(run: dict[str, Any]) -> str:
    return (
        f"{run.get('scenario', '')} {run.get('policy', '')} {run.get('seed', '')}: {run['blocks']} blocks, "
        f"{run['indents']} indents, {run['instrument_s']:.3f} s, MAPE {run['final_mape_pct']}"
    )


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, float) and isinstance(b, float):
        return math.isclose(a, b, rel_tol=0.0, abs_tol=TOL) or (math.isnan(a) and math.isnan(b))
    return bool(a == b)


def compare(before: dict[str, Any], after: dict[str, Any]) -> bool:
    """Every run of either recording, side by side; only runs both have are compared (a partial recording
    names the rest as missing)."""
    ok = True
    print("| run | blocks | indents | instrument s | final MAPE % | same |")
    print("|---|---|---|---|---|---|")
    for key in sorted(set(before["runs"]) | set(after["runs"])):
        b, a = before["runs"].get(key), after["runs"].get(key)
        if b is None or a is None:
            print(f"| {key} | missing {'before' if b is None else 'after'} | | | | no |")
            ok = False
            continue
        same = all(_same(b[f], a[f]) for f in FIELDS)
        ok &= same

        def both(f: str, fmt: str, b: dict[str, Any] = b, a: dict[str, Any] = a) -> str:
            vb, va = b[f], a[f]
            sb = format(vb, fmt) if vb is not None else "-"
            sa = format(va, fmt) if va is not None else "-"
            return sb if _same(vb, va) else f"{sb} → {sa}"

        print(
            f"| {key} | {both('blocks', 'd')} | {both('indents', 'd')} | {both('instrument_s', '.3f')} |"
            f" {both('final_mape_pct', '.6f')} | {'yes' if same else 'NO'} |"
        )
    return ok


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument("--record", type=Path, help="run the figures and write them here")
    g.add_argument("--compare", type=Path, help="run the figures and compare them with this recording")
    g.add_argument("--diff", nargs=2, type=Path, help="compare two recordings without running")
    p.add_argument("--scenarios", default=SCENARIOS, help=f"a subset (default {SCENARIOS})")
    p.add_argument("--policies", default=POLICIES, help=f"besides the grid (default {POLICIES})")
    p.add_argument(
        "--both-maps",
        action="store_true",
        help="plan with the product's default map weights (both maps, issue 37) instead of the hardness map only",
    )
    args = p.parse_args()
    if args.diff:
        before, after = (json.loads(f.read_text(encoding="utf-8")) for f in args.diff)
        return 0 if compare(before, after) else 1
    data = record(args.scenarios, args.policies, None if args.both_maps else HARDNESS_ONLY)
    print(f"{len(data['runs'])} runs in {data['wall_s'] / 60:.1f} min")
    if args.record:
        args.record.write_text(json.dumps(data, indent=1) + "\n", encoding="utf-8")
        return 0
    out = args.compare.with_name(args.compare.stem + "-after.json")
    out.write_text(json.dumps(data, indent=1) + "\n", encoding="utf-8")
    before = json.loads(args.compare.read_text(encoding="utf-8"))
    return 0 if compare(before, data) else 1


if __name__ == "__main__":
    raise SystemExit(main())

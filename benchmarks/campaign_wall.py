"""Wall time of whole emulator campaigns (issue 2's benchmark): prints a table, writes results/campaign_wall.{json,md}.

Run: python benchmarks/campaign_wall.py [--policy cost-aware] [--seeds 3]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
os.environ.setdefault("OMP_NUM_THREADS", "1")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--policy", default="cost-aware")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    args = ap.parse_args()

    from core.campaign_config import CampaignConfig
    from core.run.events import Observed, RunEvent
    from core.run.headless import run_headless
    from core.run.spec import RunSpec
    from drivers.registry import DRIVERS

    rows = []
    for seed in range(args.seeds):
        spec = RunSpec(
            campaign=CampaignConfig(policy=args.policy, seed=seed, driver_options={"scenario": "ternary"})
        )
        block_walls: list[float] = []
        last = [time.perf_counter()]

        class BlockWall:
            def emit(
                self, event: RunEvent, walls: list[float] = block_walls, mark: list[float] = last
            ) -> None:
                if isinstance(event, Observed):
                    now = time.perf_counter()
                    walls.append(now - mark[0])
                    mark[0] = now

        t0 = time.perf_counter()
        res, run = run_headless(spec, DRIVERS, sinks=[BlockWall()])
        wall = time.perf_counter() - t0
        assert run.evaluator is not None
        mape = run.evaluator.score(run.campaign).mape_pct
        rows.append(
            {
                "seed": seed,
                "wall_s": wall,
                "blocks": res.blocks,
                "indents": res.indents,
                "instrument_s": res.instrument_s,
                "median_block_wall_s": statistics.median(block_walls) if block_walls else None,
                "final_mape_pct": mape,
            }
        )
        print(f"seed {seed}: {wall:.1f} s wall, {res.blocks} blocks, MAPE {mape:.3f} %", flush=True)
    load = os.getloadavg()[0]
    med = statistics.median(r["wall_s"] for r in rows)
    lines = [
        f"# Whole `{args.policy}` campaign on the ternary emulator (budget = grid baseline, lattice 100×100)",
        "",
        f"Load average at the end: {load:.1f} on {os.cpu_count()} cores (this machine is shared).",
        "",
        "| seed | wall s | blocks | indents | instrument h | median wall per block s | final MAPE % |",
        "|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['seed']} | {r['wall_s']:.1f} | {r['blocks']} | {r['indents']} | {r['instrument_s'] / 3600:.1f} | "
            f"{r['median_block_wall_s']:.3f} | {r['final_mape_pct']:.3f} |"
        )
    lines += [
        "",
        f"Median wall time: **{med:.1f} s** for about {rows[0]['instrument_s'] / 3600:.0f} h of instrument time.",
    ]
    text = "\n".join(lines) + "\n"
    print(text)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "campaign_wall.json").write_text(
        json.dumps({"policy": args.policy, "load": load, "runs": rows}, indent=2)
    )
    (out / "campaign_wall.md").write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

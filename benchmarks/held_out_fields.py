"""Does a policy hold on fields that nothing was tuned on? Five held-out truths, scored like the bench.

The bench's robustness suite is what `aeni` was developed against; these five were written after its last
change and were never used to choose a setting. Each is a truth CSV (x_um, y_um, hardness_gpa,
noise_sd_gpa on a 101×101 lattice over the 1000 µm square: what a user loads with ``--truth``):

- ring: a hard annulus (+1.5 GPa, 80 µm wide, radius 250 µm) on a gentle gradient, 2 % noise;
- spots: a hard and a soft spot (50 and 70 µm) of opposite sign on a tilted plane, 1.5 % noise;
- checker: a soft-edged checkerboard of 250 µm squares (±0.6 GPa), 2 % noise;
- noisy: a smooth saddle under 6 % per-indent noise (the film's problem without its program changes);
- band: a steep gradient with a sigmoid step along a diagonal, 1 % + 0.03 GPa noise.

Protocol as in ``aeni bench``: the grid baseline of each seed sets the target (its final MAPE) and the
budget; the policy runs until it reaches the target and on for 10 %, and the speed-up is grid time /
policy time to the target, paired by seed (0 = never reached).

Run: python benchmarks/held_out_fields.py [--policy aeni] [--seeds 5] [--jobs 2] [--fields noisy,...]
[--lattice 50] → prints a table, writes results/held_out_<policy>[_lattice<n>].{json,md}
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from aeni_console.bench.harness import BenchRun, BenchScenario, RunRecord, run_one, write_truth_csv  # noqa: E402

SIDE_UM = 1000.0
LATTICE_N = 50  # the bench's candidate lattice
Field = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]


def _ring(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    r = np.hypot(x - 450.0, y - 550.0)
    h = 5.0 + 0.1 * x / SIDE_UM + 1.5 * np.exp(-0.5 * ((r - 250.0) / 35.0) ** 2)
    return h, 0.02 * h


def _spots(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    hard = 1.2 * np.exp(-((x - 300.0) ** 2 + (y - 300.0) ** 2) / (2 * 50.0**2))
    soft = 1.0 * np.exp(-((x - 700.0) ** 2 + (y - 650.0) ** 2) / (2 * 70.0**2))
    h = 6.0 - 0.3 * y / SIDE_UM + hard - soft
    return h, 0.015 * h


def _checker(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    s = np.tanh(8.0 * np.sin(np.pi * x / 250.0)) * np.tanh(8.0 * np.sin(np.pi * y / 250.0))
    h = 7.0 + 0.6 * s
    return h, 0.02 * h


def _noisy(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    h = 8.0 + np.sin(np.pi * x / SIDE_UM) * np.cos(0.5 * np.pi * y / SIDE_UM)
    return h, 0.06 * h


def _band(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    d = (0.6 * x + 0.8 * y) / SIDE_UM
    h = 4.0 + 3.0 * d + 0.8 / (1.0 + np.exp(-(d - 0.7) / 0.02))
    return h, 0.01 * h + 0.03


FIELDS: dict[str, Field] = {
    "ring": _ring,
    "spots": _spots,
    "checker": _checker,
    "noisy": _noisy,
    "band": _band,
}


def write_truth(key: str, folder: Path) -> Path:
    xs = np.linspace(0.0, SIDE_UM, 101)
    gx, gy = np.meshgrid(xs, xs)
    return write_truth_csv(folder / f"held_out_{key}.csv", gx, gy, *FIELDS[key](gx, gy))


def _spec(key: str, csv: Path, policy: str, seed: int, lattice_n: int, **kw: float) -> BenchRun:
    sc = BenchScenario(key, "csv", f"held-out field {key}", ("grid", policy), group="robustness")
    return BenchRun(sc, policy, seed, lattice_n, truth_csv=str(csv), **kw)  # type: ignore[arg-type]


def _grid(args: tuple[str, Path, int, int]) -> RunRecord:
    key, csv, seed, lattice_n = args
    return run_one(_spec(key, csv, "grid", seed, lattice_n))


def _policy(args: tuple[str, Path, str, int, int, float, float]) -> RunRecord:
    key, csv, policy, seed, lattice_n, budget_s, target_pct = args
    spec = _spec(key, csv, policy, seed, lattice_n, budget_s=budget_s, target_mape_pct=target_pct, margin=0.1)
    return run_one(spec)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--policy", default="aeni", help="a registry policy or an ablation BASE+modifier")
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument(
        "--lattice",
        type=int,
        default=LATTICE_N,
        help=f"candidate lattice per side ({LATTICE_N}: the bench's)",
    )
    ap.add_argument(
        "--fields", default=",".join(FIELDS), help="comma-separated subset of " + ", ".join(FIELDS)
    )
    args = ap.parse_args()
    keys = [k.strip() for k in args.fields.split(",") if k.strip()]
    unknown = [k for k in keys if k not in FIELDS]
    if unknown or args.seeds < 1 or args.jobs < 1:
        sys.exit(f"held_out_fields: unknown field(s) {unknown} or seeds/jobs < 1")
    out = ROOT / "benchmarks" / "results"
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp, ProcessPoolExecutor(args.jobs) as ex:
        csvs = {k: write_truth(k, Path(tmp)) for k in keys}  # rebuilt from this file: only results are kept
        grids = list(ex.map(_grid, [(k, csvs[k], s, args.lattice) for k in keys for s in range(args.seeds)]))
        tasks = [
            (
                g.scenario,
                csvs[g.scenario],
                args.policy,
                g.seed,
                args.lattice,
                g.instrument_s,
                g.final_mape_pct,
            )
            for g in grids
        ]
        runs = list(ex.map(_policy, tasks))
    speedups: dict[str, list[float]] = {k: [] for k in keys}
    rows = []
    for g, r in zip(grids, runs, strict=True):
        assert g.t_hit_s is not None  # the grid reaches its own final MAPE by definition
        x = g.t_hit_s / r.t_hit_s if r.t_hit_s else 0.0
        speedups[g.scenario].append(x)
        rows.append(
            {
                "field": g.scenario,
                "seed": g.seed,
                "grid_final_mape_pct": g.final_mape_pct,
                "grid_t_hit_s": g.t_hit_s,
                "policy_t_hit_s": r.t_hit_s,
                "policy_final_mape_pct": r.final_mape_pct,
                "indents": r.indents,
                "speedup": x,
                "stop_reason": r.stop_reason,
            }
        )
    lines = [
        f"# Held-out fields: `{args.policy}` against the grid ({args.seeds} seeds, lattice {args.lattice})",
        "",
        "Grid time / policy time to reach the grid's final MAPE, paired by seed (0 = never reached).",
        "",
        "| field | median | worst seed | reached |",
        "| --- | --- | --- | --- |",
    ]
    for k in keys:
        v = speedups[k]
        lines.append(
            f"| {k} | {statistics.median(v):.1f}× | {min(v):.1f}× | {sum(x > 0 for x in v)}/{len(v)} |"
        )
    wall = time.perf_counter() - t0
    lines += [
        "",
        f"{len(grids) + len(runs)} campaigns in {wall / 60:.1f} min of wall time, --jobs {args.jobs}.",
    ]
    text = "\n".join(lines)
    print(text)
    name = args.policy.replace("+", "_") + ("" if args.lattice == LATTICE_N else f"_lattice{args.lattice}")
    (out / f"held_out_{name}.md").write_text(text + "\n", encoding="utf-8")
    data = {"policy": args.policy, "seeds": args.seeds, "fields": keys, "runs": rows, "wall_s": wall}
    (out / f"held_out_{name}.json").write_text(json.dumps(data, indent=1), encoding="utf-8")


if __name__ == "__main__":
    main()

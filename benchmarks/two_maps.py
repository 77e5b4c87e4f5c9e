"""Hardness and modulus mapped together (issue 27): how soon each map reaches the grid's final error.

For each seed on a scenario (ternary by default):

- the grid baseline (``grid``, its full 9×9 blocks of 5×5) with both maps learned from its indents: its
  final hardness and modulus MAPEs are the targets, and the grid's own time to reach each is its time;
- ``aeni`` hardness only (``map_weights = { hardness = 1, modulus = 0 }``, the default) and ``aeni`` aiming at
  both (``{ hardness = 1, modulus = 1 }``), each stopped once both maps are at their targets (or at the cap).
  In the hardness-only run the modulus map is fitted from the same indents for the score only. The modes
  ``hardness-bends`` and ``both-bends`` do the same with ``aeni+bends`` (each map's error weighed more where
  that map bends).

A seed that never reaches a target within the cap counts below every other seed in the median.

It prints a table per run and the medians and worst seeds, and writes benchmarks/results/two_maps.{md,json}.

    nice -n 10 python benchmarks/two_maps.py [--seeds 0 1 2] [--scenario ternary] [--cap-s 60000]
        [--modes both --reuse earlier.json]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
os.environ.setdefault("OMP_NUM_THREADS", "1")

from aeni_console.bench.harness import GRID_REFIT_EVERY  # noqa: E402
from core.metrics import time_to_mape  # noqa: E402
from core.run.events import Observed, RunEvent  # noqa: E402
from core.run.headless import RunTally, run_headless  # noqa: E402
from core.run.spec import RunSpec  # noqa: E402
from core.runconfig import make_campaign_config  # noqa: E402
from drivers.registry import DRIVERS  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"
HARDNESS_ONLY = {"hardness": 1.0, "modulus": 0.0}
BOTH = {"hardness": 1.0, "modulus": 1.0}
# mode: (policy, map weights); the +bends modes weigh each map's reference points by where it bends
MODES: dict[str, tuple[str, dict[str, float]]] = {
    "hardness": ("aeni", HARDNESS_ONLY),
    "both": ("aeni", BOTH),
    "hardness-bends": ("aeni+bends", HARDNESS_ONLY),
    "both-bends": ("aeni+bends", BOTH),
}
DEFAULT_MODES = ("hardness", "both")


def sim_spec(
    scenario: str,
    policy: str,
    seed: int,
    weights: dict[str, float],
    budget_s: float | None,
    lattice_n: int,
    grid_refit_every: int = GRID_REFIT_EVERY,
) -> RunSpec:
    """A run on the simulated instrument with these map weights.

    The grid is refitted once per row of blocks, as in the bench, unless told otherwise."""
    config = make_campaign_config(
        scenario=scenario,
        policy=policy,
        seed=seed,
        lattice_n=lattice_n,
        settings={"budget_s": budget_s, "map_weights": weights},
    )
    return RunSpec(campaign=config, refit_every=grid_refit_every if policy == "grid" else 1)


def one_run(
    scenario: str,
    policy: str,
    seed: int,
    weights: dict[str, float],
    targets: tuple[float, float] | None,
    cap_s: float | None,
    lattice_n: int,
) -> dict[str, Any]:
    """A run with both maps scored after every refit; stopped once both reach ``targets`` (H, E) if given."""
    modulus: list[tuple[float, float]] = []
    parts: list[tuple[Any, Any]] = []  # the campaign and its scorer, once composed

    class ModulusScore(RunTally):
        def emit(self, event: RunEvent) -> None:
            if isinstance(event, Observed) and event.fit.fitted:
                campaign, evaluator = parts[0]
                mape = evaluator.score_modulus(campaign)
                if mape is not None:
                    modulus.append((event.t_s, mape))

    def sinks(campaign: Any, evaluator: Any) -> list[Any]:
        parts.append((campaign, evaluator))
        return [ModulusScore()]

    def stop_when(res: RunTally) -> str | None:
        if targets is None or not res.trajectory or not modulus:
            return None
        if (
            time_to_mape(res.trajectory, targets[0]) is not None
            and time_to_mape(modulus, targets[1]) is not None
        ):
            return "both maps at the grid's final MAPE"
        return None

    start = time.monotonic()
    spec = sim_spec(scenario, policy, seed, weights, cap_s, lattice_n)
    result, _ = run_headless(spec, DRIVERS, sinks=sinks, stop_when=stop_when)
    campaign, evaluator = parts[0]
    hardness = list(result.trajectory)
    if policy == "grid" and len(campaign.centres) >= 2:
        # the grid's final maps on all its indents
        campaign.surrogate.fit(campaign.observations())
        hardness.append((result.instrument_s, evaluator.score(campaign).mape_pct or float("nan")))
        campaign.modulus_map.fit(campaign.calibration.to_uv)
        modulus.append((result.instrument_s, evaluator.score_modulus(campaign) or float("nan")))
    return {
        "policy": policy,
        "seed": seed,
        "weights": weights,
        "instrument_s": result.instrument_s,
        "indents": result.indents,
        "final_mape_pct": hardness[-1][1] if hardness else None,
        "final_mape_modulus_pct": modulus[-1][1] if modulus else None,
        "trajectory": hardness,
        "trajectory_modulus": modulus,
        "stop_reason": result.stop_reason,
        "wall_s": time.monotonic() - start,
    }


def _t(traj: list[tuple[float, float]], target: float) -> float | None:
    return time_to_mape(traj, target)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--scenario", default="ternary")
    ap.add_argument("--cap-s", type=float, default=60_000.0, help="instrument-time cap of the aeni runs")
    ap.add_argument("--lattice-n", type=int, default=50, help="candidates per side (the bench's 50)")
    ap.add_argument("--out", type=Path, default=RESULTS / "two_maps")
    ap.add_argument(
        "--reuse",
        type=Path,
        nargs="+",
        default=[],
        help="earlier runs' JSON (same scenario, lattice and cap): their grid runs, and those of the modes "
        "not in --modes, are taken from them instead of rerun (for a change that touches only some modes)",
    )
    ap.add_argument(
        "--modes", nargs="*", choices=list(MODES), default=list(DEFAULT_MODES), help="modes to run"
    )
    args = ap.parse_args(argv)
    earlier = {r["seed"]: r for path in args.reuse for r in json.loads(path.read_text())}
    rows: list[dict[str, Any]] = []
    for seed in args.seeds:
        old = earlier.get(seed, {"runs": {}})
        grid = old["runs"].get("grid") or one_run(
            args.scenario, "grid", seed, HARDNESS_ONLY, None, None, args.lattice_n
        )
        target_h, target_e = grid["final_mape_pct"], grid["final_mape_modulus_pct"]
        t_grid_h = _t(grid["trajectory"], target_h)
        t_grid_e = _t(grid["trajectory_modulus"], target_e)
        row: dict[str, Any] = {
            "seed": seed,
            "target_h_pct": target_h,
            "target_e_pct": target_e,
            "grid_t_h_s": t_grid_h,
            "grid_t_e_s": t_grid_e,
            "runs": {"grid": grid},
        }
        for mode, (policy, weights) in MODES.items():
            reused = mode not in args.modes
            if not reused:
                run = one_run(
                    args.scenario, policy, seed, weights, (target_h, target_e), args.cap_s, args.lattice_n
                )
            elif mode in old["runs"]:
                run = old["runs"][mode]
            else:
                continue  # neither run nor reused: the row has no such mode
            t_h, t_e = _t(run["trajectory"], target_h), _t(run["trajectory_modulus"], target_e)
            row["runs"][mode] = run
            row[f"{mode}_t_h_s"], row[f"{mode}_t_e_s"] = t_h, t_e
            row[f"{mode}_speedup_h"] = t_grid_h / t_h if t_h and t_grid_h else None
            row[f"{mode}_speedup_e"] = t_grid_e / t_e if t_e and t_grid_e else None
            print(
                f"seed {seed} {mode:8s}: H {target_h:.3f} % at {t_h} s (grid {t_grid_h:.0f} s), "
                f"E {target_e:.3f} % at {t_e} s (grid {t_grid_e:.0f} s), wall {run['wall_s']:.0f} s"
                + (" (reused)" if reused else ""),
                flush=True,
            )
        rows.append(row)
        print(
            f"seed {seed} grid: H {target_h:.3f} % E {target_e:.3f} %, wall {grid['wall_s']:.0f} s",
            flush=True,
        )
        _write(rows, args)  # after every seed: a long run stopped early keeps what it finished
    print("\n".join(_table(rows, args)))
    return 0


def _write(rows: list[dict[str, Any]], args: argparse.Namespace) -> None:
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".md").write_text("\n".join(_table(rows, args)) + "\n")
    args.out.with_suffix(".json").write_text(json.dumps(rows, indent=1, default=float))


def _median_missing_low(vals: list[float | None]) -> float | None:
    """The median over every seed, a seed that never reached the target (None) counting below all others;
    None when the median falls on such a seed."""
    ranked = sorted(vals, key=lambda v: -math.inf if v is None else v)
    mid = ranked[(len(ranked) - 1) // 2 : len(ranked) // 2 + 1]
    return (
        None if not mid or any(v is None for v in mid) else statistics.fmean(v for v in mid if v is not None)
    )


def _fmt(v: float | None, spec: str = ".1f") -> str:
    return "—" if v is None else format(v, spec)


def _table(rows: list[dict[str, Any]], args: argparse.Namespace) -> list[str]:
    out = [
        f"# Hardness and modulus mapped together: {args.scenario}, seeds {', '.join(str(r['seed']) for r in rows)}",
        "",
        f"aeni runs stop once both maps are at the grid's final MAPE (cap {args.cap_s:,.0f} s). "
        "Speed-up: the grid's time to its own final MAPE over the run's time to reach it (per map).",
        "",
        "| seed | grid H % | grid E % | mode | t(H) s | t(E) s | t(both) s | speed-up H | speed-up E |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        for mode in (m for m in MODES if f"{m}_t_h_s" in r):
            t_h, t_e = r[f"{mode}_t_h_s"], r[f"{mode}_t_e_s"]
            both = max(t_h, t_e) if t_h is not None and t_e is not None else None
            out.append(
                f"| {r['seed']} | {r['target_h_pct']:.3f} | {r['target_e_pct']:.3f} | {mode} | {_fmt(t_h, ',.0f')} "
                f"| {_fmt(t_e, ',.0f')} | {_fmt(both, ',.0f')} | {_fmt(r[f'{mode}_speedup_h'])}× "
                f"| {_fmt(r[f'{mode}_speedup_e'])}× |"
            )
    out += ["", "| summary | median | worst seed |", "|---|---|---|"]
    for mode in MODES:
        for key in ("speedup_h", "speedup_e"):
            vals = [(r[f"{mode}_{key}"], r["seed"]) for r in rows if f"{mode}_{key}" in r]
            if not vals:
                continue
            worst = min(vals, key=lambda p: -1.0 if p[0] is None else p[0])
            out.append(
                f"| {mode}: {key.replace('_', ' ')} | {_fmt(_median_missing_low([v for v, _ in vals]))}× "
                f"| {_fmt(worst[0])}× (seed {worst[1]}) |"
            )
    # the cost of aiming at both: time to the hardness target, and to both targets, against hardness only
    extra_h, extra_both = [], []
    for r in rows:
        base = r.get("hardness_t_h_s")
        if base and "both_t_h_s" in r:
            if r["both_t_h_s"]:
                extra_h.append((100.0 * (r["both_t_h_s"] / base - 1.0), r["seed"]))
            t_both = [r["both_t_h_s"], r["both_t_e_s"]]
            if all(t is not None for t in t_both):
                extra_both.append((100.0 * (max(t_both) / base - 1.0), r["seed"]))
    for label, vals in (
        ("both: extra time to the hardness target vs hardness only", extra_h),
        ("both: extra time to both targets vs hardness only to its target", extra_both),
    ):
        if vals:
            worst = max(vals)
            out.append(
                f"| {label} | {statistics.median(v for v, _ in vals):+.1f} % | {worst[0]:+.1f} % (seed {worst[1]}) |"
            )
    return out


if __name__ == "__main__":
    raise SystemExit(main())

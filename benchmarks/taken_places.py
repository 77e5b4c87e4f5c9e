"""Planners and the safety interlock agree on which places are taken: count the proposals it would refuse.

Each case draws a random sample (rotated, skewed, tilted corners, exclusions, earlier indents, sometimes a
tight stage), a random history of blocks on it whose indents are measured, failed, not run or unverified
(an export refused that still says where the tip went), feeds the history to a real Campaign with one of
the real planners (``aeni`` and every reference policy) and to an Interlock, and asks the planner for its
next block. The interlock must let every proposal through. In about half the cases the model is fitted
on the history first, so the planners' model-driven phases are exercised as well as their starts.

    nice -n 10 python benchmarks/taken_places.py [--cases 10000] [--seed 0]

writes benchmarks/results/taken_places.md and .json. tests/test_taken_places.py runs the same case on
samples drawn by hypothesis.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import sys
import time
from collections import Counter, defaultdict
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
os.environ.setdefault("OMP_NUM_THREADS", "1")

from core.campaign import Campaign  # noqa: E402
from core.campaign_config import CampaignConfig  # noqa: E402
from core.errors import InputError  # noqa: E402
from core.geometry import Calibration, Corner  # noqa: E402
from core.interlock import Interlock  # noqa: E402
from core.plan import Block, IndentResult, IndentSpec, PlannerSettings  # noqa: E402
from core.policies.registry import policy_names  # noqa: E402
from core.sample import CircleExclusion, PolygonExclusion, Sample  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"
STATUSES = ("measured", "failed", "not_run", "unverified")
STATUS_P = (0.55, 0.2, 0.1, 0.15)
MODEL_PHASES = ("exploit",)  # phases in which the fitted map places the block


@dataclass(frozen=True)
class CaseOutcome:
    policy: str
    fitted: bool
    proposed: bool  # False: the planner (or a budget) had nothing to propose
    refusal: str | None  # the interlock's reason, None when it let the proposal through
    phase: str  # the planner's phase for the proposal (seed, explore, exploit, grid ...)
    statuses: dict[str, int]  # the history's indents by status
    seconds: float


def random_sample(rng: np.random.Generator, lattice_n: int = 16) -> Sample | None:
    """A corner set like tests/test_interlock.py's ``samples`` strategy draws (None: degenerate corners)."""
    cx, cy = rng.uniform(2_000.0, 90_000.0, 2)
    w, h = rng.uniform(300.0, 6_000.0, 2)
    theta = math.radians(rng.uniform(-40.0, 40.0))
    skew = rng.uniform(-0.08, 0.08, 8)
    a, b = rng.uniform(-0.02, 0.02, 2)
    zn = rng.uniform(-2.0, 2.0, 4)
    base = [(-w / 2, h / 2), (w / 2, h / 2), (w / 2, -h / 2), (-w / 2, -h / 2)]
    c, s = math.cos(theta), math.sin(theta)
    corners = []
    for k, (px, py) in enumerate(base):
        px += skew[2 * k] * w
        py += skew[2 * k + 1] * h
        x, y = cx + c * px - s * py, cy + s * px + c * py
        corners.append(Corner(x, y, 200.0 + a * (x - cx) + b * (y - cy) + zn[k]))
    try:
        cal = Calibration.from_corners(*corners)
    except InputError:
        return None
    x_min, x_max, y_min, y_max = cal.bounds_um
    span = max(x_max - x_min, y_max - y_min)

    def point(margin: float = 0.2) -> tuple[float, float]:
        u, v = rng.uniform(-margin, 1 + margin, 2)
        return (float(x_min + u * (x_max - x_min)), float(y_min + v * (y_max - y_min)))

    exclusions: list[CircleExclusion | PolygonExclusion] = []
    for _ in range(int(rng.integers(0, 4))):
        if rng.random() < 0.5:
            px, py = point()
            exclusions.append(CircleExclusion(px, py, float(rng.uniform(5.0, 0.3 * span))))
        else:
            exclusions.append(PolygonExclusion(tuple(point() for _ in range(int(rng.integers(3, 7))))))
    earlier = tuple(point(0.0) for _ in range(int(rng.integers(0, 26))))
    if rng.random() < 0.5:
        stage = (x_min - 50.0, y_min - 50.0, x_max + 50.0, y_max - rng.uniform(0.0, 0.5) * (y_max - y_min))
    else:
        stage = (0.0, 0.0, 100_000.0, 100_000.0)
    return Sample(
        name="generated",
        profile="kla-imicro",
        calibration=cal,
        lattice_n=lattice_n,
        dz_safe_um=float(rng.uniform(0.5, 10.0)),
        r_excl_um=float(rng.uniform(0.0, 40.0)),
        edge_band_um=float(rng.uniform(0.0, 60.0)),
        stage_rect_um=tuple(float(v) for v in stage),  # type: ignore[arg-type]
        exclusions=tuple(exclusions),
        earlier_indents_um=earlier,
    )


def _result(
    rng: np.random.Generator, block_id: int, i: int, spec: IndentSpec, status: str, t_s: float
) -> IndentResult:
    nan = math.nan
    dx, dy = rng.normal(0.0, 0.5, 2)
    ax, ay = spec.x_um + dx, spec.y_um + dy
    if status == "measured":
        h = float(rng.normal(10.0, 1.0))
        return IndentResult(
            block_id, i, spec.x_um, spec.y_um, ax, ay, spec.hold_s, h, 150.0, float(rng.normal(0, 0.05)), t_s
        )
    if status == "failed" and rng.random() < 0.5:
        ax, ay = nan, nan  # the instrument reported no position either: the commanded one is taken
    if status == "not_run":
        ax, ay = nan, nan
    return IndentResult(
        block_id,
        i,
        spec.x_um,
        spec.y_um,
        ax,
        ay,
        spec.hold_s,
        nan,
        nan,
        nan,
        t_s,
        status,  # type: ignore[arg-type]
        f"generated {status}",
    )


def random_history(
    rng: np.random.Generator, sample: Sample, hold_s: float
) -> list[tuple[Block, list[IndentResult]]]:
    """Blocks of a few indents, replicate grids and scattered singles, on the sample and around its edges,
    their indents measured, failed, not run or unverified. The first block opens a program."""
    cal = sample.calibration
    out: list[tuple[Block, list[IndentResult]]] = []
    t_s = 0.0
    n_blocks = int(rng.integers(1, 16))
    for bid in range(n_blocks):
        kind = "global" if bid == 0 or rng.random() < 0.3 else "local"
        u, v = rng.uniform(-0.05, 1.05, 2)
        cx, cy = (float(c) for c in cal.to_stage(u, v))
        if rng.random() < 0.5:
            g, pitch = int(rng.integers(2, 6)), 5.0
            half = (g - 1) / 2.0
            sites = [
                IndentSpec(cx + (col - half) * pitch, cy + (row - half) * pitch, hold_s)
                for row in range(g)
                for col in range(g)
            ]
        else:
            g, pitch = 1, 5.0
            spread = float(rng.choice([30.0, 150.0, 400.0]))
            sites = [
                IndentSpec(cx + float(dx), cy + float(dy), hold_s)
                for dx, dy in rng.uniform(-spread, spread, (int(rng.integers(1, 25)), 2))
            ]
        block = Block(bid, kind, cx, cy, g, pitch, hold_s, tuple(sites))  # type: ignore[arg-type]
        statuses = rng.choice(len(STATUSES), size=len(sites), p=STATUS_P)
        results = []
        for i, (spec, k) in enumerate(zip(sites, statuses, strict=True)):
            t_s += 60.0
            results.append(_result(rng, bid, i, spec, STATUSES[int(k)], t_s))
        out.append((block, results))
    return out


def run_case(sample: Sample, policy: str, seed: int, fit: bool) -> CaseOutcome:
    """Feed a random history to a real Campaign and an Interlock; ask the planner once; let the interlock judge."""
    t0 = time.perf_counter()
    rng = np.random.default_rng([seed, 23])
    settings = PlannerSettings(budget_s=1e9)
    campaign = Campaign(CampaignConfig(policy=policy, seed=seed, settings=settings, sample=sample))
    history = random_history(rng, sample, campaign.profile.default_hold_s)
    interlock = Interlock(sample, campaign.profile)
    interlock.restore(history)
    for k, (block, results) in enumerate(history):
        campaign.observe_block(block, results, refit=fit and k == len(history) - 1)
    last_block = history[-1][0]
    # the stage is where the last indent went (or was sent); now and then the program was closed since
    position = (last_block.indents[-1].x_um, last_block.indents[-1].y_um)
    program_open = bool(rng.random() < 0.8)
    clock_s = max(r.t_s for _, rs in history for r in rs)
    statuses = Counter(r.status for _, rs in history for r in rs)
    decision = campaign.propose(clock_s, position, program_open, len(history))
    refusal = None if decision is None else interlock.check(decision.block, position, program_open)
    return CaseOutcome(
        policy,
        campaign.has_map(),
        decision is not None,
        refusal,
        "" if decision is None else decision.phase,
        dict(statuses),
        time.perf_counter() - t0,
    )


def run_cases(n_cases: int, seed: int) -> list[CaseOutcome]:
    rng = np.random.default_rng(seed)
    policies = policy_names()
    out: list[CaseOutcome] = []
    while len(out) < n_cases:
        sample = random_sample(rng)
        if sample is None:
            continue
        policy = policies[len(out) % len(policies)]
        out.append(run_case(sample, policy, int(rng.integers(2**31)), fit=bool(rng.random() < 0.5)))
    return out


def table(outcomes: list[CaseOutcome], wall_s: float) -> str:
    by: dict[str, list[CaseOutcome]] = defaultdict(list)
    for o in outcomes:
        by[o.policy].append(o)
    lines = [
        "| policy | cases | with a fitted map | proposals | of them model-driven | refused by the interlock "
        "| median s/case |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for name in policy_names():
        rows = by.get(name, [])
        if not rows:
            continue
        lines.append(
            f"| {name} | {len(rows)} | {sum(o.fitted for o in rows)} | {sum(o.proposed for o in rows)} | "
            f"{sum(o.phase in MODEL_PHASES for o in rows)} | {sum(o.refusal is not None for o in rows)} | {statistics.median(o.seconds for o in rows):.3f} |"
        )
    total = Counter[str]()
    for o in outcomes:
        total.update(o.statuses)
    lines.append(
        f"| all | {len(outcomes)} | {sum(o.fitted for o in outcomes)} | {sum(o.proposed for o in outcomes)} | "
        f"{sum(o.phase in MODEL_PHASES for o in outcomes)} | "
        f"{sum(o.refusal is not None for o in outcomes)} | "
        f"{statistics.median(o.seconds for o in outcomes):.3f} |"
    )
    lines.append("")
    lines.append(
        "History indents: "
        + ", ".join(f"{s} {total.get(s, 0):,}" for s in STATUSES)
        + f". Wall time {wall_s:,.0f} s."
    )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", type=int, default=10_000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=RESULTS / "taken_places")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    outcomes = run_cases(args.cases, args.seed)
    wall = time.perf_counter() - t0
    text = table(outcomes, wall)
    refused = [o for o in outcomes if o.refusal is not None]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".md").write_text(
        f"# Taken places: planner proposals the interlock refuses\n\n"
        f"`python benchmarks/taken_places.py --cases {args.cases} --seed {args.seed}`\n\n{text}\n"
    )
    args.out.with_suffix(".json").write_text(
        json.dumps(
            {
                "cases": args.cases,
                "seed": args.seed,
                "wall_s": wall,
                "refused": [replace(o, statuses=o.statuses).__dict__ for o in refused],
            },
            indent=1,
        )
    )
    print(text)
    for o in refused[:10]:
        print(f"refused ({o.policy}): {o.refusal}")
    return 1 if refused else 0


if __name__ == "__main__":
    sys.exit(main())

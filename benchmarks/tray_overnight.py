"""A tray overnight against the same samples one after another (issue 40's benchmark): prints a table, writes
results/tray_overnight.{json,md}.

Four samples: the ternary library, the quaternary film, a robustness field (``step``) and a fused-silica
reference. Both arms run on the simulated instrument with the same operator calendar: started Monday 18:00
(the lab loads the instrument as it leaves), operator hours Mon-Fri 08:30-18:00, response 10 min, a routine
visit every 2 h during hours.

- tray: one run (``RunSpec.tray``): the reference checked before the first library, every 4 h and after the
  last; the planner goes from library to library by information per second.
- one after another: each library its own run (no tip checks: the arm is given the benefit of the doubt),
  each started when the previous one ended, its first arrays loaded when the operator answers.

Measured per arm: wall clock from Monday 18:00 until every library reached its goal, operator visits,
instrument time and stalls (a load that waited across an absence: the instrument stood idle with work left).

Run: python benchmarks/tray_overnight.py [--seeds 3] [--lattice-n 30]
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import statistics
import sys
import time
from datetime import datetime, timedelta
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
os.environ.setdefault("OMP_NUM_THREADS", "1")

from core.campaign_config import CampaignConfig  # noqa: E402
from core.operator import OperatorAvailability, OperatorHours  # noqa: E402
from core.plan import PlannerSettings  # noqa: E402
from core.run.headless import run_headless  # noqa: E402
from core.run.spec import RunSpec  # noqa: E402
from core.run.tray import goal_settings  # noqa: E402
from core.sample.tray import Goal, Reference, Tray, TraySample, block_sample, placed_sample  # noqa: E402
from core.sample_change import change_s  # noqa: E402
from core.visits import OperatorCalendar, SimulatedOperator  # noqa: E402
from drivers.registry import DRIVERS, default_sample  # noqa: E402

STAGE = (0.0, 0.0, 100_000.0, 100_000.0)
HOURS = "Mon-Fri 08:30-18:00"
RESPONSE_S = 600.0
VISIT_EVERY_S = 7200.0
MONDAY_1800 = datetime(2026, 11, 23, 18, 0)  # a Monday
# (name, sim scenario, offset on the stage µm, goal): the film's own sample sits at (10, 20) mm
LIBRARIES = (
    ("ternary", "ternary", (0.0, 0.0), Goal("rel_sd_pct", 2.0)),
    ("film", "film", (0.0, 0.0), Goal("rel_sd_pct", 4.0)),
    ("step", "step", (3000.0, 0.0), Goal("rel_sd_pct", 2.5)),
)
REFERENCE = Reference("fused-silica", 9.0, 72.0, 5.0, 4.0)


def calendar(start: datetime) -> OperatorCalendar:
    return OperatorCalendar(
        OperatorAvailability(OperatorHours.parse(HOURS), RESPONSE_S, VISIT_EVERY_S), start
    )


def tray_of(seed: int, with_reference: bool = True) -> Tray:
    samples = []
    for name, scenario, offset, goal in LIBRARIES:
        own = default_sample("sim", {"scenario": scenario}, seed)
        samples.append(
            TraySample(
                name, "library", placed_sample(own, offset, STAGE), offset, goal, sim={"scenario": scenario}
            )
        )
    if with_reference:
        block = block_sample("fused-silica", "kla-imicro", 0.0, 0.0, 5000.0, 5000.0)
        samples.append(
            TraySample(
                "fused-silica", "reference", placed_sample(block, (30_000.0, 0.0), STAGE), (30_000.0, 0.0),
                reference=REFERENCE,
            )
        )  # fmt: skip
    return Tray("overnight", tuple(samples), STAGE)


# the lab loads the first arrays as it leaves at 18:00: the calendar starts one response time earlier, so that
# request is answered at 18:00; every wall clock below counts from 18:00
T0 = MONDAY_1800 - timedelta(seconds=RESPONSE_S)


def run_tray(seed: int, lattice_n: int, with_reference: bool = True) -> dict[str, float]:
    spec = RunSpec(
        campaign=CampaignConfig(seed=seed, lattice_n=lattice_n),
        calendar=calendar(T0),
        tray=tray_of(seed, with_reference),
    )
    tally, run = run_headless(spec, DRIVERS)
    assert run.visits is not None and run.tray is not None
    tc, v = run.tray, run.visits
    missed = [n for n, lane in tc.lanes.items() if lane.done_at_s is None]
    if missed:
        raise RuntimeError(
            f"seed {seed}: the tray ended before {missed} reached their goal: {tally.stop_reason}"
        )
    goal_t = max(lane.done_at_s for lane in tc.lanes.values() if lane.done_at_s is not None)
    wall = v.wall_at(goal_t)
    assert wall is not None
    change_h = tc.changes * change_s(next(iter(tc.lanes.values())).campaign.profile) / 3600
    return {
        "wall_to_goals_h": (wall - RESPONSE_S) / 3600,
        "visits": v.visits,
        "instrument_h": tally.instrument_s / 3600,
        "stalls": _stalls(v),
        "tip_checks": len(tc.checks),
        "failed_checks": sum(not c.passed for c in tc.checks),
        **_breakdown(tally.ledger.seconds, tc.reference_s / 3600, tc.changes, change_h),
        "waits_h": (wall - goal_t) / 3600,
    }


def _breakdown(seconds: dict[str, float], check_h: float, changes: int, change_h: float) -> dict[str, float]:
    """Instrument time by kind: indenting (approach, load, hold and unload on every sample, the reference's
    included), the tip checks (everything on the reference: its indents, moves and changes), the sample
    changes' extra surface find and settle, and the rest (setup, lift, move, engage, drift, comeback)."""
    indent_h = (seconds.get("indent", 0.0) + seconds.get("hold", 0.0)) / 3600
    return {
        "indent_h": indent_h,
        "check_h": check_h,
        "changes": changes,
        "change_h": change_h,
        "overhead_h": sum(seconds.values()) / 3600 - indent_h,
    }


def _stalls(v: SimulatedOperator) -> int:
    """Waits across an absence, from the calendar's points: the wall clock jumped past instrument time by
    more than a response time between two blocks."""
    gaps = [(b.wall_s - b.t_s) - (a.wall_s - a.t_s) for a, b in itertools.pairwise(v.points)]
    return sum(g > RESPONSE_S + 1.0 for g in gaps)


def run_one_after_another(seed: int, lattice_n: int) -> dict[str, float]:
    wall_s, visits, instrument_s, stalls, waits_s = 0.0, 0, 0.0, 0, 0.0
    ledger: dict[str, float] = {}
    for k, (name, scenario, offset, goal) in enumerate(LIBRARIES):
        own = placed_sample(default_sample("sim", {"scenario": scenario}, seed), offset, STAGE)
        spec = RunSpec(
            campaign=CampaignConfig(
                seed=seed, lattice_n=lattice_n, sample=own, name=name,
                settings=goal_settings(PlannerSettings(), goal), driver_options={"scenario": scenario},
            ),
            calendar=calendar(T0 + timedelta(seconds=wall_s)),
        )  # fmt: skip
        tally, run = run_headless(spec, DRIVERS)
        v = run.visits
        assert v is not None
        if "below stop_rel_sd_pct" not in tally.stop_reason:
            raise RuntimeError(f"seed {seed}: {name} ended before its goal: {tally.stop_reason}")
        if k > 0 and v.waited_s > RESPONSE_S + 1.0:
            stalls += 1  # the instrument stood idle with this sample's run still to start
        wall_s += v.wall_s(tally.instrument_s)
        waits_s += v.waited_s
        for k2, sec in tally.ledger.seconds.items():
            ledger[k2] = ledger.get(k2, 0.0) + sec
        visits += v.visits
        instrument_s += tally.instrument_s
        stalls += _stalls(v)
    return {
        "wall_to_goals_h": (wall_s - RESPONSE_S) / 3600,
        "visits": visits,
        "instrument_h": instrument_s / 3600,
        "stalls": stalls,
        "tip_checks": 0,
        "failed_checks": 0,
        **_breakdown(ledger, 0.0, 0, 0.0),
        "waits_h": waits_s / 3600 - RESPONSE_S / 3600,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--lattice-n", type=int, default=30, help="candidate centres per side on every sample")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    ap.add_argument(
        "--no-reference",
        action="store_true",
        help="the tray without its reference (what the tip checks cost)",
    )
    args = ap.parse_args()
    rows = []
    started = time.perf_counter()
    for seed in range(args.seeds):
        t0 = time.perf_counter()
        tray = run_tray(seed, args.lattice_n, not args.no_reference)
        seq = run_one_after_another(seed, args.lattice_n)
        row = {"seed": seed, "tray": tray, "one_after_another": seq, "cpu_s": time.perf_counter() - t0}
        row["speedup"] = seq["wall_to_goals_h"] / tray["wall_to_goals_h"]
        rows.append(row)
        print(
            f"seed {seed}: tray {tray['wall_to_goals_h']:.1f} h, {tray['visits']} visits; one after another "
            f"{seq['wall_to_goals_h']:.1f} h, {seq['visits']} visits; ×{row['speedup']:.2f}",
            flush=True,
        )
    med = statistics.median(r["speedup"] for r in rows)
    worst = min(rows, key=lambda r: r["speedup"])
    goals = ", ".join(f"{n} {g.kind} {g.value:g}" for n, _, _, g in LIBRARIES)
    lines = [
        "# A tray overnight against one run after another (issue 40)"
        + (": the tray without its reference" if args.no_reference else ""),
        "",
        f"Libraries and goals: {goals}; "
        + (
            "no reference in the tray (what the tip checks cost)."
            if args.no_reference
            else f"a fused-silica reference checked every {REFERENCE.check_every_h:g} h in the tray."
        )
        + f" Policy `aeni`, lattice {args.lattice_n}×{args.lattice_n} per sample, simulated instrument.",
        f"Calendar: start Monday 18:00, operator {HOURS}, response {RESPONSE_S / 60:g} min, a visit every "
        f"{VISIT_EVERY_S / 3600:g} h during hours. Wall clock from Monday 18:00 to the last library's goal.",
        "",
        "Instrument time by kind (h): indenting (load, hold, unload; every sample), overhead (setup, lift, move,"
        " engage, drift settle, comeback: all the rest, so indenting + overhead = instrument), of which the tip"
        " checks (all time on the reference) and the sample changes' extra surface find and settle; waits: the"
        " wall clock to every goal the instrument stood waiting for a person.",
        "",
        "| seed | arm | wall to every goal h | visits | instrument h | indenting h | overhead h | tip checks h"
        " (n, failed) | sample changes h (n) | waits h | stalls |",
        "|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        for arm in ("tray", "one_after_another"):
            a = r[arm]
            lines.append(
                f"| {r['seed']} | {arm.replace('_', ' ')} | {a['wall_to_goals_h']:.1f} | {a['visits']} | "
                f"{a['instrument_h']:.1f} | {a['indent_h']:.1f} | {a['overhead_h']:.1f} | {a['check_h']:.1f} "
                f"({a['tip_checks']}, {a['failed_checks']}) | {a['change_h']:.1f} ({a['changes']}) | "
                f"{a['waits_h']:.1f} | {a['stalls']} |"
            )
    lines += [
        "",
        f"Wall-clock ratio one-after-another / tray: median **×{med:.2f}**, worst seed {worst['seed']} "
        f"×{worst['speedup']:.2f} (target ≥ ×1.5). Computed in {time.perf_counter() - started:.0f} s; "
        f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} shared cores.",
    ]
    text = "\n".join(lines) + "\n"
    print(text)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    stem = "tray_overnight_noref" if args.no_reference else "tray_overnight"
    (out / f"{stem}.json").write_text(json.dumps({"lattice_n": args.lattice_n, "runs": rows}, indent=2))
    (out / f"{stem}.md").write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

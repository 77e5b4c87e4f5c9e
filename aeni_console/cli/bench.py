"""``aeni bench``: policies × scenarios × seeds on the emulator, then RESULTS.md, results.json and figures."""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

from aeni_console.cli.common import add_operator_args, map_weights_arg, operator_calendar, whole_number
from core.errors import InputError
from drivers.sim.failures import FailureModes

if TYPE_CHECKING:
    from aeni_console.bench.harness import RunRecord


def _handler(args: argparse.Namespace) -> int:
    # imported here, not at the top: the bench and its report pull torch and pandas; `aeni --help` must start fast
    from aeni_console.bench.harness import BenchConfig, run_bench
    from aeni_console.reports.bench import write_report
    from core.settings import settings_from_dict

    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise InputError(str(out), "--out must be a folder, and this is a file")
    if args.render_from is not None:
        return _render([Path(p) for p in args.render_from.split(",") if p.strip()], out)
    config = BenchConfig.make(
        quick=args.quick, seeds=args.seeds, jobs=args.jobs, only=args.scenarios, policies=args.policies
    )
    if args.lattice is not None:
        config = replace(config, lattice_n=args.lattice)
    if args.failure_rate is not None:
        FailureModes.at_rate(args.failure_rate, 0)  # refuse a bad rate before anything runs
        config = replace(config, failure_rate=args.failure_rate)
    if args.map_weights is not None:
        settings_from_dict({"map_weights": args.map_weights})  # refuse bad weights before anything runs
        config = replace(config, map_weights=args.map_weights)

    calendar = operator_calendar(args)
    if calendar is not None:
        config = replace(config, calendar=calendar)
    n_runs = sum(len(s.policies) * min(config.seeds, s.max_seeds or config.seeds) for s in config.scenarios)
    start = time.monotonic()
    done = 0

    def progress(r: RunRecord) -> None:
        nonlocal done
        done += 1
        if not args.quiet:
            hit = "—" if r.t_hit_s is None else f"{r.t_hit_s:,.0f} s"
            # on the calendar: the wall clock and visits to the target, so a bench cut short still says them
            cal = (
                f"  {r.wall_clock_h:6.1f} h wall, {r.operator_visits} visits"
                if r.wall_clock_h is not None and r.operator_visits is not None
                else ""
            )
            sys.stderr.write(
                f"[{done:4d}/{n_runs}] {r.scenario:<15} {r.policy:<15} seed {r.seed:<3} "
                f"target at {hit:>12}{cal}  final MAPE {r.final_mape_pct or float('nan'):6.3f} %  "
                f"{r.blocks:4d} blocks  {r.wall_s:5.1f} s  (elapsed {time.monotonic() - start:6.0f} s)\n"
            )
            sys.stderr.flush()

    with tempfile.TemporaryDirectory(prefix="aeni-bench-") as work:
        records = run_bench(config, Path(work), progress, dask_address=args.dask)
    wall = time.monotonic() - start
    paths = write_report(records, config, out, wall)
    print(
        f"{len(records)} campaigns in {wall / 60:.1f} min; wrote {', '.join(str(p) for p in paths[:2])}"
        f" and {len(paths) - 2} figure(s)"
    )
    return 0


def _render(sources: list[Path], out: Path) -> int:
    """The report again from one run's results.json (after a change to the report, or if rendering failed),
    or from several merged (a sweep run in pieces). The map figures of each part are carried over."""
    from aeni_console.bench.harness import merge_results, records_from_json
    from aeni_console.reports.bench import write_report

    if not sources:
        raise InputError("--render-from", "name at least one results.json")
    parts = []
    for source in sources:
        try:
            data = json.loads(source.read_text(encoding="utf-8"))
        except OSError as exc:
            raise InputError(str(source), f"cannot read it ({exc.strerror or exc})") from None
        except ValueError as exc:
            raise InputError(str(source), f"not JSON ({exc})") from None
        if not isinstance(data, dict):
            raise InputError(str(source), "not the output of aeni bench (expected a JSON object)")
        try:
            parts.append(records_from_json(data))
        except InputError as exc:
            raise InputError(str(source), exc.problem) from None
    records, config, wall = merge_results(parts) if len(parts) > 1 else parts[0]
    maps_dir = out / "figures"
    for source in sources:  # later parts win, as their runs do
        for fig in sorted((source.parent / "figures").glob("maps_*.png")):
            if fig.resolve() != (maps_dir / fig.name).resolve():
                maps_dir.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(fig, maps_dir / fig.name)
    paths = write_report(records, config, out, wall, keep_existing_maps=True, parts=len(parts))
    what = sources[0] if len(sources) == 1 else f"{len(sources)} runs"
    print(f"rendered {len(records)} campaigns from {what}; wrote {paths[0]} and {len(paths) - 2} figure(s)")
    return 0


def register(sub: argparse._SubParsersAction) -> None:

    p = sub.add_parser(
        "bench", help="benchmark the policies on the emulator (RESULTS.md, results.json, figures)"
    )
    p.add_argument(
        "--quick", action="store_true", help="one scenario, 2 seeds, a small lattice: a quick check"
    )
    p.add_argument(
        "--seeds",
        type=whole_number("--seeds", 1, 1000),
        default=None,
        help="seeds per scenario (10; quick: 2)",
    )
    p.add_argument(
        "--jobs", type=whole_number("--jobs", 1, 64), default=2, help="worker processes (default 2)"
    )
    p.add_argument(
        "--lattice",
        type=whole_number("--lattice", 10, 400),
        default=None,
        help="candidate lattice per side (50; quick: 30; the product's default on the 1000 µm square is 100)",
    )
    p.add_argument(
        "--scenarios",
        default=None,
        metavar="KEY[,KEY...]",
        help="run only these bench scenarios (keys as in RESULTS.md: ternary, good-drift, film, ...)",
    )
    p.add_argument(
        "--policies",
        default=None,
        metavar="P[,P...]",
        help="score only these policies (the grid always runs: it sets every target); an ablation "
        "BASE+modifier named here runs on every scenario",
    )
    p.add_argument(
        "--dask",
        default=None,
        metavar="ADDRESS",
        help="run the sweep on a Dask cluster (scheduler address, e.g. tcp://host:8786; the dask extra)",
    )
    p.add_argument(
        "--failure-rate",
        dest="failure_rate",
        type=float,
        default=None,
        help="share of indents the simulated instrument fails (invalid values; a quarter of it of the blocks "
        "find no surface or are aborted); default 0.015, about what a real instrument does; 0: never",
    )
    p.add_argument(
        "--map-weights",
        type=map_weights_arg,
        default=None,
        metavar="hardness=W,modulus=W",
        help="the planner's map_weights, and score the modulus map too: each policy's time to both grids' "
        "final MAPEs (default: hardness=1,modulus=1, the product's; modulus=0: hardness only, no modulus scored)",
    )

    add_operator_args(p)
    p.add_argument("--out", default="bench-out", help="folder for RESULTS.md, results.json and figures/")
    p.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    p.add_argument(
        "--render-from",
        default=None,
        metavar="RESULTS_JSON[,...]",
        help="run nothing: write the report into --out again from a bench's results.json, or from several"
        " merged (a later file's runs replace the same runs of an earlier one)",
    )
    p.set_defaults(func=_handler)

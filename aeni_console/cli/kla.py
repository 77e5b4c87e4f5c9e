"""``aeni kla read FILE``: show, dump or convert a KLA/Agilent export (InView .xlsx, NanoSuite .xls)."""

from __future__ import annotations

import argparse
import contextlib
import functools
import os
import signal
import sys
import time
from collections.abc import Callable
from dataclasses import replace
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import TYPE_CHECKING, Any

from aeni_console.cli.common import dumps, positive_float, seed_arg
from aeni_console.cli.tray import resolve_tray
from aeni_console.files import input_file, write_atomic
from core.cost import block_steps
from core.errors import InputError
from core.profile import load_profile
from drivers.kla.exchange import ExchangeFolder, check_block, check_exchange_dir, make_ticket, ticket_text

if TYPE_CHECKING:
    from drivers.kla.export import KlaExport
    from drivers.sim.tray import TraySimDriver


def register(subparsers: Any) -> None:
    kla = subparsers.add_parser("kla", help="KLA/Agilent nanoindenter files", description=__doc__)
    actions = kla.add_subparsers(dest="kla_command", metavar="ACTION", parser_class=type(kla))
    actions.required = True
    read = actions.add_parser(
        "read",
        help="read an export into indent records",
        description=(
            "Read a KLA export: a short table by default, --json for records, --csv to convert. Several files or a "
            "folder (InView's one CSV per test) are read as one export, in natural test order."
        ),
    )
    read.add_argument(
        "file",
        metavar="FILE",
        nargs="+",
        help="InView .xlsx/.xls or CSV export, NanoSuite .xls, NanoBlitz CSV, or per-test CSVs / their folder",
    )
    read.add_argument("--json", action="store_true", help="print a JSON list of indent records")
    read.add_argument("--csv", metavar="OUT", type=Path, help="write the records to a CSV file")
    read.set_defaults(func=_read)

    fake = actions.add_parser(
        "fake-inview",
        help="a fake InView for tests and demos: runs each ticket's array on the emulator",
        description=(
            "Watch DIR/outbox for tickets, run each array on the emulator (the cost model's time ÷ --speed) "
            "and write InView-like exports to DIR/inbox until stopped (Ctrl-C). Faults: "
            "aborted, surface-not-found, missing-export, duplicate-export, mm-um, flipped-y "
            "(NAME for every block, NAME@BLOCK for one). A fast array's ticket (NanoBlitz) is read from the "
            "emulator's fast channel and exported as the NanoBlitz CSV, whatever --format says."
        ),
    )
    fake.add_argument("--exchange", metavar="DIR", type=Path, required=True, help="the exchange folder")
    fake.add_argument("--speed", type=positive_float("--speed"), default=None, help="instrument s per wall s")
    fake.add_argument("--fault", action="append", default=[], metavar="NAME[@BLOCK]", help="inject a fault")
    fake.add_argument("--scenario", default="ternary", help="emulator scenario (the run's)")
    fake.add_argument("--seed", type=seed_arg, default=0, help="emulator seed (the run's)")
    fake.add_argument("--noise", default=None, help="noise override (the run's)")
    fake.add_argument("--drift", default=None, help="drift override (the run's)")
    fake.add_argument(
        "--sample", default=None, metavar="FILE", help="the run's sample file: the scenario is laid onto it"
    )
    fake.add_argument("--profile", default=None, help="instrument profile (default: the scenario's)")
    fake.add_argument(
        "--tray",
        default=None,
        metavar="TRAY.toml",
        help="the run's tray file: every sample's truth on one stage (each library's scenario or truth CSV), "
        "each ticket run on the sample it names, with the sample changes the simulated tray charges",
    )
    fake.add_argument(
        "--tip-wear-pct-per-h",
        dest="tip_wear_pct_per_h",
        type=float,
        default=0.0,
        help="--tray: wear the tip (hardness reads high by this many %% per hour of instrument time)",
    )
    fake.add_argument(
        "--format",
        dest="fmt",
        choices=("xlsx", "csv", "records"),
        default="xlsx",
        help="export format ('records': a folder of per-test record CSVs, one per test, as InView can write)",
    )
    fake.add_argument(
        "--invalid-rate",
        type=float,
        default=0.03,
        help="share of indents exported as 1.797e308 (0-1); blank cells in a NanoBlitz CSV",
    )
    fake.add_argument(
        "--no-positions",
        dest="positions",
        action="store_false",
        help="export without X/Y Test Position columns (a lab template that leaves them out)",
    )
    fake.add_argument(
        "--ledger",
        type=Path,
        default=None,
        metavar="FILE",
        help="append every indent this fake instrument makes to FILE (JSON lines; outside the exchange folder)",
    )
    fake.set_defaults(func=_fake_inview)

    check = actions.add_parser(
        "check",
        help="first-run check: a 3-site array at a known origin shows the axis signs, origin and units",
        description=(
            "Publish a 3-site test array (an L: 100 µm along x, 50 µm along y) at the origin you give, print its "
            "ticket, then wait for InView's export in DIR/inbox and say whether the sign convention, the origin and "
            "the units are right, or what to change in the profile's [inview] section. Exit 0 when right."
        ),
    )
    check.add_argument("--exchange", metavar="DIR", type=Path, required=True, help="the exchange folder")
    check.add_argument("--x-mm", type=float, required=True, help="origin X on the stage (XY Control), mm")
    check.add_argument("--y-mm", type=float, required=True, help="origin Y on the stage (XY Control), mm")
    check.add_argument(
        "--hold-s", type=float, default=None, help="hold of the test indents (default: profile's)"
    )
    check.add_argument("--profile", default="kla-imicro", help="instrument profile name or TOML file")
    check.add_argument("--run", default=None, help="name for the files (default: check-<UTC time>)")
    check.add_argument(
        "--timeout-s", type=positive_float("--timeout-s"), default=None, help="wait at most this long"
    )
    check.set_defaults(func=_check)


def _read(args: argparse.Namespace) -> int:
    # imported here, not at the top: the export readers pull pandas and scipy; `aeni --help` must start fast
    from drivers.kla.export import read_kla_exports, records

    sources = [Path(f) if Path(f).is_dir() else input_file(f, "export file") for f in args.file]
    export = read_kla_exports(sources)
    if args.csv is not None:
        write_csv_atomic(export, args.csv)
    for note in export.warnings:
        print(f"aeni: warning: {note}", file=sys.stderr)
    if args.json:
        text = dumps(records(export))
    else:
        text = format_table(export)
        if args.csv is not None:
            text += f"\nwrote {len(export.indents)} records to {args.csv}"
    print_to_pipe(text)
    return 0


def print_to_pipe(text: str) -> None:
    """Print, and end quietly when the reader went away (``aeni kla read F --json | head``).

    Python's own advice: on EPIPE point stdout at /dev/null so the flush at exit cannot raise again.
    """
    try:
        sys.stdout.write(text + "\n")
        sys.stdout.flush()
    except BrokenPipeError:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)


def write_csv_atomic(export: KlaExport, out: Path) -> None:
    """Temp file beside the target, then rename: a reader never sees half a CSV."""
    if not (out.parent if str(out.parent) else Path(".")).is_dir():
        raise InputError(str(out), "output directory does not exist")
    write_atomic(out, export.to_frame().to_csv(index=False))


def _num(value: float | None, digits: int) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def format_table(export: KlaExport) -> str:
    lines = [export.summary]
    if export.analysis:
        lines.append(f"computed from the curves: {export.analysis}")
    lines += [
        f"{'test':>6} {'x_um':>12} {'y_um':>12} {'H_GPa':>8} {'E_GPa':>8} {'drift_nm_s':>11}  failure",
    ]
    for i in export.indents:
        lines.append(
            f"{i.test_id:>6} {_num(i.x_um, 2):>12} {_num(i.y_um, 2):>12} {_num(i.hardness_gpa, 3):>8} "
            f"{_num(i.modulus_gpa, 2):>8} {_num(i.drift_rate_nm_s, 4):>11}"
            + (f"  {i.failure}" if i.failure else "")
        )
    return "\n".join(lines)


def _fake_inview(args: argparse.Namespace) -> int:
    from core.sample import load_sample
    from drivers.kla.fake_inview import FakeInView, parse_fault
    from drivers.sim.scenarios import make_scenario

    check_exchange_dir(args.exchange)
    if not 0.0 <= args.invalid_rate <= 1.0:
        raise InputError("--invalid-rate", f"must be from 0 to 1, got {args.invalid_rate}")
    faults = tuple(parse_fault(f) for f in args.fault)
    tray_driver: Callable[[], TraySimDriver] | None = None
    make_emulator: Callable[[], Any] | None = None  # a tray's stations measure
    if args.tray is not None:
        tray_driver, profile_name = _fake_tray(args)
    else:
        if args.tip_wear_pct_per_h:
            raise InputError("--tip-wear-pct-per-h", "only a fake InView over a tray (--tray) wears its tip")
        scenario = make_scenario(args.scenario, args.seed, noise=args.noise, drift=args.drift)
        if args.sample is not None:  # the scenario's truth on the run's sample, as the sim driver lays it
            scenario = scenario.on_sample(load_sample(args.sample))
        profile_name = scenario.profile_name
        make_emulator = functools.partial(scenario.make_emulator, load_profile(args.profile or profile_name))
    profile = load_profile(args.profile or profile_name)
    fake = FakeInView(
        args.exchange,
        profile,
        make_emulator,
        speed=args.speed,
        faults=faults,
        fmt=args.fmt,
        invalid_rate=args.invalid_rate,
        positions=args.positions,
        log=lambda line: print(f"fake-inview: {line}", flush=True),
        ledger=args.ledger,
        tray_driver=tray_driver,
    )

    def stop(_signum: int, _frame: object) -> None:
        raise KeyboardInterrupt  # SIGTERM ends it like Ctrl-C

    signal.signal(signal.SIGTERM, stop)
    shown = ", ".join(args.fault) or "none"
    print(
        f"fake-inview: watching {args.exchange}/outbox (speed {args.speed or 'real time'}, faults {shown}"
        + (f", tray {args.tray}: each ticket on the sample it names)" if args.tray else ")"),
        flush=True,
    )
    with contextlib.suppress(KeyboardInterrupt):
        fake.serve_forever()
    return 0


def _fake_tray(args: argparse.Namespace) -> tuple[Callable[[], TraySimDriver], str]:
    """The simulated tray a fake InView runs (the run's tray file and seed), and its first library's profile
    (the InView settings, unless --profile names them)."""
    from core.sample.tray import parse_tray
    from drivers.registry import sim_scenario
    from drivers.sim.tray import make_tray_driver

    for flag, value in (("--sample", args.sample), ("--noise", args.noise), ("--drift", args.drift)):
        if value is not None:
            raise InputError(
                flag, "a tray names its samples and their truths itself: leave it out with --tray"
            )
    tray, problems = resolve_tray(parse_tray(args.tray), "sim", args.seed)
    if problems:
        src, _, what = problems[0].partition(": ")
        raise InputError(src, what)
    options = {"tip_wear_pct_per_h": args.tip_wear_pct_per_h}
    make_tray_driver(tray, options, args.seed, sim_scenario)  # bad options or truths: refused now, not later
    return (
        lambda: make_tray_driver(tray, options, args.seed, sim_scenario, args.speed),
        tray.libraries[0].placed.profile,
    )


def _check(args: argparse.Namespace) -> int:
    from drivers.kla.array_run import ArrayRun
    from drivers.kla.inbox import MATCHED_BY_ORDER, ExportArchive, InboxWatcher

    profile = load_profile(args.profile)
    profile.check_stage_mm(args.x_mm, "--x-mm")
    profile.check_stage_mm(args.y_mm, "--y-mm")
    hold = profile.check_hold(args.hold_s, "--hold-s") if args.hold_s is not None else profile.default_hold_s
    run = args.run or datetime.now(UTC).strftime("check-%Y%m%dT%H%M%SZ")
    folder = ExchangeFolder(args.exchange, run, profile.inview)
    block = check_block(args.x_mm * 1000.0, args.y_mm * 1000.0, hold)
    expected = sum(
        s.seconds for s in block_steps(profile, block, (block.center_x_um, block.center_y_um), False)
    )
    ticket = make_ticket(run, block, profile.inview, expected_s=expected)
    if args.timeout_s is not None:
        deadline = datetime.now(UTC) + timedelta(seconds=args.timeout_s)
        ticket = replace(ticket, deadline_utc=deadline.replace(microsecond=0).isoformat())
    folder.publish(ticket)
    print_to_pipe(ticket_text(ticket))
    array = ArrayRun(folder, InboxWatcher(folder, ExportArchive(args.exchange / "checks")), ticket)
    shown = 0
    while True:
        end = array.poll()
        for event in array.events[shown:]:
            print_to_pipe(("" if event.accepted else "refused: ") + event.text)
        shown = len(array.events)
        if any(e.kind == "refused" for e in array.events):
            print_to_pipe(
                "NOT RIGHT: fix the profile's [inview] section (or the origin) and run the check again"
            )
            return 1
        if end is not None:
            break
        time.sleep(profile.inview.poll_s)
    measured = [o for o in end.outcomes if o.status == "measured"]
    if any(n.startswith(MATCHED_BY_ORDER) for n in end.notes):  # nothing to check the sites against
        print_to_pipe(
            "NOT RIGHT: the export has no X/Y positions, so the check cannot see the axis signs or the "
            "origin: add X/Y Test Position to the export template and run the check again"
        )
        return 1
    if len(measured) < len(end.outcomes) or any("not in the array's order" in n for n in end.notes):
        for note in end.notes:
            print_to_pipe(f"note: {note}")
        print_to_pipe(f"NOT RIGHT: {end.how}; {len(measured)} of {len(end.outcomes)} test indents measured")
        return 1
    for note in end.notes:
        print_to_pipe(f"note: {note}")
    print_to_pipe(
        "RIGHT: the three indents landed on the planned sites, in order: the axis signs, the origin, the "
        "units and the export are as the profile says"
    )
    return 0

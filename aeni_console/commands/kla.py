"""``aeni kla read FILE``: show, dump or convert a KLA/Agilent export (InView .xlsx, NanoSuite .xls)."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from aeni_console.commands.common import dumps, write_atomic
from core.errors import InputError

if TYPE_CHECKING:
    from drivers.kla.export import KlaExport


def register(subparsers: Any) -> None:
    kla = subparsers.add_parser("kla", help="KLA/Agilent nanoindenter files", description=__doc__)
    actions = kla.add_subparsers(dest="kla_command", metavar="ACTION", parser_class=type(kla))
    actions.required = True
    read = actions.add_parser(
        "read",
        help="read an export into indent records",
        description="Read a KLA export: a short table by default, --json for records, --csv to convert.",
    )
    read.add_argument("file", metavar="FILE", help="InView .xlsx/.xls or CSV export, NanoSuite .xls")
    read.add_argument("--json", action="store_true", help="print a JSON list of indent records")
    read.add_argument("--csv", metavar="OUT", type=Path, help="write the records to a CSV file")
    read.set_defaults(func=_read)


def _read(args: argparse.Namespace) -> int:
    from drivers.kla.export import read_kla_export, records  # pandas/scipy load only when used

    export = read_kla_export(args.file)
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
    sources = sorted({i.source for i in export.indents})
    lines = [
        f"{Path(export.path).name} ({export.software}): {len(export.indents)} tests, "
        f"hardness from {'/'.join(sources)}",
        f"{'test':>6} {'x_um':>12} {'y_um':>12} {'H_GPa':>8} {'E_GPa':>8} {'drift_nm_s':>11}  failure",
    ]
    for i in export.indents:
        lines.append(
            f"{i.test_id:>6} {_num(i.x_um, 2):>12} {_num(i.y_um, 2):>12} {_num(i.hardness_gpa, 3):>8} "
            f"{_num(i.modulus_gpa, 2):>8} {_num(i.drift_rate_nm_s, 4):>11}"
            + (f"  {i.failure}" if i.failure else "")
        )
    return "\n".join(lines)

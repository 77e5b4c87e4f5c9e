"""Small helpers the CLI commands share: JSON output, ledger tables, atomic writes, path checks.

The path checks turn what the OS would say with a traceback (a folder where a file is expected, a file
in the way of a folder, permission denied) into one line naming the path, before anything is written.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import stat
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from aeni_console.files import make_folder
from core.errors import InputError
from core.operator import parse_start

if TYPE_CHECKING:
    from core.cost import CostLedger
    from core.visits import OperatorCalendar


def _clean(obj: Any) -> Any:
    if isinstance(obj, float):
        return None if not math.isfinite(obj) else obj
    if isinstance(obj, dict):
        return {k: _clean(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_clean(v) for v in obj]
    return obj


def dumps(obj: Any) -> str:
    return json.dumps(_clean(obj), indent=2, ensure_ascii=False)


def ledger_table(ledger: CostLedger) -> str:
    total = ledger.total_s
    lines = [f"{'category':<12} {'seconds':>12} {'share':>7}"]
    for cat, sec in ledger.seconds.items():
        if sec:
            lines.append(f"{cat:<12} {sec:>12,.1f} {100 * sec / total:>6.1f}%")
    lines.append(f"{'total':<12} {total:>12,.1f}  ({total / 3600:.2f} h)")
    return "\n".join(lines)


def positive_float(flag: str) -> Callable[[str], float]:
    """An argparse type: a finite number > 0, with an error naming the flag."""

    def parse(text: str) -> float:
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{flag} must be a number, got {text!r}") from None
        if not math.isfinite(v) or v <= 0:
            raise argparse.ArgumentTypeError(f"{flag} must be > 0, got {text}")
        return v

    return parse


def whole_number(flag: str, lo: int, hi: int) -> Callable[[str], int]:
    """An argparse type: an integer in [lo, hi], with an error naming the flag."""

    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{flag} must be a whole number, got {text!r}") from None
        if not lo <= v <= hi:
            raise argparse.ArgumentTypeError(f"{flag} must be from {lo} to {hi}, got {v}")
        return v

    return parse


seed_arg = whole_number("--seed", 0, 2**32 - 1)


# --------------------------------------------------------------------------------------------------
# paths: one line naming the path and what is wrong, before anything is written


def _is_sqlite(path: Path) -> bool:
    try:
        with open(path, "rb") as fh:
            return fh.read(16) == b"SQLite format 3\x00"
    except OSError:
        return False


def check_new_journal(path: str | Path) -> Path:
    """A path where a new journal can be created: nothing there yet, and a folder that can hold it."""
    p = Path(path)
    if p.is_dir():
        raise InputError(str(p), "is a folder; --journal takes a file path such as DIR/run.sqlite")
    if p.exists() or p.is_symlink():
        if _is_sqlite(p):
            raise InputError(str(p), "journal already exists; use `aeni resume` to continue it")
        raise InputError(str(p), "a file that is not a journal is already there; choose another path")
    make_folder(p.parent if str(p.parent) else Path("."), "journal's folder")
    return p


def check_resumable_journal(path: str | Path) -> Path:
    """A journal the engine may write again: not marked read-only, in a folder it can write its lock in."""
    p = Path(path)
    mode = p.stat().st_mode
    if not mode & stat.S_IWUSR or not os.access(p, os.W_OK):
        raise InputError(
            str(p),
            f"journal is read-only (mode {stat.S_IMODE(mode):04o}); a resumed engine must write it "
            "(chmod u+w to allow that)",
        )
    folder = p.parent if str(p.parent) else Path(".")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise InputError(
            str(folder), "cannot write in the journal's folder (the engine keeps its lock there)"
        )
    return p


def map_weights_arg(text: str) -> dict[str, float]:
    """``hardness=1,modulus=0.5`` as the run file's ``map_weights`` table (checked where the settings are)."""
    out: dict[str, float] = {}
    for part in text.split(","):
        name, sep, value = part.partition("=")
        try:
            out[name.strip()] = float(value)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected hardness=W,modulus=W, got {text!r}") from None
        if not sep:
            raise argparse.ArgumentTypeError(f"expected hardness=W,modulus=W, got {text!r}")
    return out


def add_operator_args(p: argparse.ArgumentParser) -> None:
    """The simulated operator's calendar (``aeni simulate``, ``aeni bench``); none given: no calendar."""
    g = p.add_argument_group("the simulated operator (wall clock and visits; default: none)")
    g.add_argument(
        "--operator-hours",
        default=None,
        metavar="HOURS",
        help="when someone is at the instrument, e.g. 'Mon-Fri 08:30-18:00' (default 'always')",
    )
    g.add_argument(
        "--response-min", type=float, default=None, help="minutes to answer a request during hours (10)"
    )
    g.add_argument(
        "--visit-every-min",
        type=float,
        default=None,
        help="minutes between the operator's routine visits during hours (120)",
    )
    g.add_argument("--start", default=None, metavar="WHEN", help="the run's start: 'Mon 09:00' (default)")


def operator_calendar(args: argparse.Namespace) -> OperatorCalendar | None:
    """An operator calendar from the flags, checked as the run file's [operator] section; None when no flag
    was given (the run is not put on a calendar)."""
    # imported here, not at the top: the run file's reader pulls torch, and `aeni --help` must start fast
    from core.runconfig import load_run_config
    from core.visits import OperatorCalendar

    flags = {
        "operator.hours": args.operator_hours,
        "operator.response_min": args.response_min,
        "operator.visit_every_min": args.visit_every_min,
    }
    if all(v is None for v in flags.values()) and args.start is None:
        return None
    flags["operator.hours"] = args.operator_hours or "always"
    availability = load_run_config(None, flags).options.operator
    assert availability is not None
    return OperatorCalendar(availability, parse_start(args.start or "Mon 09:00", "--start"))

"""``aeni report RUN [--out DIR]``: figures and a Markdown summary of a run, for the lab notebook."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from aeni_console.cli.run import resolve_run


def default_out(journal: Path) -> Path:
    """``runs/<run>.report/`` beside the journal."""
    return journal.with_name(journal.stem + ".report")


def _handler(args: argparse.Namespace) -> int:
    # imported here, not at the top: the reports pull torch, the journal scipy; `aeni --help` must start fast
    from aeni_console.reports.run import write_report
    from aeni_console.reports.tray import write_tray_report
    from core.journal import JournalReader
    from core.run.tray_view import journal_tray

    path = resolve_run(args.run)
    out = args.out if args.out is not None else default_out(path)
    with JournalReader(path) as r:
        is_tray = journal_tray(r.meta) is not None
    # a tray: a folder per library with its own report, and the tray's summary (docs/tray.md)
    written = write_tray_report(path, out) if is_tray else write_report(path, out)
    print(f"wrote {len(written)} files to {out}: {', '.join(p.name for p in written)}")
    return 0


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "report",
        help="PNG figures and a Markdown summary of a run (needs the report extra)",
        description="Write a run's figures (maps, instrument time, uncertainty, drift and holds, decisions) "
        "and a Markdown summary. Works on finished and running runs, real or simulated; a simulated "
        "run's summary adds the map error against the truth. A tray run gets a folder per library with its own "
        "report and a summary of the tray (goals, indents, instrument time, tip checks). Needs matplotlib (pip install -e '.[report]').",
    )
    p.add_argument("run", metavar="RUN", help="journal path or part of a run name under ./runs")
    p.add_argument("--out", type=Path, default=None, help="output folder (default: RUN.report beside it)")
    p.set_defaults(func=_handler)

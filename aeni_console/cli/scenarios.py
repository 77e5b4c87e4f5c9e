"""``aeni scenarios``: the built-in emulator scenarios that ``aeni simulate``, ``run`` and ``demo`` accept."""

from __future__ import annotations

import argparse
from typing import Any

from aeni_console.cli.common import dumps


def scenario_table() -> list[dict[str, str]]:
    """Every scenario name with its one-line description, in the registry's order."""
    # imported here, not at the top: the emulator pulls scipy, and `aeni --help` must start fast
    from drivers.sim.scenarios import SCENARIOS

    return [{"name": name, "description": text} for name, text in SCENARIOS.items()]


def _handler(args: argparse.Namespace) -> int:
    rows = scenario_table()
    if args.json:
        print(dumps(rows))
        return 0
    width = max(len(r["name"]) for r in rows)
    for r in rows:
        print(f"{r['name']:<{width}}  {r['description']}")
    print("\n`csv` needs --truth FILE.csv (aeni simulate) or campaign.truth_csv (a run file).")
    return 0


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "scenarios",
        help="list the emulator scenarios (samples with a known truth)",
        description="The emulator scenarios accepted by --scenario and campaign.scenario.",
    )
    p.add_argument("--json", action="store_true", help="a JSON list of {name, description}")
    p.set_defaults(func=_handler)

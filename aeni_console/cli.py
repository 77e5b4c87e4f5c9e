"""The ``aeni`` command: one entry point, subcommands registered by small modules.

Bad input ends in one line on stderr and exit code 2, never a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from core.errors import InputError

# Each module exposes register(subparsers); its handlers return an exit code.
COMMAND_MODULES: tuple[str, ...] = (
    "aeni_console.commands.cost",
    "aeni_console.commands.simulate",
    "aeni_console.commands.kla",
    "aeni_console.commands.run",
    "aeni_console.commands.console",
    "aeni_console.commands.bench",
    "aeni_console.commands.sample",
)


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # argparse's default prints usage; keep it to one line
        self.exit(2, f"aeni: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="aeni", description="AE-NI console: cost-aware automated nanoindentation")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        code = int(args.func(args) or 0)
    except InputError as exc:
        print(f"aeni: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("aeni: interrupted", file=sys.stderr)
        return 130
    return code


if __name__ == "__main__":
    sys.exit(main())

"""The ``aeni`` command: one entry point, subcommands registered by small modules.

Bad input ends in one line on stderr and exit code 2, never a traceback: an :class:`InputError` says
what is wrong with which file, field or flag, and an OS error (a folder that cannot be created, a
file where a folder is expected, permission denied) is reported with the path it concerns. Library
warnings go to stderr as one line each, so stdout stays clean for ``--json`` and tables.
Set ``AENI_TRACEBACK=1`` to see the traceback of an OS error when debugging.
"""

from __future__ import annotations

import argparse
import importlib
import os
import select
import sys
import warnings
from collections.abc import Sequence
from typing import Any, NoReturn, TextIO

from aeni_console.files import os_error_line
from core.errors import InputError

# Each module exposes register(subparsers); its handlers return an exit code.
COMMAND_MODULES: tuple[str, ...] = (
    "aeni_console.cli.cost",
    "aeni_console.cli.simulate",
    "aeni_console.cli.scenarios",
    "aeni_console.cli.kla",
    "aeni_console.cli.run",
    "aeni_console.cli.runs",
    "aeni_console.cli.report",
    "aeni_console.cli.console",
    "aeni_console.cli.bench",
    "aeni_console.cli.sample",
    "aeni_console.cli.tray",
    "aeni_console.cli.notify",
)


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:  # argparse's default prints usage; keep it to one line
        self.exit(2, f"aeni: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="aeni", description="AE-NI console: cost-aware automated nanoindentation")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def _warning_line(
    message: Warning | str,
    category: type[Warning],
    filename: str,
    lineno: int,
    file: TextIO | None = None,
    line: str | None = None,
) -> None:
    """A library warning as one line on stderr (never stdout, never the source line that raised it)."""
    text = " ".join(str(message).split())
    print(f"aeni: warning: {category.__name__}: {text}", file=sys.stderr)


def _stdout_closed() -> bool:
    """Whether stdout's reader has gone (a pipe whose reader closed polls as an error); if so, point stdout
    at /dev/null so the interpreter's last flush stays quiet."""
    try:
        fd = sys.stdout.fileno()
        poller = select.poll()
        poller.register(fd, select.POLLOUT)
        events = poller.poll(0)
    except (OSError, ValueError, AttributeError):  # no real file behind stdout (a test's capture)
        return False
    if not any(ev & (select.POLLERR | select.POLLHUP) for _, ev in events):
        return False
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, fd)
    os.close(devnull)
    return True


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    previous: Any = warnings.showwarning
    warnings.showwarning = _warning_line
    try:
        code = int(args.func(args) or 0)
        sys.stdout.flush()  # a reader gone shows here, inside the handlers below, not in the exit's flush
    except InputError as exc:
        print(f"aeni: error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError as exc:
        if _stdout_closed():  # `aeni … | head`: the reader has what it wanted; end quietly, as Unix tools do
            return 141
        if os.environ.get("AENI_TRACEBACK"):
            raise
        print(f"aeni: error: {os_error_line(exc)}", file=sys.stderr)
        return 2
    except OSError as exc:  # the environment refused: a path that cannot be made, read or written
        if os.environ.get("AENI_TRACEBACK"):
            raise
        print(f"aeni: error: {os_error_line(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("aeni: interrupted", file=sys.stderr)
        return 130
    finally:
        warnings.showwarning = previous
    return code


if __name__ == "__main__":
    sys.exit(main())

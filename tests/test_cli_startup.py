"""`aeni --help` and every `aeni COMMAND --help` start without the heavy packages.

A newcomer's first command is `aeni --help`: building the parser must not import torch, gpytorch, pandas,
scipy or textual (seconds of startup on a small machine). Each command imports them when it runs. A fresh
interpreter is the only place where sys.modules says what building the parser imported.
"""

from __future__ import annotations

import json
import subprocess
import sys

HEAVY = ("torch", "gpytorch", "pandas", "scipy", "textual")

_PROBE = f"""
import argparse, contextlib, io, json, sys
from aeni_console.cli.main import build_parser

parser = build_parser()
helped = []
sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
for command in sub.choices:
    with contextlib.redirect_stdout(io.StringIO()) as out, contextlib.suppress(SystemExit):
        parser.parse_args([command, "--help"])
    helped.append((command, "usage: aeni " + command in out.getvalue()))
print(json.dumps({{"helped": helped, "loaded": [m for m in {HEAVY!r} if m in sys.modules]}}))
"""


def test_the_parser_and_every_command_help_build_without_torch_pandas_or_scipy() -> None:
    proc = subprocess.run(
        [sys.executable, "-c", _PROBE], capture_output=True, text=True, timeout=60, check=False
    )
    assert proc.returncode == 0, proc.stderr
    seen = json.loads(proc.stdout)
    helped = dict(seen["helped"])
    assert {"run", "simulate", "console", "bench", "kla"} <= helped.keys()
    assert all(helped.values()), helped  # every command printed its own usage
    assert seen["loaded"] == [], f"building the parser imported {seen['loaded']}"


def test_the_journal_the_run_spec_and_the_settings_import_no_model() -> None:
    """`aeni status`, `aeni export` and the alert watcher read a journal and a run spec: neither needs the
    GP, so neither may pull torch in (the settings once did, through the policy registry, for one rule)."""
    probe = (
        "import json, sys; import core.journal, core.run.spec, core.settings, core.campaign_config; "
        "print(json.dumps([m for m in ('torch', 'gpytorch', 'pandas', 'textual') if m in sys.modules]))"
    )
    proc = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, timeout=60, check=False
    )
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout) == []

"""``aeni notify test RUN|CONFIG``: send a test alert to a run's (or a run file's) alert URLs."""

from __future__ import annotations

import argparse
from pathlib import Path

from aeni_console.cli.run import resolve_run
from core.errors import InputError
from core.notifyconfig import load_run_notify, notify_path_for


def _cmd_test(args: argparse.Namespace) -> int:
    # imported here, not at the top: alerts pull scipy, the run file's reader torch; `aeni --help` must start fast
    from aeni_console.alerts import Severity, send
    from core.runconfig import load_run_config

    target = Path(args.target)
    if target.suffix == ".toml":
        notify = load_run_config(target).notify
        where = f"[notify] of {target}"
    else:
        run = resolve_run(args.target)
        notify = load_run_notify(run)
        where = str(notify_path_for(run))
    if not notify.enabled:
        raise InputError(str(target), "has no alert URLs ([notify] urls or urls_file)")
    ok, how = send(
        notify.urls, f"test alert from AE-NI ({target.name}): alerts reach you", Severity.INFO, "a test alert"
    )
    if not ok:
        raise InputError(where, f"the test alert was not sent: {how}")
    print(f"test alert {how}")
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("notify", help="alerts: send a test message")
    sub = p.add_subparsers(dest="notify_command", metavar="ACTION")
    sub.required = True
    t = sub.add_parser("test", help="send a test alert to a run's or a run file's [notify] URLs")
    t.add_argument("target", metavar="RUN|CONFIG", help="a run (journal) or a run file (.toml)")
    t.set_defaults(func=_cmd_test)

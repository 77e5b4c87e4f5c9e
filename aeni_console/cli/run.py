"""``aeni run | resume | replay | export | send | status``: the CLI verbs over a run and its journal.

The engine process owns one journal (``./runs/<UTC time>-<name>.sqlite`` by default). Consoles attach
to the journal, never to the process, so an engine started with ``--detach`` outlives the terminal or
the SSH session that started it, and ``aeni resume`` picks up a run whose process died. The engine process
itself, and how it is launched with its RunSpec, is ``aeni_console.cli.host``.
"""

from __future__ import annotations

import argparse
import dataclasses
import getpass
import json
import os
import sys
import time
from datetime import datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

from aeni_console.cli.common import check_new_journal, positive_float, whole_number
from aeni_console.cli.host import (  # re-exported: the engine host's entry points
    engine_argv,
    launch_engine,
    preflight_resume,
    run_engine,
    start_engine_process,
)
from aeni_console.cli.tray import tray_spec
from aeni_console.files import check_out_folder
from core.errors import InputError
from core.operator import parse_when
from core.profile import load_profile
from core.run.machine import SUPERVISION_MODES, CommandKind, EngineState

if TYPE_CHECKING:
    from core.run.spec import RunSpec

__all__ = ["engine_argv", "launch_engine", "preflight_resume", "run_engine", "start_engine_process"]

# --------------------------------------------------------------------------------------------------
# CLI handlers


def resolve_run(arg: str, runs_dir: str | Path = "runs") -> Path:
    """A journal path, or a unique part of a run's file name under ./runs."""
    p = Path(arg)
    if p.is_file():
        return p
    if p.is_dir():
        raise InputError(arg, "is a folder, not a journal file (`aeni runs FOLDER` lists the runs in it)")
    d = Path(runs_dir)
    matches = sorted(d.glob(f"*{arg}*.sqlite")) if d.is_dir() and "/" not in arg else []
    if len(matches) == 1:
        return matches[0]
    if len(matches) > 1:
        names = ", ".join(m.name for m in matches[:5])
        raise InputError(arg, f"matches {len(matches)} runs ({names}); give the journal path")
    raise InputError(arg, f"no such journal (give a path or part of a run name under {d}/)")


def _overrides(args: argparse.Namespace) -> dict[str, Any]:
    return {
        "name": args.name,
        "campaign.policy": args.policy,
        "campaign.seed": args.seed,
        "campaign.scenario": args.scenario,
        "sample.file": args.sample,
        "campaign.lattice_n": args.lattice_n,
        "campaign.fast": args.fast,
        "planner.budget_s": args.budget_s,
        "run.driver": args.driver,
        "run.exchange": args.exchange,
        "run.supervision": args.supervision,
        "run.journal": args.journal,
        "run.speed": args.speed,
        "run.group": args.group,
        "run.max_refusals": args.max_refusals,
        "run.approval_timeout_s": args.approval_timeout_s,
        "run.on_timeout": args.on_timeout,
        "run.auto_resume": args.auto_resume,
    }


def _cmd_run(args: argparse.Namespace) -> int:
    # imported here, not at the top: the run's spec and journal pull scipy, the run file's reader torch; `aeni --help` must start fast
    from core.journal import default_journal_path
    from core.run.spec import RunSpec
    from core.runconfig import load_run_config

    if args.spec_stdin:  # an engine started by launch_engine: its RunSpec comes on stdin
        if not args.journal:
            raise InputError("--spec-stdin", "needs --journal")
        spec = RunSpec.from_json(sys.stdin.read(), "--spec-stdin")
        if args.resume:
            return run_engine(args.journal, resume_with=spec, quiet=args.quiet)
        return run_engine(args.journal, create=spec, quiet=args.quiet)
    rc = load_run_config(args.config, _overrides(args))
    options = rc.options
    spec = rc.spec()
    if args.tray:  # several samples, one run (docs/tray.md)
        spec = tray_spec(spec, args.tray, args.tip_wear_pct_per_h)
    journal = Path(options.journal) if options.journal else default_journal_path(spec.name, options.runs_dir)
    check_new_journal(journal)
    if args.detach:
        check_fast_mode(spec)
        rules = spec.rules
        pid = launch_engine(spec, journal, detach=True, auto_resume=rules.auto_resume).pid
        print(f"journal {journal}")
        print(
            f"supervisor PID {pid} (detached; it runs the engine, alerts and resumes it if it dies, "
            f"{rules.auto_resume} times in a row at most; log {journal.name}.log)"
        )
        print(f"watch: aeni runs {journal.parent}    stop: send abort from a console, or kill {pid}")
        return 0
    return run_engine(journal, create=spec, quiet=args.quiet, watch=True)


def check_fast_mode(spec: RunSpec) -> None:
    """A fast run on a profile without a fast mode is refused here, before a detached engine starts (the campaign
    refuses it too, in the engine, with the same words; a detached start would leave its log behind)."""
    from drivers.registry import default_sample

    c = spec.campaign
    if not spec.fast or spec.tray is not None or (c.sample is None and spec.driver != "sim"):
        return
    sample = c.sample or default_sample(spec.driver, c.driver_options, c.seed)
    profile = load_profile(c.profile or sample.profile)
    if profile.fast is None:
        raise InputError("--fast", f"profile {profile.name} has no fast mode (no [fast] section)")


def check_not_stopped(path: Path, anyway: bool) -> None:
    """A run the operator aborted or stopped is not resumed by accident: only with ``--continue``."""
    from core.journal import JournalReader

    with JournalReader(path) as reader:  # refuses a bad journal before anything opens it for writing
        row = reader.q.engine_row()
    if anyway or row.get("completed") or row.get("state") != EngineState.STOPPED.value:
        return
    why = str(row.get("stop_reason") or "stopped by the operator")
    raise InputError(
        str(path), f"the run was stopped ({why}); `aeni resume --continue {path}` resumes it anyway"
    )


def with_resume_flags(spec: RunSpec, args: argparse.Namespace) -> RunSpec:
    """The run's own spec (its journal's) as ``aeni resume`` runs it: a flag given overrides its rule."""
    given = {
        k: v
        for k, v in (
            ("supervision", args.supervision),
            ("auto_resume", args.auto_resume),
            ("resume_backoff_s", args.resume_backoff_s),
        )
        if v is not None
    }
    return dataclasses.replace(spec, rules=dataclasses.replace(spec.rules, **given)) if given else spec


def _cmd_resume(args: argparse.Namespace) -> int:
    from core.journal import engine_running

    path = resolve_run(args.run)
    if engine_running(path):
        raise InputError(str(path), "an engine is already running this journal")
    check_not_stopped(path, args.continue_stopped)
    if args.detach:
        spec = preflight_resume(path, args.speed)
        if spec is None:
            return 0
        spec = with_resume_flags(spec, args)
        proc = launch_engine(
            spec, path, resume=True, detach=True, wait_s=120.0, auto_resume=spec.rules.auto_resume
        )
        print(f"journal {path}")
        print(
            f"supervisor PID {proc.pid} (detached; it runs the engine, alerts and resumes it if it dies, "
            f"{spec.rules.auto_resume} times in a row at most; log {path.name}.log)"
        )
        return 0
    return run_engine(path, speed=args.speed, supervision=args.supervision, quiet=args.quiet, watch=True)


def _fmt_s(v: float | None) -> str:
    return "—" if v is None else f"{v:,.0f} s"


def status_line(path: str | Path) -> str:
    from core.journal import JournalReader

    with JournalReader(path) as r:
        s = r.snapshot()
    cur = (
        f"block {s.current_block.block_id} ({s.current_block.kind} {s.current_block.grid_g}×{s.current_block.grid_g})"
        if s.current_block
        else "between blocks"
    )
    parts = [
        f"{s.run_name}: {s.state.label}",
        f"[{s.supervision}]",
        cur,
        f"{s.n_blocks} blocks, {s.n_indents} indents",
        f"t={_fmt_s(s.instrument_s)}",
    ]
    if s.mape_pct is not None:
        parts.append(f"MAPE {s.mape_pct:.2f} %")
    if s.pending is not None:
        parts.append(f"PENDING block {s.pending.block.block_id} ({s.pending.block.kind})")
    parts.append(
        f"owner {s.owner}" + (" (watching read-only)" if not s.finished and not s.can_command else "")
    )
    return "  ".join(parts)


def tray_lines(path: str | Path) -> list[str]:
    """A line per sample of a tray run (none for a single-sample run)."""
    from core.journal import JournalReader
    from core.run.tray_view import journal_tray, progress_line, tray_progress

    with JournalReader(path) as r:
        tray = journal_tray(r.meta)
        if tray is None:
            return []
        latest = r.latest_campaign_state()
    return [progress_line(p) for p in tray_progress(tray, None if latest is None else latest[0])]


def _cmd_status(args: argparse.Namespace) -> int:
    path = resolve_run(args.run)
    print(status_line(path))
    for line in tray_lines(path):
        print(f"  {line}")
    return 0


def _cmd_replay(args: argparse.Namespace) -> int:
    from core.journal import JournalReader

    path = resolve_run(args.run)
    with JournalReader(path) as r:
        blocks = r.blocks()
        name = r.name
    if args.block is not None:
        recs = [b for b in blocks if b.block.block_id == args.block]
        if not recs:
            raise InputError("--block", f"{args.block} is not in the run (blocks 0–{len(blocks) - 1})")
        rec = recs[0]
        print(_replay_line(rec))
        if rec.decision is not None:
            d = rec.decision
            print(
                f"  decision: {d.policy} [{d.phase}] score {d.score:.4g} acquisition {d.acquisition:.4g} "
                f"predicted {d.predicted_cost_s:,.0f} s  {d.reason}"
            )
            for a in d.alternatives:
                print(
                    f"    alt {a.kind:<6} ({a.center_x_um:8.1f}, {a.center_y_um:8.1f}) score {a.score:.4g} cost {a.cost_s:,.0f} s"
                )
        print(f"  {'i':>3} {'x_um':>10} {'y_um':>10} {'hold_s':>6} {'H_GPa':>8} {'t_s':>10}")
        for res in rec.results:
            print(
                f"  {res.indent_index:>3} {res.actual_x_um:>10.2f} {res.actual_y_um:>10.2f} {res.hold_s:>6g} "
                + (f"{res.hardness_gpa:>8.3f}" if res.measured else f"{res.status:>8}")
                + f" {res.t_s:>10,.0f}"
            )
        return 0
    print(f"replay of {name}: {len(blocks)} blocks")
    print(
        f"{'block':>5} {'kind':<6} {'centre x,y (µm)':>20} {'g':>2} {'hold':>5} {'n':>3} {'median H':>9} "
        f"{'block s':>9} {'t end':>10} {'MAPE':>7}  status"
    )
    for rec in blocks:
        print(_replay_line(rec))
        if args.step and sys.stdin.isatty():
            try:
                input("  [Enter] next block, Ctrl-D to stop ")
            except EOFError:
                print()
                break
    return 0


def _replay_line(rec: Any) -> str:
    b = rec.block
    med = rec.median_gpa
    mape = rec.fit_summary.get("mape_pct")
    return (
        f"{b.block_id:>5} {b.kind:<6} {f'({b.center_x_um:.0f}, {b.center_y_um:.0f})':>20} {b.grid_g:>2} "
        f"{b.hold_s:>5g} {len(rec.results):>3} {('—' if med is None else f'{med:.3f}'):>9} "
        f"{rec.seconds:>9,.0f} {('—' if rec.finished_t_s is None else f'{rec.finished_t_s:,.0f}'):>10} "
        f"{('—' if mape is None else f'{mape:.2f}%'):>7}  {rec.status}"
    )


def _export_files(journal: Path, indents: Any) -> list[str]:
    """Each indent's instrument export (a KLA run's archive beside the journal); '' for a simulated run."""
    from drivers.kla.driver import archive_dir_for
    from drivers.kla.inbox import ExportArchive

    folder = archive_dir_for(journal)
    if not (folder / "manifest.jsonl").is_file():
        return [""] * len(indents)
    files = ExportArchive(folder).export_files()
    return [
        files.get((int(b), str(s)), "") for b, s in zip(indents["block_id"], indents["status"], strict=True)
    ]


def export_run(path: str | Path, out_dir: str | Path, fmt: str = "csv") -> list[Path]:
    """Tidy tables of a run: indents (each with its channel, csm or fast), blocks, decisions, alternatives,
    commands, ledger, gp_snapshots, events, sessions and predictions (both maps' final means and sds, and H/E);
    fast_bias, the fast channel's learnt bias H_csm − H_fast on the same points, where the run has one."""
    import pandas as pd

    from aeni_console.reports.finalmaps import FINAL_MAP_COLUMNS, final_maps, tray_final_maps
    from core.journal import JournalReader
    from core.run.tray_view import journal_tray

    if fmt not in ("csv", "parquet"):
        raise InputError("--format", f"{fmt!r} is not allowed: expected csv or parquet")
    if fmt == "parquet":
        try:
            import pyarrow  # noqa: F401
        except ImportError:
            raise InputError(
                "--format", "parquet needs the pyarrow package (pip install pyarrow); use --format csv"
            ) from None
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    tables: dict[str, pd.DataFrame] = {}
    with JournalReader(path) as r:
        cols, rows = r.table("indents")
        ind = pd.DataFrame(rows, columns=cols)
        ind = ind.rename(columns={"actual_x_um": "x_um", "actual_y_um": "y_um"})
        ind["export_file"] = _export_files(Path(path), ind)
        if "channel" not in ind.columns:  # a journal before the fast channel (schema < 6): all CSM
            ind["channel"] = "csm"
        tray = journal_tray(r.meta)
        if (
            tray is not None
        ):  # which sample each indent is on: the tray's own geometry, as the interlock reads it
            ind["sample"] = [
                getattr(tray.sample_at(float(x), float(y)), "name", "")
                for x, y in zip(ind["commanded_x_um"], ind["commanded_y_um"], strict=True)
            ]
        first = [
            "block_id",
            "x_um",
            "y_um",
            "hold_s",
            "hardness_gpa",
            "t_s",
            "status",
            "channel",
            "note",
            "depth_at_max_load_nm",
            "export_file",
            "indent_index",
            "commanded_x_um",
            "commanded_y_um",
            "modulus_gpa",
            "drift_rate_nm_s",
            "wall_utc",
            "session_id",
        ]
        tables["indents"] = ind.sort_values(["block_id", "indent_index"])[
            first + (["sample"] if tray else [])
        ]
        cols, rows = r.table("blocks")
        blocks = pd.DataFrame(rows, columns=cols)
        blocks["channel"] = [json.loads(b).get("channel", "csm") for b in blocks["block_json"]]
        tables["blocks"] = blocks.drop(columns=["block_json"])
        cols, rows = r.table("decisions")
        dec = pd.DataFrame(rows, columns=cols)
        alts = []
        for did, dj in zip(dec["decision_id"], dec["decision_json"], strict=True):
            for rank, a in enumerate(json.loads(dj).get("alternatives", []), start=1):
                alts.append({"decision_id": did, "rank": rank, **a})
        dec["n_alternatives"] = [len(json.loads(j).get("alternatives", [])) for j in dec["decision_json"]]
        tables["decisions"] = dec.drop(columns=["decision_json"])
        tables["alternatives"] = pd.DataFrame(
            alts,
            columns=[
                "decision_id",
                "rank",
                "center_x_um",
                "center_y_um",
                "kind",
                "score",
                "acquisition",
                "cost_s",
            ],
        )
        cols, rows = r.table("commands")
        tables["commands"] = pd.DataFrame(rows, columns=cols)
        cols, rows = r.table("steps")
        tables["ledger"] = pd.DataFrame(rows, columns=cols)
        cols, rows = r.table("gp_snapshots")
        snaps = pd.DataFrame(rows, columns=cols)
        summ = [json.loads(s) for s in snaps["summary_json"]]
        flat = pd.DataFrame(
            [{k: (json.dumps(v) if isinstance(v, list | dict) else v) for k, v in s.items()} for s in summ]
        )
        tables["gp_snapshots"] = pd.concat(
            [
                snaps[["snapshot_id", "block_id", "wall_utc", "t_s", "hyper_json"]].reset_index(drop=True),
                flat,
            ],
            axis=1,
        )
        for name in ("events", "sessions"):
            cols, rows = r.table(name)
            tables[name] = pd.DataFrame(rows, columns=cols)
    # both maps' final predictions on the candidate lattice (empty before the run has a map)

    maps = final_maps(path)
    tables["predictions"] = (
        pd.DataFrame(maps.columns()) if maps is not None else pd.DataFrame(columns=list(FINAL_MAP_COLUMNS))
    )
    if (
        maps is not None and maps.fast_bias_gpa is not None
    ):  # the fast channel's learnt bias, where there is one
        tables["fast_bias"] = pd.DataFrame(
            {"x_um": maps.x_um, "y_um": maps.y_um, "bias_gpa": maps.fast_bias_gpa}
        )
    written = []
    for name, df in tables.items():
        written.append(_write_table(df, out / f"{name}.{fmt}", fmt))
    if tray is not None:  # a folder per sample with its own indents
        for s in tray.samples:
            folder = out / "samples" / s.name
            folder.mkdir(parents=True, exist_ok=True)
            own = tables["indents"][tables["indents"]["sample"] == s.name]
            written.append(_write_table(own, folder / f"indents.{fmt}", fmt))
        for name, lib_maps in tray_final_maps(path).items():
            columns: dict[str, Any] = (
                lib_maps.columns() if lib_maps is not None else {c: [] for c in FINAL_MAP_COLUMNS}
            )
            written.append(
                _write_table(pd.DataFrame(columns), out / "samples" / name / f"predictions.{fmt}", fmt)
            )
    return written


def _write_table(df: Any, target: Path, fmt: str) -> Path:
    """One exported table, written beside its target and renamed: never half-written."""
    tmp = target.with_name(f".{target.name}.tmp")
    if fmt == "csv":
        df.to_csv(tmp, index=False)
    else:
        df.to_parquet(tmp, index=False)
    os.replace(tmp, target)
    return target


def _cmd_export(args: argparse.Namespace) -> int:
    path = resolve_run(args.run)
    check_out_folder(args.out)
    written = export_run(path, args.out, args.format)
    print(f"wrote {len(written)} tables to {args.out}: {', '.join(p.name for p in written)}")
    return 0


def _command_kinds() -> list[Any]:

    return list(CommandKind)


def _payload_value(text: str) -> Any:
    try:
        return json.loads(text)
    except ValueError:
        return text


# the instrument reports of the KLA driver take plain words, not field=value
_INSTRUMENT_REPORTS: dict[str, tuple[str, ...]] = {
    "confirm": ("token",),
    "report": ("kind", "token"),
    "skip": ("site",),
}


def _cmd_send(args: argparse.Namespace) -> int:
    from core.journal import JournalReader, send_command
    from core.policies.hold_settings import check_hold_in_force
    from core.runview import Command
    from core.settings import check_adjust, check_veto

    path = resolve_run(args.run)
    payload: dict[str, Any] = {}
    if args.kind in _INSTRUMENT_REPORTS:  # confirm TOKEN | report KIND TOKEN | skip SITE
        names = _INSTRUMENT_REPORTS[args.kind]
        if len(args.fields) != len(names):
            usage = " ".join(n.upper() for n in names)
            raise InputError(args.kind, f"expected `aeni send RUN {args.kind} {usage}`")
        payload = dict(zip(names, args.fields, strict=True))
        args.fields = []
    if args.kind == "away-until":  # away-until 08:00 | "Mon 09:00" | ISO: the next such local time
        if len(args.fields) != 1:
            raise InputError(args.kind, "expected `aeni send RUN away-until HH:MM` (or 'Mon 09:00', or ISO)")
        until = parse_when(args.fields[0], datetime.now(), "away-until")
        payload = {"until": until.isoformat(timespec="minutes")}
        args.fields = []
    for item in args.fields:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise InputError(item, "expected field=value (e.g. beta=2.5)")
        payload[key] = _payload_value(value)
    if args.kind == "adjust" and not payload:
        raise InputError("adjust", "give at least one field=value (e.g. beta=2.5 target_sem_gpa=0.1)")
    if args.kind == "adjust":  # the engine's own rules and the run's holds: a bad value is never queued
        with JournalReader(path) as reader:
            payload = check_adjust(payload, reader.profile.allowed_holds_s)
            check_hold_in_force(reader.snapshot().policy, payload, "adjust")
    # the other commands' fields, by the same rules the engine applies: nothing the engine must reject is queued
    allowed = {"veto": ("hold_blocks", "decision_id"), "approve": ("decision_id",), "step": ("decision_id",)}
    if args.kind not in ("adjust", "away-until") and args.kind not in _INSTRUMENT_REPORTS:
        extra = [k for k in payload if k not in allowed.get(args.kind, ())]
        if extra:
            takes = ", ".join(allowed.get(args.kind, ())) or "no fields"
            raise InputError(extra[0], f"is not a field of {args.kind} (it takes {takes})")
    if args.kind == "veto":
        check_veto(payload)
    cid = send_command(path, Command(CommandKind(args.kind), author=getpass.getuser(), payload=payload))
    if args.no_wait:
        print(f"command {cid} ({args.kind}) queued for {path}; the engine answers at its next checkpoint")
        return 0
    verdict = wait_for_verdict(path, cid, args.wait_s)
    if verdict is None:
        print(
            f"command {cid} ({args.kind}) queued; no verdict within {args.wait_s:g} s (the engine answers "
            f"at its next checkpoint, after the indent in progress): see `aeni status {path}`"
        )
        return SEND_NO_VERDICT
    outcome, reason = verdict
    print(f"command {cid} ({args.kind}) {outcome}" + (f": {reason}" if reason else ""))
    return 0 if outcome == "accepted" else SEND_REJECTED


SEND_REJECTED = 1  # the engine refused the command (bad input refused before queueing exits 2)
SEND_NO_VERDICT = 3  # still queued: the engine did not answer within the wait


def wait_for_verdict(
    path: Path, command_id: int, wait_s: float, poll_s: float = 0.05
) -> tuple[str, str] | None:
    """The engine's (outcome, reason) for a queued command, or None when it has not answered within wait_s."""
    from core.journal import JournalReader

    deadline = time.monotonic() + wait_s
    with JournalReader(path) as reader:
        while True:
            row = next((c for c in reader.commands() if c["command_id"] == command_id), None)
            if row is not None and row["processed"]:
                return str(row["outcome"]), str(row["reason"] or "")
            if time.monotonic() >= deadline:
                return None
            time.sleep(poll_s)


def register(subparsers: Any) -> None:
    run = subparsers.add_parser(
        "run",
        help="run a campaign as a journaled engine process",
        description="Run a campaign (TOML config, flags override it) as an engine process with a crash-safe journal.",
    )
    run.add_argument("config", nargs="?", metavar="CONFIG.toml", help="run configuration (optional)")
    run.add_argument("--sample", help="sample file (sample.toml); default: the scenario's built-in sample")
    run.add_argument("--tray", metavar="TRAY.toml", help="run every sample of a tray file in one run")
    run.add_argument(
        "--tip-wear-pct-per-h", dest="tip_wear_pct_per_h", type=float, help="--tray, driver sim: wear the tip"
    )
    run.add_argument("--driver", help="instrument driver (sim | kla)")
    run.add_argument("--exchange", help="driver kla: the exchange folder shared with the instrument PC")
    run.add_argument("--policy", help="planning policy")
    run.add_argument("--seed", help="random seed")
    run.add_argument(
        "--fast",
        choices=("off", "on"),
        help="on: the plan prices the profile's fast (NanoBlitz-class) arrays beside CSM indents "
        "(docs/two-fidelity.md); off: CSM indents only (default: the run file's campaign.fast, else off)",
    )
    run.add_argument("--scenario", help="emulator scenario")
    run.add_argument("--lattice-n", dest="lattice_n", help="candidate lattice size per side")
    run.add_argument("--budget-s", dest="budget_s", help="instrument-time budget in seconds")
    run.add_argument("--supervision", help="auto | supervised | step")
    run.add_argument("--journal", help="journal path (default ./runs/<UTC time>-<name>.sqlite)")
    run.add_argument("--speed", help="simulated instrument speed-up (default: as fast as possible)")
    run.add_argument("--group", help="OS group that may watch the run (journal 0640); see docs/security.md")
    run.add_argument("--name", help="run name")
    run.add_argument(
        "--max-refusals", dest="max_refusals", help="refused blocks in a row that stop the run (default 5)"
    )
    run.add_argument(
        "--approval-timeout-s", dest="approval_timeout_s", help="an unanswered approval times out (seconds)"
    )
    run.add_argument(
        "--on-timeout", dest="on_timeout", help="approve | veto | pause | stop (default approve)"
    )
    run.add_argument("--detach", action="store_true", help="run in the background, surviving the terminal")
    run.add_argument(
        "--auto-resume",
        dest="auto_resume",
        help="with --detach: resumes in a row after the engine dies (default 3; 0: alert only)",
    )
    run.add_argument("--quiet", action="store_true", help="no per-block progress lines")
    run.add_argument("--spec-stdin", dest="spec_stdin", action="store_true", help=argparse.SUPPRESS)
    run.add_argument("--resume", action="store_true", help=argparse.SUPPRESS)  # with --spec-stdin
    run.set_defaults(func=_cmd_run)

    res = subparsers.add_parser("resume", help="continue a run whose engine stopped or died")
    res.add_argument("run", metavar="RUN", help="journal path or part of a run name")
    res.add_argument("--speed", type=positive_float("--speed"), help="simulated instrument speed-up")
    res.add_argument("--supervision", choices=SUPERVISION_MODES)
    res.add_argument("--detach", action="store_true", help="resume in the background")
    res.add_argument(
        "--continue",
        dest="continue_stopped",
        action="store_true",
        help="resume a run the operator aborted or stopped",
    )
    res.add_argument("--quiet", action="store_true")
    res.add_argument(
        "--auto-resume",
        dest="auto_resume",
        type=whole_number("--auto-resume", 0, 100),
        default=None,
        help="with --detach: resumes in a row after the engine dies (default: the run's [run] auto_resume; "
        "0: alert only)",
    )
    res.add_argument(
        "--resume-backoff-s",
        dest="resume_backoff_s",
        type=positive_float("--resume-backoff-s"),
        default=None,
        help="with --detach: the pause before the first automatic resume (doubled for each next; default: the "
        "run's [run] resume_backoff_s)",
    )
    res.set_defaults(func=_cmd_resume)

    rep = subparsers.add_parser("replay", help="walk a recorded run block by block")
    rep.add_argument("run", metavar="RUN")
    rep.add_argument("--step", action="store_true", help="wait for Enter after each block")
    rep.add_argument("--block", type=int, help="show one block in detail (decision, alternatives, indents)")
    rep.set_defaults(func=_cmd_replay)

    exp = subparsers.add_parser("export", help="write a run's journal as tidy tables")
    exp.add_argument("run", metavar="RUN")
    exp.add_argument("--format", choices=("csv", "parquet"), default="csv")
    exp.add_argument("--out", required=True, type=Path, help="output directory")
    exp.set_defaults(func=_cmd_export)

    send = subparsers.add_parser(
        "send",
        help="send an operator command to a running engine (owner only)",
        description="Queue an operator command in the run's journal, wait (bounded) for the engine's verdict and "
        "print it. Exit 0 accepted, 1 rejected by the engine, 2 refused before queueing, 3 no verdict yet.",
    )
    send.add_argument("run", metavar="RUN")
    send.add_argument(
        "kind",
        choices=[k.value for k in _command_kinds()],
        metavar="COMMAND",
        help="pause | resume | approve | veto | step | adjust | stop-after-block | abort | "
        "confirm TOKEN | report aborted|surface-not-found TOKEN | skip SITE | away-until HH:MM",
    )
    send.add_argument(
        "fields",
        nargs="*",
        metavar="FIELD=VALUE",
        help="adjust: settings to change; veto: hold_blocks=N; confirm/report/skip: the token or site",
    )
    send.add_argument(
        "--no-wait",
        dest="no_wait",
        action="store_true",
        help="only queue the command; do not wait for the verdict",
    )
    send.add_argument(
        "--wait-s",
        dest="wait_s",
        type=positive_float("--wait-s"),
        default=5.0,
        help="how long to wait for the engine's verdict (default 5 s; exit 3 when it has not answered)",
    )
    send.set_defaults(func=_cmd_send)

    st = subparsers.add_parser("status", help="one line: a run's state and progress")
    st.add_argument("run", metavar="RUN")
    st.set_defaults(func=_cmd_status)

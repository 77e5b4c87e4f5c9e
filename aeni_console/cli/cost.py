"""``aeni cost``: price a grid or an indent path on an instrument profile."""

from __future__ import annotations

import argparse
import csv
import math

from aeni_console.cli.common import dumps, ledger_table, positive_float, whole_number
from aeni_console.files import input_file
from core.cost import CostLedger, grid_baseline_blocks, price_sequence
from core.errors import InputError
from core.plan import Block, IndentSpec
from core.plausible import MAX_STAGE_UM, check_stage_um
from core.profile import fit_move_model, load_profile


def _emit(args: argparse.Namespace, ledger: CostLedger, extra: dict[str, object]) -> int:
    if args.json:
        print(dumps({"total_s": ledger.total_s, "ledger": ledger.as_dict(), **extra}))
    else:
        for k, v in extra.items():
            print(f"{k}: {v}")
        print(ledger_table(ledger))
    return 0


def _grid(args: argparse.Namespace) -> int:
    profile = load_profile(args.profile)
    hold = profile.check_hold(args.hold_s if args.hold_s is not None else profile.default_hold_s, "--hold-s")
    blocks = grid_baseline_blocks(args.area_um, args.area_um, args.blocks, args.size, args.pitch_um, hold)
    ledger = price_sequence(profile, blocks)
    return _emit(
        args,
        ledger,
        {
            "profile": profile.name,
            "blocks": len(blocks),
            "indents": ledger.indents,
            "reconfigurations": ledger.reconfigurations,
        },
    )


def _read_path(path: str, default_hold_s: float, allowed: tuple[float, ...]) -> list[IndentSpec]:
    src = input_file(path)
    try:
        text = src.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise InputError(path, "not a UTF-8 text CSV") from None
    reader = csv.DictReader(text.splitlines())
    header = [h.strip() for h in (reader.fieldnames or [])]
    missing = [c for c in ("x_um", "y_um") if c not in header]
    if missing:
        raise InputError(
            path, f"missing column(s) {', '.join(missing)} (found: {', '.join(header) or 'none'})"
        )
    unknown = [c for c in header if c not in ("x_um", "y_um", "hold_s")]
    if unknown:
        raise InputError(path, f"unknown column(s) {', '.join(unknown)} (allowed: x_um, y_um, hold_s)")
    out: list[IndentSpec] = []
    for lineno, raw in enumerate(reader, start=2):
        row = {(k or "").strip(): (v or "").strip() for k, v in raw.items()}
        try:
            x, y = float(row["x_um"]), float(row["y_um"])
            hold = float(row["hold_s"]) if row.get("hold_s") else default_hold_s
        except ValueError:
            raise InputError(path, f"line {lineno}: x_um, y_um and hold_s must be numbers") from None
        if not all(math.isfinite(v) for v in (x, y, hold)):
            raise InputError(path, f"line {lineno}: values must be finite")
        for axis, value in (("x_um", x), ("y_um", y)):
            check_stage_um(path, f"line {lineno}: {axis}", value, -MAX_STAGE_UM, MAX_STAGE_UM)
        if not any(math.isclose(hold, h) for h in allowed):
            raise InputError(
                path, f"line {lineno}: hold_s {hold:g} is not one of {', '.join(f'{h:g}' for h in allowed)}"
            )
        out.append(IndentSpec(x, y, hold))
    if not out:
        raise InputError(path, "no indents (the file has a header but no rows)")
    return out


def _path(args: argparse.Namespace) -> int:
    profile = load_profile(args.profile)
    indents = _read_path(args.file, profile.default_hold_s, profile.allowed_holds_s)
    first = indents[0]
    block = Block(0, "global", first.x_um, first.y_um, 0, 0.0, first.hold_s, tuple(indents))
    ledger = price_sequence(profile, [block])
    return _emit(
        args,
        ledger,
        {"profile": profile.name, "indents": ledger.indents, "reconfigurations": ledger.reconfigurations},
    )


def _fit(args: argparse.Namespace) -> int:
    fit = fit_move_model(input_file(args.file))
    m = fit.model
    text = (
        "[move]\n"
        f"short_a = {m.short_a:.6g}\nshort_b = {m.short_b:.6g}\nshort_c = {m.short_c:.6g}\n"
        f"long_slope = {m.long_slope:.6g}\nlong_intercept = {m.long_intercept:.6g}\nbreakpoint_um = {m.breakpoint_um:g}\n"
    )
    if args.json:
        print(dumps({"n_points": fit.n_points, "rmse_s": fit.rmse_s, "move": m.__dict__}))
    else:
        print(f"# fitted to {fit.n_points} moves, RMSE {fit.rmse_s:.3f} s; paste into a profile TOML")
        print(text, end="")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("cost", help="price a grid, an indent path, or fit a stage's move-time model")
    csub = p.add_subparsers(dest="cost_command", metavar="WHAT", parser_class=type(p))
    csub.required = True

    g = csub.add_parser("grid", help="price the n×n-blocks-of-g×g grid baseline")
    g.add_argument(
        "--blocks", type=whole_number("--blocks", 1, 50), default=9, help="blocks per side (default 9)"
    )
    g.add_argument(
        "--size", type=whole_number("--size", 1, 10), default=5, help="indents per block side (default 5)"
    )
    g.add_argument(
        "--pitch-um", type=positive_float("--pitch-um"), default=5.0, help="indent pitch in a block"
    )
    g.add_argument(
        "--area-um", type=positive_float("--area-um"), default=1000.0, help="side of the square area"
    )
    g.add_argument("--hold-s", type=float, default=None, help="hold per indent (default: the profile's)")
    g.add_argument("--profile", default=None, help="built-in profile name or TOML file (default kla-imicro)")
    g.add_argument("--json", action="store_true")
    g.set_defaults(func=_grid)

    pp = csub.add_parser("path", help="price indents (CSV x_um, y_um[, hold_s]) in order as one block")
    pp.add_argument("file")
    pp.add_argument("--profile", default=None)
    pp.add_argument("--json", action="store_true")
    pp.set_defaults(func=_path)

    f = csub.add_parser("fit-move", help="fit the move-time model to measured distance_um, seconds pairs")
    f.add_argument("file")
    f.add_argument("--json", action="store_true")
    f.set_defaults(func=_fit)

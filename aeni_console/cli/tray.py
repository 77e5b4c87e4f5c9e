"""``aeni tray new | check``: write a commented tray file; validate one (one line per problem, exit 2) and
draw it on the stage with the moves between its samples."""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import math
from typing import TYPE_CHECKING, Any

from aeni_console.files import write_new_file
from core.errors import InputError
from core.profile import load_profile

if TYPE_CHECKING:
    from core.run.spec import RunSpec
    from core.sample import Sample
    from core.sample.tray import Tray, TraySample


def tray_spec(spec: RunSpec, path: str, tip_wear_pct_per_h: float | None = None) -> RunSpec:
    """``aeni run --tray``: the run's spec over the tray in ``path`` (its policy, seed, lattice and settings
    for every library; the driver's options are the tray's own, e.g. the simulated tip's wear, and the KLA
    driver's exchange folder)."""
    # imported here, not at the top: the tray's samples and drivers pull torch; `aeni --help` must start fast
    from core.sample.tray import parse_tray
    from drivers.registry import KLA_OPTIONS

    tray = parse_tray(path)
    if spec.campaign.sample is not None:
        raise InputError("--sample", "a tray names its samples itself: leave out --sample with --tray")
    tray, problems = resolve_tray(tray, spec.driver, spec.campaign.seed)
    if problems:
        src, _, what = problems[0].partition(": ")
        raise InputError(src, what)
    options: dict[str, Any] = {k: v for k, v in spec.driver_options.items() if k in KLA_OPTIONS}
    if spec.driver != "kla":
        options = {}
    if tip_wear_pct_per_h is not None:
        if spec.driver != "sim":
            raise InputError("--tip-wear-pct-per-h", "only the simulated instrument wears its tip on purpose")
        options["tip_wear_pct_per_h"] = tip_wear_pct_per_h
    name = spec.campaign.name if spec.campaign.name != "run" else tray.name
    campaign = dataclasses.replace(spec.campaign, driver_options=options, name=name)
    return dataclasses.replace(spec, campaign=campaign, tray=tray)


def _cmd_new(args: argparse.Namespace) -> int:
    from core.sample.tray import TRAY_TEMPLATE

    path = write_new_file(args.file, TRAY_TEMPLATE, force=args.force)
    print(f"wrote {path}: point each sample at its sample file and goal, then `aeni tray check {path}`")
    return 0


def sim_builtin(seed: int = 0) -> Any:
    """The sim driver's own sample for a tray entry that names a scenario (or truth CSV) and no file."""
    from drivers.registry import default_sample

    def builtin(entry: TraySample) -> Sample:
        if not entry.sim:
            raise InputError(f"sample {entry.name!r}", "no sample file, and no scenario for the sim driver")
        return default_sample("sim", entry.sim, seed)

    return builtin


def resolve_tray(tray: Tray, driver: str, seed: int = 0) -> tuple[Tray, list[str]]:
    """The tray with the sim driver's built-in samples placed (``driver`` sim), and the problems left."""
    from core.campaign_config import CampaignConfig
    from core.run.tray import tray_profiles
    from core.sample.tray import layout_problems
    from drivers.kla.tray import KlaTray

    problems: list[str] = []
    if driver == "sim":
        try:
            tray = tray.resolved(sim_builtin(seed))
        except InputError as exc:
            return tray, [f"{tray.source}: {exc}"]
        problems = [f"{tray.source}: {p}" for p in layout_problems(tray)]
    missing = [s.name for s in tray.samples if s.sample is None]
    problems += [
        f"{tray.source}: sample {n!r}: no sample file (a scenario needs --driver sim)" for n in missing
    ]
    if driver == "kla" and not problems:  # one InView over the tray: one convention, one method set
        try:
            KlaTray(tray, tray_profiles(tray, CampaignConfig()))
        except InputError as exc:
            problems.append(f"{tray.source}: {exc}")
    return tray, problems


def move_lines(tray: Tray) -> list[str]:
    """The moves between samples in the order they are first visited, each priced from its target's profile
    (travel lifted, then the new surface's find and settle beyond a block's own overhead)."""
    from core.sample.tray import centre_um, visit_order
    from core.sample_change import change_s, travel_s

    out = []
    order = visit_order(tray)
    for a, b in itertools.pairwise(order):
        pa, pb = centre_um(a.placed), centre_um(b.placed)
        profile = load_profile(b.placed.profile)
        dist = math.hypot(pb[0] - pa[0], pb[1] - pa[1])
        t_move, t_change = travel_s(profile, pa, pb), change_s(profile)
        out.append(
            f"  {a.name} → {b.name}: {dist / 1000:,.1f} mm, travel {t_move:,.0f} s + surface find and settle "
            f"{t_change:,.0f} s"
        )
    return out


def _goal_text(s: TraySample) -> str:
    if s.reference is not None:
        r = s.reference
        return (
            f"reference {r.material} (H {r.hardness_gpa:g} GPa, E {r.modulus_gpa:g} GPa, ±{r.tolerance_pct:g} %, "
            f"every {r.check_every_h:g} h)"
        )
    assert s.goal is not None
    return f"goal {s.goal.kind} {s.goal.value:g}, priority {s.priority:g}"


def _cmd_check(args: argparse.Namespace) -> int:
    from core.sample.tray import draw_tray, read_tray

    tray, problems = read_tray(args.file)
    if tray is not None and not problems:
        tray, problems = resolve_tray(tray, args.driver)
    if problems or tray is None:
        for line in problems:
            print(f"aeni: error: {line}")
        return 2
    print(
        f"{args.file}: valid ({len(tray.libraries)} librar{'y' if len(tray.libraries) == 1 else 'ies'}"
        f"{', a reference' if tray.reference else ', no reference: the tip is not checked'})"
    )
    for k, s in enumerate(tray.samples):
        x0, x1, y0, y1 = s.placed.calibration.bounds_um
        print(
            f"{chr(ord('A') + k)}  {s.name}: {s.role}, x {x0:,.0f}…{x1:,.0f} µm, y {y0:,.0f}…{y1:,.0f} µm; "
            + _goal_text(s)
        )
    print("moves between samples (first visits):")
    for line in move_lines(tray):
        print(line)
    if not args.no_plot:
        print(draw_tray(tray, args.width, args.height))
    return 0


def register(subparsers: Any) -> None:
    p = subparsers.add_parser("tray", help="write or check a tray file (tray.toml): several samples, one run")
    sub = p.add_subparsers(dest="tray_command", metavar="ACTION")
    sub.required = True
    new = sub.add_parser("new", help="write a commented tray file template")
    new.add_argument("file", nargs="?", default="tray.toml", metavar="FILE")
    new.add_argument("--force", action="store_true", help="overwrite an existing file")
    new.set_defaults(func=_cmd_new)
    chk = sub.add_parser("check", help="validate a tray file and draw it on the stage")
    chk.add_argument("file", metavar="FILE")
    chk.add_argument(
        "--driver",
        choices=("sim", "kla"),
        default="kla",
        help="sim: a library may name a scenario instead of a sample file",
    )
    chk.add_argument("--width", type=int, default=72, help="drawing width in characters")
    chk.add_argument("--height", type=int, default=24, help="drawing height in characters")
    chk.add_argument("--no-plot", action="store_true", help="print the facts only")
    chk.set_defaults(func=_cmd_check)

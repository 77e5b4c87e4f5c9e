"""``aeni sample new | check``: write a commented sample file; validate one and draw it as the sample is seen."""

from __future__ import annotations

import argparse
import math
import sys
from typing import Any

import numpy as np

from aeni_console.files import write_new_file
from core.profile import load_profile


def _cmd_new(args: argparse.Namespace) -> int:
    # imported here, not at the top: the sample's geometry pulls scipy; `aeni --help` must start fast
    from core.sample import SAMPLE_TEMPLATE

    path = write_new_file(args.file, SAMPLE_TEMPLATE, force=args.force)
    print(f"wrote {path}: edit the corners, safety distances and exclusions, then `aeni sample check {path}`")
    return 0


def allowed_lattice(sample: Any) -> tuple[np.ndarray, np.ndarray]:
    """The campaign's candidate lattice (stage µm) and which centres a run may use on this sample."""
    from core.geometry import CandidateLattice
    from core.policies.base import DEFAULT_PITCH_UM

    h = 2 * DEFAULT_PITCH_UM
    lattice = CandidateLattice.build(sample.calibration, sample.lattice_n, grid_halfwidth_um=h)
    return lattice.xy_um, sample.allowed(lattice.xy_um, h)


def sample_facts(sample: Any) -> list[str]:
    """The lines ``aeni sample check`` prints: what the file says and what it implies."""
    from core.policies.base import DEFAULT_PITCH_UM
    from core.sample import grid_baseline_s

    cal = sample.calibration
    profile = load_profile(sample.profile)
    _, ok = allowed_lattice(sample)
    tilt = 1000.0 * cal.plane.slope
    downhill = math.degrees(math.atan2(-cal.plane.b, -cal.plane.a)) if tilt > 0 else 0.0
    base_s = grid_baseline_s(sample, profile, DEFAULT_PITCH_UM)
    lines = [
        f"sample {sample.name}  (profile {profile.name}, {sample.lattice_n}×{sample.lattice_n} lattice)",
        f"area {cal.area_um2 / 1e6:.3f} mm² ({cal.area_um2:,.0f} µm²), diagonal {cal.diagonal_um:,.0f} µm",
        f"parallelogram defect {cal.parallelogram_residual_um:.1f} µm per corner "
        f"({100 * cal.parallelogram_residual_um / cal.diagonal_um:.2f} % of the diagonal)",
        f"plane tilt {tilt:.2f} µm/mm (falls towards {downhill:.0f}° from +x; "
        f"profile allows {profile.max_tilt_um_per_mm:g} µm/mm)",
        f"safety: dz_safe {sample.dz_safe_um:g} µm, r_excl {sample.r_excl_um:g} µm, "
        f"edge band {sample.edge_band_um:g} µm, stage {list(sample.stage_rect_um)} µm",
        f"{len(sample.exclusions)} exclusion region(s), {len(sample.earlier_indents_um)} earlier indent(s)",
        f"candidate centres allowed: {int(ok.sum())} of {ok.size} ({100 * ok.mean():.0f} %)",
        f"grid baseline (9×9 blocks of 5×5, {profile.default_hold_s:g} s hold) on this sample: "
        f"{base_s:,.0f} s ({base_s / 3600:.1f} h)",
    ]
    lines += [f"warning: {w}" for w in cal.warnings()]
    return lines


def _outline(points: np.ndarray) -> tuple[list[float], list[float]]:
    closed = np.vstack([points, points[:1]])
    return closed[:, 0].tolist(), closed[:, 1].tolist()


def draw_sample(sample: Any, width: int = 100, height: int = 32, color: bool = True) -> str:
    """The outline, exclusions, earlier indents and allowed lattice in stage µm, x reversed per the profile."""
    import plotext as plt

    from core.sample import CircleExclusion

    profile = load_profile(sample.profile)
    flip = -1.0 if profile.reverse_x else 1.0
    cal = sample.calibration
    xy, ok = allowed_lattice(sample)
    plt.clear_figure()
    plt.plotsize(width, height)
    plt.theme("clear")
    allowed = xy[ok]
    if len(allowed):
        plt.scatter(
            (flip * allowed[:, 0]).tolist(),
            allowed[:, 1].tolist(),
            marker="dot",
            color="gray",
            label="lattice",
        )
    xs, ys = _outline(cal.corners_xy_um)
    plt.plot([flip * x for x in xs], ys, color="blue", label="corners")
    for k, region in enumerate(sample.exclusions):
        if isinstance(region, CircleExclusion):
            t = np.linspace(0.0, 2 * math.pi, 73)
            pts = np.column_stack(
                [region.x_um + region.radius_um * np.cos(t), region.y_um + region.radius_um * np.sin(t)]
            )
        else:
            pts = np.vstack([np.asarray(region.vertices_um), region.vertices_um[:1]])
        plt.plot(
            (flip * pts[:, 0]).tolist(),
            pts[:, 1].tolist(),
            color="red",
            label="exclusion" if k == 0 else None,
        )
    if len(sample.earlier_indents_um):
        e = sample.earlier_xy_um
        plt.scatter(
            (flip * e[:, 0]).tolist(), e[:, 1].tolist(), marker="x", color="orange", label="earlier indents"
        )
    x0, x1, _, _ = cal.bounds_um
    ticks = np.linspace(x0, x1, 5)
    plt.xticks((flip * ticks).tolist(), [f"{t:,.0f}" for t in ticks])
    plt.xlabel("stage x (µm)" + (", reversed: as the sample is seen" if profile.reverse_x else ""))
    plt.ylabel("stage y (µm)")
    plt.title(f"{sample.name}")
    out: str = plt.build()
    plt.clear_figure()
    return out if color else str(plt.uncolorize(out))


def _cmd_check(args: argparse.Namespace) -> int:
    from core.sample import load_sample

    sample = load_sample(args.file)
    print(f"{args.file}: valid")
    for line in sample_facts(sample):
        print(line)
    if not args.no_plot:
        print(draw_sample(sample, args.width, args.height, color=sys.stdout.isatty()))
    return 0


def register(subparsers: Any) -> None:
    p = subparsers.add_parser("sample", help="write or check a sample file (sample.toml)")
    sub = p.add_subparsers(dest="sample_command", metavar="ACTION")
    sub.required = True
    new = sub.add_parser("new", help="write a commented sample file template")
    new.add_argument("file", nargs="?", default="sample.toml", metavar="FILE")
    new.add_argument("--force", action="store_true", help="overwrite an existing file")
    new.set_defaults(func=_cmd_new)
    chk = sub.add_parser("check", help="validate a sample file and draw it in the terminal")
    chk.add_argument("file", metavar="FILE")
    chk.add_argument("--width", type=int, default=100, help="plot width in characters")
    chk.add_argument("--height", type=int, default=32, help="plot height in characters")
    chk.add_argument("--no-plot", action="store_true", help="print the facts only")
    chk.set_defaults(func=_cmd_check)

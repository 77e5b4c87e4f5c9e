"""A run's report for the lab notebook: PNG figures and a short Markdown summary, read from its journal.

Works on any journal, finished or running, real or simulated, because it reads only what the journal
holds (read-only). Figures are drawn in stage µm as the sample is seen (the x axis reversed where the
instrument profile says so). For a simulated run the summary adds the map's error against the truth,
rebuilt from the run's own configuration; a real run has no truth, so no error is claimed.
"""

from __future__ import annotations

import json
import math
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from aeni_console.files import check_out_folder, write_atomic
from aeni_console.reports.fast import FastTally, fast_summary_lines, fast_tally
from aeni_console.reports.finalmaps import final_maps
from core.campaign_config import campaign_config_from_dict
from core.errors import InputError
from core.journal import JournalReader
from core.run.tray_view import journal_tray
from core.sample import sample_from_dict
from drivers.registry import sim_scenario
from drivers.sim.emulator import truth_modulus_gpa

FIGURE_DPI = 110
LEDGER_ORDER = ("setup", "lift", "move", "engage", "drift", "indent", "hold", "reconfigure", "comeback")
DECISION_STYLE = {  # who decided (decision_who): (marker, colour, label)
    "approved": ("o", "tab:green", "approved by the operator"),
    "approved-timeout": ("o", "tab:olive", "approved by the timeout (approval_timeout_s)"),
    "vetoed": ("X", "tab:red", "vetoed by the operator"),
    "vetoed-timeout": ("X", "tab:purple", "vetoed by the timeout (approval_timeout_s)"),
    "vetoed-engine": ("X", "tab:brown", "vetoed by the engine"),
    "pending": ("s", "tab:orange", "waiting for the operator"),
    "auto": (".", "0.55", "automatic"),
    "dropped": ("x", "0.3", "dropped (superseded)"),
}
BY_OPERATOR = ("approved", "vetoed")
UNMEASURED_STYLE = {  # unmeasured_kind: (marker, colour, label): what the instrument did instead of measuring
    "failed": ("x", "tab:red", "failed (indented, no value)"),
    "unverified-refused": ("D", "tab:orange", "unverified: made, its export refused"),
    "unverified-no-export": ("d", "tab:purple", "unverified: started, no export at all"),
    "not_run": ("o", "tab:blue", "never indented (not run)"),
}


def decision_who(d: Any, resolved_by: dict[int, str]) -> str:
    """A decision's status with who took it where it was not the operator: an approval the timeout took is
    not the operator's (``approval_timeout_s``), nor a veto the engine made."""
    who = resolved_by.get(int(d.decision_id), "")
    if d.status in ("approved", "vetoed") and who in ("timeout", "engine"):
        return f"{d.status}-{who}"
    return str(d.status)


def unmeasured_kind(r: Any) -> str:
    """An unverified indent's kind: made with its export refused (the note says so), or a confirmed start
    with no export at all (drivers.kla.array_run's two cases)."""
    if r.status != "unverified":
        return str(r.status)
    return "unverified-refused" if "refused" in (r.note or "") else "unverified-no-export"


@dataclass
class RunData:
    """Everything the report draws, read from the journal in one go."""

    path: Path
    name: str
    state: str
    finished: bool
    supervision: str
    policy: str
    driver: str
    config: dict[str, Any]
    profile_name: str
    reverse_x: bool
    outline_xy_um: np.ndarray  # (4, 2) corners TL, TR, BR, BL
    avoid_centers_um: list[tuple[float, float]]
    exclusions: tuple[Any, ...]  # the sample's CircleExclusion / PolygonExclusion regions
    earlier_indents_um: list[tuple[float, float]]  # indents of earlier runs the sample file names
    indents: list[Any]  # IndentResult
    ledger_s: dict[str, float]
    instrument_s: float
    grid_baseline_s: float
    decisions: list[Any]  # StoredDecision
    snapshots: list[tuple[int, float]]  # (snapshot_id, t_s) with stored map fields
    final_map: Any | None  # MapFields of the last snapshot
    uncertainty: list[tuple[float, float, float]] = field(default_factory=list)  # (t_s, mean epi sd, total)
    # per stored map, in the same order: (block_id, length-scales µm, collapse alarm) of that fit
    fits: list[tuple[int, tuple[float, ...], bool]] = field(default_factory=list)
    warnings: list[tuple[float, str]] = field(default_factory=list)  # (t_s, text) of the run's warn events
    commands: list[dict[str, Any]] = field(default_factory=list)
    resolved_by: dict[int, str] = field(default_factory=dict)  # decision_id: operator's name, timeout, engine
    stop_reason: str = ""
    recorded_mape_pct: float | None = None
    final_maps: Any | None = (
        None  # aeni_console.reports.finalmaps.FinalMaps: both maps rebuilt from the journal
    )
    block_s: dict[int, float] = field(default_factory=dict)  # the ledger's seconds per block (-1: the run's)

    @property
    def fast(self) -> FastTally:
        """The indents by channel and the time in fast arrays (of these indents: a tray's library has its own)."""
        return fast_tally(self.indents, self.block_s.items())


def read_run(path: str | Path) -> RunData:
    """Read a journal read-only into RunData (any state: a running engine keeps writing meanwhile)."""

    p = Path(path)
    with JournalReader(p) as r:
        snap = r.snapshot()
        meta = r.meta
        row = r.q.engine_row()
        cols, rows = r.table("gp_snapshots")
        i_sid, i_t, i_blob, i_sum = (
            cols.index("snapshot_id"),
            cols.index("t_s"),
            cols.index("fields_npz"),
            cols.index("summary_json"),
        )
        with_maps = [(int(x[i_sid]), float(x[i_t])) for x in rows if x[i_blob] is not None]
        i_bid = cols.index("block_id")
        fit_of = {int(x[i_sid]): (int(x[i_bid]), json.loads(x[i_sum])) for x in rows if x[i_blob] is not None}
        recorded = None

        for x in rows:
            m = json.loads(x[i_sum]).get("mape_pct")
            if m is not None:
                recorded = float(m)
        uncertainty = []
        fits = []
        final_map = None
        for sid, t_s in with_maps:
            mf = r.map_fields(sid)
            epi, tot = mf.epistemic_sd_gpa, mf.total_sd_gpa
            if np.isfinite(epi).any():
                uncertainty.append((t_s, float(np.nanmean(epi)), float(np.nanmean(tot))))
                bid, summ = fit_of[sid]
                scales = tuple(float(v) for v in summ.get("lengthscales_um") or ())
                fits.append((bid, scales, bool(summ.get("collapse_alarm", False))))
            final_map = mf
        warnings = [(e.t_s, e.text) for e in r.events() if e.level in ("warn", "error")]
        d_cols, d_rows = r.table("decisions")
        i_did, i_by = d_cols.index("decision_id"), d_cols.index("resolved_by")
        resolved_by = {int(x[i_did]): str(x[i_by]) for x in d_rows if x[i_by] is not None}
        cal = meta.get("calibration") or {}
        corners: list[Any] = [cal.get(k) for k in ("tl", "tr", "br", "bl")]
        if all(isinstance(c, dict) for c in corners):
            outline = np.array([[float(c["x_um"]), float(c["y_um"])] for c in corners])
        else:
            x0, x1, y0, y1 = snap.stage_bounds_um
            outline = np.array([[x0, y1], [x1, y1], [x1, y0], [x0, y0]], dtype=float)
        sample = _sample(meta)
        indents = r.results()
        s_cols, s_rows = r.table("steps")
        i_b, i_s = s_cols.index("block_id"), s_cols.index("seconds")
        block_s: dict[int, float] = defaultdict(float)
        for x in s_rows:
            block_s[int(x[i_b])] += float(x[i_s])
        data = RunData(
            path=p,
            name=snap.run_name,
            state=snap.state.value,
            finished=snap.finished,
            supervision=snap.supervision,
            policy=snap.policy,
            driver=str(meta.get("driver", "sim")),
            config=dict(meta.get("config") or {}),
            profile_name=snap.profile_name,
            reverse_x=snap.reverse_x,
            outline_xy_um=outline,
            avoid_centers_um=[(float(x), float(y)) for x, y in snap.settings.avoid_centers_um],
            exclusions=tuple(sample.exclusions) if sample is not None else (),
            earlier_indents_um=[(float(x), float(y)) for x, y in sample.earlier_indents_um] if sample else [],
            indents=indents,
            ledger_s=dict(snap.ledger),
            instrument_s=snap.instrument_s,
            grid_baseline_s=snap.grid_baseline_s,
            decisions=r.decisions(),
            snapshots=with_maps,
            final_map=final_map,
            uncertainty=uncertainty,
            fits=fits,
            warnings=warnings,
            commands=r.commands(),
            resolved_by=resolved_by,
            stop_reason=str(row.get("stop_reason") or ""),
            recorded_mape_pct=recorded,
            block_s=dict(block_s),
        )

    data.final_maps = final_maps(p)
    return data


def _sample(meta: dict[str, Any]) -> Any | None:
    """The Sample the run indented, as its journal holds it (None for a journal without one)."""

    raw = (meta.get("config") or {}).get("sample")
    return None if raw is None else sample_from_dict(raw, "journal sample")


# --------------------------------------------------------------------------------------------------
# truth (simulated runs only)


def truth_mape_pct(data: RunData) -> tuple[float, int] | None:
    """MAPE (%) of the last stored mean map against the simulated truth at the same points, and their count.

    None for a run that is not simulated or has no map yet. The truth is rebuilt from the run's
    configuration (the driver's options, the seed and the sample), as the simulated instrument built it.
    """
    if data.driver != "sim" or data.final_map is None:
        return None

    cfg = campaign_config_from_dict(data.config)
    scenario = sim_scenario(cfg.driver_options, cfg.seed, cfg.sample)
    mf = data.final_map
    gx, gy = np.meshgrid(mf.x_um, mf.y_um)
    truth = np.asarray(scenario.truth.hardness_gpa(gx, gy), dtype=float)
    mean = np.asarray(mf.mean_gpa, dtype=float)
    ok = np.isfinite(mean) & np.isfinite(truth) & (truth != 0)
    if not ok.any():
        return None
    return float(100.0 * np.mean(np.abs(mean[ok] - truth[ok]) / np.abs(truth[ok]))), int(ok.sum())


# --------------------------------------------------------------------------------------------------
# figures


def _pyplot() -> Any:
    try:
        import matplotlib
    except ImportError:
        raise InputError(
            "aeni report", "needs matplotlib: pip install -e '.[report]' (the report extra)"
        ) from None
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _stage_axes(ax: Any, data: RunData) -> None:
    from matplotlib.ticker import MaxNLocator, ScalarFormatter

    ax.set_xlabel("stage x (µm)")
    ax.set_ylabel("stage y (µm)")
    ax.set_aspect("equal", adjustable="box")
    for axis in (ax.xaxis, ax.yaxis):
        # a few round ticks in plain µm: stage values are five digits wide and must not run together
        axis.set_major_locator(MaxNLocator(nbins=4, steps=[1, 2, 2.5, 5, 10]))
        plain = ScalarFormatter(useOffset=False)
        plain.set_scientific(False)
        axis.set_major_formatter(plain)
    if data.reverse_x and not ax.xaxis_inverted():
        ax.invert_xaxis()  # as the sample is seen: +x moves the sample right, indents walk left


def _overlay(ax: Any, data: RunData, indents: bool = True, vetoes: bool = True) -> None:
    from matplotlib.patches import Circle, Polygon

    closed = np.vstack([data.outline_xy_um, data.outline_xy_um[:1]])
    ax.plot(closed[:, 0], closed[:, 1], color="black", lw=1.2, label="sample outline")
    measured = [r for r in data.indents if r.measured and r.channel != "fast"]
    fast = [r for r in data.indents if r.measured and r.channel == "fast"]
    if indents and fast:  # a fast array's indents, under the CSM ones: dense, and read apart
        xs = [r.actual_x_um for r in fast]
        ys = [r.actual_y_um for r in fast]
        ax.scatter(
            xs,
            ys,
            s=6,
            c="tab:green",
            marker="s",
            linewidths=0,
            label=f"fast indents ({len(fast)})",
            zorder=3,
        )
    if indents and measured:
        xs = [r.actual_x_um for r in measured]
        ys = [r.actual_y_um for r in measured]
        label = f"CSM indents ({len(measured)})" if fast else "indents"
        ax.scatter(xs, ys, s=4, c="white", edgecolors="black", linewidths=0.3, label=label, zorder=3)
    for status, style in UNMEASURED_STYLE.items():
        rs = [r for r in data.indents if unmeasured_kind(r) == status]
        if not indents or not rs:
            continue
        # where the tip went when the instrument said so, else where it was sent
        xy = [
            (r.actual_x_um, r.actual_y_um)
            if math.isfinite(r.actual_x_um) and math.isfinite(r.actual_y_um)
            else (r.commanded_x_um, r.commanded_y_um)
            for r in rs
        ]
        marker, colour, label = style
        ax.scatter(
            [p[0] for p in xy],
            [p[1] for p in xy],
            s=18,
            marker=marker,
            c=colour if marker in ("x", "+") else "none",
            edgecolors=None if marker in ("x", "+") else colour,
            linewidths=1.0,
            label=f"{label} ({len(rs)})",
            zorder=4,
        )
    for i, region in enumerate(data.exclusions):
        region_label = "sample exclusions" if i == 0 else None
        if hasattr(region, "radius_um"):
            patch: Any = Circle((region.x_um, region.y_um), region.radius_um)
        else:
            patch = Polygon(np.asarray(region.vertices_um, dtype=float), closed=True)
        patch.set(
            facecolor=(0.8, 0.1, 0.1, 0.25), edgecolor="tab:red", hatch="//", label=region_label, zorder=3
        )
        ax.add_patch(patch)
    if data.earlier_indents_um:
        ex, ey = zip(*data.earlier_indents_um, strict=True)
        ax.scatter(ex, ey, s=6, marker="s", c="0.4", label="earlier runs' indents", zorder=3)
    if data.avoid_centers_um:
        ax_x, ax_y = zip(*data.avoid_centers_um, strict=True)
        ax.scatter(ax_x, ax_y, s=60, marker="x", c="tab:red", label="excluded centres", zorder=4)
    if vetoes:
        for who in ("vetoed", "vetoed-timeout", "vetoed-engine"):
            _vetoes(ax, data, DECISION_STYLE[who][2], who)


def _vetoes(ax: Any, data: RunData, label: str, who: str = "vetoed") -> int:
    """Vetoed proposals (``who``: the DECISION_STYLE key of who vetoed) where they were proposed; several at
    one centre are one marker with their count."""
    at: dict[tuple[float, float], int] = defaultdict(int)
    for d in data.decisions:
        if decision_who(d, data.resolved_by) == who:
            at[(round(d.decision.block.center_x_um, 1), round(d.decision.block.center_y_um, 1))] += 1
    if not at:
        return 0
    total = sum(at.values())
    marker, colour, _ = DECISION_STYLE[who]
    ax.scatter(
        [p[0] for p in at],
        [p[1] for p in at],
        s=[60 + 15 * min(n - 1, 8) for n in at.values()],
        marker=marker,
        c=colour,
        label=f"{label} ({total})",
        zorder=5,
    )
    for (x, y), n in at.items():
        if n > 1:
            ax.annotate(f"×{n}", (x, y), xytext=(4, 4), textcoords="offset points", fontsize=7, color=colour)
    return total


def _map_figure(plt: Any, data: RunData, out: Path) -> Path:
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.8), constrained_layout=True)
    mf = data.final_map
    panels = (("mean hardness (GPa)", "mean_gpa", "viridis"), ("total sd (GPa)", "total_sd_gpa", "magma"))
    for ax, (title, attr, cmap) in zip(axes, panels, strict=True):
        if mf is not None and np.isfinite(getattr(mf, attr)).any():
            im = ax.pcolormesh(
                mf.x_um, mf.y_um, np.asarray(getattr(mf, attr), float), cmap=cmap, shading="auto"
            )
            fig.colorbar(im, ax=ax, shrink=0.85)
        else:
            ax.text(0.5, 0.5, "no model yet", transform=ax.transAxes, ha="center", va="center")
        _overlay(ax, data)
        ax.set_title(title)
        _stage_axes(ax, data)
    axes[0].legend(loc="upper left", fontsize=7, framealpha=0.8)
    fig.suptitle(f"{data.name}: the model after {len(data.indents)} indents ({data.state})")
    return _save(fig, plt, out / "maps.png")


def _modulus_figure(plt: Any, data: RunData, out: Path) -> Path:
    """The modulus map beside the hardness one (issue 27): its mean, its epistemic sd and H/E."""
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.6), constrained_layout=True)
    fm = data.final_maps
    panels = (
        ("mean modulus (GPa)", "modulus_mean_gpa", "viridis"),
        ("modulus epistemic sd (GPa)", "modulus_epistemic_sd_gpa", "magma"),
        ("H/E", "h_over_e", "cividis"),
    )
    for ax, (title, attr, cmap) in zip(axes, panels, strict=True):
        values = None if fm is None else np.asarray(getattr(fm, attr), float)
        if fm is not None and values is not None and np.isfinite(values).sum() >= 3:
            ok = np.isfinite(values)
            im = ax.tripcolor(fm.x_um[ok], fm.y_um[ok], values[ok], cmap=cmap, shading="gouraud")
            fig.colorbar(im, ax=ax, shrink=0.85)
        else:
            ax.text(0.5, 0.5, "no modulus map yet", transform=ax.transAxes, ha="center", va="center")
        _overlay(ax, data, vetoes=False)
        ax.set_title(title)
        _stage_axes(ax, data)
    how = (
        "planned for (map_weights)"
        if fm is not None and fm.modulus_planned
        else "fitted from the same indents for this report"
    )
    fig.suptitle(f"{data.name}: the modulus map, {how}")
    return _save(fig, plt, out / "modulus.png")


def modulus_mape_pct(data: RunData) -> tuple[float, int] | None:
    """MAPE (%) of the modulus map against the simulated modulus truth at its points (None: not simulated,
    or no modulus map)."""
    fm = data.final_maps
    if data.driver != "sim" or fm is None or not np.isfinite(fm.modulus_mean_gpa).any():
        return None

    cfg = campaign_config_from_dict(data.config)
    scenario = sim_scenario(cfg.driver_options, cfg.seed, cfg.sample)
    truth = truth_modulus_gpa(scenario.truth, fm.x_um, fm.y_um)
    mean = np.asarray(fm.modulus_mean_gpa, dtype=float)
    ok = np.isfinite(mean) & np.isfinite(truth) & (truth != 0)
    return float(100.0 * np.mean(np.abs(mean[ok] - truth[ok]) / np.abs(truth[ok]))), int(ok.sum())


def _bias_figure(plt: Any, data: RunData, out: Path) -> Path:
    """The fast channel's learnt bias H_csm − H_fast (issue 36), on a diverging scale centred on no bias,
    with the fast and CSM indents."""
    fig, ax = plt.subplots(1, 1, figsize=(6.4, 5.0), constrained_layout=True)
    fm = data.final_maps
    bias = None if fm is None else fm.fast_bias_gpa
    if fm is not None and bias is not None and np.isfinite(bias).sum() >= 3:
        ok = np.isfinite(bias)
        top = float(np.max(np.abs(bias[ok]))) or 1e-6
        im = ax.tripcolor(
            fm.x_um[ok], fm.y_um[ok], bias[ok], cmap="RdBu_r", vmin=-top, vmax=top, shading="gouraud"
        )
        fig.colorbar(im, ax=ax, shrink=0.85, label="GPa")
    else:
        ax.text(0.5, 0.5, "no bias learnt yet", transform=ax.transAxes, ha="center", va="center")
    _overlay(ax, data, vetoes=False)
    ax.set_title("fast-channel bias H_csm − H_fast (GPa)")
    _stage_axes(ax, data)
    ax.legend(loc="upper left", fontsize=7, framealpha=0.8)
    fig.suptitle(f"{data.name}: what the fast channel reads off the CSM map")
    return _save(fig, plt, out / "bias.png")


def _time_figure(plt: Any, data: RunData, out: Path) -> Path:
    fig, ax = plt.subplots(figsize=(8, 4.2), constrained_layout=True)
    cats = [c for c in LEDGER_ORDER if data.ledger_s.get(c)] + sorted(
        c for c, v in data.ledger_s.items() if v and c not in LEDGER_ORDER
    )
    hours = [data.ledger_s[c] / 3600 for c in cats]
    total = sum(data.ledger_s.get(c, 0.0) for c in cats)
    bars = ax.barh(cats[::-1], hours[::-1], color="tab:blue")
    for bar, c in zip(bars, cats[::-1], strict=True):
        share = 100 * data.ledger_s[c] / total if total else 0.0
        ax.text(
            bar.get_width(), bar.get_y() + bar.get_height() / 2, f" {share:.0f} %", va="center", fontsize=8
        )
    ax.set_xlabel("instrument time (h)")
    ax.set_title(f"instrument time by category: {total / 3600:.2f} h in all")
    if not cats:
        ax.text(0.5, 0.5, "no instrument time yet", transform=ax.transAxes, ha="center")
    return _save(fig, plt, out / "time.png")


JUMP_FACTOR = 1.3  # a total sd this many times the previous fit's is a jump the figure explains


def uncertainty_jumps(data: RunData) -> list[tuple[int, str]]:
    """Where the mean total sd rises by JUMP_FACTOR or more from one fit to the next, and why: a guard
    event or warning logged in between, a new program (a global block), or a refit that moved the
    length-scales; "no logged cause" where none of these happened."""
    programs = {d.decision.block.block_id for d in data.decisions if d.decision.block.kind == "global"}
    out: list[tuple[int, str]] = []
    for i in range(1, min(len(data.uncertainty), len(data.fits))):
        (t0, _, tot0), (t1, _, tot1) = data.uncertainty[i - 1], data.uncertainty[i]
        if not tot0 > 0 or tot1 < JUMP_FACTOR * tot0:
            continue
        bid, scales, alarm = data.fits[i]
        old_scales = data.fits[i - 1][1]
        why: list[str] = []
        if alarm:
            why.append("guard: length-scale collapse")
        why += [f"warning: {text[:48]}" for t, text in data.warnings if t0 < t <= t1][:1]
        if bid in programs:
            why.append(f"new program (block {bid})")
        if scales and old_scales and len(scales) == len(old_scales):
            moved = max(abs(a / b - 1) for a, b in zip(scales, old_scales, strict=True) if b > 0)
            if moved > 0.2:
                before = "×".join(f"{v:.0f}" for v in old_scales)
                after = "×".join(f"{v:.0f}" for v in scales)
                why.append(f"refit: ℓ {before} → {after} µm")
        out.append((i, f"sd ×{tot1 / tot0:.1f}: " + ("; ".join(why) or "no logged cause")))
    return out


def _uncertainty_figure(plt: Any, data: RunData, out: Path) -> Path:
    fig, ax = plt.subplots(figsize=(8, 4.2), constrained_layout=True)
    if data.uncertainty:
        t = [u[0] / 3600 for u in data.uncertainty]
        ax.plot(t, [u[1] for u in data.uncertainty], "o-", ms=3, label="epistemic sd (the model's own)")
        ax.plot(t, [u[2] for u in data.uncertainty], "s--", ms=3, label="total sd (with the noise)")
        for i, why in uncertainty_jumps(data):
            ax.axvline(t[i], color="0.6", lw=0.8, ls=":")
            ax.annotate(
                why,
                (t[i], data.uncertainty[i][2]),
                xytext=(6, 6),
                textcoords="offset points",
                fontsize=7,
                color="0.25",
                arrowprops={"arrowstyle": "-", "color": "0.6", "lw": 0.6},
            )
        ax.legend()
    else:
        ax.text(0.5, 0.5, "no model fitted yet", transform=ax.transAxes, ha="center")
    ax.set_xlabel("instrument time (h)")
    ax.set_ylabel("mean over the sample (GPa)")
    ax.set_title("the model's uncertainty over time")
    return _save(fig, plt, out / "uncertainty.png")


def _drift_figure(plt: Any, data: RunData, out: Path) -> Path:
    fig, ax = plt.subplots(figsize=(8, 4.2), constrained_layout=True)
    pts = [
        (r.t_s / 3600, r.drift_rate_nm_s, r.hold_s)
        for r in data.indents
        if math.isfinite(r.drift_rate_nm_s) and math.isfinite(r.t_s)
    ]
    if pts:
        t, rate, hold = zip(*pts, strict=True)
        ax.scatter(t, rate, s=6, c="tab:purple", label="drift rate (nm/s)")
        ax.set_ylabel("drift rate (nm/s)")
        ax2 = ax.twinx()
        ax2.step(t, hold, where="post", color="tab:orange", lw=1.2, label="hold (s)")
        ax2.set_ylabel("hold (s)")
        ax2.set_ylim(bottom=-2)
        lines = ax.get_legend_handles_labels()
        more = ax2.get_legend_handles_labels()
        ax.legend(lines[0] + more[0], lines[1] + more[1], loc="upper right", fontsize=8)
    else:
        ax.text(0.5, 0.5, "no drift readings yet", transform=ax.transAxes, ha="center")
    ax.set_xlabel("instrument time (h)")
    ax.set_title("drift readings and the holds used")
    return _save(fig, plt, out / "drift.png")


def _decision_figure(plt: Any, data: RunData, out: Path) -> Path:
    fig, (ax_map, ax_t) = plt.subplots(1, 2, figsize=(11, 4.6), constrained_layout=True)
    by_status: dict[str, list[Any]] = defaultdict(list)
    for d in data.decisions:
        by_status[decision_who(d, data.resolved_by)].append(d)
    rows = [s for s in DECISION_STYLE if by_status.get(s)]
    for s in rows:
        marker, colour, label = DECISION_STYLE[s]
        ds = by_status[s]
        if s.startswith("vetoed"):
            _vetoes(ax_map, data, label, s)
        else:
            ax_map.scatter(
                [d.decision.block.center_x_um for d in ds],
                [d.decision.block.center_y_um for d in ds],
                marker=marker,
                c=colour,
                s=50 if s != "auto" else 25,
                label=f"{label} ({len(ds)})",
            )
        ax_t.scatter([d.t_s / 3600 for d in ds], [rows.index(s)] * len(ds), marker=marker, c=colour, s=40)
        at_once: dict[float, int] = defaultdict(int)  # decisions made at one instrument time share a marker
        for d in ds:
            at_once[round(d.t_s / 3600, 2)] += 1
        for t_h, n in at_once.items():
            if n > 1:
                ax_t.annotate(
                    f"×{n}", (t_h, rows.index(s)), xytext=(5, 5), textcoords="offset points", fontsize=8
                )
    _overlay(ax_map, data, indents=False, vetoes=False)
    _stage_axes(ax_map, data)
    ax_map.set_title("decisions on the sample")
    if rows:
        ax_map.legend(loc="upper left", fontsize=7, framealpha=0.8)
    ax_t.set_yticks(range(len(rows)), [r.replace("-", " by ") for r in rows])
    ax_t.set_ylim(-0.5, max(len(rows), 1) - 0.5)
    ax_t.set_xlabel("instrument time (h)")
    n_op = sum(len(by_status.get(s, ())) for s in BY_OPERATOR)
    ax_t.set_title(f"operator decisions: {n_op} of {len(data.decisions)}")
    return _save(fig, plt, out / "decisions.png")


def _save(fig: Any, plt: Any, target: Path) -> Path:
    tmp = target.with_name(f".{target.name}.tmp.png")
    try:
        fig.savefig(tmp, dpi=FIGURE_DPI)
        tmp.replace(target)  # a reader never sees half a figure
    finally:
        plt.close(fig)
        tmp.unlink(missing_ok=True)
    return target


# --------------------------------------------------------------------------------------------------
# summary


def report_head(title: str, data: RunData) -> list[str]:
    """A report's title and the lines that say which journal it reads and how the run stands."""
    return [
        f"# {title}: {data.name}",
        "",
        f"- journal: `{data.path}`",
        f"- state: {data.state}" + ("" if data.finished else " (the engine is still running; a snapshot)"),
        f"- stop reason: {data.stop_reason or '—'}",
    ]


def summary_markdown(data: RunData, figures: list[Path], mape: tuple[float, int] | None) -> str:
    hard = [r.hardness_gpa for r in data.indents if r.measured]
    n_failed = sum(1 for r in data.indents if r.status == "failed")
    n_not_run = sum(1 for r in data.indents if r.status == "not_run")
    unverified = [r for r in data.indents if r.status == "unverified"]
    n_refused = sum(1 for r in unverified if unmeasured_kind(r) == "unverified-refused")
    ops = [c for c in data.commands if c.get("kind") in ("approve", "veto", "adjust")]
    counts: dict[str, int] = defaultdict(int)
    for d in data.decisions:
        counts[decision_who(d, data.resolved_by)] += 1
    unmeasured_text = ""
    if n_failed + len(unverified) + n_not_run:
        unmeasured_text = (
            f"{n_failed} failed"
            + (
                f", {len(unverified)} unverified ({n_refused} made with their export refused, "
                f"{len(unverified) - n_refused} started with no export at all)"
                if unverified
                else ""
            )
            + f" and {n_not_run} not run"
        )
    lines = [
        *report_head("Run report", data),
        f"- policy `{data.policy}`, driver `{data.driver}`, profile `{data.profile_name}`, "
        f"supervision `{data.supervision}`",
        f"- instrument time {data.instrument_s:,.0f} s ({data.instrument_s / 3600:.2f} h)"
        + (f"; the grid baseline would take {data.grid_baseline_s:,.0f} s" if data.grid_baseline_s else ""),
        f"- {len(hard)} indents measured in {len({r.block_id for r in data.indents})} blocks"
        + (f"; {unmeasured_text} (no value, never learnt from)" if unmeasured_text else ""),
    ]
    if hard:
        lines.append(
            f"- measured hardness {min(hard):.3f}–{max(hard):.3f} GPa (median {float(np.median(hard)):.3f} GPa)"
        )
    if data.fast.fast_indents:
        lines += fast_summary_lines(
            data.fast, data.instrument_s, getattr(data.final_maps, "fast_bias_gpa", None)
        )
    mod = [r.modulus_gpa for r in data.indents if r.measured and np.isfinite(r.modulus_gpa)]
    if mod:
        lines.append(
            f"- measured modulus {min(mod):.1f}–{max(mod):.1f} GPa (median {float(np.median(mod)):.1f} GPa)"
        )
    fm = data.final_maps
    if fm is not None and np.isfinite(fm.modulus_mean_gpa).any():
        lines.append(
            "- modulus map: "
            + (
                "planned for beside the hardness (map_weights)"
                if fm.modulus_planned
                else "fitted from the same indents"
            )
            + f"; H/E {np.nanmin(fm.h_over_e):.4f}–{np.nanmax(fm.h_over_e):.4f}"
        )
    lines.append(
        f"- decisions: {len(data.decisions)} ("
        + ", ".join(f"{counts[s]} {DECISION_STYLE[s][2]}" for s in DECISION_STYLE if counts.get(s))
        + f"); {len(ops)} operator commands that steer (approve, veto, adjust)"
    )
    if data.driver == "sim":
        if mape is not None:
            lines.append(
                f"- map error against the simulated truth: MAPE {mape[0]:.2f} % over the {mape[1]} points of "
                "the last stored map"
            )
        else:
            lines.append("- map error against the simulated truth: no model yet")
        e_mape = modulus_mape_pct(data)
        if e_mape is not None:
            lines.append(
                f"- modulus map error against the simulated truth: MAPE {e_mape[0]:.2f} % over the "
                f"{e_mape[1]} candidate points inside the sample"
            )
    else:
        lines.append("- map error: not known (a real sample has no ground truth)")
    if unverified:
        lines += [
            "",
            "## Unverified indents",
            "",
            f"Made, or maybe made, with no value: {n_refused} whose export was refused (the tip went where the "
            f"refused export says), {len(unverified) - n_refused} of arrays confirmed started for which no export "
            "came (taken at the planned place). Never learnt from; their places are kept clear.",
            "",
            "| block | indent | kind | x (µm) | y (µm) | note |",
            "|---:|---:|---|---:|---:|---|",
        ]
        for r in unverified:
            x, y = (
                (r.actual_x_um, r.actual_y_um)
                if math.isfinite(r.actual_x_um) and math.isfinite(r.actual_y_um)
                else (r.commanded_x_um, r.commanded_y_um)
            )
            kind = "export refused" if unmeasured_kind(r) == "unverified-refused" else "no export"
            note = (r.note or "").replace("|", "/")
            lines.append(f"| {r.block_id} | {r.indent_index} | {kind} | {x:.1f} | {y:.1f} | {note} |")
    lines += ["", "## Figures", ""]
    captions = {
        "maps.png": "mean and total sd maps in stage µm as the sample is seen, with the indents and exclusions",
        "modulus.png": "the modulus map: mean, epistemic sd and H/E, with the indents",
        "time.png": "instrument time by category",
        "uncertainty.png": "the model's uncertainty over time",
        "drift.png": "drift readings and the holds used",
        "decisions.png": "decisions, and who took them: the operator, the approval timeout or the engine",
        "bias.png": "the fast channel's learnt bias H_csm − H_fast, with the fast and CSM indents",
    }
    for f in figures:
        lines.append(f"- {captions.get(f.name, f.name)}: ![{f.stem}]({f.name})")
    return "\n".join(lines) + "\n"


def write_report(path: str | Path, out_dir: str | Path) -> list[Path]:
    """Write maps.png, modulus.png, time.png, uncertainty.png, drift.png, decisions.png (bias.png where the run has fast indents) and summary.md to
    ``out_dir``."""
    _pyplot()  # before reading anything: a missing matplotlib is said at once
    with JournalReader(path) as r:
        if journal_tray(r.meta) is not None:
            # one report over several samples would mix their maps and score one against another's truth
            raise InputError(str(path), "a tray run's report is one per sample (aeni_console.reports.tray)")
    return render_report(read_run(path), out_dir)


def render_report(data: RunData, out_dir: str | Path) -> list[Path]:
    """The figures and the summary of a run already read."""

    plt = _pyplot()
    out = check_out_folder(out_dir)
    figures = [
        _map_figure(plt, data, out),
        _modulus_figure(plt, data, out),
        _time_figure(plt, data, out),
        _uncertainty_figure(plt, data, out),
        _drift_figure(plt, data, out),
        _decision_figure(plt, data, out),
    ]
    if data.fast.fast_indents:  # a run with fast arrays: its learnt bias
        figures.append(_bias_figure(plt, data, out))
    summary = out / "summary.md"
    write_atomic(summary, summary_markdown(data, figures, truth_mape_pct(data)))
    return [*figures, summary]

"""The bench report's figures (PNG, matplotlib: the ``report`` extra) and the policies' order and colours.

matplotlib is imported only when a figure is drawn, so ``aeni`` works without it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from aeni_console.bench.harness import BenchConfig, RunRecord, summarise
from core.policies.registry import policy_names

_PALETTE = (
    "#ff7f0e", "#000000", "#7f7f7f", "#1f77b4", "#17becf", "#2ca02c", "#bcbd22", "#d62728",
    "#8c564b", "#e377c2", "#393b79", "#9467bd", "#ff9896", "#8c6d31",
)  # fmt: skip


def policy_order(names: Sequence[str]) -> list[str]:
    """The registry's policies in its order (the recommended one first), then any ablations by name."""
    known = [p for p in policy_names() if p in names]
    return known + sorted(set(names) - set(known))


def policy_color(name: str, names: Sequence[str]) -> str:
    order = policy_order(names)
    return _PALETTE[order.index(name) % len(_PALETTE)] if name in order else "#999999"


LEDGER_COLORS: dict[str, str] = {
    "setup": "#c7c7c7",
    "lift": "#aec7e8",
    "move": "#98df8a",
    "engage": "#ffbb78",
    "drift": "#ff9896",
    "indent": "#1f77b4",
    "hold": "#9467bd",
    "reconfigure": "#d62728",
    "comeback": "#8c564b",
    "recovery": "#e377c2",
}


# -- figures ---------------------------------------------------------------------------------------------


def _step_curves(runs: Sequence[RunRecord], key: str, t_grid: np.ndarray) -> np.ndarray:
    """(runs, times): each run's last value at or before t; NaN before its first point and after it stopped."""
    out = np.full((len(runs), len(t_grid)), np.nan)
    for i, r in enumerate(runs):
        pts = getattr(r, key)
        if not pts:
            continue
        ts = np.array([p[0] for p in pts])
        vs = np.array([p[1] for p in pts])
        j = np.searchsorted(ts, t_grid, side="right") - 1
        ok = (j >= 0) & (t_grid <= r.instrument_s)
        out[i, ok] = vs[j[ok]]
    return out


def _band(curves: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Median and quartiles where at least half of the runs are still running."""
    enough = np.sum(np.isfinite(curves), axis=0) * 2 >= curves.shape[0]
    q = np.full((3, curves.shape[1]), np.nan)
    cols = np.flatnonzero(enough)
    if len(cols):
        q[:, cols] = np.nanquantile(curves[:, cols], [0.25, 0.5, 0.75], axis=0)
    return q[0], q[1], q[2]


def matplotlib_pyplot() -> Any:
    """pyplot on the Agg backend (ImportError without the ``report`` extra)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def figure_curves(records: Sequence[RunRecord], scenario: str, title: str, path: Path) -> None:
    plt = matplotlib_pyplot()
    runs = [r for r in records if r.scenario == scenario]
    names = [r.policy for r in runs]
    policies = policy_order(names)
    t_max = max(r.instrument_s for r in runs)
    t_grid = np.geomspace(2_000.0, t_max, 300)
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(12, 4.4))
    target = np.median([r.target_mape_pct for r in runs if r.policy == "grid" and r.target_mape_pct])
    for p in policies:
        pr = [r for r in runs if r.policy == p]
        c = policy_color(p, names)
        lo, med, hi = _band(_step_curves(pr, "trajectory", t_grid))
        ax1.plot(t_grid / 3600, med, color=c, label=p, lw=1.8)
        ax1.fill_between(t_grid / 3600, lo, hi, color=c, alpha=0.15, lw=0)
        lo, med, hi = _band(_step_curves(pr, "max_found", t_grid))
        ax2.plot(t_grid / 3600, med, color=c, label=p, lw=1.8)
        ax2.fill_between(t_grid / 3600, lo, hi, color=c, alpha=0.15, lw=0)
    ax1.axhline(target, color="k", ls="--", lw=0.8, label="grid's final MAPE")
    ax1.set(xscale="log", yscale="log", xlabel="instrument time (h)", ylabel="MAPE (%)", title="MAPE")
    ax1.grid(True, which="both", alpha=0.3)
    true_max = float(np.median([r.true_max_gpa for r in runs]))
    ax2.axhline(true_max, color="k", ls="--", lw=0.8, label="true maximum")
    ax2.set(xscale="log", xlabel="instrument time (h)", ylabel="GPa", title="maximum hardness found")
    ax2.grid(True, which="both", alpha=0.3)
    from matplotlib.ticker import FixedLocator, NullFormatter, ScalarFormatter

    ticks = [t for t in (0.5, 1, 2, 5, 10, 20, 50, 100, 200) if t <= t_max / 3600 * 1.05]
    for ax in (ax1, ax2):
        ax.xaxis.set_major_locator(FixedLocator(ticks))
        ax.xaxis.set_major_formatter(ScalarFormatter())
        ax.xaxis.set_minor_formatter(NullFormatter())
    ax1.legend(fontsize=8, loc="upper right")
    fig.suptitle(f"{title} — median and inter-quartile band over seeds", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def figure_maps(records: Sequence[RunRecord], scenario: str, title: str, path: Path) -> bool:
    plt = matplotlib_pyplot()
    runs = [r for r in records if r.scenario == scenario and r.maps is not None]
    if not runs:
        return False
    order = policy_order([r.policy for r in runs])
    runs.sort(key=lambda r: order.index(r.policy))
    fields = (
        ("mean", "mean (GPa)"),
        ("epistemic_sd", "epistemic sd"),
        ("noise_sd", "noise sd"),
        ("total_sd", "total sd"),
    )
    first = runs[0].maps
    assert first is not None
    ratio = float(abs(first["y_um"][-1] - first["y_um"][0]) / abs(first["x_um"][-1] - first["x_um"][0]))
    fig, axes = plt.subplots(len(runs), 4, figsize=(15, (0.8 + 3.0 * ratio) * len(runs)), squeeze=False)
    for row, r in zip(axes, runs, strict=True):
        m = r.maps
        assert m is not None
        extent = (m["x_um"][0], m["x_um"][-1], m["y_um"][0], m["y_um"][-1])
        for ax, (k, label) in zip(row, fields, strict=True):
            im = ax.imshow(m[k], origin="lower", extent=extent, aspect="equal", cmap="viridis")
            fig.colorbar(im, ax=ax, shrink=0.75)
            c = m["centres_um"]
            if len(c):
                loc = m["local"][: len(c)]
                ax.scatter(c[~loc, 0], c[~loc, 1], s=9, c="k", marker="o", label="global")
                ax.scatter(c[loc, 0], c[loc, 1], s=7, c="#4fc3f7", marker="s", label="local")
            if m["reverse_x"]:
                ax.invert_xaxis()
            ax.set_title(f"{r.policy}: {label}", fontsize=9)
            ax.tick_params(labelsize=7)
        row[0].set_ylabel("y (µm)")
    for ax in axes[-1]:
        ax.set_xlabel("x (µm)", fontsize=8)
    axes[0][0].legend(fontsize=7, loc="upper right")
    fig.suptitle(f"{title} — final maps, seed 0 (x as the sample is seen)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return True


def figure_costs(records: Sequence[RunRecord], config: BenchConfig, path: Path) -> None:
    plt = matplotlib_pyplot()
    scens = [s for s in config.scenarios if any(r.scenario == s.key for r in records)]
    ncol = min(3, len(scens))
    nrow = math.ceil(len(scens) / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(5.2 * ncol, 3.2 * nrow), squeeze=False)
    summaries = summarise(records)
    for ax, sc in zip(axes.ravel(), scens, strict=False):
        names = policy_order([s.policy for s in summaries if s.scenario == sc.key])
        rows = [s for p in names for s in summaries if s.scenario == sc.key and s.policy == p]
        left = np.zeros(len(rows))
        for cat, color in LEDGER_COLORS.items():
            vals = np.array([r.ledger_s.get(cat, 0.0) for r in rows]) / 3600
            if not vals.any():
                continue
            ax.barh(range(len(rows)), vals, left=left, color=color, label=cat)
            left += vals
        ax.set_yticks(range(len(rows)), [r.policy for r in rows], fontsize=8)
        ax.invert_yaxis()
        ax.set_title(sc.key, fontsize=9)
        ax.set_xlabel("instrument time used (h, median)", fontsize=8)
        ax.tick_params(labelsize=7)
    for ax in axes.ravel()[len(scens) :]:
        ax.axis("off")
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=len(labels), fontsize=8)
    fig.suptitle("Where the time went, per policy (each run until it stopped)", fontsize=10)
    fig.tight_layout(rect=(0, 0.05, 1, 1))
    fig.savefig(path, dpi=100)
    plt.close(fig)

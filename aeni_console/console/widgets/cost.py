"""Cost panel: where the instrument's time went, against the grid baseline's projected time."""

from __future__ import annotations

from rich.table import Table
from rich.text import Text

from aeni_console.console.widgets.base import SnapshotPanel
from aeni_console.console.widgets.fmt import bar, hms, short_duration
from core.runview import RunSnapshot

# (label, ledger categories): the seven, with lift and comeback folded into setup.
ROWS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("setup", ("setup", "lift", "comeback")),
    ("move", ("move",)),
    ("engage", ("engage",)),
    ("drift", ("drift",)),
    ("indents", ("indent",)),
    ("holds", ("hold",)),
    ("reconfig.", ("reconfigure",)),
    ("recovery", ("recovery",)),  # only shown when a crash recovery cost time
)


def cost_rows(ledger: dict[str, float]) -> list[tuple[str, float]]:
    """Seconds per displayed row; the recovery row appears only when non-zero."""
    out = []
    for label, cats in ROWS:
        seconds = sum(float(ledger.get(c, 0.0)) for c in cats)
        if label == "recovery" and seconds <= 0:
            continue
        out.append((label, seconds))
    known = {c for _, cats in ROWS for c in cats}
    other = sum(v for k, v in ledger.items() if k not in known)
    if other > 0:
        out.append(("other", other))
    return out


class CostPanel(SnapshotPanel):
    """Seconds by category, total instrument time and the grid baseline for comparison."""

    BORDER_TITLE = "Cost"

    def show(self, snap: RunSnapshot) -> None:
        self.snap = snap
        rows = cost_rows(snap.ledger)
        total = sum(s for _, s in rows)
        width = max(self.size.width - 2, 20)
        two_cols = self.size.height < len(rows) + 2
        table = Table.grid(padding=(0, 1), expand=True)
        ncol = 2 if two_cols else 1
        for _ in range(ncol):
            table.add_column(style="bold", no_wrap=True)
            table.add_column(justify="right", no_wrap=True)
            if not two_cols:
                table.add_column(justify="right", no_wrap=True, style="dim")
                table.add_column(no_wrap=True, ratio=1)
        if two_cols:
            half = (len(rows) + 1) // 2
            for i in range(half):
                cells: list[str] = []
                for label, secs in (rows[i], rows[i + half] if i + half < len(rows) else ("", 0.0)):
                    cells += [label, hms(secs) if label else ""]
                table.add_row(*cells)
        else:
            bar_w = max(width - 26, 4)
            for label, secs in rows:
                frac = secs / total if total > 0 else 0.0
                table.add_row(label, hms(secs), f"{100 * frac:.0f}%", Text(bar(frac, bar_w), style="cyan"))
        summary = Text(no_wrap=True, overflow="ellipsis")
        share = f"{100 * snap.instrument_s / snap.grid_baseline_s:.1f}%" if snap.grid_baseline_s > 0 else "–"
        if two_cols:
            summary.append("total ", style="bold")
            summary.append(f"{hms(snap.instrument_s)}", style="bold cyan")
            summary.append(f" · grid {short_duration(snap.grid_baseline_s)} ({share})")
        else:
            summary.append("instrument ", style="bold")
            summary.append(f"{hms(snap.instrument_s)}", style="bold cyan")
            summary.append(f"  {snap.n_indents} indents, {snap.reconfigurations} reconfig.\n")
            summary.append("grid baseline ", style="bold")
            summary.append(f"{short_duration(snap.grid_baseline_s)}")
            summary.append(f"  (this run {share} of it)", style="dim")
        outer = Table.grid(expand=True)
        outer.add_column()
        outer.add_row(table)
        outer.add_row(summary)
        self.update(outer)
        self.border_subtitle = short_duration(snap.instrument_s)

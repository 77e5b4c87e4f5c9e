"""Drift panel: the last drift rate, the hold mode and the area error against its threshold."""

from __future__ import annotations

from rich.text import Text

from aeni_console.console.widgets.base import SnapshotPanel
from aeni_console.console.widgets.fmt import bar, hms
from core.runview import RunSnapshot


def drift_text(snap: RunSnapshot, width: int) -> Text:
    d = snap.drift
    t = Text(no_wrap=True, overflow="ellipsis")
    t.append("rate  ", style="bold")
    t.append("–" if d.last_rate_nm_s is None else f"{d.last_rate_nm_s:+.3f} nm/s")
    t.append("  hold ", style="bold")
    t.append(d.hold_mode or "–")
    t.append("\narea  ", style="bold")
    if d.area_error_pct is None:
        t.append("–")
    else:
        over = d.area_error_pct >= d.threshold_pct
        t.append(f"{d.area_error_pct:.2f}% ", style="bold red" if over else "green")
        scale = max(2 * d.threshold_pct, d.area_error_pct)
        w = max(width - 17, 4)
        filled = bar(d.area_error_pct / scale, w)
        mark = int(w * d.threshold_pct / scale)
        t.append(filled[:mark], style="red" if over else "green")
        t.append("│", style="bold")
        t.append(filled[mark:], style="red" if over else "green")
        t.append(f" {d.threshold_pct:g}%", style="dim")
    t.append("\nevents ", style="bold")
    if not d.events:
        t.append("none")
    else:
        t.append(f"{len(d.events)}", style="bold yellow")
        last_t, last_rate = d.events[-1]
        t.append(f", last {last_rate:+.3f} nm/s at {hms(last_t)}")
    return t


class DriftPanel(SnapshotPanel):
    """Last drift rate, hold mode, area error % against the 2 % threshold, drift events."""

    BORDER_TITLE = "Drift"

    def show(self, snap: RunSnapshot) -> None:
        self.snap = snap
        self.update(drift_text(snap, max(self.size.width - 2, 20)))
        over = snap.drift.area_error_pct is not None and snap.drift.area_error_pct >= snap.drift.threshold_pct
        self.set_class(over, "-alert")

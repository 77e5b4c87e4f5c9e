"""Tray panel: the samples of a tray run, each one's progress to its goal, the current one, the time left.

Shown only for a tray run (docs/tray.md); what it shows comes from the journal (core.run.tray_view)."""

from __future__ import annotations

from rich.text import Text

from aeni_console.console.widgets.base import SnapshotPanel
from aeni_console.console.widgets.fmt import bar
from core.run.tray_view import SampleProgress
from core.runview import RunSnapshot


def tray_text(samples: tuple[SampleProgress, ...], width: int) -> Text:
    t = Text(no_wrap=True, overflow="ellipsis")
    name_w = min(max((len(p.name) for p in samples), default=4), 14)
    for k, p in enumerate(samples):
        if k:
            t.append("\n")
        t.append("▶ " if p.current else "  ", style="bold yellow")
        t.append(f"{p.name[:name_w]:<{name_w}} ", style="bold" if p.current else "")
        if p.role == "reference":
            t.append(p.text, style="red" if "FAILED" in p.text else "dim")
            continue
        w = max(min(width - name_w - 30, 16), 4)
        done = bool(p.done)
        t.append(bar(p.fraction or 0.0, w), style="green" if done else "cyan")
        t.append(" ✓ " if done else "   ", style="green")
        t.append(p.text, style="dim" if done else "")
    known = [p.left_s for p in samples if p.role == "library" and not p.done]
    if known:
        left = [s for s in known if s is not None]
        t.append("\ntime left ", style="bold")
        if left:
            more = " + the relative-sd goals" if len(left) < len(known) else ""
            t.append(f"~{sum(left) / 3600:.1f} h of instrument time{more}")
        else:
            t.append("until the maps reach their relative-sd goals")
    return t


class TrayPanel(SnapshotPanel):
    BORDER_TITLE = "Tray"

    def show(self, snap: RunSnapshot) -> None:
        self.snap = snap
        self.display = bool(snap.tray)
        if snap.tray:
            self.update(tray_text(snap.tray, max(self.size.width - 2, 20)))

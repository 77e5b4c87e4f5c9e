"""Queue panel: the indents still to run (current block, then the pending proposal) with ETA."""

from __future__ import annotations

from textual.widgets import DataTable

from aeni_console.console.widgets.fmt import hms, short_duration
from core.runview import RunSnapshot

MAX_ROWS = 60


class QueuePanel(DataTable[str]):
    """Upcoming indents: block, index, position, grid size, hold, ETA on the instrument clock."""

    BORDER_TITLE = "Queue"
    can_focus = False  # the app's keys (← → space …) must never be taken by the table

    def on_mount(self) -> None:
        self.cursor_type = "none"
        self.zebra_stripes = True
        self.show_cursor = False
        self.add_columns("blk.#", "x µm", "y µm", "g", "hold")
        # a fixed width (h:mm:ss up to 99 h): an auto width follows the rows a refresh later, and a screen
        # drawn in between clipped the clock to "7:2"
        self.add_column("ETA", width=8)

    def show(self, snap: RunSnapshot) -> None:
        self.clear()
        pending_id = snap.pending.block.block_id if snap.pending is not None else None
        for item in snap.queue[:MAX_ROWS]:
            waiting = "?" if item.block_id == pending_id else ""
            self.add_row(
                f"{item.block_id}.{item.indent_index + 1}{waiting}",
                f"{item.spec.x_um:.0f}",
                f"{item.spec.y_um:.0f}",
                f"{item.grid_g}",
                f"{item.spec.hold_s:g}s",
                hms(snap.instrument_s + item.eta_s),
            )
        if snap.queue:
            left = snap.queue[-1].eta_s
            more = f" (+{len(snap.queue) - MAX_ROWS} more)" if len(snap.queue) > MAX_ROWS else ""
            self.border_subtitle = f"{len(snap.queue)} indents · {short_duration(left)}{more}"
        else:
            self.border_subtitle = "empty"

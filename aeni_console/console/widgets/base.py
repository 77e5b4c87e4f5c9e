"""The shared shape of the text panels: keep the last snapshot and redraw it when the panel is resized."""

from __future__ import annotations

from textual.widgets import Static

from core.runview import RunSnapshot


class SnapshotPanel(Static):
    snap: RunSnapshot | None = None

    def on_resize(self) -> None:
        if self.snap is not None:
            self.show(self.snap)

    def show(self, snap: RunSnapshot) -> None:
        raise NotImplementedError

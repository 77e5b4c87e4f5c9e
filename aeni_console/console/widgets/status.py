"""The status bar: the state in capitals first, then the clocks and the numbers an operator checks."""

from __future__ import annotations

import time

from rich.text import Text
from textual.widgets import Static

from aeni_console.console.widgets.fmt import hms
from core.runview import EngineState, RunSnapshot

STATE_STYLES: dict[EngineState, str] = {
    EngineState.IDLE: "bold reverse",
    EngineState.RUNNING: "bold black on green",
    EngineState.PAUSED: "bold black on yellow",
    EngineState.AWAITING_APPROVAL: "bold white on magenta",
    EngineState.WAITING_FOR_INSTRUMENT: "bold black on cyan",
    EngineState.STOPPING: "bold black on yellow",
    EngineState.STOPPED: "bold reverse",
    EngineState.FAILED: "bold white on red",
}


def status_text(
    snap: RunSnapshot | None,
    now_s: float,
    width: int,
    replay: tuple[int, int] | None = None,
    note: str = "",
    wall_s: float | None = None,
) -> Text:
    """One line; the least important items go first when the terminal is narrow. ``wall_s`` is the
    session's wall time now, when it has moved on since the snapshot was read."""
    text = Text(no_wrap=True, overflow="ellipsis")
    if snap is None:
        text.append(" CONNECTING ", style="bold reverse")
        text.append(f"  {note}" if note else "  waiting for the run…")
        return text
    label = snap.state.label
    if replay is not None:
        text.append(f" REPLAY {replay[0] + 1}/{replay[1]} ", style="bold black on cyan")
        text.append(" ")
    text.append(f" {label} ", style=STATE_STYLES.get(snap.state, "bold reverse"))
    if snap.gp.collapse_alarm:
        text.append(" ", style="")
        text.append(" ⚠ COLLAPSE ", style="bold white on red")
    items: list[tuple[int, str]] = [  # (priority: lower survives longer, text)
        (0, f"instr {hms(snap.instrument_s)}"),
        (2, f"wall {hms(snap.wall_s if wall_s is None else wall_s)}"),
        (0, f"{snap.n_indents} ind"),
        (1, f"{snap.n_blocks} blk"),
    ]
    n_fast = sum(1 for m in snap.indents if m.channel == "fast")
    if n_fast:  # a run with fast arrays: how many of its indents are fast (issue 36)
        items.insert(3, (1, f"{n_fast} fast"))
    if snap.mape_pct is not None:
        items.append((1, f"MAPE {snap.mape_pct:.1f}%"))
    if snap.gp.lengthscales_um:
        items.append((3, "ℓ " + "×".join(f"{v:.0f}" for v in snap.gp.lengthscales_um) + " µm"))
    if not snap.can_command and replay is None:
        items.append((2, "read-only"))
    items.append((4, snap.supervision))
    items.append((5, time.strftime("%H:%M:%S", time.localtime(now_s))))
    if note:
        items.append((1, note))
    used = len(text.plain)
    for limit in range(5, -1, -1):
        kept = [s for p, s in items if p <= limit]
        if used + sum(len(s) + 3 for s in kept) <= width:
            break
    for s in kept:
        text.append(" │ ", style="dim")
        text.append(s)
    return text


class StatusBar(Static):
    """Top line of the console."""

    DEFAULT_CSS = """
    StatusBar { height: 1; dock: top; background: $panel; }
    """

    _shown: tuple[RunSnapshot | None, float, tuple[int, int] | None, str, float | None] | None = None

    def show(
        self,
        snap: RunSnapshot | None,
        now_s: float,
        replay: tuple[int, int] | None = None,
        note: str = "",
        wall_s: float | None = None,
    ) -> None:
        shown = (snap, now_s, replay, note, wall_s)
        if shown == self._shown:
            return
        self._shown = shown
        self.update(status_text(snap, now_s, self.size.width or 100, replay, note, wall_s))

    def on_resize(self) -> None:
        """The items that fit depend on the width: lay the line out again once it is known or changes."""
        if self._shown is not None:
            shown, self._shown = self._shown, None
            self.show(*shown)

"""Log panel: the run's events (decisions, commands, warnings), newest at the bottom."""

from __future__ import annotations

from rich.text import Text
from textual import events
from textual.widgets import RichLog

from aeni_console.console.widgets.fmt import hms
from core.runview import LogEvent

LEVEL_STYLES = {
    "info": "",
    "warn": "yellow",
    "error": "bold red",
    "command": "cyan",
    "decision": "magenta",
    "console": "dim italic",
}


def event_key(e: LogEvent) -> tuple[str, float, str, str]:
    return (e.wall_utc, e.t_s, e.level, e.text)


def event_text(e: LogEvent) -> Text:
    clock = e.wall_utc[11:19] if len(e.wall_utc) >= 19 else e.wall_utc
    t = Text(no_wrap=False)
    t.append(f"{clock} ", style="dim")
    t.append(f"{hms(e.t_s):>8} ", style="dim")
    t.append(e.text, style=LEVEL_STYLES.get(e.level, ""))
    return t


class LogPanel(RichLog):
    """Events of the run; appends only what is new, rewrites when the run's history changes (replay)."""

    BORDER_TITLE = "Log"
    can_focus = False

    def __init__(self, **kwargs: object) -> None:
        super().__init__(wrap=True, markup=False, highlight=False, max_lines=2000, min_width=20, **kwargs)  # type: ignore[arg-type]
        self._shown: list[tuple[str, float, str, str]] = []
        self._lines: list[Text] = []  # what was written, to wrap again at a new width
        self._width = 0

    def _add(self, line: Text) -> None:
        self._lines.append(line)
        del self._lines[:-2000]
        self.write(line)

    def on_resize(self, event: events.Resize) -> None:
        """Lines are wrapped when written: at a new width (an SSH window resized, or the first layout) they are
        written again, so no line keeps the wrap of a width the panel no longer has."""
        if event.size.width == self._width:
            return
        self._width = event.size.width
        if self._lines:
            self.clear()
            for line in self._lines:
                self.write(line)

    def show_events(self, events: tuple[LogEvent, ...]) -> None:
        keys = [event_key(e) for e in events]
        start = None
        if self._shown and keys:
            last = self._shown[-1]
            if last in keys:
                start = len(keys) - keys[::-1].index(last)
        if start is None or (not keys and self._shown):
            self.clear()
            self._shown = []
            self._lines = []
            start = 0
        for e in events[start:]:
            self._add(event_text(e))
        self._shown.extend(keys[start:])
        self._shown = self._shown[-2000:]

    def note(self, text: str, level: str = "console") -> None:
        """A line from the console itself (a command sent, an error), not from the run's journal."""
        t = Text()
        t.append("console  ", style="dim")
        t.append(text, style=LEVEL_STYLES.get(level, ""))
        self._add(t)

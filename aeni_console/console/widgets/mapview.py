"""Map panel: the GP's fields as a coloured heatmap, built in a worker thread and swapped in whole.

The UI thread never builds a picture: it asks a thread worker for one (after new fields, a resize or
``m``), and the worker posts back a finished ``HeatmapImage``; a newer request supersedes older ones.
"""

from __future__ import annotations

import threading

from rich.console import Console
from rich.segment import Segment
from rich.style import Style
from rich.text import Text
from textual import work
from textual.app import ComposeResult
from textual.containers import Vertical
from textual.message import Message
from textual.strip import Strip
from textual.widget import Widget
from textual.widgets import Static

from aeni_console.console.heatmap import (
    FIELD_LABELS,
    FIELD_UNITS,
    LEGEND,
    MARK_EARLIER,
    MARK_EXCLUDED,
    MARK_FAST,
    MARK_MEASURED,
    MARK_NEWEST,
    MARK_OUTLINE,
    MARK_PLANNED,
    STATUS_MARKS,
    HeatmapImage,
    MapMarks,
    field_keys_of,
    mark_of,
    marks_for,
    render_heatmap,
)
from core.runview import MapFields, RunSnapshot

# plotext keeps some drawing state at module level: two builds at once (a resize during a refit) could
# mix their axes, so builds take turns
_BUILD_LOCK = threading.Lock()

_SEGMENT_CONSOLE = Console(color_system="truecolor", force_terminal=True, width=1000, legacy_windows=False)


def to_strips(text: Text) -> list[Strip]:
    """Rich Text to Textual strips (done in the worker, so the UI thread only copies finished lines)."""
    options = _SEGMENT_CONSOLE.options.update(width=max(text.cell_len, 1), no_wrap=True, overflow="crop")
    return [Strip(line).simplify() for line in _SEGMENT_CONSOLE.render_lines(text, options, pad=False)]


class HeatmapView(Widget):
    """Shows the last finished picture (Line API over pre-rendered strips): never a plot build, never a
    Rich render on the UI thread."""

    DEFAULT_CSS = """
    HeatmapView { width: 1fr; height: 1fr; }
    """

    def __init__(self, **kwargs: object) -> None:
        super().__init__(**kwargs)  # type: ignore[arg-type]
        self.image: HeatmapImage | None = None
        self._text: Text = Text("waiting for the first GP fit…", style="dim")
        self._strips: list[Strip] = []
        self._cache: dict[tuple[int, int], Strip] = {}

    def on_resize(self) -> None:
        """The legend above may take another line: the picture is drawn again for the new size."""
        if isinstance(self.parent, MapPanel):
            self.parent.request()

    def set_image(self, image: HeatmapImage, strips: list[Strip]) -> None:
        self.image = image
        self._text = image.text
        self._strips = strips
        self._cache.clear()
        self.refresh()

    def render_line(self, y: int) -> Strip:
        width = self.size.width
        key = (y, width)
        cached = self._cache.get(key)
        if cached is not None:
            return cached
        base = self.rich_style
        if not self._strips:
            strip = Strip([Segment(self._text.plain, Style(dim=True))]) if y == 0 else Strip.blank(0)
        else:
            strip = self._strips[y] if y < len(self._strips) else Strip.blank(0)
        out = strip.crop_extend(0, width, base).apply_style(base)
        self._cache[key] = out
        return out


class MapPanel(Vertical):
    """Heatmaps of mean, epistemic sd, noise sd and total sd (``m`` cycles), with the sample's edge and
    exclusions, earlier indents, every indent of the run by status, and the sites still to run."""

    BORDER_TITLE = "Map"

    class ImageReady(Message):
        def __init__(self, image: HeatmapImage, generation: int, strips: list[Strip]) -> None:
            super().__init__()
            self.image = image
            self.generation = generation
            self.strips = strips

    def __init__(self, no_color: bool = False, **kwargs: object) -> None:
        super().__init__(**kwargs)  # type: ignore[arg-type]
        self.no_color = no_color
        self.field_index = 0
        self.fields: MapFields | None = None
        self.snap: RunSnapshot | None = None
        self.marks = MapMarks()
        self.generation = 0
        self.builds = 0  # finished builds (tests and the benchmark read it)
        self.applied_generation = 0
        self._want: tuple[object, ...] | None = None

    def compose(self) -> ComposeResult:
        yield HeatmapView(id="heatmap")
        yield Static(self._legend(), id="map-legend")

    @property
    def field_key(self) -> str:
        keys = field_keys_of(self.fields)
        return keys[self.field_index % len(keys)]

    def _legend(self) -> Text:
        """One entry per meaning drawn on this map (it wraps to a second line on a narrow panel)."""
        marks = self.marks
        present = {MARK_OUTLINE: bool(marks.outline_um), MARK_EXCLUDED: bool(marks.exclusions)}
        present[MARK_EARLIER] = bool(marks.earlier_um)
        statuses = {m.status for m in marks.indents}
        for status, mark in STATUS_MARKS.items():
            present[mark] = status in statuses
        present[MARK_MEASURED] = any(m.status == "measured" and m.channel != "fast" for m in marks.indents)
        present[MARK_FAST] = any(m.status == "measured" and m.channel == "fast" for m in marks.indents)
        present[MARK_NEWEST] = any(mark_of(m, marks.newest_block_id) is MARK_NEWEST for m in marks.indents)
        present[MARK_PLANNED] = bool(marks.planned_um)
        width = max(self.size.width - 2, 20) if self.size.width else 1000
        t = Text(no_wrap=True, overflow="ellipsis")
        used = 0
        for mark, word in LEGEND:
            if not present.get(mark):
                continue
            entry = len(word) + 3
            if used and used + entry > width:  # a mark and its word stay on one line
                t.append("\n")
                used = 0
            t.append(mark[1] if self.no_color else mark[0], style="bold" if mark is MARK_NEWEST else "")
            t.append(f" {word} ")
            used += entry
        if not t.plain:
            t.append("no indents yet", style="dim")
        return t

    def _show_legend(self) -> None:
        legends = self.query("#map-legend")
        if legends:
            legends.first(Static).update(self._legend())

    def on_mount(self) -> None:
        self._titles()

    def _titles(self) -> None:
        self.border_title = f"Map · {FIELD_LABELS[self.field_key]} ({FIELD_UNITS[self.field_key]})"
        sid = self.fields.snapshot_id if self.fields is not None else None
        self.border_subtitle = f"fit {sid}" if sid is not None else "no fit yet"

    def cycle(self) -> str:
        self.field_index = (self.field_index + 1) % len(field_keys_of(self.fields))
        self._titles()
        self.request()
        return self.field_key

    def set_fields(self, fields: MapFields) -> None:
        self.fields = fields
        self._titles()
        self.request()

    def set_snapshot(self, snap: RunSnapshot) -> None:
        old = self.snap
        self.snap = snap
        if (
            old is None
            or old.indents != snap.indents
            or old.sample != snap.sample
            or old.reverse_x != snap.reverse_x
            or old.pending != snap.pending
            or old.queue != snap.queue
        ):
            marks = marks_for(snap)
            if marks != self.marks:
                self.marks = marks
                self._show_legend()
            self.request()

    def on_resize(self) -> None:
        self._show_legend()
        self.request()

    def request(self) -> None:
        """Ask for a new picture if anything it depends on changed."""
        if self.snap is None or not self.is_mounted:
            return
        views = self.query(HeatmapView)
        if not views:
            return  # leaving: the view is already unmounted
        view = views.first()
        width, height = view.size.width, view.size.height
        if width < 8 or height < 5:
            return
        key = (
            self.field_key,
            width,
            height,
            self.fields.snapshot_id if self.fields is not None else None,
            id(self.fields),
            self.marks,
            self.snap.reverse_x,
        )
        if key == self._want:
            return
        self._want = key
        self.generation += 1
        self._build(self.generation, width, height, self.snap, self.fields, self.field_key, self.marks)

    @work(thread=True, group="heatmap")
    def _build(
        self,
        generation: int,
        width: int,
        height: int,
        snap: RunSnapshot,
        fields: MapFields | None,
        field_key: str,
        marks: MapMarks,
    ) -> None:
        with _BUILD_LOCK:
            image = self._draw(width, height, snap, fields, field_key, marks)
        self.post_message(self.ImageReady(image, generation, to_strips(image.text)))

    def _draw(
        self,
        width: int,
        height: int,
        snap: RunSnapshot,
        fields: MapFields | None,
        field_key: str,
        marks: MapMarks,
    ) -> HeatmapImage:
        return render_heatmap(
            fields,
            field_key,
            width,
            height,
            snap.stage_bounds_um,
            marks=marks,
            reverse_x=snap.reverse_x,
            no_color=self.no_color,
        )

    def on_map_panel_image_ready(self, message: ImageReady) -> None:
        message.stop()
        if message.generation != self.generation:
            return  # a newer picture is on its way
        self.builds += 1
        self.applied_generation = message.generation
        self.query_one(HeatmapView).set_image(message.image, message.strips)

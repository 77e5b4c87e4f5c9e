"""Helpers that drive the console headless (tests, the latency benchmark, the screenshot script)."""

from __future__ import annotations

import time
from collections.abc import Callable

from textual.pilot import Pilot

from aeni_console.fake import FakeRun
from aeni_console.widgets.mapview import MapPanel


async def wait_until(
    pilot: Pilot[None], cond: Callable[[], bool], timeout_s: float = 10.0, what: str = ""
) -> None:
    """Let the app run until ``cond()`` holds; a clear error instead of a hang when it never does."""
    deadline = time.monotonic() + timeout_s
    while not cond():
        if time.monotonic() > deadline:
            raise TimeoutError(f"console did not reach: {what or cond}")
        await pilot.pause(0.02)


def map_settled(app: object) -> bool:
    """The snapshot is shown and the heatmap drawn from the fields of its last fit, with nothing in flight."""
    snap = getattr(app, "snapshot", None)
    if snap is None:
        return False
    panel = app.query_one(MapPanel)  # type: ignore[attr-defined]
    sid = snap.gp.snapshot_id
    feed = getattr(app, "feed", None)
    if sid is not None:
        if feed is not None and feed.map_checked_id != sid:
            return False  # the fields of this fit are still being looked up
        if feed is None and getattr(app, "replay_loaded", None) != getattr(app, "replay_index", None):
            return False
        has_fields: set[int] = getattr(app, "fields_seen", set())
        if sid in has_fields and (panel.fields is None or panel.fields.snapshot_id != sid):
            return False
    if panel.builds == 0 or panel.applied_generation != panel.generation:
        return False
    return panel._want is not None and panel._want[5] == snap.tested


def in_sync(app: object) -> bool:
    """For the in-memory fake (whose snapshots are deterministic): the console shows the latest one."""
    source = getattr(app, "source", None)
    if not isinstance(source, FakeRun) or getattr(app, "replay_mode", False):
        return True
    return getattr(app, "snapshot", None) == source.snapshot()


def footer_synced(app: object) -> bool:
    """The footer shows exactly the keys that apply now (it recomposes a moment after a state change)."""
    from textual.widgets import Footer
    from textual.widgets._footer import FooterKey

    screen = app.screen  # type: ignore[attr-defined]
    try:
        footer = screen.query_one(Footer)
    except Exception:
        return True  # a modal screen without a footer
    shown = {k.action for k in footer.query(FooterKey)}
    want = {b.binding.action for b in screen.active_bindings.values() if b.binding.show}
    return shown == want


async def settle(pilot: Pilot[None], timeout_s: float = 10.0) -> None:
    """Wait until the console shows the source's current state completely (for snapshots and asserts)."""
    app = pilot.app
    feed = getattr(app, "feed", None)
    if feed is not None:
        feed.poke()
    await wait_until(pilot, lambda: in_sync(app), timeout_s, "the source's latest snapshot shown")
    await wait_until(pilot, lambda: map_settled(app), timeout_s, "snapshot and heatmap shown")
    await pilot.pause(0.05)
    await wait_until(pilot, lambda: map_settled(app), timeout_s, "snapshot and heatmap shown")
    await wait_until(pilot, lambda: footer_synced(app), timeout_s, "footer shows the valid keys")
    await pilot.pause()


def widget_text(widget: object) -> str:
    """What a widget shows on screen right now, as plain text (border and title included)."""
    from textual.geometry import Region

    region = widget.region  # type: ignore[attr-defined]
    strips = widget.render_lines(Region(0, 0, region.width, region.height))  # type: ignore[attr-defined]
    return "\n".join(strip.text for strip in strips)

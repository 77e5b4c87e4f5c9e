"""Console responsiveness: keypress-to-screen latency during a running demo, and heatmap redraw cost.

    python benchmarks/console_latency.py              # a real engine process (auto, ×200) + headless console
    python benchmarks/console_latency.py --in-process # the test harness's engine, one indent every 50 ms

Prints one table (medians and 90th percentiles over the presses). Latencies are measured from the key
event to the moment the frame that shows its effect has been composed, on a 100×30 headless console
while snapshots keep arriving from the feed. Nothing here is asserted: numbers vary with the machine.
"""

from __future__ import annotations

import argparse
import asyncio
import statistics
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402
from textual import events  # noqa: E402

from aeni_console.console.app import ConsoleApp  # noqa: E402
from aeni_console.console.heatmap import FIELD_KEYS, MapMarks, render_heatmap  # noqa: E402
from aeni_console.console.widgets.help import HelpScreen  # noqa: E402
from aeni_console.console.widgets.mapview import HeatmapView, MapPanel  # noqa: E402
from aeni_console.testkit.live import settle, wait_until  # noqa: E402
from core.runview import IndentMark, MapFields  # noqa: E402


def pct(values: list[float], q: float) -> float:
    return float(np.percentile(values, q)) if values else float("nan")


def heatmap_cost(n: int = 50, repeats: int = 40) -> dict[str, list[float]]:
    """A 50×50 field: the worker's build (plotext + strips) at two panel sizes, and the UI thread's share
    (copying the finished strips into the frame)."""
    from rich.style import Style

    from aeni_console.console.widgets.mapview import to_strips

    xs = np.linspace(0, 1000, n)
    xx, yy = np.meshgrid(xs, xs)
    mean = 3 + 4 * np.exp(-((xx - 200) ** 2 + (yy - 300) ** 2) / 1e5)
    fields = MapFields(1, xs, xs.copy(), mean, mean * 0.05, mean * 0.02, mean * 0.06, (500.0, 500.0))
    rng = np.random.default_rng(0)
    indents = tuple(
        IndentMark(float(x), float(y), i // 16, ("measured", "failed", "not_run")[i % 3])
        for i, (x, y) in enumerate(rng.uniform(0, 1000, (272, 2)))
    )
    marks = MapMarks(
        outline_um=((0.0, 1000.0), (1000.0, 1000.0), (1000.0, 0.0), (0.0, 0.0)),
        indents=indents,
        planned_um=(tuple((float(x), float(y)) for x, y in rng.uniform(0, 1000, (16, 2))),),
        newest_block_id=16,
    )
    out: dict[str, list[float]] = {}
    render_heatmap(fields, "mean", 48, 18, (0, 1000, 0, 1000))  # import plotext once, outside the timing
    base = Style(bgcolor="rgb(30,30,30)")
    for label, (w, h) in (("48×18 (100×30 console)", (48, 18)), ("96×40 (large terminal)", (96, 40))):
        build, ui = [], []
        for _ in range(repeats):
            t0 = time.perf_counter()
            img = render_heatmap(fields, "mean", w, h, (0, 1000, 0, 1000), marks, reverse_x=True)
            strips = to_strips(img.text)
            build.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            for strip in strips:  # what HeatmapView.render_line does once per line after a swap
                strip.crop_extend(0, w, base).apply_style(base)
            ui.append(time.perf_counter() - t0)
        out[f"50×50 heatmap {label}: worker build"] = build
        out[f"50×50 heatmap {label}: UI-thread draw"] = ui
    return out


async def measure_keys(app: ConsoleApp, presses: int, size: tuple[int, int]) -> dict[str, list[float]]:
    """Key events go in the way a terminal driver delivers them; a latency ends at the first frame the
    app composes that shows the key's effect (the headless driver skips only the final terminal write)."""
    results: dict[str, list[float]] = {
        "key m → title": [],
        "key m → new heatmap": [],
        "key ? → help": [],
        "key esc → help closed": [],
        "snapshot apply (UI thread)": [],
    }
    waiting: dict[str, tuple[float, Callable[[], bool]]] = {}
    original_apply = app.apply_snapshot
    original_display = app._display

    def timed_apply(snap):  # type: ignore[no-untyped-def]
        t0 = time.perf_counter()
        original_apply(snap)
        results["snapshot apply (UI thread)"].append(time.perf_counter() - t0)

    def display(screen, renderable):  # type: ignore[no-untyped-def]
        original_display(screen, renderable)
        now = time.perf_counter()
        for name, (t0, cond) in list(waiting.items()):
            if cond():
                results[name].append(now - t0)
                del waiting[name]

    app.apply_snapshot = timed_apply  # type: ignore[method-assign]
    app._display = display  # type: ignore[method-assign]

    async def key(name: str, char: str | None, expect: dict[str, Callable[[], bool]]) -> None:
        t0 = time.perf_counter()
        for label, cond in expect.items():
            waiting[label] = (t0, cond)
        app.post_message(events.Key(name, char))
        deadline = time.monotonic() + 10
        while any(label in waiting for label in expect):
            if time.monotonic() > deadline:
                raise TimeoutError(f"no frame showed the effect of {name!r}")
            await asyncio.sleep(0.001)

    async with app.run_test(size=size) as pilot:
        await wait_until(
            pilot,
            lambda: app.snapshot is not None and app.snapshot.gp.snapshot_id is not None,
            120,
            "a first GP fit",
        )
        await settle(pilot, timeout_s=60)
        panel = app.query_one(MapPanel)
        view = app.query_one(HeatmapView)
        for _ in range(presses):
            title = str(panel.border_title)
            builds = panel.builds
            nxt = FIELD_KEYS[(panel.field_index + 1) % len(FIELD_KEYS)]
            await key(
                "m",
                "m",
                {
                    "key m → title": lambda t=title: str(panel.border_title) != t,  # type: ignore[misc]
                    "key m → new heatmap": lambda b=builds, k=nxt: (
                        panel.builds > b and view.image is not None and view.image.field_key == k
                    ),  # type: ignore[misc]
                },
            )
            await key("question_mark", "?", {"key ? → help": lambda: isinstance(app.screen, HelpScreen)})
            await key(
                "escape", None, {"key esc → help closed": lambda: not isinstance(app.screen, HelpScreen)}
            )
            await asyncio.sleep(0.1)
    return results


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "--in-process",
        action="store_true",
        help="the console tests' engine in this process (one indent every 50 ms) instead of an engine process",
    )
    ap.add_argument("--speed", type=float, default=200.0, help="engine speed factor (default 200)")
    ap.add_argument("--presses", type=int, default=25)
    args = ap.parse_args()

    rows: dict[str, list[float]] = {}
    rows.update(heatmap_cost())

    proc = None
    stop = threading.Event()
    with tempfile.TemporaryDirectory() as tmp:
        if args.in_process:
            from aeni_console.testkit.live import LiveRun

            run = LiveRun(tmp, supervision="auto", name="bench")
            run.start()
            source = run.source()

            def tick() -> None:
                while not stop.is_set() and not run.ended:
                    run.advance(1)
                    time.sleep(0.05)

            threading.Thread(target=tick, daemon=True).start()
            where = "in-process engine, one indent every 50 ms"
        else:
            from aeni_console.cli.run import start_engine_process
            from aeni_console.console.journal_source import JournalSource
            from core.campaign_config import CampaignConfig

            journal = Path(tmp) / "bench.sqlite"
            proc = start_engine_process(CampaignConfig(name="bench", seed=0), journal, "auto", args.speed)
            source = JournalSource(journal)
            where = f"engine process, auto, speed ×{args.speed:g}"
        try:
            app = ConsoleApp(source)
            rows.update(asyncio.run(measure_keys(app, args.presses, (100, 30))))
            posted = app.feed.posted if app.feed is not None else 0
        finally:
            stop.set()
            if args.in_process:
                run.close()
            if proc is not None and not isinstance(proc, int):
                proc.terminate()
                proc.wait(timeout=30)

    import os

    title = (
        f"AE-NI console latency ({where}; 100×30 headless; {args.presses} presses; {posted} snapshots fed)"
    )
    print(title)
    print(f"{'measure':<56} {'n':>4} {'median ms':>10} {'p90 ms':>9}")
    md = [f"# {title}", "", f"Load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores.", ""]
    md += ["| measure | n | median ms | p90 ms |", "|---|---:|---:|---:|"]
    for name, vals in rows.items():
        ms = [v * 1000 for v in vals]
        print(f"{name:<56} {len(ms):>4} {statistics.median(ms):>10.2f} {pct(ms, 90):>9.2f}")
        md.append(f"| {name} | {len(ms)} | {statistics.median(ms):.2f} | {pct(ms, 90):.2f} |")
    out = ROOT / "benchmarks" / "results"
    out.mkdir(parents=True, exist_ok=True)
    (out / "console_latency.md").write_text("\n".join(md) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Write screenshots/*.svg: the console's main screens on a deterministic run of the real engine.

    python scripts/make_screenshots.py [--out screenshots] [--seed 0] [--blocks 8]

The run is the console tests' ``LiveRun``: the real engine, campaign and journal on the ternary emulator
(supervised, fixed seed), the simulated instrument advanced by this script, and the journal's wall clock
tied to the instrument clock. A headless console attached to it approves the planner's proposals until
the map has some history, then each screen is captured as SVG: the proposal waiting for approval
(80×24 and 100×30), another GP field, the adjust form, help, a paused run, the abort confirmation, and
the finished run in replay. The same seed gives the same files, byte for byte.
"""

from __future__ import annotations

import argparse
import asyncio
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from aeni_console.console.app import ConsoleApp  # noqa: E402
from aeni_console.console.widgets.adjust import AdjustScreen  # noqa: E402
from aeni_console.console.widgets.confirm import ConfirmScreen  # noqa: E402
from aeni_console.console.widgets.help import HelpScreen  # noqa: E402
from aeni_console.testkit.live import FIXED_WALL_UNIX, LiveRun, settle, wait_until  # noqa: E402
from core.runview import EngineState  # noqa: E402

FIXED_CLOCK = FIXED_WALL_UNIX  # the status bar's time of day: 2025-01-01 10:00 UTC


def _state(app: ConsoleApp) -> EngineState | None:
    return app.snapshot.state if app.snapshot is not None else None


async def shoot(app: ConsoleApp, pilot, path: Path) -> None:  # type: ignore[no-untyped-def]
    app.clear_notifications()
    await pilot.pause()
    path.write_text(app.export_screenshot(title="AE-NI console"), encoding="utf-8")
    print(f"wrote {path}")


def console(run: LiveRun) -> ConsoleApp:
    return ConsoleApp(
        run.source(), poll_s=0.05, clock=lambda: FIXED_CLOCK, author="operator", cursor_blink=False
    )


async def approve_until(run: LiveRun, min_blocks: int) -> None:
    """Approve every proposal, with the console's key, until ``min_blocks`` are done and a jump waits."""
    app = console(run)
    async with app.run_test(size=(100, 30)) as pilot:
        while True:
            snap = run.until_awaiting()
            if snap.n_blocks >= min_blocks and snap.gp.snapshot_id is not None:
                break
            await wait_until(pilot, lambda s=snap: app.snapshot == s, 60, "the proposal shown")  # type: ignore[misc]
            await pilot.press("a")
            await wait_until(pilot, lambda: _state(app) is EngineState.RUNNING, 60, "approval taken")


async def waiting_80x24(run: LiveRun, out: Path) -> None:
    app = console(run)
    async with app.run_test(size=(80, 24)) as pilot:
        await settle(pilot, timeout_s=60)
        await shoot(app, pilot, out / "awaiting-approval-80x24.svg")
        await pilot.press("q")  # leaving the console does not stop the run


async def live_screens(run: LiveRun, out: Path) -> None:
    app = console(run)
    async with app.run_test(size=(100, 30)) as pilot:
        await settle(pilot, timeout_s=60)
        await shoot(app, pilot, out / "awaiting-approval.svg")
        for _ in range(3):
            await pilot.press("m")
        await settle(pilot, timeout_s=60)
        await shoot(app, pilot, out / "map-total-sd.svg")
        await pilot.press("m")
        await settle(pilot, timeout_s=60)
        await pilot.press("e")
        await wait_until(pilot, lambda: isinstance(app.screen, AdjustScreen), 10, "adjust form")
        await shoot(app, pilot, out / "adjust.svg")
        await pilot.press("escape")
        await pilot.press("question_mark")
        await wait_until(pilot, lambda: isinstance(app.screen, HelpScreen), 10, "help")
        await shoot(app, pilot, out / "help.svg")
        await pilot.press("escape")
        await pilot.press("space")  # pause while the proposal waits
        await wait_until(pilot, lambda: _state(app) is EngineState.PAUSED, 60, "paused")
        await settle(pilot, timeout_s=60)
        await shoot(app, pilot, out / "paused.svg")
        await pilot.press("x")
        await wait_until(pilot, lambda: isinstance(app.screen, ConfirmScreen), 10, "abort confirmation")
        await shoot(app, pilot, out / "abort-confirm.svg")
        await pilot.press("y")
        await wait_until(pilot, lambda: app.snapshot is not None and app.snapshot.finished, 120, "stopped")


async def replay_screen(run: LiveRun, out: Path) -> None:
    source = run.replay()
    app = ConsoleApp(source, replay=True, clock=lambda: FIXED_CLOCK, cursor_blink=False)
    try:
        async with app.run_test(size=(100, 30)) as pilot:
            await wait_until(pilot, lambda: app.replay_count > 0 and app.snapshot is not None, 60, "replay")
            target = max(app.replay_count - 4, 0)
            await pilot.press("home")
            for _ in range(target):
                await pilot.press("right")
            await wait_until(pilot, lambda: app.snapshot.n_blocks == target + 1, 30, "replay position")
            await settle(pilot, timeout_s=60)
            await shoot(app, pilot, out / "replay.svg")
    finally:
        source.close()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=ROOT / "screenshots")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--blocks", type=int, default=8, help="blocks to run before the screenshots")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    # the scenario's own lattice and the engine's display grid: the screens of a real run
    with (
        tempfile.TemporaryDirectory() as tmp,
        LiveRun(tmp, seed=args.seed, lattice_n=None, display_n=50, name="screenshots") as run,
    ):
        asyncio.run(approve_until(run, args.blocks))
        asyncio.run(waiting_80x24(run, args.out))
        asyncio.run(live_screens(run, args.out))
        run.wait_quiet()
        asyncio.run(replay_screen(run, args.out))
    return 0


if __name__ == "__main__":
    sys.exit(main())

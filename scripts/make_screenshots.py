"""Write screenshots/*.svg: the console's main screens on a deterministic emulator run.

    python scripts/make_screenshots.py [--out screenshots] [--seed 0]

A real engine process runs the ternary emulator (supervised, as fast as it can, fixed seed) on a
temporary journal; a headless console attached to it approves the planner's proposals until the map
has some history, then each screen is captured as SVG: the proposal waiting for approval (100×30 and
80×24), another GP field, the adjust form, help, a paused run, and the finished run in replay. The
planner's choices and the numbers come from the seed; only wall-clock times differ between runs.
"""

from __future__ import annotations

import argparse
import asyncio
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from aeni_console.app import ConsoleApp  # noqa: E402
from aeni_console.journal_source import JournalReplay, JournalSource  # noqa: E402
from aeni_console.testing import settle, wait_until  # noqa: E402
from aeni_console.widgets.adjust import AdjustScreen  # noqa: E402
from aeni_console.widgets.confirm import ConfirmScreen  # noqa: E402
from aeni_console.widgets.help import HelpScreen  # noqa: E402
from core.runview import EngineState  # noqa: E402

FIXED_CLOCK = 1_735_725_600.0  # the status bar's time of day: 2025-01-01 10:00 UTC


def _state(app: ConsoleApp) -> EngineState | None:
    return app.snapshot.state if app.snapshot is not None else None


async def shoot(app: ConsoleApp, pilot, path: Path) -> None:  # type: ignore[no-untyped-def]
    app.clear_notifications()
    await pilot.pause()
    path.write_text(app.export_screenshot(title="AE-NI console"), encoding="utf-8")
    print(f"wrote {path}")


async def live_screens(journal: Path, out: Path, min_blocks: int, size: tuple[int, int], tag: str) -> None:
    source = JournalSource(journal)
    app = ConsoleApp(source, poll_s=0.05, clock=lambda: FIXED_CLOCK, author="operator", cursor_blink=False)
    try:
        async with app.run_test(size=size) as pilot:
            while True:  # approve until the map has history and a global jump waits
                await wait_until(
                    pilot, lambda: _state(app) is EngineState.AWAITING_APPROVAL, 300, "a proposal"
                )
                snap = app.snapshot
                assert snap is not None
                if (
                    snap.n_blocks >= min_blocks
                    and snap.pending is not None
                    and snap.gp.snapshot_id is not None
                ):
                    break
                before = snap.pending
                await pilot.press("a")
                await wait_until(pilot, lambda b=before: app.snapshot.pending != b, 300, "approval taken")  # type: ignore[misc]
            await settle(pilot, timeout_s=60)
            await shoot(app, pilot, out / f"awaiting-approval{tag}.svg")
            if tag:
                return
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
            await wait_until(
                pilot, lambda: app.snapshot is not None and app.snapshot.finished, 120, "stopped"
            )
    finally:
        source.close()


async def replay_screen(journal: Path, out: Path) -> None:
    source = JournalReplay(journal)
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


def run_engine(journal: Path, seed: int) -> subprocess.Popen[bytes]:
    from aeni_console.commands.run import start_engine_process
    from core.campaign import CampaignConfig

    proc = start_engine_process(CampaignConfig(name="screenshots", seed=seed), journal, "supervised", None)
    assert isinstance(proc, subprocess.Popen)
    return proc


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=ROOT / "screenshots")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--blocks", type=int, default=8, help="blocks to run before the screenshots")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        for tag, size in (("-80x24", (80, 24)), ("", (100, 30))):
            journal = Path(tmp) / f"screens{tag}.sqlite"
            proc = run_engine(journal, args.seed)
            try:
                asyncio.run(live_screens(journal, args.out, args.blocks, size, tag))
            finally:
                if proc.poll() is None:
                    proc.terminate()
                proc.wait(timeout=60)
        asyncio.run(replay_screen(Path(tmp) / "screens.sqlite", args.out))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Screenshots of WAITING FOR INSTRUMENT (the KLA driver's ticket panel) at 80×24 and 100×30.

A real engine process runs the ternary emulator campaign with ``--driver kla`` on a temporary exchange
folder; no instrument answers, so the first block waits for it. The console's clock is pinned 12 min 34 s
after the ticket was written, so the countdown is the same on every run (only the token and the run's
time stamps differ, and the token is never shown).

    python scripts/make_kla_screenshots.py [--out screenshots]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import subprocess
import sys
import tempfile
import time
from datetime import datetime
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from aeni_console.cli.run import start_engine_process  # noqa: E402
from aeni_console.console.app import ConsoleApp  # noqa: E402
from aeni_console.console.journal_source import JournalSource  # noqa: E402
from aeni_console.testkit.live import wait_until, widget_text  # noqa: E402
from core.campaign_config import CampaignConfig  # noqa: E402
from core.runview import EngineState  # noqa: E402

SHOTS = (("waiting-for-instrument-80x24.svg", (80, 24)), ("waiting-for-instrument.svg", (100, 30)))


async def shoot(journal: Path, ticket: Path, out: Path, size: tuple[int, int]) -> None:
    created = datetime.fromisoformat(json.loads(ticket.read_text())["created_utc"]).timestamp()
    app = ConsoleApp(
        JournalSource(journal),
        poll_s=0.05,
        author="operator",
        cursor_blink=False,
        clock=lambda: created + 754.0,
    )
    async with app.run_test(size=size) as pilot:
        await wait_until(
            pilot,
            lambda: app.snapshot is not None and app.snapshot.state is EngineState.WAITING_FOR_INSTRUMENT,
            60,
            "WAITING FOR INSTRUMENT",
        )
        await wait_until(pilot, lambda: "deadline in" in widget_text(app.ticket_panel), 10, "ticket panel")
        await pilot.pause(0.5)
        app._show_status()
        await pilot.pause()
        app.save_screenshot(filename=out.name, path=str(out.parent))
        assert app.feed is not None
        app.feed.stop()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ROOT / "screenshots")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        exchange = Path(tmp) / "exchange"
        exchange.mkdir()
        journal = Path(tmp) / "ternary-kla.sqlite"
        config = CampaignConfig(name="ternary-kla", seed=3, lattice_n=30)
        proc = start_engine_process(config, journal, "auto", None, driver="kla", exchange=str(exchange))
        assert isinstance(proc, subprocess.Popen)
        try:
            ticket = exchange / "outbox" / "ternary-kla-000-ticket.json"
            deadline = time.monotonic() + 120
            while not ticket.exists() and time.monotonic() < deadline:
                time.sleep(0.1)
            for name, size in SHOTS:
                asyncio.run(shoot(journal, ticket, args.out / name, size))
                print(f"wrote {args.out / name}")
        finally:
            proc.terminate()
            proc.wait(timeout=30)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""``aeni demo --driver kla``: a fake InView process beside the engine on a temporary exchange folder, the
console attached; leaving the demo stops the fake InView and the run."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import pytest

from aeni_console.cli.console import kla_demo
from aeni_console.console.app import ConsoleApp
from aeni_console.console.journal_source import JournalSource
from aeni_console.testkit.live import wait_until
from core.runconfig import make_campaign_config
from core.runview import EngineState

pytestmark = pytest.mark.slow

FAST_PROFILE = 'extends = "kla-imicro"\n[inview]\nstable_polls = 2\npoll_s = 0.05\n'


def _observed(journal: Path) -> int:
    with sqlite3.connect(journal) as conn:
        return int(conn.execute("SELECT COUNT(*) FROM blocks WHERE status = 'observed'").fetchone()[0])


async def test_kla_demo_runs_blocks_through_its_fake_inview_and_stops_it_on_leaving(tmp_path: Path) -> None:
    profile = tmp_path / "fast.toml"
    profile.write_text(FAST_PROFILE)
    config = make_campaign_config(
        "demo",
        source="test",
        policy="cost-aware",
        scenario="ternary",
        seed=3,
        lattice_n=30,
        profile=str(profile),
    )
    journal = tmp_path / "runs" / "demo.sqlite"
    seen: set[EngineState] = set()
    with kla_demo(config, journal, "auto", 1e6) as (exchange, engine, fake):
        assert exchange.is_dir() and (exchange / "outbox").is_dir()
        app = ConsoleApp(
            JournalSource(journal), poll_s=0.05, max_rate_hz=20.0, author="op", cursor_blink=False
        )

        def progressed() -> bool:
            if app.snapshot is not None:
                seen.add(app.snapshot.state)
            return _observed(journal) >= 2

        async with app.run_test(size=(80, 24)) as pilot:
            await wait_until(pilot, progressed, 120, "two blocks measured by the fake InView")
        assert engine.poll() is None and fake.poll() is None  # both live while the demo runs
    assert engine.poll() is not None and fake.poll() is not None
    assert not exchange.exists()  # the temporary exchange folder goes with the demo
    assert EngineState.WAITING_FOR_INSTRUMENT in seen
    # what the fake InView measured is in the journal, each export archived with its hash
    with sqlite3.connect(journal) as conn:
        measured = conn.execute("SELECT COUNT(*) FROM indents WHERE status = 'measured'").fetchone()[0]
        state = conn.execute("SELECT state FROM engine_state").fetchone()[0]
    assert measured >= 2 * 9 and state != EngineState.WAITING_FOR_INSTRUMENT.value
    manifest = journal.with_name(journal.name + ".exports") / "manifest.jsonl"
    assert manifest.read_text().count('"accepted"') >= 2

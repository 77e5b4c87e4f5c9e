"""The console on a real engine with the KLA driver: WAITING FOR INSTRUMENT, the ticket panel at 80×24,
the token typed to confirm the start, a skipped site, and the run going on once the fake InView exports."""

from __future__ import annotations

import sqlite3
import subprocess
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from aeni_console.console.app import ConsoleApp
from aeni_console.console.journal_source import JournalSource
from aeni_console.console.widgets.help import INSTRUMENT_KEYS, HelpScreen, help_text
from aeni_console.console.widgets.ticket import AskScreen
from aeni_console.testkit.live import wait_until, widget_text
from core.profile import load_profile
from core.runview import EngineState
from drivers.kla.exchange import ExchangeFolder
from drivers.kla.fake_inview import FakeInView
from drivers.sim.scenarios import make_scenario

pytestmark = pytest.mark.slow

FAST_PROFILE = (
    'extends = "kla-imicro"\n[inview]\nstable_polls = 2\npoll_s = 0.05\ndeadline_margin_s = 600.0\n'
)


@pytest.fixture
def kla_engine(tmp_path: Path) -> Iterator[tuple[Path, Path, Path]]:
    from aeni_console.cli.run import start_engine_process
    from core.campaign_config import CampaignConfig

    exchange = tmp_path / "exchange"
    exchange.mkdir()
    profile = tmp_path / "fast.toml"
    profile.write_text(FAST_PROFILE)
    journal = tmp_path / "kla.sqlite"
    config = CampaignConfig(name="kla", policy="cost-aware", seed=3, lattice_n=30, profile=str(profile))
    proc = start_engine_process(config, journal, "auto", 1e6, driver="kla", exchange=str(exchange))
    assert isinstance(proc, subprocess.Popen)
    try:
        yield journal, exchange, profile
    finally:
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=10)


async def test_ticket_panel_token_confirmation_and_skip_at_80x24(kla_engine: tuple[Path, Path, Path]) -> None:
    journal, exchange, profile = kla_engine
    app = ConsoleApp(JournalSource(journal), poll_s=0.05, max_rate_hz=20.0, author="op", cursor_blink=False)

    def state() -> EngineState | None:
        return app.snapshot.state if app.snapshot is not None else None

    async with app.run_test(size=(80, 24)) as pilot:
        await wait_until(
            pilot, lambda: state() is EngineState.WAITING_FOR_INSTRUMENT, 60, "waiting for the instrument"
        )
        await wait_until(
            pilot, lambda: app.ticket_panel.display and app.ticket_panel.region.height > 0, 10, "ticket shown"
        )
        panel = widget_text(app.ticket_panel)
        assert "block 0" in panel and "deadline in" in panel and "start not confirmed" in panel
        assert " mm" in panel and "sites" in panel and "method 80 s: AENI hold 80 s.nmt" in panel
        assert not app.decision_panel.display and "WAITING FOR INSTRUMENT" in widget_text(app.status_bar)
        token = ExchangeFolder(exchange, journal.stem, load_profile(profile).inview).read_ticket(0).token  # type: ignore[union-attr]
        assert token not in panel  # read on the ticket at the instrument, typed here
        # the keys this state offers are the ones the help lists for it, and the help opens here
        assert {k: app.active_bindings[k].binding.action for k, _ in INSTRUMENT_KEYS} == {
            "c": "confirm_start",
            "a": "report_aborted",
            "f": "report_no_surface",
            "k": "skip_site",
        }
        await pilot.press("question_mark")
        await wait_until(pilot, lambda: isinstance(app.screen, HelpScreen), 5, "help")
        await pilot.press("escape")
        await wait_until(pilot, lambda: not isinstance(app.screen, HelpScreen), 5, "help closed")
        # a wrong token is refused by the engine, and journaled
        await pilot.press("c")
        await wait_until(pilot, lambda: isinstance(app.screen, AskScreen), 5, "token prompt")
        await pilot.press(*"WRONG", "enter")
        # the right one confirms the start
        await wait_until(pilot, lambda: not isinstance(app.screen, AskScreen), 5, "prompt closed")
        await pilot.press("c")
        await wait_until(pilot, lambda: isinstance(app.screen, AskScreen), 5, "token prompt")
        await pilot.press(*token.lower(), "enter")
        await wait_until(
            pilot,
            lambda: (
                app.snapshot is not None
                and app.snapshot.instrument_wait is not None
                and app.snapshot.instrument_wait.started
            ),
            20,
            "start confirmed",
        )
        await wait_until(
            pilot, lambda: "start confirmed" in widget_text(app.ticket_panel), 5, "panel shows it"
        )
        await pilot.press("k")
        await wait_until(pilot, lambda: isinstance(app.screen, AskScreen), 5, "site prompt")
        await pilot.press("2", "5", "enter")
        with sqlite3.connect(journal) as conn:
            get = "SELECT kind, outcome, reason, author FROM commands WHERE processed = 1 ORDER BY command_id"

            def rows() -> list[tuple[str, str, str, str]]:
                return list(conn.execute(get))

            await wait_until(pilot, lambda: len(rows()) == 3, 20, "three reports processed")
            done = rows()
        assert [(k, o) for k, o, _, _ in done] == [
            ("confirm", "rejected"),
            ("confirm", "accepted"),
            ("skip", "accepted"),
        ]
        assert (
            done[1][2] == "block 0: array started (token confirmed)"
            and done[2][2] == "block 0: site 25 skipped"
        )
        assert {a for *_, a in done} == {"op"}
        # the instrument exports (InView ran site 25 after all: its row is kept, nothing measured is lost)
        fake = FakeInView(
            exchange,
            load_profile(profile),
            make_scenario("ternary", 3).make_emulator,
            invalid_rate=0.0,
            log=print,
        )
        (ticket,) = fake.pending()
        thread = threading.Thread(target=fake.serve, args=(ticket,))
        thread.start()
        await wait_until(
            pilot, lambda: app.snapshot is not None and app.snapshot.n_indents == 25, 60, "block 0 in"
        )
        thread.join()
        assert app.feed is not None
        app.feed.stop()  # leave without a snapshot arriving mid-exit


def test_help_lists_the_ticket_keys_of_the_waiting_state() -> None:
    import re

    from rich.console import Console

    console = Console(width=100, record=True)
    console.print(help_text())
    text = console.export_text()
    section = text[text.index("in WAITING FOR INSTRUMENT") : text.index("Panels")]
    for key, what in INSTRUMENT_KEYS:
        assert re.search(rf"^\s*{key}\s+{re.escape(what[:30])}", section, re.M), key
    assert "Ticket" in text[text.index("Panels") :]

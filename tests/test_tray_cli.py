"""One tray run through the CLI: ``aeni run --tray`` (one journal), ``aeni status`` a line per sample,
``aeni export`` each indent's sample and a folder per sample, a crashed tray resumed to its goals."""

from __future__ import annotations

import csv
from datetime import datetime
from pathlib import Path
from typing import Any

import pytest

from aeni_console.cli.host import create_run_journal, run_engine
from aeni_console.cli.main import main
from aeni_console.cli.tray import tray_spec
from aeni_console.console.app import ConsoleApp
from aeni_console.console.journal_source import JournalSource
from aeni_console.testkit.live import settle, widget_text
from core.campaign_config import CampaignConfig
from core.driver import Driver
from core.journal import JournalReader
from core.operator import OperatorAvailability, OperatorHours
from core.plan import STRETCH_CONTINUES, IndentResult
from core.run.compose import Hosting, compose
from core.run.spec import RunSpec
from core.visits import OperatorCalendar
from drivers.registry import DRIVERS
from tests.test_tray_run import _tray as night_tray

TRAY = """
name = "night"
[[samples]]
name = "tern"
scenario = "ternary"
goal = { indents = 30 }
[[samples]]
name = "film"
scenario = "film"
goal = { indents = 30 }
[[samples]]
name = "silica"
role = "reference"
size_um = [3000.0, 3000.0]
offset_um = [30000.0, 0.0]
check_every_h = 2.0
"""


@pytest.fixture()
def tray_file(tmp_path: Path) -> Path:
    p = tmp_path / "tray.toml"
    p.write_text(TRAY, encoding="utf-8")
    return p


@pytest.fixture(scope="module")
def tray_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[str]]:
    """One tray run through ``aeni run --tray``: its journal and the command that made it."""
    tmp = tmp_path_factory.mktemp("tray")
    tray = tmp / "tray.toml"
    tray.write_text(TRAY, encoding="utf-8")
    journal = tmp / "runs" / "night.sqlite"
    argv = ["run", "--tray", str(tray), "--driver", "sim", "--lattice-n", "20", "--journal", str(journal)]
    assert main([*argv, "--quiet"]) == 0
    return journal, argv


def test_run_status_and_export_of_a_tray(
    tray_run: tuple[Path, list[str]], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    journal, argv = tray_run
    capsys.readouterr()
    assert main(["status", str(journal)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert "STOPPED" in lines[0]
    assert any("tern: at its goal: 30 of 30 indents" in x for x in lines)
    assert any("film: at its goal: 30 of 30 indents" in x for x in lines)
    assert any("silica: reference:" in x and "passed" in x for x in lines)
    out = tmp_path / "export"
    assert main(["export", str(journal), "--out", str(out)]) == 0
    with (out / "indents.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert rows and all(r["sample"] in ("tern", "film", "silica") for r in rows)
    for name in ("tern", "film", "silica"):
        with (out / "samples" / name / "indents.csv").open() as f:
            own = list(csv.DictReader(f))
        assert own and {r["sample"] for r in own} == {name}
    assert sum(1 for r in rows if r["sample"] == "tern" and r["status"] == "measured") == 30
    assert (out / "samples" / "film" / "predictions.csv").stat().st_size > 100
    # a tray names its own samples; a second --tray run on the same journal is refused
    assert main([*argv, "--quiet"]) == 2


def test_report_of_a_tray_is_one_per_library_and_a_tray_summary(
    tray_run: tuple[Path, list[str]], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    pytest.importorskip("matplotlib")
    journal, _ = tray_run
    out = tmp_path / "report"
    assert main(["report", str(journal), "--out", str(out)]) == 0
    assert not (out / "silica").exists()  # the reference is in the tray summary, not a library report
    for name in ("tern", "film"):
        text = (out / name / "summary.md").read_text(encoding="utf-8")
        # its own indents only (30 each), its own goal, and its map scored against its own truth
        assert f"# Run report: night/{name}" in text
        assert "- 30 indents measured" in text
        assert "- stop reason: indent budget reached (30 of 30 indents)" in text
        mape = float(text.split("MAPE ")[1].split(" %")[0])
        assert 0.0 < mape < 40.0
        assert (out / name / "maps.png").stat().st_size > 5000
    summary = (out / "summary.md").read_text(encoding="utf-8")
    rows = {line.split("|")[1].strip(): line for line in summary.splitlines() if line.startswith("| ")}
    assert "| 30 indents | yes" in rows["tern"] and "| 30 indents | yes" in rows["film"]
    assert "| reference |" in rows["silica"]
    checks = [line for line in summary.splitlines() if line.endswith("| passed |")]
    assert len(checks) >= 2  # before the first library and after the last
    for line in checks:
        median = float(line.split("|")[3])
        assert abs(median / 9.0 - 1.0) < 0.05  # fused silica's nominal 9 GPa within the tolerance


def _crash_after(n: int) -> Any:
    def wrap(driver: Driver) -> Driver:
        run = driver.execute_block
        seen = [0]

        def execute_block(block: Any, start: int = 0) -> Any:
            for ev in run(block, start):
                yield ev
                if isinstance(ev, IndentResult):
                    seen[0] += 1
                    if seen[0] == n:
                        raise RuntimeError("simulated engine crash")

        driver.execute_block = execute_block  # type: ignore[method-assign]
        return driver

    return wrap


def test_a_crashed_tray_run_resumes_to_every_goal(tray_file: Path, tmp_path: Path) -> None:
    spec = tray_spec(RunSpec(campaign=CampaignConfig(seed=0, lattice_n=20)), str(tray_file))
    journal = tmp_path / "crash.sqlite"
    opened: list[Any] = []

    def record(s: RunSpec, c: Any) -> Any:
        opened.append(create_run_journal(journal, s, c))
        return opened[0]

    run = compose(
        spec, DRIVERS, record, journal=journal, hosting=Hosting(watch_s=None), driver=_crash_after(25)
    )
    with pytest.raises(RuntimeError, match="simulated engine crash"):
        run.engine.run()
    opened[0].close()
    with JournalReader(journal) as r:
        assert 0 < r.snapshot().n_indents < 40
    assert run_engine(journal, quiet=True) == 0  # what `aeni resume` does
    with JournalReader(journal) as r:
        snap = r.snapshot()
        row = r.q.engine_row()
        results = r.results()
        tray_state = r.latest_campaign_state()
    assert snap.finished and row["completed"] and "every library reached its goal" in row["stop_reason"]
    assert tray_state is not None
    assert tray_state[0]["tray_run"]["indents"] == {"tern": 30, "film": 30}
    assert spec.tray is not None
    assert all(spec.tray.sample_at(r.commanded_x_um, r.commanded_y_um) is not None for r in results)


async def test_the_console_shows_the_tray(tray_run: tuple[Path, list[str]]) -> None:
    journal, _ = tray_run
    source = JournalSource(journal)
    app = ConsoleApp(
        source, poll_s=0.02, max_rate_hz=50.0, clock=lambda: 0.0, author="tester", cursor_blink=False
    )
    try:
        async with app.run_test(size=(100, 30)) as pilot:
            await settle(pilot)
            panel = app.tray_panel
            assert panel.display
            text = widget_text(panel)
            assert "tern" in text and "film" in text and "silica" in text
            assert "30 of 30 indents" in text and "tip check" in text
            assert "▶" in text  # the current sample (the last block's: the final tip check)
    finally:
        source.close()


def test_a_tray_crashed_in_the_nights_load_resumes_in_the_same_load(tmp_path: Path) -> None:
    """Loaded at 18:00 and left for the night (tests/test_tray_run.py): an engine that dies in the night and is
    resumed goes on with the arrays loaded at the visit, asking for no new one (the load is in the state)."""
    cal = OperatorCalendar(
        OperatorAvailability(OperatorHours.parse("Mon-Fri 08:30-18:00"), 600, 7200),
        datetime(2026, 11, 23, 17, 50),
    )
    spec = RunSpec(campaign=CampaignConfig(seed=0, lattice_n=20), calendar=cal, tray=night_tray())
    journal = tmp_path / "night.sqlite"
    opened: list[Any] = []

    def record(s: RunSpec, c: Any) -> Any:
        opened.append(create_run_journal(journal, s, c))
        return opened[0]

    run = compose(
        spec, DRIVERS, record, journal=journal, hosting=Hosting(watch_s=None), driver=_crash_after(30)
    )
    with pytest.raises(RuntimeError, match="simulated engine crash"):
        run.engine.run()
    opened[0].close()
    assert run_engine(journal, quiet=True) == 0
    with JournalReader(journal) as r:
        row = r.q.engine_row()
        phases = [d.decision.phase for d in r.decisions()]
    assert row["completed"] and "every library reached its goal" in row["stop_reason"]
    assert phases[0] == "tip-check" and set(phases[1:]) == {STRETCH_CONTINUES}  # one visit, as uncrashed

"""The console's view is a fold over the run's event log (core.journal.snapshot): on journals made before the
change (schema 3 and 4, whose events are rebuilt from their tables, and schema 5) it shows what the reader that
read the tables kind by kind showed, now and at every replay step; an engine's migration keeps it; and the
fold of the events as the engine emits them is the fold of the journal it writes."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import pytest

from aeni_console.cli.host import create_run_journal
from aeni_console.cli.main import main
from core.journal import Journal, JournalReader
from core.journal.snapshot import SnapshotFold
from core.run.compose import HEADLESS, compose
from core.run.events import RunEvent
from core.run.spec import RunSpec
from core.runconfig import make_campaign_config
from core.runview import RunSnapshot
from core.settings import settings_to_dict
from drivers.registry import DRIVERS

DATA = Path(__file__).parent / "data"
FOLD = DATA / "journal_before_snapshot_fold"
EXPECTED: dict[str, Any] = json.loads((FOLD / "views.json").read_text(encoding="utf-8"))


def view(s: RunSnapshot) -> dict[str, Any]:
    """The console's view as plain data (views.json was written with this, by the reader before the fold)."""
    return {
        "state": s.state.value,
        "supervision": s.supervision,
        "finished": s.finished,
        "instrument_s": s.instrument_s,
        "n_indents": s.n_indents,
        "n_blocks": s.n_blocks,
        "reconfigurations": s.reconfigurations,
        "ledger": s.ledger,
        "queue": [[q.block_id, q.indent_index, round(q.eta_s, 6)] for q in s.queue],
        "current_block": None if s.current_block is None else s.current_block.block_id,
        "pending": None if s.pending is None else s.pending.block.block_id,
        "last_decision": None if s.last_decision is None else s.last_decision.block.block_id,
        "drift": [
            s.drift.last_rate_nm_s,
            s.drift.hold_mode,
            s.drift.area_error_pct,
            [list(e) for e in s.drift.events],
        ],
        "gp": [s.gp.snapshot_id, list(s.gp.lengthscales_um), s.gp.collapse_alarm, s.gp.refit_s],
        "mape_pct": s.mape_pct,
        "max_found_gpa": s.max_found_gpa,
        "tested": [[t.x_um, t.y_um, t.block_id, t.median_gpa] for t in s.tested],
        "settings": settings_to_dict(s.settings),
        "log": [[e.t_s, e.level, e.text] for e in s.log],
        "position_um": None if s.position_um is None else list(s.position_um),
    }


def views(path: Path) -> dict[str, Any]:
    with JournalReader(path) as r:
        out = {
            "now": view(r.snapshot()),
            "replay": {str(b): view(r.snapshot(upto=b)) for b in r.replay_blocks()},
            "blocks": [
                [
                    b.block.block_id,
                    b.status,
                    None if b.decision is None else b.decision.block.block_id,
                    len(b.results),
                    len(b.steps),
                    b.snapshot_id,
                    b.planned_t_s,
                    b.finished_t_s,
                ]
                for b in r.blocks()
            ],
        }
    return json.loads(json.dumps(out, default=str))  # as views.json holds it (tuples as lists)


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_a_journal_made_before_the_fold_shows_what_it_showed(name: str, tmp_path: Path) -> None:
    path = tmp_path / Path(name).name
    shutil.copy(DATA / name, path)
    path.chmod(0o640)
    assert views(path) == EXPECTED[name]


@pytest.mark.parametrize(
    "name", ["journal_before_run_spec/finished.sqlite", "journal_before_one_loop/finished.sqlite"]
)
def test_an_engines_migration_keeps_the_view(name: str, tmp_path: Path) -> None:
    """A schema 3 or 4 journal reopened by an engine gets its event log written (in the order rebuilt in
    memory before): the console's view does not change."""
    path = tmp_path / "old.sqlite"
    shutil.copy(DATA / name, path)
    path.chmod(0o640)
    Journal.open_writer(path).close()
    assert views(path) == EXPECTED[name]


def test_a_journal_made_before_the_fold_replays_exports_and_says_it_is_finished(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "finished.sqlite"
    shutil.copy(FOLD / "finished.sqlite", path)
    path.chmod(0o640)
    assert main(["replay", str(path)]) == 0
    assert main(["export", str(path), "--out", str(tmp_path / "out")]) == 0
    assert (tmp_path / "out" / "indents.csv").read_text(encoding="utf-8").count("\n") == 51
    capsys.readouterr()
    assert main(["resume", str(path)]) == 0
    assert "already finished" in capsys.readouterr().out


def test_the_fold_of_the_emitted_events_is_the_fold_of_the_journal(tmp_path: Path) -> None:
    """A sink folding the events as the engine emits them sees what a reader of the journal sees."""
    config = make_campaign_config(
        scenario="ternary", policy="cost-aware", seed=1, lattice_n=10, settings={"indent_budget": 75}
    )
    spec = RunSpec(config)
    live = SnapshotFold()
    seen: list[RunEvent] = []

    class Folding:
        def emit(self, event: RunEvent) -> None:
            seen.append(event)

    path = tmp_path / "run.sqlite"
    run = compose(
        spec,
        DRIVERS,
        lambda s, c: create_run_journal(path, s, c),
        journal=path,
        sinks=[Folding()],
        hosting=HEADLESS,
    )
    run.engine.run()
    for event in seen:
        live.emit(event)
    with JournalReader(path) as r:
        stored = r.snapshot()
        blocks = r.blocks()
    assert live.n_indents == stored.n_indents > 0 and live.rounded_ledger() == stored.ledger
    assert [(b.block.block_id, b.status, len(b.results)) for b in live.block_records()] == [
        (b.block.block_id, b.status, len(b.results)) for b in blocks
    ]

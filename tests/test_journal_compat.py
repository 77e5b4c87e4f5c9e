"""Journals written before the engine emitted events (commit 854f58b, `aeni run --policy aeni --seed 2
--budget-s 3000`; the second one stopped by SIGTERM after its first indent) still open, replay, export
and resume with this version."""

from __future__ import annotations

import shutil
from pathlib import Path

import pandas as pd
import pytest

from aeni_console.cli.main import main
from core.journal import JournalReader
from core.runview import EngineState

DATA = Path(__file__).parent / "data" / "journal_before_one_loop"


def _copy(tmp_path: Path, name: str) -> Path:
    target = tmp_path / name
    shutil.copy(DATA / name, target)
    target.chmod(0o640)
    return target


def _indents(path: Path) -> list[tuple[object, ...]]:
    with JournalReader(path) as r:
        return [
            (x.block_id, x.indent_index, x.actual_x_um, x.actual_y_um, x.hold_s, x.hardness_gpa)
            for x in r.results()
        ]


def test_an_old_journal_opens_replays_and_exports(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = _copy(tmp_path, "finished.sqlite")
    with JournalReader(path) as r:
        snap = r.snapshot()
        steps = [r.snapshot(upto=b) for b in r.replay_blocks()]
    assert snap.state is EngineState.STOPPED and snap.n_indents == 17 and snap.n_blocks == 2
    assert steps and steps[-1].n_indents == 17
    assert main(["export", str(path), "--out", str(tmp_path / "out")]) == 0
    assert len(pd.read_csv(tmp_path / "out" / "indents.csv")) == 17
    assert main(["resume", str(path)]) == 0
    assert "already finished" in capsys.readouterr().out


def test_an_old_aborted_journal_resumes_to_the_indents_of_the_uninterrupted_old_run(tmp_path: Path) -> None:
    path = _copy(tmp_path, "aborted.sqlite")
    assert len(_indents(path)) == 1
    # it was stopped by a signal: resume refuses it unless told to go on (issue 23)
    assert main(["resume", str(path), "--quiet"]) == 2
    # the old run was made at 40× (its journal's speed); the simulated clock's pace changes no indent
    assert main(["resume", str(path), "--quiet", "--continue", "--speed", "1e9"]) == 0
    with JournalReader(path) as r:
        snap = r.snapshot()
    assert snap.state is EngineState.STOPPED
    assert _indents(path) == _indents(DATA / "finished.sqlite")

"""One run spec (core.run.spec): a run file with every section is one RunSpec, its JSON round-trips, and the
same run in-process, detached and killed and resumed, keeps the same spec and makes the same indents. A journal
of the release before the spec opens, replays, exports and resumes."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import signal
import sqlite3
import time
from pathlib import Path

import pandas as pd
import pytest

from aeni_console.cli.main import main
from core.errors import InputError
from core.journal import JournalReader, engine_running
from core.run.spec import RunSpec, run_spec_from_meta
from core.runconfig import load_run_config
from core.runview import EngineState

ROOT = Path(__file__).resolve().parents[1]
OLD = Path(__file__).parent / "data" / "journal_before_run_spec"
RUN_FILE = """
name = "every-section"

[sample]
file = "{sample}"

[campaign]
policy = "cost-aware"
seed = 4
lattice_n = 15

[planner]
indent_budget = 50
beta = 2.5

[run]
supervision = "auto"
speed = 20000.0
max_refusals = 7
approval_timeout_s = 3600
on_timeout = "veto"

[operator]
hours = "always"
response_min = 5
visit_every_min = 90

[notify]
urls = ["json://127.0.0.1:9/never"]
instrument_silence_s = 900
repeat_s = 600
"""


def _run_file(tmp_path: Path) -> Path:
    path = tmp_path / "every.toml"
    path.write_text(RUN_FILE.format(sample=ROOT / "docs/examples/NiTiCu-library-07.toml"), encoding="utf-8")
    return path


def _indents(path: Path) -> list[tuple[object, ...]]:
    with JournalReader(path) as r:
        return [
            (x.block_id, x.indent_index, x.actual_x_um, x.actual_y_um, x.hold_s, x.hardness_gpa, x.status)
            for x in r.results()
        ]


def _stored_spec(path: Path) -> RunSpec:
    with JournalReader(path) as r:
        return run_spec_from_meta(r.meta)


def _count(path: Path) -> int:
    try:
        with sqlite3.connect(f"file:{path}?mode=ro", uri=True, timeout=1.0) as conn:
            return int(conn.execute("SELECT count(*) FROM indents").fetchone()[0])
    except sqlite3.Error:
        return 0


def test_a_run_file_with_every_section_is_one_spec_and_one_json(tmp_path: Path) -> None:
    spec = load_run_config(_run_file(tmp_path)).spec()
    assert spec.campaign.sample is not None and spec.campaign.sample.name == "NiTiCu-library-07"
    assert (spec.campaign.policy, spec.campaign.seed, spec.campaign.settings.beta) == ("cost-aware", 4, 2.5)
    assert (spec.rules.max_refusals, spec.rules.approval_timeout_s, spec.rules.on_timeout) == (
        7,
        3600.0,
        "veto",
    )
    assert spec.operator is not None and spec.operator.hours.text == "always"
    assert spec.operator.visit_every_s == 90 * 60.0 and spec.speed == 20000.0
    assert spec.notify.urls == ("json://127.0.0.1:9/never",) and spec.notify.repeat_s == 600.0
    back = RunSpec.from_json(spec.to_json())
    assert back.to_json() == spec.to_json()
    assert back.operator == spec.operator and back.rules == spec.rules and back.notify == spec.notify
    # the journal's copy has no secrets
    assert "127.0.0.1:9" not in spec.public().to_json() and spec.public().rules == spec.rules


def test_a_bad_spec_is_one_line_naming_what_is_wrong() -> None:
    with pytest.raises(InputError, match="--spec-stdin: not valid JSON"):
        RunSpec.from_json("{", "--spec-stdin")
    with pytest.raises(InputError, match="unknown field"):
        RunSpec.from_json(json.dumps({"campaign": {}, "colour": "red"}))
    with pytest.raises(InputError, match="on_timeout"):
        RunSpec.from_json(json.dumps({"rules": {"on_timeout": "shrug"}}))


def test_in_process_detached_killed_and_resumed_the_same_spec_and_indents(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The calendar run can be detached (it used to end with `unrecognized arguments: --operator`); killed
    with SIGKILL mid-run and resumed, it ends with the in-process run's spec and indents."""
    run_file = _run_file(tmp_path)
    here, away = tmp_path / "here.sqlite", tmp_path / "away.sqlite"
    assert main(["run", str(run_file), "--journal", str(here), "--quiet"]) == 0
    # --auto-resume 0: its supervisor journals and alerts the kill but leaves the resume to this test
    assert main(["run", str(run_file), "--journal", str(away), "--detach", "--auto-resume", "0"]) == 0
    assert "supervisor PID" in capsys.readouterr().out
    deadline = time.monotonic() + 120
    while _count(away) < 3 and time.monotonic() < deadline:
        time.sleep(0.02)
    with JournalReader(away) as r:
        pid = int(r.q.engine_row()["pid"])  # the engine's own PID (the supervisor's is printed)
    os.kill(pid, signal.SIGKILL)
    while engine_running(away) and time.monotonic() < deadline:
        time.sleep(0.05)
    killed_at = _count(away)
    assert 3 <= killed_at < 50, killed_at
    assert main(["resume", str(away), "--quiet"]) == 0
    with JournalReader(away) as r:
        assert r.snapshot().state is EngineState.STOPPED
    assert _indents(away) == _indents(here) and len(_indents(here)) == 50
    assert _indents(here) == _indents(OLD / "finished.sqlite")  # as the release before the spec made them
    expected = load_run_config(run_file).spec().public().to_json()
    away_spec = _stored_spec(away)  # --auto-resume 0 is one of the run's rules: its journal keeps it
    assert away_spec.rules.auto_resume == 0
    away_spec = dataclasses.replace(away_spec, rules=dataclasses.replace(away_spec.rules, auto_resume=3))
    assert _stored_spec(here).to_json() == away_spec.to_json() == expected
    assert "127.0.0.1:9" not in away.read_bytes().decode("latin-1")  # the alert URL stays out of the journal


def test_a_journal_of_the_release_before_the_spec_opens_replays_exports_and_resumes(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "aborted.sqlite"
    shutil.copy(OLD / "aborted.sqlite", path)
    path.chmod(0o640)
    spec = _stored_spec(path)  # config + driver + speed + engine_rules, read as the spec they describe
    assert spec.operator is not None and spec.operator.hours.text == "always"
    assert (spec.rules.max_refusals, spec.rules.on_timeout, spec.speed) == (7, "veto", 20000.0)
    assert spec.campaign.sample is not None and spec.campaign.policy == "cost-aware"
    assert main(["replay", str(path)]) == 0
    assert main(["export", str(path), "--out", str(tmp_path / "out")]) == 0
    assert len(pd.read_csv(tmp_path / "out" / "indents.csv")) == len(_indents(path)) >= 1
    capsys.readouterr()
    assert main(["resume", str(path), "--quiet"]) == 2  # stopped by a signal: only with --continue
    assert main(["resume", str(path), "--quiet", "--continue", "--speed", "1e9"]) == 0
    assert _indents(path) == _indents(OLD / "finished.sqlite")


def test_the_product_constructs_an_engine_in_one_place() -> None:
    """compose is the one builder: no other module of core, drivers or the application calls Engine(...)."""
    import ast

    callers = set()
    for package in ("core", "drivers", "aeni_console"):
        for path in (ROOT / package).rglob("*.py"):
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if (
                    isinstance(node, ast.Call)
                    and isinstance(node.func, ast.Name)
                    and node.func.id == "Engine"
                ):
                    callers.add(path.relative_to(ROOT).as_posix())
    assert callers == {"core/run/compose.py"}

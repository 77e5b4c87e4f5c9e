"""Issue 38: a run's resume rules (``[run] auto_resume``, ``resume_backoff_s``) are rules of the run, kept with
its RunSpec in its journal. ``aeni resume --detach`` hands its supervisor the journal's rules, not a flag's
default; a flag given overrides."""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import shutil
import signal
import sqlite3
import time
from pathlib import Path

import pytest

from aeni_console.cli.main import main
from aeni_console.cli.run import with_resume_flags
from aeni_console.cli.supervisor import supervisor_pid
from core.errors import InputError
from core.journal import JournalReader, engine_running
from core.run.spec import EngineRules, RunSpec, run_spec_from_meta
from core.runconfig import load_run_config

OLD = Path(__file__).parent / "data" / "journal_before_run_spec"


def test_the_run_file_rules_travel_in_the_spec_and_back(tmp_path: Path) -> None:
    run_file = tmp_path / "run.toml"
    run_file.write_text('name = "r"\n[run]\nauto_resume = 1\nresume_backoff_s = 0.3\n')
    spec = load_run_config(run_file).spec()
    assert (spec.rules.auto_resume, spec.rules.resume_backoff_s) == (1, 0.3)
    assert RunSpec.from_json(spec.to_json()).rules == spec.rules
    # a spec journaled before these rules reads as the defaults
    old = json.loads(spec.to_json())
    del old["rules"]["auto_resume"], old["rules"]["resume_backoff_s"]
    assert RunSpec.from_dict(old).rules == dataclasses.replace(
        spec.rules, auto_resume=3, resume_backoff_s=5.0
    )
    with pytest.raises(InputError, match=r"run\.auto_resume"):
        EngineRules(auto_resume=-1)


def _flags(**given: object) -> argparse.Namespace:
    return argparse.Namespace(**{"supervision": None, "auto_resume": None, "resume_backoff_s": None, **given})


def test_a_flag_given_overrides_only_its_own_rule() -> None:
    spec = RunSpec(rules=EngineRules(supervision="supervised", auto_resume=1, resume_backoff_s=0.3))
    assert with_resume_flags(spec, _flags()) == spec
    assert with_resume_flags(spec, _flags(auto_resume=0)).rules == dataclasses.replace(
        spec.rules, auto_resume=0
    )
    got = with_resume_flags(spec, _flags(resume_backoff_s=2.0, supervision="auto")).rules
    assert (got.auto_resume, got.resume_backoff_s, got.supervision) == (1, 2.0, "auto")


def test_resume_detach_hands_its_supervisor_the_journals_rules(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A real `aeni resume --detach` of an aborted run whose journal says auto_resume 1, backoff 0.3 s: its
    supervisor's command line says the same (the flag's default would be 3 and 5 s)."""
    path = tmp_path / "aborted.sqlite"
    shutil.copy(OLD / "aborted.sqlite", path)
    path.chmod(0o640)
    with JournalReader(path) as r:
        spec = run_spec_from_meta(r.meta)
    rules = dataclasses.replace(spec.rules, auto_resume=1, resume_backoff_s=0.3)
    spec = dataclasses.replace(spec, rules=rules, speed=1e9)
    with sqlite3.connect(path) as c:  # the journal as a release with the rules in its spec writes it
        c.execute("INSERT INTO meta (key, value) VALUES ('run_spec', ?)", (json.dumps(spec.to_dict()),))
    c.close()
    capsys.readouterr()
    assert main(["resume", str(path), "--detach", "--continue"]) == 0
    assert "1 times in a row at most" in capsys.readouterr().out
    sup = supervisor_pid(path)
    try:
        assert sup is not None
        argv = Path(f"/proc/{sup}/cmdline").read_bytes().decode().split("\0")
        assert argv[argv.index("--auto-resume") + 1] == "1"
        assert float(argv[argv.index("--backoff-s") + 1]) == 0.3
    finally:  # stopped as Ctrl-C would: the engine finishes its indent, the supervisor does not resume it
        if sup is not None:
            os.kill(sup, signal.SIGTERM)
        deadline = time.monotonic() + 60.0
        while supervisor_pid(path) is not None and time.monotonic() < deadline:
            time.sleep(0.1)
    assert supervisor_pid(path) is None and not engine_running(path)

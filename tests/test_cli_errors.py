"""One line, exit code 2, no traceback: the paths and journals a new user gets wrong (issue 15)."""

from __future__ import annotations

import json
import os
import sqlite3
import stat
import subprocess
import sys
import warnings
from pathlib import Path

import pytest

from aeni_console.cli.main import main
from core.campaign_config import CampaignConfig
from core.plan import PlannerSettings

ROOT = Path(__file__).resolve().parents[1]


def _run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    try:
        code = main(list(argv))
    except SystemExit as exc:  # argparse errors
        code = int(exc.code or 0)
    out, err = capsys.readouterr()
    return code, out, err


def _one_line_error(code: int, err: str, *needles: str) -> None:
    assert code == 2, err
    assert "Traceback" not in err
    assert err.count("\n") == 1, err
    for n in needles:
        assert n in err, (n, err)


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A tiny finished emulator run (one block)."""
    from aeni_console.cli.run import run_engine
    from core.runconfig import RunOptions

    path = tmp_path_factory.mktemp("runs") / "done.sqlite"
    config = CampaignConfig(name="done", settings=PlannerSettings(indent_budget=1))
    assert run_engine(path, create=(config, RunOptions()), quiet=True) == 0
    return path


# --------------------------------------------------------------------------------------------------
# the four tracebacks of the issue


@pytest.mark.parametrize("where", ["file-in-the-way", "cannot-create"])
def test_journal_folder_that_cannot_be_created(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], where: str
) -> None:
    blocker = tmp_path / "blocker"
    blocker.write_text("x", encoding="utf-8")
    journal = blocker / "runs" / "j.sqlite" if where == "file-in-the-way" else Path("/proc/aeni/j.sqlite")
    code, _, err = _run(capsys, "run", "--journal", str(journal), "--budget-s", "2000")
    _one_line_error(code, err, "cannot create the journal's folder")
    assert not list(tmp_path.glob("**/*.sqlite"))


def test_runs_folder_that_is_a_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cfg = tmp_path / "run.toml"
    (tmp_path / "runs").write_text("not a folder", encoding="utf-8")
    cfg.write_text(f'[run]\nruns_dir = "{tmp_path / "runs"}"\n[planner]\nbudget_s = 2000\n', encoding="utf-8")
    code, _, err = _run(capsys, "run", str(cfg))
    _one_line_error(code, err, str(tmp_path / "runs"), "is a file")


def test_export_out_is_an_existing_file(
    finished_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    target = tmp_path / "out.csv"
    target.write_text("keep me", encoding="utf-8")
    code, _, err = _run(capsys, "export", str(finished_run), "--out", str(target))
    _one_line_error(code, err, str(target), "is a file; --out takes a folder")
    assert target.read_text(encoding="utf-8") == "keep me"


def test_resume_of_a_read_only_journal(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from aeni_console.cli.run import run_engine
    from core.runconfig import RunOptions

    path = tmp_path / "ro.sqlite"
    config = CampaignConfig(name="ro", settings=PlannerSettings(indent_budget=1))
    run_engine(path, create=(config, RunOptions()), quiet=True)
    conn = sqlite3.connect(path)  # make it look like a run whose engine died mid-way
    conn.execute("UPDATE engine_state SET completed = 0, state = 'running'")
    conn.commit()
    conn.close()
    before = path.read_bytes()
    path.chmod(0o444)
    try:
        code, _, err = _run(capsys, "resume", str(path))
    finally:
        path.chmod(0o644)
    _one_line_error(code, err, str(path), "read-only (mode 0444)")
    assert path.read_bytes() == before


def test_send_from_a_user_who_does_not_own_the_run(
    finished_run: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    st = finished_run.stat()
    os.chown(finished_run, st.st_uid + 4242, -1) if os.getuid() == 0 else None
    if finished_run.stat().st_uid == os.getuid():
        pytest.skip("needs root to give the journal to another user")
    try:
        code, _, err = _run(capsys, "send", str(finished_run), "pause")
    finally:
        os.chown(finished_run, st.st_uid, -1)
    _one_line_error(code, err, str(finished_run), "only the run's owner")


# --------------------------------------------------------------------------------------------------
# messages that point the right way


def test_a_folder_where_a_file_is_expected(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    folder = tmp_path / "data"
    folder.mkdir()
    for argv, needle in (
        (("cost", "path", str(folder)), "is a folder"),
        (("run", str(folder)), "is a folder"),
        (("status", str(folder)), "is a folder, not a journal file"),
        (("report", str(folder)), "is a folder, not a journal file"),
    ):
        code, _, err = _run(capsys, *argv)
        _one_line_error(code, err, str(folder), needle)
        assert "no such" not in err


@pytest.mark.parametrize("kind", ["text", "folder", "journal"])
def test_journal_flag_on_something_that_exists(
    tmp_path: Path, finished_run: Path, capsys: pytest.CaptureFixture[str], kind: str
) -> None:
    target = {"text": tmp_path / "notes.txt", "folder": tmp_path, "journal": finished_run}[kind]
    if kind == "text":
        target.write_text("my notes", encoding="utf-8")
    code, _, err = _run(capsys, "run", "--journal", str(target))
    want = {
        "text": "not a journal is already there",
        "folder": "is a folder; --journal takes a file path",
        "journal": "use `aeni resume`",
    }[kind]
    _one_line_error(code, err, str(target), want)
    if kind != "journal":
        assert "resume" not in err
    if kind == "text":
        assert target.read_text(encoding="utf-8") == "my notes"


def test_library_warnings_go_to_stderr_as_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    from aeni_console.cli import main as cli

    with warnings.catch_warnings():
        warnings.simplefilter("always")
        warnings.showwarning = cli._warning_line
        warnings.warn("a library\nsays something", UserWarning, stacklevel=1)
    out, err = capsys.readouterr()
    assert out == ""
    assert err == "aeni: warning: UserWarning: a library says something\n"


def test_simulate_json_stdout_is_only_json_even_when_libraries_warn(tmp_path: Path) -> None:
    code = (
        "import warnings, sys\n"
        "import aeni_console.cli.simulate as s\n"
        "orig = s.run_simulation\n"
        "def noisy(*a, **k):\n"
        "    warnings.warn('numerical trouble in a library', RuntimeWarning)\n"
        "    print('x', file=sys.stderr)\n"
        "    return orig(*a, **k)\n"
        "s.run_simulation = noisy\n"
        "from aeni_console.cli.main import main\n"
        "sys.exit(main(['simulate', '--budget-s', '3000', '--json']))\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, timeout=120, check=False
    )
    assert proc.returncode == 0, proc.stderr
    json.loads(proc.stdout)
    assert "aeni: warning: RuntimeWarning: numerical trouble in a library" in proc.stderr


def test_a_reader_that_has_gone_ends_the_command_quietly(tmp_path: Path) -> None:
    """`aeni … | head`: the reader closes early; the command ends with 141 (as a SIGPIPE'd Unix tool
    does), nothing on stderr, no traceback and no 'Exception ignored' at exit."""
    read_end, write_end = os.pipe()
    os.close(read_end)  # the reader is gone before a line is written
    try:
        proc = subprocess.run(
            [sys.executable, "-m", "aeni_console.cli.main", "scenarios"],
            stdout=write_end,
            stderr=subprocess.PIPE,
            text=True,
            cwd=tmp_path,
            timeout=120,
            check=False,
        )
    finally:
        os.close(write_end)
    assert proc.returncode == 141, proc.stderr
    assert proc.stderr == ""


def test_scenarios_exists_and_simulate_help_points_to_it(capsys: pytest.CaptureFixture[str]) -> None:
    from drivers.sim.scenarios import SCENARIOS

    code, out, _ = _run(capsys, "simulate", "--help")
    assert code == 0 and "aeni scenarios" in out
    code, out, _ = _run(capsys, "scenarios", "--json")
    assert code == 0
    assert [r["name"] for r in json.loads(out)] == list(SCENARIOS)
    code, out, _ = _run(capsys, "scenarios")
    assert code == 0 and all(name in out for name in SCENARIOS)


# --------------------------------------------------------------------------------------------------
# aeni runs


def test_runs_lists_state_owner_engine_and_age(
    finished_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from core.journal import user_name

    folder = finished_run.parent
    (folder / "broken.sqlite").write_bytes(b"not a database at all" * 10)
    try:
        code, out, _ = _run(capsys, "runs", str(folder), "--json")
        assert code == 0
        rows = {Path(r["journal"]).name: r for r in json.loads(out)}
        done = rows["done.sqlite"]
        assert done["state"] == "stopped" and done["engine_alive"] is False and done["pid"] is None
        assert done["owner"] == user_name(os.getuid())
        assert 0 <= done["age_s"] < 600 and done["indents"] >= 1
        assert rows["broken.sqlite"]["state"] == "unreadable"
        assert "not an SQLite database" in rows["broken.sqlite"]["problem"]
        code, out, _ = _run(capsys, "runs", str(folder))
        assert code == 0 and "done.sqlite" in out and "stopped" in out and "unreadable" in out
    finally:
        (folder / "broken.sqlite").unlink()
    for bad, needle in ((tmp_path / "nope", "no such folder"), (finished_run, "is a file")):
        code, _, err = _run(capsys, "runs", str(bad))
        _one_line_error(code, err, str(bad), needle)


def test_runs_shows_a_live_engine_with_its_pid(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from aeni_console.cli.run import start_engine_process

    journal = tmp_path / "live.sqlite"
    config = CampaignConfig(name="live", settings=PlannerSettings(budget_s=200_000))
    proc = start_engine_process(config, journal, "supervised", speed=1.0)
    assert not isinstance(proc, int)
    try:
        code, out, _ = _run(capsys, "runs", str(tmp_path), "--alive", "--json")
        assert code == 0
        (row,) = json.loads(out)
        assert row["engine_alive"] is True and row["pid"] == proc.pid
    finally:
        proc.terminate()
        proc.wait(timeout=60)
    code, out, _ = _run(capsys, "runs", str(tmp_path), "--alive", "--json")
    assert json.loads(out) == []


def test_write_atomic_gives_the_usual_file_mode(tmp_path: Path) -> None:
    from aeni_console.files import write_atomic

    target = tmp_path / "summary.md"
    write_atomic(target, "hello")
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(target.stat().st_mode) == 0o666 & ~umask


def test_xlrd_file_warnings_stay_off_stdout(
    tmp_path: Path, kla_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """xlrd prints file-format complaints to stdout by default; they must not break `--json`."""
    odd = tmp_path / "odd.xls"
    odd.write_bytes((kla_dir / "Example.xls").read_bytes() + b"abc")  # not a whole number of sectors
    code, out, err = _run(capsys, "kla", "read", str(odd), "--json")
    assert code == 0
    assert len(json.loads(out)) == 16
    assert "aeni: warning: UserWarning: odd.xls: WARNING *** file size" in err

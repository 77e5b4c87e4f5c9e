"""Who may command a run rests on what the OS enforces: journal files 0640, a configurable group, and an
engine that trusts command rows only while nobody but the owner can write them (docs/security.md)."""

from __future__ import annotations

import grp
import os
import pwd
import shutil
import stat
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from aeni_console.cli.main import main
from aeni_console.cli.run import start_engine_process
from core.access import JOURNAL_MODE, command_channel_problem
from core.journal import JournalReader, lock_path_for
from core.runconfig import load_run_config
from core.runview import EngineState

ROOT = Path(__file__).resolve().parents[1]


def _mode(p: Path) -> int:
    return stat.S_IMODE(p.stat().st_mode)


def _run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    try:
        code = main(list(argv))
    except SystemExit as exc:
        code = int(exc.code or 0)
    out, err = capsys.readouterr()
    return code, out, err


def _other_group() -> tuple[str, int] | None:
    """A group this user may give files to other than its own (root: any; others: a supplementary one)."""
    mine = os.getgid()
    candidates = [g for g in grp.getgrall() if g.gr_gid != mine]
    if os.getuid() != 0:
        candidates = [g for g in candidates if g.gr_gid in os.getgroups()]
    return (candidates[0].gr_name, candidates[0].gr_gid) if candidates else None


def _start(tmp_path: Path, group: str | None = None) -> tuple[Path, object]:
    rc = load_run_config(None, {"name": "sec", "planner.budget_s": 200_000})
    journal = tmp_path / "sec.sqlite"
    proc = start_engine_process(rc.campaign, journal, "supervised", speed=1e5, group=group)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        with JournalReader(journal) as r:
            if r.state()[0] == EngineState.AWAITING_APPROVAL:
                return journal, proc
        time.sleep(0.1)
    raise TimeoutError("engine never waited for approval")


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """One supervised engine waiting for approval, shared by the tests that look at or command it.

    Its folder is one other users may enter (pytest's own are 0700), so a test can try it as nobody.
    """
    import tempfile

    folder = Path(tempfile.mkdtemp(prefix="aeni-security-"))
    folder.chmod(0o755)
    journal, proc = _start(folder)
    try:
        yield journal
    finally:
        proc.terminate()  # type: ignore[attr-defined]
        proc.wait(timeout=60)  # type: ignore[attr-defined]
        shutil.rmtree(folder, ignore_errors=True)


def test_journal_and_its_side_files_are_0640(live: Path) -> None:
    for f in (live, Path(f"{live}-wal"), Path(f"{live}-shm"), lock_path_for(live), Path(f"{live}.log")):
        assert f.exists(), f
        assert _mode(f) == JOURNAL_MODE, (f.name, oct(_mode(f)))
    assert command_channel_problem(live, live.stat().st_uid) == ""


def test_a_group_writable_journal_gets_its_commands_rejected(
    live: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    live.chmod(0o660)
    code, out, _ = _run(capsys, "send", str(live), "approve")
    assert code == 1
    assert "rejected: sec.sqlite is writable by its group (mode 0660): commands are not trusted" in out
    live.chmod(0o640)
    code, out, _ = _run(capsys, "send", str(live), "approve")
    assert code == 0 and "accepted" in out
    with JournalReader(live) as r:
        first = r.commands()[0]
    assert first["outcome"] == "rejected" and "not trusted" in first["reason"]  # recorded, with the reason


def test_a_watching_group_gets_the_journal_and_its_side_files(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    other = _other_group()
    if other is None:
        pytest.skip("this user belongs to no other group")
    name, gid = other
    journal, proc = _start(tmp_path, group=name)
    try:
        for f in (journal, Path(f"{journal}-wal"), Path(f"{journal}-shm"), lock_path_for(journal)):
            assert f.stat().st_gid == gid and _mode(f) == JOURNAL_MODE, f.name
    finally:
        proc.terminate()  # type: ignore[attr-defined]
        proc.wait(timeout=60)  # type: ignore[attr-defined]


def test_an_unknown_group_is_refused_before_the_run(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code, _, err = _run(
        capsys, "run", "--group", "no-such-lab-group", "--journal", str(tmp_path / "j.sqlite")
    )
    assert code == 2 and err.count("\n") == 1
    assert "run.group" in err and "no such group 'no-such-lab-group'" in err
    assert not list(tmp_path.iterdir())


@pytest.mark.skipif(os.getuid() != 0 or shutil.which("setpriv") is None, reason="needs root and setpriv")
def test_another_user_can_neither_command_nor_forge(live: Path) -> None:
    """nobody runs `aeni send`: one line, exit 2, and no row reaches the journal."""
    _send_as_nobody(live)


def _send_as_nobody(live: Path) -> None:
    with JournalReader(live) as r:
        before = r.commands()
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.run(
        ["setpriv", "--reuid=65534", "--regid=65534", "--clear-groups", sys.executable, "-m",
         "aeni_console.cli.main", "send", str(live), "abort"],
        capture_output=True, text=True, timeout=120, env=env, cwd="/", check=False,
    )  # fmt: skip
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr and proc.stderr.count("\n") == 1
    owner = pwd.getpwuid(live.stat().st_uid).pw_name
    assert f"only the run's owner {owner} may command it" in proc.stderr
    with JournalReader(live) as r:
        assert r.commands() == before

"""SIGKILL real engine processes at random points, resume them, and demand the uninterrupted run's indents.

Uses the real Campaign and SimulatedDriver (cost-aware on the ternary scenario, 15 000 s budget, a 30×30
lattice). Engines are forked from a preloaded fork server; one trial goes through ``aeni run`` and
``aeni resume`` as a user would. benchmarks/crash_resume.py runs the same trials 100 times.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from benchmarks.crash_resume import TrialRun, compare, crash_trial, indent_count, run_trials, where_killed
from core.journal import JournalReader

ROOT = Path(__file__).resolve().parents[1]
# kills are placed by indent count, so a fast clock still lands them mid-run; half the benchmark's budget
# (5 blocks, 114 indents rather than 10 and 229) proves the same resume on a third of the fits
SPEC = TrialRun(speed=5e4, budget_s=15000.0)

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def trials(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list]:
    work = tmp_path_factory.mktemp("crash")
    # kills after a random number of committed indents (plus 0–10 ms): each one lands while the run is going
    ref, ref_wall, results = run_trials(work, SPEC, trials=9, workers=2, p_time=0.0)
    cli = crash_trial(work, SPEC, 9, ref, ref_wall, cli=True, p_time=0.0)
    return ref, [*results, cli]


def test_reference_run_is_complete(trials: tuple[Path, list]) -> None:
    ref, _ = trials
    with JournalReader(ref) as r:
        snap = r.snapshot()
        blocks = r.blocks()
    assert snap.finished and snap.n_indents == sum(len(b.results) for b in blocks) >= 100
    assert all(b.status == "observed" for b in blocks)
    assert snap.ledger["recovery"] == 0.0


def test_at_least_ten_sigkills_landed(trials: tuple[Path, list]) -> None:
    _, results = trials
    assert sum(t.kills_landed for t in results) >= 10
    assert sum(1 for t in results if t.kills_landed) >= 10
    assert any(t.cli and t.kills_landed for t in results)


def test_every_killed_run_resumes_to_identical_indents(trials: tuple[Path, list]) -> None:
    _, results = trials
    bad = [(t.trial, t.kills, t.error, t.comparison) for t in results if not t.identical]
    assert bad == []
    for t in results:
        c = t.comparison
        assert c.n_got == c.n_ref and c.duplicates == 0 and c.missing == 0 and c.extra == 0
        assert c.plans_identical and c.ledger_identical
        if t.kills_landed:
            # the crash cost real instrument time (re-engage, drift settle), journaled as recovery
            assert c.recovery_s > 0


def test_the_journal_records_the_recovery(trials: tuple[Path, list], tmp_path: Path) -> None:
    ref, results = trials
    t = next(t for t in results if t.kills_landed)
    journal = ref.parent / t.journal
    with JournalReader(journal) as r:
        events = r.events()
        sessions = r.table("sessions")[1]
        snap = r.snapshot()
    assert any(e.text.startswith("resumed:") for e in events)
    assert len(sessions) == 1 + t.resumes
    assert snap.finished and snap.state.value == "stopped"


def test_kill_mid_block_continues_at_the_first_unfinished_indent(
    tmp_path: Path, trials: tuple[Path, list]
) -> None:
    """A deterministic kill inside a block: the resumed engine runs only the missing indents of that block."""
    import time
    from dataclasses import replace

    from benchmarks.crash_resume import EngineProc

    ref, _ = trials
    journal = tmp_path / "mid.sqlite"
    proc = EngineProc(journal, replace(SPEC, speed=2000.0), create=True)  # ~60 ms per indent
    while proc.alive() and indent_count(journal) < 37:
        time.sleep(0.002)
    proc.kill()
    assert proc.wait() == -signal.SIGKILL
    assert where_killed(journal) == "inside a block"
    with JournalReader(journal) as r:
        before = {(x.block_id, x.indent_index) for x in r.results()}
        open_block = r.q.open_block()
    assert open_block is not None
    block, _, done = open_block
    assert 0 < done < block.n_indents
    out = subprocess.run(
        [sys.executable, "-m", "aeni_console.cli.main", "resume", str(journal), "--speed", "1e9"],
        capture_output=True,
        text=True,
        timeout=120,
        env=dict(os.environ, PYTHONPATH=str(ROOT)),
    )
    assert out.returncode == 0, out.stderr
    assert f"block {block.block_id} continues at indent {done} of {block.n_indents}" in out.stdout
    with JournalReader(journal) as r:
        rows = r.results()
        sessions = r.table("sessions")[1]
    resumed = {(x.block_id, x.indent_index) for x in rows} - before
    assert min(resumed) == (block.block_id, done)  # the first indent the second engine measured
    assert len(sessions) == 2
    assert compare(ref, journal).identical


def test_resume_of_a_corrupt_journal_changes_nothing(tmp_path: Path, trials: tuple[Path, list]) -> None:
    ref, _ = trials
    bad = tmp_path / "cut.sqlite"
    data = ref.read_bytes()
    bad.write_bytes(data[: len(data) // 3])
    before = bad.read_bytes()
    out = subprocess.run(
        [sys.executable, "-m", "aeni_console.cli.main", "resume", str(bad)],
        capture_output=True,
        text=True,
        timeout=60,
        env=dict(os.environ, PYTHONPATH=str(ROOT)),
    )
    assert out.returncode == 2 and "truncated" in out.stderr and out.stderr.count("\n") == 1
    assert bad.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cut.sqlite"]


def test_detached_engine_outlives_its_launcher_and_obeys_abort(tmp_path: Path) -> None:
    import time

    from core.journal import engine_running, send_command
    from core.runview import Command, CommandKind, EngineState

    journal = tmp_path / "runs" / "bg.sqlite"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    argv = [sys.executable, "-m", "aeni_console.cli.main", "run", "--detach", "--journal", str(journal), "--speed", "100",
            "--lattice-n", "30", "--budget-s", "30000", "--seed", "5",
            "--policy", "cost-aware"]  # 5×5 blocks: an abort lands inside the first ones  # fmt: skip
    out = subprocess.run(argv, capture_output=True, text=True, timeout=120, env=env, cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert f"journal {journal}" in out.stdout
    pid = int(out.stdout.split("supervisor PID ")[1].split()[0])  # the engine runs under it (issue 38)
    assert os.getsid(pid) == pid != os.getsid(0)  # its own session: closing the terminal does not reach it
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        with JournalReader(journal) as r:
            snap = r.snapshot()
        if snap.n_indents >= 1:
            break
        time.sleep(0.1)
    assert snap.state == EngineState.RUNNING and not snap.finished and snap.can_command
    # a second engine on the same journal is refused
    second = subprocess.run(
        [sys.executable, "-m", "aeni_console.cli.main", "resume", str(journal)], capture_output=True, text=True,
        timeout=60, env=env,
    )  # fmt: skip
    assert second.returncode == 2 and "already running" in second.stderr
    send_command(journal, Command(CommandKind.ABORT, author="tester"))
    deadline = time.monotonic() + 60
    while engine_running(journal) and time.monotonic() < deadline:
        time.sleep(0.1)
    with JournalReader(journal) as r:
        snap = r.snapshot()
        commands = r.commands()
    # at 100× a block takes ~35 s (at 500× a loaded machine let the first block end before the abort landed):
    # the abort cut the running block short, finished its indent and lifted
    assert snap.state == EngineState.STOPPED and snap.finished
    assert commands[-1]["kind"] == "abort" and commands[-1]["outcome"] == "accepted"
    assert snap.n_indents < 25 and snap.ledger["comeback"] > 0
    assert (journal.parent / "bg.sqlite.log").exists()


def test_start_engine_process_for_the_demo_console(tmp_path: Path) -> None:
    """The demo console's entry point: a step-mode engine process that waits for the operator."""
    import time

    from aeni_console.cli.run import start_engine_process
    from core.campaign_config import CampaignConfig
    from core.journal import send_command
    from core.plan import PlannerSettings
    from core.runview import Command, CommandKind, EngineState

    config = CampaignConfig(seed=2, lattice_n=30, settings=PlannerSettings(budget_s=30000), name="demo")
    journal = tmp_path / "demo.sqlite"
    proc = start_engine_process(config, journal, "step", speed=None, detach=False)
    assert isinstance(proc, subprocess.Popen) and journal.exists()
    deadline = time.monotonic() + 60
    snap = None
    while time.monotonic() < deadline:
        with JournalReader(journal) as r:
            snap = r.snapshot()
        if snap.state == EngineState.AWAITING_APPROVAL:
            break
        time.sleep(0.05)
    assert snap is not None and snap.state == EngineState.AWAITING_APPROVAL
    assert snap.pending is not None and snap.pending.block.block_id == 0 and snap.n_indents == 0
    assert snap.supervision == "step" and snap.run_name == "demo"
    assert [q.block_id for q in snap.queue] == [
        0
    ] * snap.pending.block.n_indents  # the pending block, with ETAs
    send_command(journal, Command(CommandKind.ABORT, author="tester"))
    assert proc.wait(timeout=60) == 0
    with JournalReader(journal) as r:
        snap = r.snapshot()
        decisions = r.decisions()
    assert snap.state == EngineState.STOPPED and snap.n_indents == 0 and decisions[0].status == "dropped"

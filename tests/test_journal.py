"""The journal: schema and codecs, the one-writer lock, reading while written, refusing bad files untouched."""

from __future__ import annotations

import hashlib
import math
import os
import shutil
import sqlite3
import subprocess
import sys
import textwrap
import threading
from pathlib import Path

import numpy as np
import pytest

from core.errors import InputError
from core.journal import (
    DriverState,
    Journal,
    JournalLockedError,
    JournalReader,
    NotOwnerError,
    decision_from_dict,
    default_journal_path,
    engine_running,
    map_fields_from_bytes,
    map_fields_to_bytes,
    send_command,
    to_json,
)
from core.journal.schema import SCHEMA_VERSION
from core.plan import Alternative, Block, Decision, IndentResult, PlannerSettings, StepRecord, local_grid
from core.profile import load_profile
from core.run.events import Decided, FitSummary, Indent, Observed, PlanState, StateChanged
from core.runview import Command, CommandKind, EngineState, MapFields

ROOT = Path(__file__).resolve().parents[1]


def make_journal(path: Path) -> Journal:
    return Journal.create(
        path,
        {"name": "j", "policy": "cost-aware", "settings": {"beta": 2.0}},
        load_profile("kla-imicro"),
        {"corners": [[0, 0, 0]]},
        supervision="supervised",
        grid_baseline_s=286392.0,
        stage_bounds_um=(0.0, 1000.0, 0.0, 1000.0),
        name="j",
    )


def block(bid: int, kind: str = "global", g: int = 5) -> Block:
    cx, cy = 100.0 + 50 * bid, 300.0
    return Block(bid, kind, cx, cy, g, 5.0, 80.0, local_grid(cx, cy, g, 5.0, 80.0))  # type: ignore[arg-type]


def result(b: Block, i: int, t: float) -> IndentResult:
    s = b.indents[i]
    return IndentResult(
        b.block_id, i, s.x_um, s.y_um, s.x_um + 0.1, s.y_um - 0.1, s.hold_s, 5.0 + 0.01 * i, 120.0, 0.003, t
    )


def fill(j: Journal, n_blocks: int, g: int = 5) -> None:
    """n_blocks planned, measured and observed blocks, as the engine writes them."""
    t = 0.0
    for bid in range(n_blocks):
        b = block(bid, "global" if bid % 4 == 0 else "local", g)
        d = Decision(
            b,
            "cost-aware",
            0.4,
            0.001,
            3000.0,
            alternatives=(Alternative(1.0, 2.0, "local", 0.1, 0.2, 30.0),),
        )
        j.emit(
            Decided(
                t,
                bid + 1,
                d,
                "auto",
                "",
                "",
                PlanState(bid, "planned", {"blocks_done": bid}, PlannerSettings()),
            )
        )
        for i in range(b.n_indents):
            t += 120.0
            j.emit(
                Indent(
                    t,
                    result(b, i, t),
                    ((StepRecord("indent", 40.0, bid, i), t - 80), (StepRecord("hold", 80.0, bid, i), t)),
                    DriverState(t, t, (b.indents[i].x_um, b.indents[i].y_um), True, "indent"),
                )
            )
        xs = np.linspace(0, 1000, 50)
        z = np.full((50, 50), 5.0, dtype=np.float32)
        fit = FitSummary(3.0, None, fitted=True, lengthscales_um=(100.0, 200.0))
        plan = PlanState(bid, "observed", {"blocks_done": bid + 1}, PlannerSettings(beta=1.5))
        j.emit(
            Observed(
                t,
                bid,
                j.next_snapshot_id(),
                {"ls": [0.1, 0.2]},
                fit,
                MapFields(0, xs, xs, z, z, z, z),
                plan,
                f"block {bid} observed",
            )
        )


def test_create_and_snapshot(tmp_path: Path) -> None:
    path = tmp_path / "runs" / "a.sqlite"
    j = make_journal(path)
    with JournalReader(path) as r:
        snap = r.snapshot()
        assert snap.run_name == "j" and snap.policy == "cost-aware" and snap.profile_name == "kla-imicro"
        assert snap.state == EngineState.IDLE and snap.supervision == "supervised"
        assert snap.owner and snap.can_command  # the writer holds the journal: its owner may command it
        assert r.snapshot(reader_user=os.getuid() + 1).can_command is False
        assert snap.n_indents == 0 and snap.queue == () and snap.grid_baseline_s == 286392.0
        assert snap.settings.beta == 2.0  # from the config until the planner records its own
    fill(j, 3)
    j.emit(StateChanged(0.0, EngineState.RUNNING))
    with JournalReader(path) as r:
        snap = r.snapshot()
        assert snap.state == EngineState.RUNNING and not snap.finished and snap.can_command
        assert snap.n_indents == 75 and snap.n_blocks == 3
        assert snap.ledger["indent"] == 75 * 40.0 and snap.ledger["hold"] == 75 * 80.0
        assert snap.mape_pct == 3.0 and snap.gp.lengthscales_um == (100.0, 200.0)
        assert snap.settings.beta == 1.5
        assert [t.median_gpa for t in snap.tested] == [pytest.approx(5.12)] * 3
    j.close()
    with JournalReader(path) as r:  # the engine is gone: it shows as failed (it never said it stopped)
        snap = r.snapshot()
        assert snap.state == EngineState.FAILED and snap.finished and not snap.can_command
    assert not (tmp_path / "runs" / "a.sqlite-wal").exists()  # folded back into one file on close


def test_queue_etas_follow_the_cost_model(tmp_path: Path) -> None:
    j = make_journal(tmp_path / "q.sqlite")
    b = block(0, "global", 2)
    j.emit(
        Decided(
            0.0,
            1,
            Decision(b, "p", 1.0, 1.0, 1.0),
            "auto",
            "",
            "",
            PlanState(0, "planned", {}, PlannerSettings()),
        )
    )
    j.emit(
        Indent(
            500.0,
            result(b, 0, 500.0),
            (),
            DriverState(500.0, 500.0, (b.indents[0].x_um, b.indents[0].y_um), True, "i"),
        )
    )
    with JournalReader(j.path) as r:
        q = r.snapshot().queue
    j.close()
    # three indents left, each 5 µm away: move t(5) + 40 s + 80 s hold
    move = load_profile("kla-imicro").move_s(5.0, 0.0)
    assert [item.indent_index for item in q] == [1, 2, 3]
    assert q[0].eta_s == pytest.approx(move + 120.0)
    assert q[2].eta_s == pytest.approx(3 * (move + 120.0))


def test_dataclasses_and_map_fields_round_trip() -> None:
    b = block(3, "local", 3)
    d = Decision(
        b,
        "aeni",
        0.5,
        0.25,
        900.0,
        stay_score=0.3,
        jump_score=0.1,
        alternatives=(Alternative(1.5, 2.5, "global", 0.1, 0.2, 600.0),),
        reason="why",
        phase="exploit",
        hold_mode="adaptive",
        area_error_pct=1.2,
    )
    import json

    assert decision_from_dict(json.loads(to_json(d))) == d
    xs = np.linspace(0.0, 1.0, 7)
    m = MapFields(
        9,
        xs,
        xs[:5],
        np.arange(35.0).reshape(5, 7),
        np.ones((5, 7)),
        np.zeros((5, 7)),
        np.full((5, 7), np.nan),
        next_candidate_um=(1.0, 2.0),
    )
    back = map_fields_from_bytes(9, map_fields_to_bytes(m))
    assert back.next_candidate_um == (1.0, 2.0) and back.snapshot_id == 9
    np.testing.assert_array_equal(back.mean_gpa, m.mean_gpa)
    assert np.isnan(back.total_sd_gpa).all()


def test_second_engine_is_refused_with_the_holder_pid(tmp_path: Path) -> None:
    j = make_journal(tmp_path / "l.sqlite")
    assert engine_running(j.path)
    with pytest.raises(JournalLockedError, match=rf"PID {os.getpid()}\b.*refusing"):
        Journal.open_writer(j.path)
    # and from another process
    code = textwrap.dedent(f"""
        import sys; sys.path.insert(0, {str(ROOT)!r})
        from core.journal import Journal
        from core.errors import InputError
        try:
            Journal.open_writer({str(j.path)!r})
        except InputError as e:
            print(e); sys.exit(3)
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 3 and f"PID {os.getpid()}" in out.stdout and str(j.path) in out.stdout
    j.close()
    assert not engine_running(j.path)
    j2 = Journal.open_writer(j.path)  # free again once the first engine ended
    j2.close()


def test_the_lock_dies_with_the_process(tmp_path: Path) -> None:
    path = tmp_path / "k.sqlite"
    make_journal(path).close()
    code = textwrap.dedent(f"""
        import sys, os, signal; sys.path.insert(0, {str(ROOT)!r})
        from core.journal import Journal
        j = Journal.open_writer({str(path)!r})
        print("locked", flush=True)
        os.kill(os.getpid(), signal.SIGKILL)
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert "locked" in out.stdout and out.returncode == -9
    assert not engine_running(path)
    Journal.open_writer(path).close()


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_truncated_journal_is_refused_and_left_untouched(tmp_path: Path) -> None:
    j = make_journal(tmp_path / "t.sqlite")
    fill(j, 4)
    j.close()
    data = j.path.read_bytes()
    bad = tmp_path / "truncated.sqlite"
    bad.write_bytes(data[: len(data) // 2])
    before = _digest(bad)
    for opener in (JournalReader, Journal.open_writer):
        with pytest.raises(InputError, match="truncated"):
            opener(bad)
    assert _digest(bad) == before
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith("truncated")) == [
        "truncated.sqlite"
    ]


def test_corrupt_and_foreign_files_are_refused_untouched(tmp_path: Path) -> None:
    j = make_journal(tmp_path / "c.sqlite")
    fill(j, 4)
    j.close()
    data = bytearray(j.path.read_bytes())
    page = int.from_bytes(data[16:18], "big")
    rng = np.random.default_rng(0)
    for p in range(2, len(data) // page):  # scribble over every b-tree page but the first
        data[p * page + 8 : p * page + 64] = rng.integers(0, 256, 56, dtype=np.uint8).tobytes()
    corrupt = tmp_path / "corrupt.sqlite"
    corrupt.write_bytes(bytes(data))
    before = _digest(corrupt)
    with pytest.raises(InputError, match=r"corrupt|malformed|not an AE-NI"):
        JournalReader(corrupt)
    with pytest.raises(InputError):
        Journal.open_writer(corrupt)
    assert _digest(corrupt) == before
    text = tmp_path / "notes.sqlite"
    text.write_text("hello, this is not a database at all" * 10)
    with pytest.raises(InputError, match="not an SQLite database"):
        JournalReader(text)
    other = tmp_path / "other.sqlite"
    sqlite3.connect(other).execute("CREATE TABLE x (a)").connection.commit()
    with pytest.raises(InputError, match="not an AE-NI journal"):
        JournalReader(other)
    with pytest.raises(InputError, match="no such journal"):
        JournalReader(tmp_path / "missing.sqlite")


def test_unknown_schema_version_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "v.sqlite"
    make_journal(path).close()
    conn = sqlite3.connect(path)
    conn.execute("UPDATE schema_version SET version = 99")
    conn.commit()
    conn.close()
    with pytest.raises(InputError, match="schema version 99 is not supported"):
        JournalReader(path)
    # a journal from before indents had a status: refused with one line that says where to read why
    conn = sqlite3.connect(path)
    conn.execute("UPDATE schema_version SET version = 1")
    conn.commit()
    conn.close()
    with pytest.raises(InputError) as info:
        JournalReader(path)
    assert "schema version 1 is not supported (this program reads version 6" in str(info.value)
    assert "docs/journal.md" in str(info.value) and "\n" not in str(info.value)


def test_reader_sees_consistent_snapshots_while_a_process_writes(tmp_path: Path) -> None:
    path = tmp_path / "live.sqlite"
    make_journal(path).close()
    code = textwrap.dedent(f"""
        import sys; sys.path.insert(0, {str(ROOT)!r}); sys.path.insert(0, {str(ROOT / "tests")!r})
        from core.journal import Journal
        from test_journal import fill
        j = Journal.open_writer({str(path)!r})
        print("go", flush=True)
        fill(j, 12, g=4)
        j.close()
    """)
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None and proc.stdout.readline().strip() == "go"
    seen = []
    with JournalReader(path) as r:
        while proc.poll() is None:
            s = r.snapshot()
            # a snapshot is one transaction: the ledger and the indent count always agree
            assert s.ledger["indent"] == pytest.approx(40.0 * s.n_indents)
            seen.append(s.n_indents)
        proc.wait(timeout=60)
        final = r.snapshot()
    assert proc.returncode == 0
    assert seen == sorted(seen) and final.n_indents == 12 * 16
    assert len(set(seen)) > 2  # it really read while the writer was writing


def test_send_command_checks_owner_and_engine(tmp_path: Path) -> None:
    j = make_journal(tmp_path / "s.sqlite")
    c = Command(kind=CommandKind.PAUSE, author="me", payload={}, shown_scores={"score": 1.0})
    with pytest.raises(NotOwnerError, match="may watch"):
        send_command(j.path, c, uid=os.getuid() + 1)
    cid = send_command(j.path, c)
    with JournalReader(j.path) as r:
        rows = r.commands()
    assert rows[0]["command_id"] == cid and rows[0]["kind"] == "pause" and rows[0]["processed"] == 0
    assert rows[0]["author"] == "me" and rows[0]["uid"] == os.getuid() and rows[0]["wall_utc"]
    j.close()
    with pytest.raises(InputError, match="no engine is running"):
        send_command(j.path, c)


def test_read_only_journal_file_can_be_watched_not_commanded(tmp_path: Path) -> None:
    if os.getuid() == 0:
        pytest.skip("root ignores file permissions")
    path = tmp_path / "ro.sqlite"
    j = make_journal(path)
    fill(j, 1)
    j.close()
    os.chmod(path, 0o444)
    with JournalReader(path) as r:
        assert r.snapshot().n_indents == 25


def test_blocks_for_replay(tmp_path: Path) -> None:
    j = make_journal(tmp_path / "r.sqlite")
    fill(j, 3, g=2)
    j.close()
    with JournalReader(j.path) as r:
        recs = r.blocks()
    assert [x.block.block_id for x in recs] == [0, 1, 2]
    assert all(x.status == "observed" and len(x.results) == 4 and x.decision is not None for x in recs)
    assert recs[1].seconds == pytest.approx(4 * 120.0)
    assert recs[2].snapshot_id == 3 and recs[2].fit_summary["mape_pct"] == 3.0
    assert recs[0].decision is not None and recs[0].decision.alternatives[0].cost_s == 30.0


def test_default_journal_path_is_utc_stamped_and_safe() -> None:
    p = default_journal_path("my run/1", "runs")
    assert p.parent == Path("runs") and p.suffix == ".sqlite"
    assert p.name.endswith("-my-run-1.sqlite") and p.name[8] == "T" and "/" not in p.name


def test_existing_journal_is_not_overwritten(tmp_path: Path) -> None:
    path = tmp_path / "x.sqlite"
    make_journal(path).close()
    before = _digest(path)
    with pytest.raises(InputError, match="already exists"):
        make_journal(path)
    assert _digest(path) == before


def test_snapshot_of_a_large_journal_reads_everything(tmp_path: Path) -> None:
    """2,000 indents: the console's view still adds up (speed is measured in benchmarks/)."""
    j = make_journal(tmp_path / "big.sqlite")
    j.conn.execute("PRAGMA synchronous = OFF")  # test data: 2,000 fsyncs would only slow the suite
    fill(j, 80)
    j.emit(StateChanged(0.0, EngineState.RUNNING))
    with JournalReader(j.path) as r:
        for _ in range(3):
            s = r.snapshot()
    j.close()
    assert s.n_indents == 2000 and len(s.tested) == 80 and len(s.log) == 80
    assert math.isclose(sum(s.ledger.values()), 2000 * 120.0)


def test_threads_can_share_a_reader_file(tmp_path: Path) -> None:
    j = make_journal(tmp_path / "th.sqlite")
    fill(j, 2, g=2)
    errors: list[BaseException] = []

    def read() -> None:
        try:
            with JournalReader(j.path) as r:
                for _ in range(20):
                    assert r.snapshot().n_indents == 8
        except BaseException as exc:  # pragma: no cover - reported below
            errors.append(exc)

    ts = [threading.Thread(target=read) for _ in range(3)]
    for t in ts:
        t.start()
    for t in ts:
        t.join()
    j.close()
    assert errors == []
    shutil.rmtree(tmp_path / "unused", ignore_errors=True)


def test_a_corrupt_wal_mode_copy_gets_no_sidecar_files(tmp_path: Path) -> None:
    """A journal copied while its engine ran is in WAL mode; checking it must not create -wal/-shm files."""
    j = make_journal(tmp_path / "live.sqlite")
    fill(j, 3)
    j.conn.execute("PRAGMA wal_checkpoint(TRUNCATE)")
    data = bytearray(j.path.read_bytes())
    j.close()
    assert data[18] == 2  # WAL mode in the header
    page = int.from_bytes(data[16:18], "big")
    for p in range(3, len(data) // page):
        data[p * page : p * page + 100] = b"\xff" * 100
    copy = tmp_path / "copy" / "live.sqlite"
    copy.parent.mkdir()
    copy.write_bytes(bytes(data))
    with pytest.raises(InputError, match="corrupt"):
        Journal.open_writer(copy)
    assert [p.name for p in copy.parent.iterdir()] == ["live.sqlite"]
    assert copy.read_bytes() == bytes(data)


def test_a_version_3_journal_is_read_and_converted_on_resume(tmp_path: Path) -> None:
    """Schema 4 adds the 'unverified' status (5 the event log): a version 3 journal still opens, and a resume
    converts it."""
    path = tmp_path / "v3.sqlite"
    with make_journal(path) as j:
        fill(j, 1)
    conn = sqlite3.connect(path)
    v4 = conn.execute("SELECT sql FROM sqlite_master WHERE name = 'indents'").fetchone()[0]
    v3 = v4.replace(", 'unverified'", "")
    conn.executescript(
        f"PRAGMA foreign_keys = OFF; {v3.replace('CREATE TABLE indents', 'CREATE TABLE old', 1)};"
        "INSERT INTO old SELECT * FROM indents; DROP TABLE indents; ALTER TABLE old RENAME TO indents;"
        "DROP TABLE run_events; UPDATE schema_version SET version = 3;"  # the event log came with 5
    )
    conn.close()
    assert len(JournalReader(path).results()) == 25
    with Journal.open_writer(path) as j:
        b = block(7)
        made = IndentResult.unmeasured(7, 0, b.indents[0], 9.0, "unverified", "export refused")
        j.record_indent(made, [], DriverState(9.0, 9.0, (0.0, 0.0), True, "indent"))
    reader = JournalReader(path)
    assert [r.status for r in reader.results()].count("unverified") == 1 and len(reader.results()) == 26
    version = sqlite3.connect(path).execute("SELECT version FROM schema_version").fetchone()[0]
    assert version == SCHEMA_VERSION

"""KLA, issue 38: a 0-byte export is refused into refused/ (it was never judged: the block waited on it
forever and the next block's status named it), and the deadline's margin shrinks with a fake InView's speed
as docs/kla.md says."""

from __future__ import annotations

import json
import time
from dataclasses import replace
from pathlib import Path

import pytest

from core.driver import InstrumentWait
from core.plan import Block, IndentResult, local_grid
from core.profile import load_profile
from drivers.kla.driver import KlaDriver
from drivers.kla.exchange import EXCHANGE_LATENCY_S, deadline_s, make_ticket, margin_s

BASE = load_profile("kla-imicro")
SHORT = replace(BASE, inview=replace(BASE.inview, stable_polls=2, poll_s=0.01, deadline_margin_s=1.5))


def _block(block_id: int) -> Block:
    return Block(block_id, "global", 500.0, 500.0, 2, 5.0, 80.0, local_grid(500.0, 500.0, 2, 5.0, 80.0))  # type: ignore[arg-type]


def _run(d: KlaDriver, b: Block) -> tuple[list[IndentResult], list[InstrumentWait]]:
    results, waits = [], []
    for ev in d.execute_block(b):
        if isinstance(ev, IndentResult):
            results.append(ev)
        elif isinstance(ev, InstrumentWait):
            waits.append(ev)
    return results, waits


def _manifest(archive: Path) -> list[dict[str, object]]:
    return [json.loads(line) for line in (archive / "manifest.jsonl").read_text().splitlines() if line]


def test_a_0_byte_export_is_refused_at_the_deadline(tmp_path: Path) -> None:
    exchange, archive = tmp_path / "x", tmp_path / "r1.sqlite.exports"
    exchange.mkdir()
    d = KlaDriver(SHORT, exchange, "r1", archive, speed=1e6)
    gen = d.execute_block(_block(0))
    first = next(gen)  # the ticket is out
    assert isinstance(first, InstrumentWait)
    empty = exchange / "inbox" / "r1-000-export.csv"
    empty.write_bytes(b"")
    waits = [ev for ev in gen if isinstance(ev, InstrumentWait)]
    assert any("r1-000-export.csv is empty (0 bytes)" in w.waiting for w in waits), [w.waiting for w in waits]
    assert not empty.exists()
    refused = [e for e in _manifest(archive) if e["status"] == "refused"]
    assert len(refused) == 1 and refused[0]["reason"] == "cannot be read: the file is empty (0 bytes)"
    assert (archive / str(refused[0]["file"])).is_file() and str(refused[0]["file"]).startswith("refused/")


def test_the_next_block_names_its_own_file_not_a_closed_blocks_empty_one(tmp_path: Path) -> None:
    exchange, archive = tmp_path / "x", tmp_path / "r1.sqlite.exports"
    exchange.mkdir()
    d = KlaDriver(SHORT, exchange, "r1", archive, speed=1e6)
    results, _ = _run(d, _block(0))  # nobody answers: block 0 closes at its deadline
    assert {r.status for r in results} == {"not_run"}
    late = exchange / "inbox" / "r1-000-export.csv"
    late.write_bytes(b"")  # block 0's export, empty, after block 0 closed
    gen = d.execute_block(_block(1))
    waits = []
    for ev in gen:
        if isinstance(ev, InstrumentWait):
            waits.append(ev.waiting)
            if not late.exists() and len(waits) > 5:
                break
    assert not any("r1-000" in w for w in waits), waits  # block 1's status is block 1's
    assert not late.exists()
    refused = [e for e in _manifest(archive) if e["status"] == "refused"]
    assert [(e["block_id"], e["reason"]) for e in refused] == [
        (0, "cannot be read: the file is empty (0 bytes)")
    ]


def test_the_deadline_margin_shrinks_with_the_speed() -> None:
    s = BASE.inview  # 180 s margin, 1.5 × the estimate
    assert margin_s(s) == margin_s(s, 1.0) == 180.0
    assert margin_s(s, 2.0) == 90.0
    floor = (s.stable_polls + 2) * s.poll_s + EXCHANGE_LATENCY_S  # what the exchange itself needs
    assert margin_s(s, 600.0) == floor < 180.0
    assert deadline_s(s, 3600.0, 600.0) == 3600.0 / 600.0 * 1.5 + floor
    assert margin_s(replace(s, deadline_margin_s=2.0), 600.0) == 2.0  # a profile's shorter margin stays
    b = _block(3)
    slow = make_ticket("r", b, s, expected_s=1200.0)
    fast = make_ticket("r", b, s, expected_s=1200.0, speed=600.0)
    assert slow.deadline_s == 1200.0 * 1.5 + 180.0
    assert fast.deadline_s == 1200.0 / 600.0 * 1.5 + floor


def test_a_wait_for_the_operator_across_a_daylight_saving_change_is_counted_in_real_seconds(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A ticket written Saturday 20:00 in Berlin before the spring-forward night is answered Sunday 08:00:
    11 hours later, not the 12 the clock readings differ by (the deadline waited an hour too long)."""
    from datetime import datetime

    from core.operator import OperatorAvailability, OperatorHours

    monkeypatch.setenv("TZ", "Europe/Berlin")
    time.tzset()
    try:
        op = OperatorAvailability(OperatorHours.parse("Mon-Sun 08:00-18:00"), 0.0, 7200.0)
        assert op.answer_delay_s(datetime(2024, 3, 30, 20, 0)) == 11 * 3600.0
        assert op.answer_delay_s(datetime(2024, 3, 29, 20, 0)) == 12 * 3600.0  # an ordinary night
    finally:
        monkeypatch.undo()
        time.tzset()


def test_a_refusal_recorded_after_a_manifest_line_cut_short_still_holds_its_rows_as_made(
    tmp_path: Path,
) -> None:
    """The soak's gap (a refused export's rows ended `not_run` instead of `unverified` after a kill and
    resume): a kill -9 or a full disk cut the manifest's last line short; the next entry (the refusal, with
    the rows it says were made) was appended to that cut line, so neither line could be read, and the resumed
    block closed with its made indents as not run (new indents could then land on them)."""
    from drivers.kla.inbox import ExportArchive, SiteOutcome

    exchange, archive = tmp_path / "x", tmp_path / "r1.sqlite.exports"
    exchange.mkdir()
    archive.mkdir()
    (archive / "manifest.jsonl").write_text('{"status": "closed", "run": "r1", "block_id": 0, "sha2')  # cut
    src = tmp_path / "r1-001-export.csv"
    src.write_text("Test,X Position,Y Position,HARDNESS\n1,1.0,2.0,5.0\n")
    made = tuple(SiteOutcome(i, "unverified", 480.0 + i, 520.0, reason="export refused") for i in range(3))
    ExportArchive(archive).refuse(src, None, "r1", 1, "positions do not match the plan: flipped", made=made)
    assert ExportArchive(archive).refused_made("r1", 1) == made
    resumed = KlaDriver(SHORT, exchange, "r1", archive, speed=1e6)  # the engine after the kill
    results, _ = _run(resumed, _block(1))
    assert [r.status for r in results] == ["unverified"] * 3 + ["not_run"]
    assert [r.actual_x_um for r in results[:3]] == [480.0, 481.0, 482.0]


def test_a_journal_whose_checkpoint_a_full_disk_cut_short_is_resumable(tmp_path: Path) -> None:
    """Soak v2 (journal folder full): SQLite's checkpoint wrote the header (n pages) and could not extend the
    file; every page is still in the -wal. The journal was refused as truncated on every resume (a crash
    loop) though SQLite reads it whole."""
    import os
    import shutil
    import sqlite3

    from core.journal.schema import SCHEMA_SQL, SCHEMA_VERSION, check_journal_file

    src, dst = tmp_path / "a.sqlite", tmp_path / "b.sqlite"
    c = sqlite3.connect(src, isolation_level=None)
    c.execute("PRAGMA journal_mode = WAL")
    c.execute("PRAGMA wal_autocheckpoint = 0")
    c.executescript(SCHEMA_SQL)
    c.execute("INSERT INTO schema_version VALUES (?)", (SCHEMA_VERSION,))
    for _ in range(60):
        c.execute(
            "INSERT INTO events (wall_utc, t_s, level, category, text) VALUES ('', 0, 'info', 'e', ?)",
            ("y" * 3000,),
        )
    c.execute("PRAGMA wal_checkpoint(PASSIVE)")  # the main file now says 80 pages; the WAL keeps them all
    shutil.copy(src, dst)
    shutil.copy(f"{src}-wal", f"{dst}-wal")  # as the disk held them when the engine died
    c.close()
    os.truncate(dst, dst.stat().st_size // 2)  # the pages the full disk did not take
    check_journal_file(dst)  # refused before: "journal is truncated: ... nothing was changed"
    with sqlite3.connect(dst) as back:
        assert back.execute("SELECT COUNT(*) FROM events").fetchone() == (60,)


def test_time_the_exchange_folder_was_gone_does_not_count_against_the_deadline(tmp_path: Path) -> None:
    """Soak v2's lost indents: the share went away (or read-only) past the deadline; at its first look after
    it came back the block closed as not run, and the export InView wrote a moment later was refused as
    stale: made indents held as not run. The block now waits the margin again once the folder is back."""
    import time as clock

    exchange, archive = tmp_path / "x", tmp_path / "r1.sqlite.exports"
    exchange.mkdir()
    d = KlaDriver(SHORT, exchange, "r1", archive, speed=1e6)
    b = _block(0)
    gen = d.execute_block(b)
    first = next(gen)
    assert isinstance(first, InstrumentWait)
    exchange.rename(tmp_path / "away")
    end = clock.monotonic() + 2.5  # past the 1.5 s deadline
    while clock.monotonic() < end:
        assert isinstance(next(gen), InstrumentWait)
    (tmp_path / "away").rename(exchange)
    rows = "".join(f"{k + 1},{s.x_um},{s.y_um},5.0,100.0\n" for k, s in enumerate(b.indents))
    (exchange / "inbox" / "r1-000-export.csv").write_text(
        f"Test,X Position,Y Position,HARDNESS,MODULUS\n{rows}"
    )
    results = [ev for ev in gen if isinstance(ev, IndentResult)]
    assert [r.status for r in results] == ["measured"] * b.n_indents, [r.note for r in results]

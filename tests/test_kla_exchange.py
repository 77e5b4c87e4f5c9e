"""The KLA file exchange: array file and ticket, the inbox's acceptance rules, and the fake InView's faults."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from dataclasses import replace
from datetime import UTC, datetime, timedelta
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st
from kla_synth import Material, RecordStyle, Tip, indent, record_rows, write_record

from core.errors import InputError
from core.plan import Block, IndentResult, local_grid
from core.profile import InstrumentProfile, InViewSettings, load_profile
from drivers.kla.exchange import (
    TOKEN_ALPHABET,
    ExchangeFolder,
    Ticket,
    array_offsets,
    from_array_offset,
    make_ticket,
    parse_sites,
    to_array_offset,
)
from drivers.kla.fake_inview import FakeInView, parse_fault
from drivers.kla.inbox import MATCHED_BY_ORDER, ExportArchive, InboxWatcher, PollResult
from drivers.sim.driver import SimulatedDriver
from drivers.sim.scenarios import make_scenario

ROOT = Path(__file__).resolve().parents[1]
PROFILE = load_profile("kla-imicro")
FAST = replace(PROFILE, inview=replace(PROFILE.inview, stable_polls=2, poll_s=0.01))


def block(
    block_id: int = 2, g: int = 3, centre: tuple[float, float] = (500.0, 400.0), hold: float = 80.0
) -> Block:
    return Block(block_id, "global", centre[0], centre[1], g, 5.0, hold, local_grid(*centre, g, 5.0, hold))


def ticket_for(b: Block, run: str = "r1", **kw: object) -> Ticket:
    return make_ticket(run, b, FAST.inview, expected_s=1000.0, **kw)  # type: ignore[arg-type]


@pytest.fixture
def exchange(tmp_path: Path) -> ExchangeFolder:
    root = tmp_path / "exchange"
    root.mkdir()
    return ExchangeFolder(root, "r1", FAST.inview)


@pytest.fixture
def watcher(exchange: ExchangeFolder, tmp_path: Path) -> InboxWatcher:
    return InboxWatcher(exchange, ExportArchive(tmp_path / "run.sqlite.exports"))


def poll_until(watcher: InboxWatcher, ticket: Ticket, n: int = 10, **kw: bool) -> PollResult:
    result = PollResult()
    for _ in range(n):
        result = watcher.poll(ticket, **kw)
        if result.accepted is not None or result.refused:
            return result
    return result


def write_export(path: Path, rows: list[list[object]], units: str = "µm", mtime: float | None = None) -> Path:
    lines = ["Test,X Position,Y Position,MODULUS,HARDNESS,Drift Rate", f",{units},{units},GPa,GPa,nm/s"]
    lines += [",".join("" if v is None else str(v) for v in r) for r in rows]
    lines += ["Mean,1,1,1,1,1", "Std. Dev.,1,1,1,1,1", "% COV,1,1,1,1,1"]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    if mtime is not None:
        os.utime(path, (mtime, mtime))
    return path


def rows_for(t: Ticket, scale: float = 1.0, flip_y: bool = False) -> list[list[object]]:
    out: list[list[object]] = []
    for k, (x, y) in enumerate(t.sites_um, start=1):
        if flip_y:
            y = 2 * t.origin_y_um - y
        out.append([k, x * scale, y * scale, 100.0 + k, 5.0 + 0.01 * k, 0.01])
    return out


# ------------------------------------------------------------------------------------- array and ticket


def test_sites_file_is_relative_to_the_origin_with_the_image_y_flip(exchange: ExchangeFolder) -> None:
    b = block()
    t = ticket_for(b)
    exchange.publish(t)
    text = (exchange.outbox / "r1-002-sites.txt").read_text()
    lines = text.splitlines()
    assert (
        len(lines) == 9 and lines[0] == "-5, 5" and lines[4] == "0, 0"
    )  # first site: (cx-5, cy-5) µm, Y flipped
    assert all(", " in ln and ln.count(",") == 1 for ln in lines)
    assert parse_sites(text, "sites") == [
        to_array_offset(FAST.inview, s.x_um - 500.0, s.y_um - 400.0) for s in b.indents
    ]
    assert array_offsets(t, FAST.inview)[0] == (-5.0, 5.0)


@given(
    dx=st.floats(-2000, 2000),
    dy=st.floats(-2000, 2000),
    sx=st.sampled_from([1, -1]),
    sy=st.sampled_from([1, -1]),
    swap=st.booleans(),
)
def test_array_convention_round_trips(dx: float, dy: float, sx: int, sy: int, swap: bool) -> None:
    s = InViewSettings(array_x_sign=sx, array_y_sign=sy, array_swap_xy=swap)
    assert from_array_offset(s, *to_array_offset(s, dx, dy)) == pytest.approx((dx, dy))


def test_ticket_fields_deadline_token_and_round_trip(exchange: ExchangeFolder) -> None:
    now = datetime(2026, 11, 23, 4, 0, tzinfo=UTC)
    t = make_ticket("r1", block(hold=0.0), FAST.inview, expected_s=2000.0, now=now)
    assert t.deadline_s == 2000.0 * 1.5 + 180.0
    assert t.deadline() - t.created() == timedelta(seconds=3180)
    assert len(t.token) == 5 and set(t.token) <= set(TOKEN_ALPHABET)
    assert [(m.hold_s, m.method, m.first_site, m.last_site) for m in t.methods] == [
        (0.0, "AENI hold 0 s.nmt", 1, 9)
    ]
    assert t.origin_mm == (0.5, 0.4) and t.export_stem == "r1-002-export"
    exchange.publish(t)
    assert exchange.read_ticket(2) == t
    text = (exchange.outbox / "r1-002-ticket.txt").read_text()
    for needed in (
        "TOKEN " + t.token,
        "X 0.5000 mm, Y 0.4000 mm",
        "r1-002-sites.txt",
        "AENI hold 0 s.nmt",
        "04:53:00 UTC",
    ):
        assert needed in text
    data = json.loads((exchange.outbox / "r1-002-ticket.json").read_text())
    assert data["origin_mm"] == [0.5, 0.4] and data["token"] == t.token
    assert sorted(p.name for p in exchange.outbox.iterdir()) == [
        "r1-002-sites.txt",
        "r1-002-ticket.json",
        "r1-002-ticket.txt",
    ]  # no temp files left


def test_profile_inview_section_and_its_errors(tmp_path: Path) -> None:
    good = tmp_path / "lab.toml"
    good.write_text(
        'extends = "kla-imicro"\n[inview]\nmethods = { "0" = "Blitz.nmt", "5" = "h5.nmt", "80" = "h80.nmt" }\n'
        "array_y_sign = 1\nstable_polls = 5\n[drift]\nnoise_floor_nm_s = 0.01\n"
    )
    p = load_profile(good)
    assert (
        p.inview.method_for(80.0) == "h80.nmt" and p.inview.array_y_sign == 1 and p.inview.stable_polls == 5
    )
    assert p.drift_noise_floor_nm_s == 0.01
    cases = {
        '[inview]\nmethods = { "80" = "h80.nmt" }\n': "no method for the allowed hold(s) 0, 5 s",
        "[inview]\narray_y_sign = 2\n": "inview.array_y_sign must be 1 or -1",
        "[inview]\ncolour = 1\n": "unknown field inview.colour",
        "[inview]\ndeadline_factor = 0.5\n": "deadline_factor must be ≥ 1",
    }
    for body, problem in cases.items():
        bad = tmp_path / "bad.toml"
        bad.write_text('extends = "kla-imicro"\n' + body)
        with pytest.raises(InputError, match=re.escape(problem)):
            load_profile(bad)


def test_bad_run_name_and_missing_folder_are_refused(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="exchange folder does not exist"):
        ExchangeFolder(tmp_path / "nope", "r1", FAST.inview)
    with pytest.raises(InputError, match="cannot name exchange files"):
        ExchangeFolder(tmp_path, "a run/with slash", FAST.inview)


# -------------------------------------------------------------------------------------- inbox rules


def test_export_is_accepted_only_when_complete_then_archived_with_its_hash(
    exchange: ExchangeFolder, watcher: InboxWatcher
) -> None:
    t = ticket_for(block())
    rows = rows_for(t)
    rows[3][4] = "--"  # InView's "no value": a failed indent, never a zero
    rows[5][4] = 1.797e308
    path = write_export(exchange.inbox / "r1-002-export.csv", rows)
    lock = exchange.inbox / "~$r1-002-export.csv"
    lock.write_text("x")
    results = [watcher.poll(t) for _ in range(4)]
    assert all(r.accepted is None for r in results)
    assert "lock file" in results[-1].waiting
    lock.unlink()
    with path.open("a") as fh:  # still growing: the stability count starts again
        fh.write("\n")
    assert "still being written" in watcher.poll(t).waiting
    assert watcher.poll(t).accepted is None  # 1 of stable_polls = 2 unchanged looks
    accepted = watcher.poll(t).accepted
    assert accepted is not None and not path.exists()
    statuses = [o.status for o in accepted.outcomes]
    assert statuses == ["measured"] * 3 + ["failed", "measured", "failed"] + ["measured"] * 3
    assert [o.indent_index for o in accepted.outcomes] == list(range(9))
    assert accepted.outcomes[3].hardness_gpa is None and "'--'" in accepted.outcomes[3].reason
    assert accepted.outcomes[0].hardness_gpa == pytest.approx(5.01)
    entry = watcher.archive.accepted("r1", 2)
    assert entry is not None and entry["sha256"] == accepted.sha256 and len(entry["sha256"]) == 64
    assert accepted.archived.is_file() and accepted.archived.parent == watcher.archive.folder
    # what was accepted is recorded with the hash: a resumed run takes it from there, without parsing
    again = watcher.archive.accepted_export("r1", 2)
    assert again is not None and again.outcomes == accepted.outcomes


def test_duplicate_stale_and_closed_block_exports_are_refused(
    exchange: ExchangeFolder, watcher: InboxWatcher
) -> None:
    t = ticket_for(block())
    path = write_export(exchange.inbox / "r1-002-export.csv", rows_for(t))
    payload = path.read_bytes()
    assert poll_until(watcher, t).accepted is not None
    # the same bytes again (exported twice)
    path.write_bytes(payload)
    refused = poll_until(watcher, t).refused
    assert len(refused) == 1 and refused[0].reason.startswith(
        "duplicate: same SHA-256 as the export accepted for block 2"
    )
    # different bytes for the block that is already closed
    write_export(exchange.inbox / "r1-002-export.csv", rows_for(t)[:-1])
    t3 = ticket_for(block(3, centre=(700.0, 400.0)))
    refused = poll_until(watcher, t3).refused
    assert refused[0].reason == "stale: block 2 has an accepted export"
    # an export older than the ticket (left over from before)
    old = datetime.fromisoformat(t3.created_utc).timestamp() - 3600
    write_export(exchange.inbox / "r1-003-export.csv", rows_for(t3), mtime=old)
    refused = poll_until(watcher, t3).refused
    assert (
        refused[0].reason.startswith("stale: written") and "before this block's ticket" in refused[0].reason
    )
    # nothing is lost: every refused file is kept with its reason
    entries = [e for e in watcher.archive.entries() if e["status"] == "refused"]
    assert len(entries) == 3 and all((watcher.archive.folder / e["file"]).is_file() for e in entries)
    assert not list(exchange.inbox.glob("r1-*-export.csv"))
    # another run's export in the same folder is not ours to touch
    other = write_export(exchange.inbox / "r2-003-export.csv", rows_for(t3))
    assert poll_until(watcher, t3).refused == () and other.exists()


def test_row_count_partial_waits_for_an_abort_report_more_rows_are_refused(
    exchange: ExchangeFolder, watcher: InboxWatcher
) -> None:
    t = ticket_for(block())
    write_export(exchange.inbox / "r1-002-export.csv", rows_for(t)[:4])
    result = poll_until(watcher, t)
    assert result.accepted is None and "has 4 of 9 rows: waiting for an 'aborted' report" in result.waiting
    accepted = watcher.poll(t, partial_ok=True).accepted
    assert accepted is not None and accepted.partial
    assert [o.status for o in accepted.outcomes] == ["measured"] * 4 + ["not_run"] * 5
    assert accepted.outcomes[-1].reason == "array aborted" and accepted.outcomes[-1].hardness_gpa is None
    t3 = ticket_for(block(3))
    extra = [*rows_for(t3), [10, 0.0, 0.0, 1.0, 1.0, 0.0]]
    write_export(exchange.inbox / "r1-003-export.csv", extra)
    refused = poll_until(watcher, t3).refused
    assert refused[0].reason == "has 10 rows, the block planned 9 (another array?)"


def test_positions_mm_as_um_flipped_y_and_wrong_origin(
    exchange: ExchangeFolder, watcher: InboxWatcher
) -> None:
    t = ticket_for(block())
    write_export(exchange.inbox / "r1-002-export.csv", rows_for(t, scale=1e-3))
    accepted = poll_until(watcher, t).accepted
    assert accepted is not None and "mm labelled as µm" in accepted.notes[0]
    assert accepted.outcomes[0].x_um == pytest.approx(t.sites_um[0][0])
    # a flipped Y on a grid centred on its origin: every row still on a planned site -> kept where measured
    t3 = ticket_for(block(3))
    write_export(exchange.inbox / "r1-003-export.csv", rows_for(t3, flip_y=True))
    accepted = poll_until(watcher, t3).accepted
    assert accepted is not None and any("the Y axis is flipped" in n for n in accepted.notes)
    first = accepted.outcomes[0]  # site 0 at cy-5 was measured in row 7 (array order mirrored)
    assert first.y_um == pytest.approx(t3.sites_um[0][1]) and first.hardness_gpa == pytest.approx(5.07)
    # the array run from another origin: refused with the offset named
    t4 = ticket_for(block(4))
    shifted = [[k, x + 40.0, y - 25.0, *rest] for k, x, y, *rest in rows_for(t4)]
    write_export(exchange.inbox / "r1-004-export.csv", shifted)
    refused = poll_until(watcher, t4).refused
    assert "another origin" in refused[0].reason and "(+40.0, -25.0) µm" in refused[0].reason


def test_unreadable_export_waits_then_is_refused_at_the_deadline(
    exchange: ExchangeFolder, watcher: InboxWatcher
) -> None:
    t = ticket_for(block())
    (exchange.inbox / "r1-002-export.xlsx").write_bytes(b"PK\x03\x04" + b"\x00" * 40)  # a cut workbook
    result = poll_until(watcher, t, n=4)
    assert result.accepted is None and "does not open cleanly yet" in result.waiting
    assert (exchange.inbox / "r1-002-export.xlsx").exists()
    refused = watcher.poll(t, final=True).refused
    assert refused and refused[0].reason.startswith("cannot be read: unreadable Excel workbook")


# ---------------------------------------------------------------------------------------- fake InView


def fake(exchange: ExchangeFolder, *faults: str, rate: float = 0.0, fmt: str = "xlsx") -> FakeInView:
    scenario = make_scenario("ternary", 7)
    return FakeInView(
        exchange.root,
        FAST,
        scenario.make_emulator,
        faults=tuple(parse_fault(f) for f in faults),
        fmt=fmt,
        invalid_rate=rate,
        write_s=0.05,
        log=lambda _line: None,
    )


def sim_results(b: Block, mirror_y: bool = False) -> list[IndentResult]:
    """What the sim driver measures for the block from the same state (the fake must agree)."""
    if mirror_y:
        b = replace(b, indents=tuple(replace(s, y_um=2 * b.center_y_um - s.y_um) for s in b.indents))
    sim = SimulatedDriver(make_scenario("ternary", 7).make_emulator(), FAST)
    sim.set_state(1234.0, (0.0, 0.0), False)
    return [ev for ev in sim.execute_block(b) if isinstance(ev, IndentResult)]


def served(
    exchange: ExchangeFolder, watcher: InboxWatcher, b: Block, *faults: str, **kw: object
) -> tuple[Ticket, FakeInView]:
    t = ticket_for(b, clock_s=1234.0)
    exchange.publish(t)
    f = fake(exchange, *faults, **kw)  # type: ignore[arg-type]
    (path,) = f.pending()
    f.serve(path)
    return t, f


@pytest.mark.parametrize("fmt", ["xlsx", "csv", "records"])
def test_fake_inview_measures_what_the_sim_driver_measures(
    exchange: ExchangeFolder, watcher: InboxWatcher, fmt: str
) -> None:
    b = block(3)  # odd block: written slowly, with a lock file
    t, f = served(exchange, watcher, b, rate=0.3, fmt=fmt)
    assert exchange.report(t, "started") == t.token
    assert f.pending() == []  # served once
    accepted = poll_until(watcher, t).accepted
    assert accepted is not None and len(accepted.outcomes) == 9
    expect = sim_results(b)
    failed = [o for o in accepted.outcomes if o.status == "failed"]
    assert failed and all("1.797e308" in o.reason and o.hardness_gpa is None for o in failed)
    for o, r in zip(accepted.outcomes, expect, strict=True):
        assert o.x_um == pytest.approx(r.commanded_x_um) and o.y_um == pytest.approx(r.commanded_y_um)
        if o.status == "measured":
            assert o.hardness_gpa == pytest.approx(r.hardness_gpa) and o.drift_rate_nm_s == pytest.approx(
                r.drift_rate_nm_s
            )
            assert o.max_depth_nm == 100.0


def test_fake_fault_aborted(exchange: ExchangeFolder, watcher: InboxWatcher) -> None:
    t, _ = served(exchange, watcher, block(2), "aborted@2")
    assert exchange.report(t, "aborted") == t.token
    assert poll_until(watcher, t).accepted is None  # 4 of 9 rows: held until the abort counts
    accepted = watcher.poll(t, partial_ok=True).accepted
    assert accepted is not None
    assert [o.status for o in accepted.outcomes] == ["measured"] * 4 + ["not_run"] * 5


def test_fake_fault_surface_not_found_and_missing_export(
    exchange: ExchangeFolder, watcher: InboxWatcher
) -> None:
    t, _ = served(exchange, watcher, block(2), "surface-not-found")
    assert exchange.report(t, "surface-not-found") == t.token
    assert not list(exchange.inbox.glob("*-export.*"))
    t3, _ = served(exchange, watcher, block(3), "missing-export@3")
    assert exchange.report(t3, "started") == t3.token
    final = watcher.poll(t3, final=True)
    assert final.accepted is None and final.waiting == "no export yet"


def test_fake_fault_duplicate_export(exchange: ExchangeFolder, watcher: InboxWatcher) -> None:
    b = block(2)
    t = ticket_for(b, clock_s=1234.0)
    exchange.publish(t)
    f = fake(exchange, "duplicate-export")
    (path,) = f.pending()
    thread = threading.Thread(target=f.serve, args=(path,))
    thread.start()
    accepted = None
    deadline = time.monotonic() + 20
    while accepted is None and time.monotonic() < deadline:
        accepted = watcher.poll(t).accepted
        time.sleep(0.01)
    assert accepted is not None
    refused: list[str] = []
    while not refused and time.monotonic() < deadline:
        refused = [r.reason for r in watcher.poll(t).refused]
        time.sleep(0.01)
    thread.join()
    assert refused and refused[0].startswith("duplicate: same SHA-256")
    assert sum(e["status"] == "accepted" for e in watcher.archive.entries()) == 1


def test_fake_faults_mm_um_and_flipped_y(exchange: ExchangeFolder, watcher: InboxWatcher) -> None:
    t, _ = served(exchange, watcher, block(2), "mm-um")
    accepted = poll_until(watcher, t).accepted
    assert accepted is not None and "mm labelled as µm" in accepted.notes[0]
    assert [o.hardness_gpa for o in accepted.outcomes] == pytest.approx(
        [r.hardness_gpa for r in sim_results(block(2))]
    )
    b3 = block(3)
    t3, _ = served(exchange, watcher, b3, "flipped-y@3")
    accepted = poll_until(watcher, t3).accepted
    assert accepted is not None and any("the Y axis is flipped" in n for n in accepted.notes)
    # each value is attributed to the site where it was measured (the mirrored array ran in mirrored order)
    mirrored = sim_results(b3, mirror_y=True)
    by_site = {(round(r.commanded_x_um, 3), round(r.commanded_y_um, 3)): r.hardness_gpa for r in mirrored}
    for o in accepted.outcomes:
        assert o.hardness_gpa == pytest.approx(by_site[(round(o.x_um or 0, 3), round(o.y_um or 0, 3))])


def test_fake_inview_process_serves_tickets_and_stops_on_sigterm(
    exchange: ExchangeFolder, watcher: InboxWatcher
) -> None:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    bad = subprocess.run(
        [
            sys.executable,
            "-m",
            "aeni_console.cli.main",
            "kla",
            "fake-inview",
            "--exchange",
            str(exchange.root),
            "--fault",
            "gremlins",
        ],
        capture_output=True,
        text=True,
        env=env,
    )
    assert bad.returncode == 2 and "'gremlins' is not a fault" in bad.stderr and "Traceback" not in bad.stderr
    proc = subprocess.Popen(
        [
            sys.executable, "-m", "aeni_console.cli.main", "kla", "fake-inview", "--exchange", str(exchange.root),
            "--speed", "100000", "--seed", "7", "--format", "csv",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=env,
    )  # fmt: skip
    try:
        t = make_ticket("r1", block(2), PROFILE.inview, expected_s=100.0, clock_s=1234.0)
        exchange.publish(t)
        accepted = None
        deadline = time.monotonic() + 60
        while accepted is None and time.monotonic() < deadline:
            accepted = watcher.poll(t).accepted
            time.sleep(0.05)
        assert accepted is not None
        assert [o.hardness_gpa for o in accepted.outcomes if o.status == "measured"] == pytest.approx(
            [
                r.hardness_gpa
                for r, o in zip(sim_results(block(2)), accepted.outcomes, strict=True)
                if o.status == "measured"
            ]
        )
    finally:
        proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=30)
    assert proc.returncode == 0, out
    assert "r1 block 2: exported r1-002-export.csv (9 rows)" in out


def test_fake_profile_is_the_sites_convention(exchange: ExchangeFolder) -> None:
    # the fake reads the array with its own profile: same convention -> the planned positions
    t = ticket_for(block(2))
    exchange.publish(t)
    f = fake(exchange)
    b = f._block(t, exchange)
    assert [(s.x_um, s.y_um) for s in b.indents] == pytest.approx(list(t.sites_um))
    assert isinstance(FAST, InstrumentProfile)


def _without_positions(path: Path, rows: list[list[object]]) -> Path:
    lines = ["Test,MODULUS,HARDNESS,Drift Rate", ",GPa,GPa,nm/s"]
    lines += [",".join(str(v) for v in (r[0], *r[3:])) for r in rows]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def test_an_export_without_positions_is_matched_by_test_order(
    exchange: ExchangeFolder, watcher: InboxWatcher
) -> None:
    t = ticket_for(block())
    _without_positions(exchange.inbox / "r1-002-export.csv", rows_for(t))
    accepted = poll_until(watcher, t).accepted
    assert accepted is not None and MATCHED_BY_ORDER in accepted.notes
    assert [o.hardness_gpa for o in accepted.outcomes] == pytest.approx(
        [5.0 + 0.01 * k for k in range(1, 10)]
    )
    assert all(o.x_um is None for o in accepted.outcomes) and accepted.fmt == "unknown"
    entry = watcher.archive.accepted("r1", 2)
    assert entry is not None and MATCHED_BY_ORDER in entry["notes"]
    # fewer rows: waits for an 'aborted' report, then the rows are the first sites; skipped sites are skipped
    t3 = ticket_for(block(3))
    _without_positions(exchange.inbox / "r1-003-export.csv", rows_for(t3)[:4])
    assert "no positions: waiting for an 'aborted' report" in poll_until(watcher, t3).waiting
    partial = watcher.poll(t3, partial_ok=True).accepted
    assert partial is not None and [o.status for o in partial.outcomes] == ["measured"] * 4 + ["not_run"] * 5
    t4 = ticket_for(block(4))
    _without_positions(exchange.inbox / "r1-004-export.csv", rows_for(t4)[:8])
    skipped = poll_until(watcher, t4, skipped=frozenset({t4.first_index + 2}))  # type: ignore[arg-type]
    assert skipped.accepted is not None
    assert [o.status for o in skipped.accepted.outcomes][:4] == [
        "measured",
        "measured",
        "not_run",
        "measured",
    ]


def test_a_refused_export_with_positions_says_which_indents_were_made(
    exchange: ExchangeFolder, watcher: InboxWatcher
) -> None:
    b = block()
    cut = replace(b, indents=b.indents[:6])  # not symmetric about the origin: a flipped Y is refused
    t = ticket_for(cut)
    write_export(exchange.inbox / "r1-002-export.csv", rows_for(t, flip_y=True))
    refused = poll_until(watcher, t).refused
    assert refused and "Y axis is flipped" in refused[0].reason
    made = refused[0].made
    assert [o.status for o in made] == ["unverified"] * 6 and all(o.hardness_gpa is None for o in made)
    assert [o.y_um for o in made] == pytest.approx([2 * t.origin_y_um - y for _, y in t.sites_um])


class _Killed(Exception):
    pass


def test_a_kill_while_an_export_is_archived_loses_nothing(
    exchange: ExchangeFolder, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The engine dies after the archive copied an export but before it recorded it: the file is still in the
    inbox and the next engine accepts it; dies after the record: the record holds what the file said."""
    t = ticket_for(block())
    path = write_export(exchange.inbox / "r1-002-export.csv", rows_for(t))
    archive = ExportArchive(tmp_path / "run.sqlite.exports")

    def killed(_self: ExportArchive, _entry: dict[str, object]) -> None:
        raise _Killed

    monkeypatch.setattr(ExportArchive, "_append", killed)
    with pytest.raises(_Killed):
        poll_until(InboxWatcher(exchange, archive), t)
    assert path.exists() and archive.accepted("r1", 2) is None  # copied, not recorded, still in the inbox
    monkeypatch.undo()
    accepted = poll_until(InboxWatcher(exchange, archive), t).accepted  # the resumed engine
    assert accepted is not None and not path.exists() and accepted.archived.is_file()
    assert archive.accepted_export("r1", 2) is not None


def test_a_block_export_as_a_folder_of_per_test_records_is_accepted_whole(
    exchange: ExchangeFolder, watcher: InboxWatcher
) -> None:
    t = ticket_for(block())
    folder = exchange.inbox / "r1-002-export"  # InView's one CSV per test, in the block's export folder
    folder.mkdir()
    material, truths = Material(5.0, 100.0), []
    for k, (x, y) in enumerate(t.sites_um, start=1):
        rows, truth = record_rows(
            indent(material, Tip(), (0.5, 1.0), seed=k, points=15), material, x, y, RecordStyle()
        )
        write_record(str(folder / f"Test{k}.csv"), rows, RecordStyle())
        truths.append(truth["H"])
    accepted = poll_until(watcher, t).accepted
    assert accepted is not None and accepted.fmt == "InView per-test record"
    assert [o.hardness_gpa for o in accepted.outcomes] == pytest.approx(truths, rel=1e-6)
    assert not folder.exists() and accepted.archived.is_dir()  # archived whole, out of the inbox

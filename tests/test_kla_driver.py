"""The KLA driver against a running fake InView: every fault ends as specified, each planned indent is
reported exactly once, and no failed or not-run indent carries a number."""

from __future__ import annotations

import json
import math
import threading
from collections.abc import Iterator
from dataclasses import replace
from datetime import UTC, datetime, timedelta
from pathlib import Path

import pytest

from core.driver import Driver, DriverAborted, InstrumentWait, WaitsForOperator
from core.plan import Block, IndentResult, StepRecord, local_grid
from core.profile import InstrumentProfile, load_profile
from drivers.kla.driver import KlaDriver, make_kla_driver
from drivers.kla.fake_inview import FakeInView, parse_fault
from drivers.sim.driver import SimulatedDriver
from drivers.sim.scenarios import make_scenario

BASE = load_profile("kla-imicro")
# a deadline that never runs out under a loaded CI machine, where a block is to end by its export or report ...
PROFILE = replace(
    BASE,
    inview=replace(BASE.inview, stable_polls=2, poll_s=0.01, deadline_factor=1.0, deadline_margin_s=30.0),
)
# ... and a short one where a test waits for the deadline itself
DEADLINE_PROFILE = replace(PROFILE, inview=replace(PROFILE.inview, deadline_margin_s=2.0))
SEED = 3


def block(block_id: int, centre: tuple[float, float] = (500.0, 500.0), kind: str = "global") -> Block:
    return Block(block_id, kind, centre[0], centre[1], 3, 5.0, 80.0, local_grid(*centre, 3, 5.0, 80.0))  # type: ignore[arg-type]


@pytest.fixture
def exchange(tmp_path: Path) -> Path:
    root = tmp_path / "exchange"
    root.mkdir()
    return root


def running_fake(exchange: Path, *faults: str, rate: float = 0.0, fmt: str = "xlsx") -> Iterator[FakeInView]:
    fake = FakeInView(
        exchange,
        PROFILE,
        make_scenario("ternary", SEED).make_emulator,
        faults=tuple(parse_fault(f) for f in faults),
        fmt=fmt,
        invalid_rate=rate,
        write_s=0.02,
        log=lambda _line: None,
    )
    stop = threading.Event()
    thread = threading.Thread(target=fake.serve_forever, kwargs={"poll_s": 0.01, "stop": stop.is_set})
    thread.start()
    try:
        yield fake
    finally:
        stop.set()
        thread.join()


def driver(exchange: Path, tmp_path: Path, profile: InstrumentProfile = PROFILE) -> KlaDriver:
    return KlaDriver(profile, exchange, "r1", tmp_path / "r1.sqlite.exports", speed=1e6)


def run_block(d: KlaDriver, b: Block) -> tuple[list[IndentResult], list[StepRecord], list[InstrumentWait]]:
    results, steps, waits = [], [], []
    for ev in d.execute_block(b):
        if isinstance(ev, IndentResult):
            results.append(ev)
        elif isinstance(ev, StepRecord):
            steps.append(ev)
        else:
            waits.append(ev)
    return results, steps, waits


def sim_hardness(b: Block, clock_s: float = 0.0) -> list[float]:
    sim = SimulatedDriver(make_scenario("ternary", SEED).make_emulator(), PROFILE)
    sim.set_state(clock_s, (0.0, 0.0), False)
    return [ev.hardness_gpa for ev in sim.execute_block(b) if isinstance(ev, IndentResult)]


def check_invariants(b: Block, results: list[IndentResult]) -> None:
    """Each planned indent exactly once, in order; a number only where it was measured."""
    assert [r.indent_index for r in results] == list(range(b.n_indents))
    for r in results:
        assert r.measured == math.isfinite(r.hardness_gpa)
        if not r.measured:
            assert math.isnan(r.hardness_gpa) and r.note


def test_kla_driver_satisfies_the_contract_and_waits_for_an_operator(exchange: Path, tmp_path: Path) -> None:
    d = driver(exchange, tmp_path)
    assert isinstance(d, Driver) and isinstance(d, WaitsForOperator)


def test_normal_block_measures_what_the_sim_measures(exchange: Path, tmp_path: Path) -> None:
    d = driver(exchange, tmp_path)
    b = block(0)
    for _ in running_fake(exchange, rate=0.25):
        results, steps, waits = run_block(d, b)
    check_invariants(b, results)
    statuses = [r.status for r in results]
    assert "failed" in statuses and set(statuses) <= {"measured", "failed"}
    expect = sim_hardness(b)
    for r, h in zip(results, expect, strict=True):
        if r.measured:
            assert r.hardness_gpa == pytest.approx(h)
    # the export's "Displacement at Max Load" reaches the drift rules; a 1.797e308 row reports no depth
    assert {r.depth_at_max_load_nm for r in results if r.measured} == {100.0}
    assert {r.depth_at_max_load_nm for r in results if not r.measured} == {None}
    assert (
        waits
        and waits[0].block_id == 0
        and "·····" in waits[0].ticket
        and d.folder.read_ticket(0).token not in waits[0].ticket
    )  # type: ignore[union-attr]
    assert waits[-1].waiting.startswith("export r1-000-export.xlsx accepted")
    assert any("array started" in n for w in waits for n in w.notes)
    # the clock is the cost model's: the same steps and seconds the sim driver would have charged
    assert d.clock_s() == pytest.approx(sum(s.seconds for s in steps)) and d.program_open()
    assert d.position_um() == (b.indents[-1].x_um, b.indents[-1].y_um)


def test_a_block_exported_as_a_folder_of_per_test_records_measures_what_the_sim_measures(
    exchange: Path, tmp_path: Path
) -> None:
    """The fake InView exports the block as InView's one CSV per test; the driver takes the folder whole."""
    d = driver(exchange, tmp_path)
    b = block(0)
    for _ in running_fake(exchange, rate=0.25, fmt="records"):
        results, _, waits = run_block(d, b)
    check_invariants(b, results)
    assert {r.status for r in results} == {"measured", "failed"}
    for r, h in zip(results, sim_hardness(b), strict=True):
        if r.measured:
            assert r.hardness_gpa == pytest.approx(h)
            assert r.depth_at_max_load_nm == pytest.approx(100.0)
    assert waits[-1].waiting.startswith("export r1-000-export accepted")
    archive = tmp_path / "r1.sqlite.exports"
    (kept,) = [p for p in archive.iterdir() if p.is_dir() and p.name.endswith("-r1-000-export")]
    assert len(list(kept.glob("Test *.csv"))) == b.n_indents  # archived whole


def test_fault_aborted_keeps_the_rows_present_rest_not_run(exchange: Path, tmp_path: Path) -> None:
    d = driver(exchange, tmp_path)
    b = block(0)
    for _ in running_fake(exchange, "aborted"):
        results, steps, _ = run_block(d, b)
    check_invariants(b, results)
    assert [r.status for r in results] == ["measured"] * 4 + ["not_run"] * 5
    assert results[-1].note == "array aborted"
    assert len([s for s in steps if s.category == "indent"]) == 4  # only what ran is charged


def test_fault_surface_not_found_runs_nothing(exchange: Path, tmp_path: Path) -> None:
    d = driver(exchange, tmp_path)
    b = block(0)
    for _ in running_fake(exchange, "surface-not-found"):
        results, steps, _ = run_block(d, b)
    check_invariants(b, results)
    assert {(r.status, r.note) for r in results} == {("not_run", "surface not found")}
    assert steps == [] and d.clock_s() == 0.0 and not d.program_open()


def test_fault_missing_export_times_out_to_sites_held_as_taken(exchange: Path, tmp_path: Path) -> None:
    """The array was confirmed started and no export came by the deadline: nothing says which sites the tip
    went down on, so every site is unverified (taken at its planned place, no value), never free."""
    d = driver(exchange, tmp_path, DEADLINE_PROFILE)
    b = block(0)
    for _ in running_fake(exchange, "missing-export"):
        results, _, waits = run_block(d, b)
    check_invariants(b, results)
    assert {r.status for r in results} == {"unverified"}
    assert all(
        r.note.startswith("no export by the deadline") and "may have indented" in r.note for r in results
    )
    assert all(math.isnan(r.actual_x_um) for r in results)
    assert waits[-2].started and waits[-2].seconds_left < 2.0


def test_fault_duplicate_export_is_refused_and_counted_once(exchange: Path, tmp_path: Path) -> None:
    d = driver(exchange, tmp_path)
    b0, b1 = block(0), block(1, (700.0, 500.0), "local")
    for _ in running_fake(exchange, "duplicate-export@0"):
        first, _, _ = run_block(d, b0)
        second, _, waits = run_block(d, b1)
    check_invariants(b0, first)
    check_invariants(b1, second)
    notes = [n for w in waits for n in w.notes]
    assert any("refused: duplicate: same SHA-256 as the export accepted for block 0" in n for n in notes)
    accepted = [e for e in d.archive.entries() if e["status"] == "accepted"]
    assert [e["block_id"] for e in accepted] == [0, 1]


@pytest.mark.parametrize("fault", ["mm-um", "flipped-y"])
def test_faults_mm_um_and_flipped_y_still_put_every_value_where_it_was_measured(
    exchange: Path, tmp_path: Path, fault: str
) -> None:
    d = driver(exchange, tmp_path)
    b = block(0)
    for _ in running_fake(exchange, fault):
        results, _, _ = run_block(d, b)
    check_invariants(b, results)
    assert all(r.measured for r in results)
    mirrored = fault == "flipped-y"
    truth_block = (
        replace(b, indents=tuple(replace(s, y_um=1000.0 - s.y_um) for s in b.indents)) if mirrored else b
    )
    measured_at = {
        (round(s.x_um, 3), round(s.y_um, 3)): h
        for s, h in zip(truth_block.indents, sim_hardness(truth_block), strict=True)
    }
    for r in results:
        assert (r.actual_x_um, r.actual_y_um) == pytest.approx((r.commanded_x_um, r.commanded_y_um))
        assert r.hardness_gpa == pytest.approx(
            measured_at[(round(r.actual_x_um, 3), round(r.actual_y_um, 3))]
        )


def test_operator_reports_through_the_driver(exchange: Path, tmp_path: Path) -> None:
    d = driver(exchange, tmp_path)
    b = block(0)
    assert d.operator_report("started", "X", "alice") == (False, "no block is waiting for the instrument")
    gen = d.execute_block(b)
    first = next(gen)
    assert isinstance(first, InstrumentWait) and not first.started
    token = d.folder.read_ticket(0).token  # type: ignore[union-attr]
    assert d.operator_report("started", "WRONG", "alice")[0] is False
    assert d.operator_report("started", token, "alice") == (True, "block 0: array started (token confirmed)")
    assert d.operator_report("skip", "9", "alice") == (True, "block 0: site 9 skipped")
    assert d.operator_report("skip", "ten", "alice")[0] is False
    assert d.operator_report("wave", token, "alice")[0] is False
    assert d.operator_report("surface-not-found", token, "alice")[0]
    rest = list(gen)
    results = [ev for ev in rest if isinstance(ev, IndentResult)]
    check_invariants(b, results)
    assert results[8].note == "skipped by the operator" and results[0].note == "surface not found"


def test_abort_while_waiting_raises_at_once(exchange: Path, tmp_path: Path) -> None:
    d = driver(exchange, tmp_path)
    gen = d.execute_block(block(0))
    assert isinstance(next(gen), InstrumentWait)
    d.abort()
    with pytest.raises(DriverAborted, match="waited for the instrument"):
        next(gen)


def test_resume_keeps_the_ticket_and_takes_an_export_accepted_before_the_crash(
    exchange: Path, tmp_path: Path
) -> None:
    journal = tmp_path / "r1.sqlite"
    d = make_kla_driver(PROFILE, journal, exchange, speed=1e6)
    b = block(0)
    gen = d.execute_block(b)
    next(gen)  # the ticket is out
    token = d.folder.read_ticket(0).token  # type: ignore[union-attr]
    del gen  # the engine dies while waiting
    for _ in running_fake(exchange):
        again = make_kla_driver(
            PROFILE, journal, None, speed=1e6
        )  # as `aeni resume`: the folder from beside the journal
        results, _, _ = run_block(again, b)
    assert again.folder.root == exchange.resolve() and again.folder.read_ticket(0).token == token  # type: ignore[union-attr]
    check_invariants(b, results)
    # a second restart after the export was accepted (but before the engine journaled it): no parse, same values
    third = make_kla_driver(PROFILE, journal, None, speed=1e6)
    replayed, _, waits = run_block(third, b)
    assert waits == [] and [r.hardness_gpa for r in replayed] == [r.hardness_gpa for r in results]


def test_a_missing_exchange_folder_is_a_wait_and_the_block_goes_on_when_it_is_back(
    exchange: Path, tmp_path: Path
) -> None:
    """A USB stick carried to the instrument PC and back while a block waits: no crash, a wait with the reason."""
    d = driver(exchange, tmp_path)
    b = block(0)
    events = d.execute_block(b)
    first = next(ev for ev in events if isinstance(ev, InstrumentWait))
    assert "missing" not in first.waiting
    away = tmp_path / "carried-away"
    exchange.rename(away)
    waits = [next(events) for _ in range(5)]
    assert all(isinstance(w, InstrumentWait) and "is missing" in w.waiting for w in waits)
    assert sum(1 for w in waits if isinstance(w, InstrumentWait) and w.notes) == 1  # journaled once
    away.rename(exchange)
    results = []
    for fake in running_fake(exchange):
        for ev in events:
            if isinstance(ev, IndentResult):
                results.append(ev)
        assert fake is not None
    assert [r.indent_index for r in results] == list(range(9))
    assert all(r.status == "measured" for r in results)


def test_an_unreadable_exchange_folder_is_a_wait_too(exchange: Path, tmp_path: Path) -> None:
    import os

    if os.geteuid() == 0:
        pytest.skip("root reads any folder: an unreadable one cannot be made")
    d = driver(exchange, tmp_path)
    events = d.execute_block(block(0))
    next(ev for ev in events if isinstance(ev, InstrumentWait))
    exchange.chmod(0)
    try:
        w = next(events)
        assert isinstance(w, InstrumentWait) and "not readable" in w.waiting
    finally:
        exchange.chmod(0o755)


def test_resume_detach_refuses_at_once_when_the_exchange_folder_is_gone(
    exchange: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """It used to print a PID, exit 0 and leave an engine that died at once."""
    import shutil
    import time

    from aeni_console.cli.main import main
    from aeni_console.cli.run import run_engine
    from core.campaign_config import CampaignConfig
    from core.journal import JournalReader, engine_running, send_command
    from core.runconfig import RunOptions
    from core.runview import Command, CommandKind

    path = tmp_path / "kla.sqlite"
    cfg = CampaignConfig(name="kla", driver_options={"scenario": "ternary"})
    engine = threading.Thread(
        target=run_engine,
        args=(path,),
        kwargs={"create": (cfg, RunOptions(driver="kla", exchange=str(exchange))), "quiet": True},
    )
    engine.start()
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        if path.exists() and engine_running(path):
            with JournalReader(path) as r:
                if r.q.engine_row()["state"] == "waiting-for-instrument":
                    break
        time.sleep(0.05)
    send_command(path, Command(CommandKind.ABORT, author="tester"))
    engine.join(60)
    assert not engine.is_alive()
    shutil.rmtree(exchange)
    capsys.readouterr()
    code = main(["resume", str(path), "--detach", "--continue"])
    out, err = capsys.readouterr()
    assert code == 2 and out == "" and "exchange folder does not exist" in err, (code, out, err)
    assert not engine_running(path)


def test_a_block_whose_indents_are_all_journaled_runs_nothing_on_resume(
    exchange: Path, tmp_path: Path
) -> None:
    """Killed after the last indent was journaled but before the block was observed: resume continues at
    indent n of n. The driver must neither make a ticket nor move (the soak found a crash here)."""
    d = driver(exchange, tmp_path)
    b = block(0)
    assert list(d.execute_block(b, b.n_indents)) == []
    outbox = exchange / "outbox"
    assert not outbox.exists() or not any(outbox.iterdir())  # no ticket
    assert d.clock_s() == 0.0 and d.position_um() == (0.0, 0.0)


def test_a_block_partly_journaled_before_a_kill_reports_only_the_rest_on_resume(
    exchange: Path, tmp_path: Path
) -> None:
    """Killed while the engine journaled an accepted block (indents 0-3 of 9 in): resume continues at indent
    4, and the driver reports indents 4-8 from the archive, once each, without a new ticket (it reported the
    whole block again, which journaled indent 4 twice: the soak's IntegrityError)."""
    journal = tmp_path / "r1.sqlite"
    b = block(0)
    for _ in running_fake(exchange):
        first, _, _ = run_block(make_kla_driver(PROFILE, journal, exchange, speed=1e6), b)
    ticket = (exchange / "outbox" / "r1-000-ticket.json").read_text()
    again = make_kla_driver(PROFILE, journal, None, speed=1e6)
    rest = [ev for ev in again.execute_block(b, 4) if isinstance(ev, IndentResult)]
    assert [r.indent_index for r in rest] == [4, 5, 6, 7, 8]
    assert [r.hardness_gpa for r in rest] == [r.hardness_gpa for r in first[4:]]
    assert (exchange / "outbox" / "r1-000-ticket.json").read_text() == ticket  # nothing new went out


def test_a_refusal_is_kept_so_a_resume_journals_the_refused_rows_as_made(
    exchange: Path, tmp_path: Path
) -> None:
    """An export refused (flipped Y on a grid that is no permutation of the plan), then the engine dies while
    the array waits for a corrected export: the resumed driver still knows which indents were made."""
    journal = tmp_path / "r1.sqlite"
    b = block(0)
    b = replace(b, indents=b.indents[:5])  # five of nine sites: mirrored in Y they lie off the plan
    d = make_kla_driver(DEADLINE_PROFILE, journal, exchange, speed=1e6)
    gen = d.execute_block(b)
    for _ in running_fake(exchange, "flipped-y"):
        for ev in gen:
            if isinstance(ev, InstrumentWait) and any("refused" in n for n in ev.notes):
                break  # refused; the array now waits for a corrected export until its deadline
    del gen  # kill -9 before the deadline
    again = make_kla_driver(DEADLINE_PROFILE, journal, None, speed=1e6)
    results, steps, _ = run_block(again, b)
    check_invariants(b, results)
    assert {r.status for r in results} == {"unverified"}
    assert [r.actual_y_um for r in results] == pytest.approx([2 * b.center_y_um - s.y_um for s in b.indents])
    assert len([s for s in steps if s.category == "indent"]) == 5  # made, so priced
    made = d.archive.refused_made("r1", 0)  # kept with the refusal, before the block closed
    assert [o.indent_index for o in made] == list(range(5)) and {o.status for o in made} == {"unverified"}


def test_a_block_handed_out_at_night_waits_for_the_morning_instead_of_closing_unrun(
    exchange: Path, tmp_path: Path
) -> None:
    """Plain `aeni` on KLA with [operator] hours, a block proposed on Monday at 20:00: nobody can load it
    before Tuesday 08:30 (+ 10 min response), so its ticket's wait counts from then. The lab's clock runs
    5 min per look at the inbox until the operator is there; they then load each array as it comes (the
    fake InView). Every indent is measured, none closes unrun overnight; during the hours the deadline is
    as it always was."""
    from core.operator import OperatorAvailability, OperatorHours
    from drivers.kla.exchange import Ticket
    from tests.test_engine import FakeCampaign, indents_of, run_engine

    hours = OperatorAvailability(OperatorHours.parse("Mon-Fri 08:30-18:00"), 600.0, 7200.0)
    evening, morning = datetime(2024, 1, 1, 20, 0), datetime(2024, 1, 2, 8, 40)
    lab = [evening]

    def utc() -> datetime:  # the driver's clock: the night passes while the block waits
        if lab[0] < morning:
            lab[0] += timedelta(minutes=5)
        return lab[0].replace(tzinfo=UTC)

    fake = FakeInView(exchange, PROFILE, make_scenario("ternary", SEED).make_emulator, invalid_rate=0.0,
                      write_s=0.0, log=lambda _line: None)  # fmt: skip
    stop = threading.Event()

    def operator() -> None:  # comes in the morning and loads every array handed out
        served: set[Path] = set()
        while not stop.wait(0.01):
            if lab[0] >= morning:
                for path in sorted((exchange / "outbox").glob("*-ticket.json")):
                    if path not in served:
                        fake.serve(path)
                        served.add(path)

    thread = threading.Thread(target=operator)
    thread.start()
    try:
        d = KlaDriver(PROFILE, exchange, "r1", tmp_path / "r1.sqlite.exports", now=utc, speed=1e6)
        eng, journal = run_engine(
            tmp_path, FakeCampaign(n_blocks=2), driver=d, operator=hours, local_now=lambda: lab[0]
        )
    finally:
        stop.set()
        thread.join()
    assert eng.completed
    rows = indents_of(journal)
    assert len(rows) == 8 and all(math.isfinite(h) for *_, h in rows)
    tickets = [
        Ticket.from_dict(json.loads(p.read_text()), str(p))
        for p in sorted((exchange / "outbox").glob("*-ticket.json"))
    ]
    night, day = tickets
    # written at night: the wait counts from Tuesday 08:40; written during the hours: from when it was written
    assert night.deadline() >= morning.replace(tzinfo=UTC) + timedelta(
        seconds=PROFILE.inview.deadline_margin_s
    )
    assert (day.deadline() - datetime.fromisoformat(day.created_utc)).total_seconds() <= day.deadline_s + 1

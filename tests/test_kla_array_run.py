"""One block's array from ticket to outcomes: token-checked reports, skips, faults and the deadline."""

from __future__ import annotations

from datetime import datetime, timedelta
from pathlib import Path

import pytest

from drivers.kla.array_run import ArrayEnd, ArrayRun
from drivers.kla.exchange import ExchangeFolder, make_ticket
from drivers.kla.inbox import ExportArchive, InboxWatcher
from tests.test_kla_exchange import FAST, block, fake, rows_for, write_export


class Clock:
    def __init__(self, start: datetime) -> None:
        self.t = start

    def __call__(self) -> datetime:
        return self.t


@pytest.fixture
def exchange(tmp_path: Path) -> ExchangeFolder:
    root = tmp_path / "exchange"
    root.mkdir()
    return ExchangeFolder(root, "r1", FAST.inview)


@pytest.fixture
def watcher(exchange: ExchangeFolder, tmp_path: Path) -> InboxWatcher:
    return InboxWatcher(exchange, ExportArchive(tmp_path / "run.sqlite.exports"))


def start(
    exchange: ExchangeFolder, watcher: InboxWatcher, block_id: int = 2, **kw: object
) -> tuple[ArrayRun, Clock]:
    t = make_ticket("r1", block(block_id, **kw), FAST.inview, expected_s=100.0, clock_s=1234.0)  # type: ignore[arg-type]
    exchange.publish(t)
    clock = Clock(t.created())
    return ArrayRun(exchange, watcher, t, now=clock), clock


def run_until_end(run: ArrayRun, n: int = 20) -> ArrayEnd | None:
    for _ in range(n):
        end = run.poll()
        if end is not None:
            return end
    return None


def test_started_file_export_and_events(exchange: ExchangeFolder, watcher: InboxWatcher) -> None:
    run, _ = start(exchange, watcher)
    (ticket_path,) = fake(exchange, rate=0.0).pending()
    fake(exchange).serve(ticket_path)
    end = run_until_end(run)
    assert end is not None and end.sha256 and end.how.startswith("export r1-002-export.xlsx accepted")
    assert [o.status for o in end.outcomes] == ["measured"] * 9
    assert run.started
    kinds = [(e.kind, e.accepted) for e in run.events]
    assert kinds == [("started", True)]
    assert run.events[0].by == "file r1-002-started.txt"


def test_tokens_decide_every_report(exchange: ExchangeFolder, watcher: InboxWatcher) -> None:
    run, _ = start(exchange, watcher)
    ok, why = run.report("started", "WRONG", "alice")
    assert not ok and "'WRONG' is not block 2's token" in why
    ok, _ = run.report("started", f"  {run.ticket.token.lower()} ", "alice")  # typed over SSH
    assert ok and run.started
    ok, why = run.report("started", run.ticket.token, "alice")
    assert not ok and "already reported" in why
    # a report file with a wrong token is ignored (once), never counted
    exchange.report_path(2, "aborted").write_text("NOPE1\n")
    assert run.poll() is None and run.poll() is None
    assert not run.aborted
    ignored = [e for e in run.events if e.kind == "aborted"]
    assert len(ignored) == 1 and not ignored[0].accepted and "NOPE1" in ignored[0].text
    assert [e.by for e in run.events[:3]] == ["alice"] * 3


def test_fault_aborted_keeps_the_rows_present(exchange: ExchangeFolder, watcher: InboxWatcher) -> None:
    run, _ = start(exchange, watcher)
    f = fake(exchange, "aborted")
    (path,) = f.pending()
    f.serve(path)
    end = run_until_end(run)
    assert end is not None and run.aborted
    assert [o.status for o in end.outcomes] == ["measured"] * 4 + ["not_run"] * 5
    assert {o.reason for o in end.outcomes[4:]} == {"array aborted"}


def test_fault_surface_not_found_closes_the_block_and_a_late_export_is_stale(
    exchange: ExchangeFolder, watcher: InboxWatcher
) -> None:
    run, _ = start(exchange, watcher)
    f = fake(exchange, "surface-not-found")
    (path,) = f.pending()
    f.serve(path)
    end = run.poll()
    assert end is not None and end.how == "surface not found" and end.sha256 is None
    assert all(o.status == "not_run" and o.reason == "surface not found" for o in end.outcomes)
    write_export(exchange.inbox / "r1-002-export.csv", rows_for(run.ticket))
    nxt, _ = start(exchange, watcher, 3, centre=(800.0, 800.0))
    assert run_until_end(nxt, 5) is None
    assert any(
        e.kind == "refused" and "stale: block 2 was closed (surface not found)" in e.text for e in nxt.events
    )


def test_fault_missing_export_ends_at_the_deadline_with_the_sites_held_as_taken(
    exchange: ExchangeFolder, watcher: InboxWatcher
) -> None:
    run, clock = start(exchange, watcher)
    f = fake(exchange, "missing-export")
    (path,) = f.pending()
    f.serve(path)
    assert run_until_end(run, 5) is None and run.started
    assert run.seconds_left() == pytest.approx(100.0 * 1.5 + 180.0)
    clock.t += timedelta(seconds=331)
    end = run.poll()
    assert end is not None and end.how.startswith("no export by the deadline")
    assert all(o.status == "unverified" and o.x_um is None for o in end.outcomes)  # started: maybe made
    closed = watcher.archive.closed("r1", 2)
    assert closed is not None and len(closed["outcomes"]) == run.ticket.n_sites  # a resume keeps them


def test_no_export_and_no_start_confirmation_by_the_deadline_leaves_the_sites_free(
    exchange: ExchangeFolder, watcher: InboxWatcher
) -> None:
    run, clock = start(exchange, watcher)  # nobody confirmed the start: nothing says the array ran
    clock.t += timedelta(hours=1)
    end = run.poll()
    assert end is not None and {o.status for o in end.outcomes} == {"not_run"}


def test_stable_partial_export_is_taken_at_the_deadline(
    exchange: ExchangeFolder, watcher: InboxWatcher
) -> None:
    run, clock = start(exchange, watcher)
    write_export(exchange.inbox / "r1-002-export.csv", rows_for(run.ticket)[:6])
    assert run_until_end(run, 5) is None and "has 6 of 9 rows" in run.waiting
    clock.t += timedelta(hours=1)
    end = run.poll()
    assert end is not None and [o.status for o in end.outcomes] == ["measured"] * 6 + ["not_run"] * 3


def test_skipped_site_is_not_expected_and_not_run(exchange: ExchangeFolder, watcher: InboxWatcher) -> None:
    run, _ = start(exchange, watcher)
    assert run.skip(3, "alice") == (True, "block 2: site 4 skipped")
    assert not run.skip(3, "alice")[0] and not run.skip(9, "alice")[0]
    rows = rows_for(run.ticket)
    del rows[3]
    write_export(exchange.inbox / "r1-002-export.csv", rows)
    end = run_until_end(run)
    assert end is not None  # 8 rows for 8 expected sites: complete, no abort needed
    assert end.outcomes[3].status == "not_run" and end.outcomes[3].reason == "skipped by the operator"
    assert [o.status for o in end.outcomes].count("measured") == 8
    assert not any("not in the array's order" in n for n in end.notes)


def test_an_aborted_report_without_an_export_waits_a_few_polls_not_to_the_deadline(
    exchange: ExchangeFolder, watcher: InboxWatcher
) -> None:
    run, clock = start(exchange, watcher)
    ok, _ = run.report("aborted", run.ticket.token, "alice")
    assert ok and run.poll() is None  # its export may follow the report
    grace_s = (FAST.inview.stable_polls + 2) * FAST.inview.poll_s
    clock.t += timedelta(seconds=grace_s)
    end = run.poll()
    assert end is not None and end.how == "array aborted; no export came"
    assert run.seconds_left() > 60.0  # long before the deadline
    assert {o.status for o in end.outcomes} == {"not_run"}


def test_an_aborted_report_keeps_the_rows_of_a_refused_export_as_made(
    exchange: ExchangeFolder, watcher: InboxWatcher
) -> None:
    from dataclasses import replace

    from drivers.kla.exchange import make_ticket

    b = block(2)
    t = make_ticket("r1", replace(b, indents=b.indents[:6]), FAST.inview, expected_s=100.0)
    exchange.publish(t)
    run = ArrayRun(exchange, watcher, t, now=Clock(t.created()))
    write_export(exchange.inbox / "r1-002-export.csv", rows_for(t, flip_y=True)[:4])  # refused: Y flipped
    assert run_until_end(run, 6) is None and len(run.made) == 4
    run.report("aborted", t.token, "alice")
    end = run.poll()
    assert end is not None and end.how.startswith("array aborted")
    assert [o.status for o in end.outcomes] == ["unverified"] * 4 + ["not_run"] * 2
    assert watcher.archive.closed("r1", 2)["outcomes"][0]["status"] == "unverified"  # type: ignore[index]

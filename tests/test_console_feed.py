"""The feed: posts only what changed, loads map fields once per fit, survives bad reads, caps its rate.

The source is the console's real one (``JournalSource``) on a run of the real engine (``LiveRun``).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import pytest
from textual.message import Message

from aeni_console.console.feed import Feed, FeedProblem, MapArrived, ReplaySource, RunSource, SnapshotArrived
from aeni_console.console.journal_source import JournalSource
from aeni_console.console.widgets.adjust import FIELDS, parse_adjust, parse_field
from aeni_console.testkit.live import LiveRun
from core.errors import InputError
from core.plan import PlannerSettings
from core.runview import RunSnapshot
from core.settings import adjust_settings

LiveRunFactory = Callable[..., LiveRun]


class Collector:
    def __init__(self) -> None:
        self.messages: list[Message] = []
        self.lock = threading.Lock()

    def __call__(self, message: Message) -> None:
        with self.lock:
            self.messages.append(message)

    def of(self, kind: type) -> list[Message]:
        with self.lock:
            return [m for m in self.messages if isinstance(m, kind)]


def test_journal_sources_satisfy_the_protocols(live_run: LiveRunFactory) -> None:
    run = live_run()
    source, replay = run.source(), run.replay()
    assert isinstance(source, RunSource) and not isinstance(source, ReplaySource)
    assert isinstance(replay, ReplaySource)
    source.close()
    replay.close()


def test_poll_posts_changes_and_map_once_per_fit(live_run: LiveRunFactory) -> None:
    run = live_run(supervision="auto")
    got = Collector()
    feed = Feed(run.source(), got)
    feed.poll_once()
    feed.poll_once()  # nothing changed: nothing new posted
    assert len(got.of(SnapshotArrived)) == 1 and got.of(MapArrived) == []  # no fit yet
    run.finish_block()
    run.finish_block()  # two centres: the first fit
    feed.poll_once()
    feed.poll_once()
    maps = got.of(MapArrived)
    assert len(got.of(SnapshotArrived)) == 2 and len(maps) == 1
    first = maps[0].fields.snapshot_id  # type: ignore[attr-defined]
    assert first == run.snapshot().gp.snapshot_id
    run.finish_block()
    feed.poll_once()
    assert [m.fields.snapshot_id for m in got.of(MapArrived)] == [first, first + 1]  # type: ignore[attr-defined]


def test_snapshot_messages_replace_each_other(live_run: LiveRunFactory) -> None:
    run = live_run(supervision="auto")
    run.finish_block()
    run.finish_block()
    source = run.source()
    snap = source.snapshot()
    fields = source.map_fields(snap.gp.snapshot_id or 0)
    assert fields is not None
    a, b = SnapshotArrived(snap), SnapshotArrived(snap)
    assert b.can_replace(a)
    assert not b.can_replace(MapArrived(fields))
    assert FeedProblem("x").can_replace(FeedProblem("y"))
    source.close()


def test_a_failing_source_is_reported_and_polling_continues(live_run: LiveRunFactory) -> None:
    class Flaky(JournalSource):
        fail = True

        def snapshot(self) -> RunSnapshot:
            if self.fail:
                raise OSError("database is locked")
            return super().snapshot()

    run = live_run()
    source = Flaky(run.path)
    got = Collector()
    feed = Feed(source, got)
    feed.poll_once()
    assert "database is locked" in got.of(FeedProblem)[0].text  # type: ignore[attr-defined]
    source.fail = False
    feed.poll_once()
    assert len(got.of(SnapshotArrived)) == 1
    source.close()


def test_thread_caps_its_rate_and_stops(live_run: LiveRunFactory) -> None:
    run = live_run(supervision="auto")
    got = Collector()
    feed = Feed(run.source(), got, poll_s=0.001, max_rate_hz=20.0)
    ticker_stop = threading.Event()

    def tick() -> None:  # the engine changes the run far faster than the cap
        while not ticker_stop.is_set():
            run.advance(1)

    ticker = threading.Thread(target=tick, daemon=True)
    ticker.start()
    feed.start()
    time.sleep(0.5)
    feed.stop()
    ticker_stop.set()
    feed.join(timeout=2)
    ticker.join(timeout=10)
    assert not feed.is_alive()
    # at most 20 polls a second (+1 for the first), however fast the run changes
    assert 2 <= feed.polls <= 12
    assert len(got.of(SnapshotArrived)) <= feed.polls


def test_poke_wakes_the_feed_early(live_run: LiveRunFactory) -> None:
    run = live_run(supervision="auto")
    got = Collector()
    feed = Feed(run.source(), got, poll_s=30.0, max_rate_hz=100.0)
    feed.start()
    deadline = time.monotonic() + 30
    # the first snapshot delivered, not only its poll begun: a poll counted but still reading could read the
    # state after the advance below, and the poke's poll would then rightly find nothing new
    while len(got.of(SnapshotArrived)) < 1 and time.monotonic() < deadline:
        time.sleep(0.01)
    run.advance(1)
    feed.poke()
    # a poll is counted when it starts, its snapshot delivered after the read: wait for the delivery too
    while (feed.polls < 2 or len(got.of(SnapshotArrived)) < 2) and time.monotonic() < deadline:
        time.sleep(0.01)
    feed.stop()
    feed.join(timeout=2)
    assert feed.polls >= 2 and len(got.of(SnapshotArrived)) == 2


def test_adjust_form_parsing() -> None:
    current = PlannerSettings(
        fixed_hold_s=80.0
    )  # as a run shows it: the campaign fills in the profile default
    spec = {f.name: f for f in FIELDS}
    assert parse_field(spec["target_sem_gpa"], "0.02") == (0.02, None)
    assert parse_field(spec["target_sem_gpa"], "0")[1] == (
        "target SEM (GPa): 0.0 is not allowed: expected a number > 0 (GPa)"
    )
    assert parse_field(spec["local_center_limit"], "3") == (3, None)
    assert "whole number" in str(parse_field(spec["local_center_limit"], "2.5")[1])
    assert parse_field(spec["budget_s"], "  ") == (None, None)
    assert parse_field(spec["beta"], "")[1] == "UCB β: a value is required"
    assert parse_field(spec["beta"], "nan")[1] is not None
    assert parse_field(spec["beta"], "abc")[1] == "UCB β: 'abc' is not allowed: expected a number ≥ 0"
    values = {"target_sem_gpa": "0.05", "beta": "2", "budget_s": "36000"}
    changes, errors = parse_adjust(values, "adaptive", current, "step", "supervised")
    assert errors == []
    assert changes == {"beta": 2.0, "budget_s": 36000.0, "hold_policy": "adaptive", "supervision": "step"}
    _, errors = parse_adjust({"beta": "x"}, "sometimes", current)
    assert len(errors) == 2


@pytest.mark.parametrize(
    ("name", "text"),
    [
        ("edge_penalty", "0.95"),
        ("edge_penalty", "0.99"),  # the old form allowed up to 1
        ("local_center_limit", "20"),
        ("local_center_limit", "21"),  # the old form allowed up to 50
        ("fixed_hold_s", "5"),
        ("fixed_hold_s", "60"),  # not one of the profile's holds; the old form allowed 0 to 600
        ("fixed_hold_s", "120"),
        ("target_sem_gpa", "-0.1"),
        ("indent_budget", "0"),
        ("mape_target_pct", "150"),
    ],
)
def test_the_form_refuses_exactly_what_the_engine_refuses(name: str, text: str) -> None:
    holds = (0.0, 5.0, 120.0)  # a profile with its own holds: the form must use the run's, not a default
    spec = next(f for f in FIELDS if f.name == name)
    value, error = parse_field(spec, text, holds)
    try:
        engine = adjust_settings(PlannerSettings(), {name: float(text)}, holds)
    except InputError:
        assert error is not None and value is None
    else:
        assert error is None and value == getattr(engine, name)


def test_replay_of_the_last_block_shows_what_the_live_console_showed(live_run: LiveRunFactory) -> None:
    """Replay rebuilds each block's view with the live reader's rules (queue, drift, ledger, map, centres)."""
    run = live_run(supervision="auto")
    for _ in range(3):
        run.finish_block()  # the engine has decided block 3 and waits before its first indent
    live = run.snapshot()
    replay = run.replay()
    assert replay.n_blocks() == 3
    then = replay.snapshot_at(2)
    assert then.tested == live.tested and then.n_indents == live.n_indents
    assert then.ledger == live.ledger and then.instrument_s == pytest.approx(live.instrument_s)
    assert then.drift == live.drift and then.gp == live.gp
    assert then.queue == live.queue  # the next block, costed from where the tip stood
    assert not then.can_command
    with pytest.raises(IndexError):
        replay.snapshot_at(3)
    replay.close()


def test_a_feed_at_rest_reads_nothing_until_the_journal_changes(live_run: LiveRunFactory) -> None:
    """An idle console (no new journal rows) reads no snapshot: a poll costs one pragma and a lock probe."""
    run = live_run(supervision="auto")
    got = Collector()
    feed = Feed(run.source(), got)
    for _ in range(20):
        feed.poll_once()
    assert feed.polls == 20 and feed.reads == 2  # the first read, and one to learn the journal's version
    assert len(got.of(SnapshotArrived)) == 1
    run.advance(1)  # the engine commits an indent: the next poll reads it
    feed.poll_once()
    assert feed.reads == 3 and len(got.of(SnapshotArrived)) == 2
    feed.poll_once()
    assert feed.reads == 3


def test_a_failed_read_is_tried_again_although_nothing_changed(live_run: LiveRunFactory) -> None:
    class FlakyLater(JournalSource):
        fail = False

        def snapshot(self) -> RunSnapshot:
            if self.fail:
                raise OSError("database is locked")
            return super().snapshot()

    run = live_run(supervision="auto")
    source = FlakyLater(run.path)
    got = Collector()
    feed = Feed(source, got)
    feed.poll_once()
    run.advance(1)
    source.fail = True
    feed.poll_once()
    assert got.of(FeedProblem)
    source.fail = False
    feed.poll_once()  # the journal has not changed since the failed read; the feed reads again anyway
    assert len(got.of(SnapshotArrived)) == 2
    source.close()

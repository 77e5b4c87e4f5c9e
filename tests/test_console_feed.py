"""The feed: posts only what changed, loads map fields once per fit, survives bad reads, caps its rate."""

from __future__ import annotations

import threading
import time

from textual.message import Message

from aeni_console.fake import FakeRun, check_adjust
from aeni_console.feed import Feed, FeedProblem, MapArrived, ReplaySource, RunSource, SnapshotArrived
from aeni_console.widgets.adjust import FIELDS, parse_adjust, parse_field
from core.errors import InputError
from core.plan import PlannerSettings


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


def test_fake_satisfies_both_protocols() -> None:
    run = FakeRun()
    assert isinstance(run, RunSource) and isinstance(run, ReplaySource)


def test_poll_posts_changes_and_map_once_per_fit() -> None:
    run = FakeRun(supervision="auto")
    got = Collector()
    feed = Feed(run, got)
    feed.poll_once()
    feed.poll_once()  # nothing changed: nothing new posted
    assert len(got.of(SnapshotArrived)) == 1 and got.of(MapArrived) == []  # no fit yet
    run.advance(2)  # one block done → first fit
    feed.poll_once()
    feed.poll_once()
    maps = got.of(MapArrived)
    assert len(got.of(SnapshotArrived)) == 2 and len(maps) == 1
    assert maps[0].fields.snapshot_id == 1  # type: ignore[attr-defined]
    run.advance(2)
    feed.poll_once()
    assert [m.fields.snapshot_id for m in got.of(MapArrived)] == [1, 2]  # type: ignore[attr-defined]


def test_snapshot_messages_replace_each_other() -> None:
    run = FakeRun()
    a, b = SnapshotArrived(run.snapshot()), SnapshotArrived(run.snapshot())
    assert b.can_replace(a)
    assert not b.can_replace(MapArrived(run.map_fields(0) or _fields(run)))
    assert FeedProblem("x").can_replace(FeedProblem("y"))


def _fields(run: FakeRun):  # type: ignore[no-untyped-def]
    run.advance(2)
    return run.map_fields(1)


def test_a_failing_source_is_reported_and_polling_continues() -> None:
    class Flaky(FakeRun):
        fail = True

        def snapshot(self):  # type: ignore[no-untyped-def]
            if self.fail:
                raise OSError("database is locked")
            return super().snapshot()

    run = Flaky()
    got = Collector()
    feed = Feed(run, got)
    feed.poll_once()
    assert "database is locked" in got.of(FeedProblem)[0].text  # type: ignore[attr-defined]
    run.fail = False
    feed.poll_once()
    assert len(got.of(SnapshotArrived)) == 1


def test_thread_caps_its_rate_and_stops() -> None:
    run = FakeRun(supervision="auto")
    got = Collector()
    feed = Feed(run, got, poll_s=0.001, max_rate_hz=20.0)
    ticker_stop = threading.Event()

    def tick() -> None:  # the "engine" changes the run far faster than the cap
        while not ticker_stop.is_set():
            run.advance()
            time.sleep(0.001)

    ticker = threading.Thread(target=tick, daemon=True)
    ticker.start()
    feed.start()
    time.sleep(0.5)
    feed.stop()
    ticker_stop.set()
    feed.join(timeout=2)
    ticker.join(timeout=2)
    assert not feed.is_alive()
    # at most 20 posts a second (+1 for the first), however fast the run changes
    assert 2 <= feed.polls <= 12
    assert len(got.of(SnapshotArrived)) <= feed.polls


def test_poke_wakes_the_feed_early() -> None:
    run = FakeRun(supervision="auto")
    got = Collector()
    feed = Feed(run, got, poll_s=30.0, max_rate_hz=100.0)
    feed.start()
    deadline = time.monotonic() + 2
    while feed.polls < 1 and time.monotonic() < deadline:
        time.sleep(0.01)
    run.advance()
    feed.poke()
    while feed.polls < 2 and time.monotonic() < deadline:
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
    assert parse_field(spec["target_sem_gpa"], "0")[1] == "target SEM (GPa): must be > 0"
    assert parse_field(spec["local_center_limit"], "2.5")[1] == "local centres: '2.5' is not a whole number"
    assert parse_field(spec["edge_penalty"], "1.5")[1] == "edge penalty: must be ≤ 1"
    assert parse_field(spec["budget_s"], "  ") == (None, None)
    assert parse_field(spec["beta"], "")[1] == "UCB β: a value is required"
    assert parse_field(spec["beta"], "nan")[1] is not None
    values = {"target_sem_gpa": "0.05", "beta": "2", "budget_s": "36000"}
    changes, errors = parse_adjust(values, "adaptive", current, "step", "supervised")
    assert errors == []
    assert changes == {"beta": 2.0, "budget_s": 36000.0, "hold_policy": "adaptive", "supervision": "step"}
    _, errors = parse_adjust({"beta": "x"}, "sometimes", current)
    assert len(errors) == 2


def test_fake_adjust_validation_matches_the_engine_contract() -> None:
    s = check_adjust({"target_sem_gpa": 0.02, "hold_policy": "adaptive"}, PlannerSettings())
    assert s.target_sem_gpa == 0.02 and s.hold_policy == "adaptive"
    for bad in ({"target_sem_gpa": -1.0}, {"nope": 1}, {"local_center_limit": 2.5}, {"hold_policy": "x"}):
        try:
            check_adjust(bad, PlannerSettings())
        except InputError:
            continue
        raise AssertionError(f"accepted {bad}")

"""Helpers that drive the console headless against the real engine (tests, screenshots, the latency benchmark).

``LiveRun`` builds a run for them as every run is built (``core.run.compose``): the real engine on a temporary
journal, the real ``Campaign`` with a cheap policy on a small lattice, and the simulated instrument
behind a gate, so an indent happens only when the test says ``advance()``. The journal's wall clock is a
``ManualWallClock`` that follows the instrument clock, so the log, the status bar and every snapshot
repeat exactly. The console reads the run through ``JournalSource``, as on a real run.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable, Generator, Iterator, Mapping
from dataclasses import replace
from datetime import UTC, datetime
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any

from textual.pilot import Pilot

from aeni_console.cli.host import create_run_journal
from aeni_console.console.heatmap import marks_for
from aeni_console.console.journal_source import JournalReplay, JournalSource
from aeni_console.console.widgets.mapview import MapPanel
from core.campaign_config import CampaignConfig
from core.driver import DriverEvent
from core.journal import JournalReader, reader, send_command, writer
from core.plan import Block, IndentResult, IndentStatus, PlannerSettings
from core.run.compose import Hosting, compose
from core.run.spec import EngineRules, RunSpec
from core.runview import Command, EngineState, MapFields, RunSnapshot
from core.sample.model import Sample
from drivers.registry import DRIVERS
from drivers.sim.driver import SimulatedDriver

if TYPE_CHECKING:
    from core.campaign import Campaign
    from core.journal import Journal

FIXED_WALL_UNIX = 1_735_725_600.0  # 2025-01-01 10:00 UTC: where every test run's wall clock starts
WALL_PER_INSTRUMENT_S = 0.01  # the journal's wall clock runs at a hundredth of the instrument clock


class ManualWallClock:
    """The journal's wall clock during a test run: it moves with the instrument clock, never by itself.

    The journal module has one clock at a time: the run started last owns it until it closes.
    """

    def __init__(self, start_unix: float = FIXED_WALL_UNIX) -> None:
        self.start_unix = start_unix
        self.instrument_s: Callable[[], float] = lambda: 0.0

    def time(self) -> float:
        return self.start_unix + WALL_PER_INSTRUMENT_S * self.instrument_s()

    def utc_now(self) -> str:
        stamp = datetime.fromtimestamp(self.time(), UTC).isoformat(timespec="milliseconds")
        return stamp.replace("+00:00", "Z")

    @contextlib.contextmanager
    def installed(self) -> Iterator[None]:
        """Make the journal stamp and read its rows with this clock (its writer and reader read the time).

        Runs may close in any order (a factory fixture closes the first first): the journal keeps the clock of
        the latest run still open, and the real clock once none is, so no test clock outlives its run."""
        _ACTIVE_CLOCKS.append(self)
        _apply_clock()
        try:
            yield
        finally:
            _ACTIVE_CLOCKS.remove(self)
            _apply_clock()


_REAL_CLOCK = (writer.utc_now, writer.time, reader.time)  # what the journal reads when no test run is open
_ACTIVE_CLOCKS: list[ManualWallClock] = []


def _apply_clock() -> None:
    """The journal's clock: the latest open test run's, or the real one."""
    if not _ACTIVE_CLOCKS:
        writer.utc_now, writer.time, reader.time = _REAL_CLOCK
        return
    clock = _ACTIVE_CLOCKS[-1]

    class _Time(ModuleType):
        def __getattr__(self, name: str) -> Any:
            return getattr(time, name)

        def time(self) -> float:
            return clock.time()

    fake_time = _Time("time")
    writer.utc_now = clock.utc_now
    writer.time = reader.time = fake_time


class _Gate:
    """Where the engine thread waits for the test: before each indent, and whenever it waits for the operator."""

    def __init__(self) -> None:
        self.cv = threading.Condition()
        self.permits = 0
        self.taken = 0
        self.where = "run"  # "gate" (before an indent), "sleep" (waiting for the operator), "run", "done"
        self.opened = False  # teardown: let the engine run to its stop

    def take(self) -> None:
        with self.cv:
            self.where = "gate"
            self.cv.notify_all()
            while self.permits == 0 and not self.opened:
                self.cv.wait()
            if self.permits:
                self.permits -= 1
            self.taken += 1
            self.where = "run"

    def sleep(self, _poll_s: float) -> None:
        """The engine's sleep while paused or awaiting approval: commands arrive through the journal."""
        with self.cv:
            self.where = "sleep"
            self.cv.notify_all()
            if not self.opened:
                self.cv.wait(0.005)
            self.where = "run"  # back to its checkpoint: it may act on a command now


class SteppedDriver(SimulatedDriver):
    """The simulated instrument, one indent per permit: the test's hand is its clock (no wall-clock sleeps)."""

    def __init__(
        self,
        *args: Any,
        gate: _Gate,
        unmeasured: Mapping[tuple[int, int], IndentStatus] | None = None,
        **kwargs: Any,
    ) -> None:
        super().__init__(*args, **kwargs)
        self._gate = gate
        self._unmeasured = dict(unmeasured or {})

    def execute_block(self, block: Block, start_index: int = 0) -> Generator[DriverEvent, None, None]:
        inner = super().execute_block(block, start_index)
        self._gate.take()
        for event in inner:
            if isinstance(event, IndentResult):
                status = self._unmeasured.get((event.block_id, event.indent_index))
                if status is not None:  # the instrument reported no value for this indent
                    spec = block.indents[event.indent_index]
                    event = IndentResult.unmeasured(
                        event.block_id, event.indent_index, spec, event.t_s, status, f"test: {status}"
                    )
            yield event
            if isinstance(event, IndentResult) and event.indent_index < block.n_indents - 1:
                self._gate.take()


class LiveRun:
    """A real engine on a temporary journal, run an indent at a time from the test's thread.

    ``supervision`` as in ``aeni run``; the policy is ``cost-aware`` (fixed 5×5 blocks, cheap to plan) on a
    15×15 candidate lattice of the ternary emulator. Use as a context manager: leaving stops the engine.
    """

    def __init__(
        self,
        directory: str | Path,
        *,
        supervision: str = "supervised",
        seed: int = 0,
        policy: str = "cost-aware",
        lattice_n: int | None = 15,
        name: str = "console-test",
        display_n: int = 40,
        sample: Sample | None = None,
        unmeasured: Mapping[tuple[int, int], IndentStatus] | None = None,
        approval_timeout_s: float | None = None,
        on_timeout: str = "approve",
        settings: PlannerSettings | None = None,
        prepare: Callable[[Campaign], None] | None = None,
    ) -> None:

        self.path = Path(directory) / f"{name}.sqlite"
        self.config = CampaignConfig(name=name, policy=policy, seed=seed, lattice_n=lattice_n, sample=sample)
        if settings is not None:
            self.config = replace(self.config, settings=settings)
        self.prepare = prepare  # called with the campaign before the engine starts (e.g. a stricter guard)
        self.unmeasured = unmeasured  # (block, indent) -> failed | not_run: what the instrument reports
        self.supervision = supervision
        self.display_n = display_n
        self.approval_timeout_s = approval_timeout_s
        self.on_timeout = on_timeout
        self.clock = ManualWallClock()
        # the engine's own wall clock (what approval_timeout_s is measured on): moved only by pass_wall_time
        self.waited_s = 0.0
        self._gate = _Gate()
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._clock_patch = self.clock.installed()
        self.engine: Any = None
        self.driver: SteppedDriver | None = None
        self._thread = threading.Thread(target=self._run, name="aeni-test-engine", daemon=True)

    # -- lifecycle ----------------------------------------------------------------------------------
    def __enter__(self) -> LiveRun:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def start(self) -> None:
        self._clock_patch.__enter__()
        self._thread.start()
        self._ready.wait(120)
        self._raise()
        self.wait_quiet()

    def _run(self) -> None:
        """The engine thread: everything that writes the journal is created and used here."""
        try:
            import torch

            torch.set_num_threads(1)  # as in the engine process: the same fits on every machine
            spec = RunSpec(
                campaign=self.config,
                rules=EngineRules(
                    self.supervision, approval_timeout_s=self.approval_timeout_s, on_timeout=self.on_timeout
                ),
            )

            def gated(sim: Any) -> SteppedDriver:
                self.driver = SteppedDriver(
                    sim.emulator,
                    sim.profile,
                    start_um=sim.position_um(),
                    gate=self._gate,
                    unmeasured=self.unmeasured,
                )
                self.clock.instrument_s = self.driver.clock_s
                return self.driver

            journals: list[Journal] = []

            def record(spec: RunSpec, campaign: Campaign) -> Journal:
                journals.append(create_run_journal(self.path, spec, campaign))
                return journals[0]

            run = compose(
                spec,
                DRIVERS,
                record,
                hosting=Hosting(
                    sleep=self._gate.sleep,
                    watch_s=None,
                    map_display_n=self.display_n,
                    wall_clock=lambda: self.waited_s,
                ),
                driver=gated,
                prepare=self.prepare,
            )
            journal, self.engine = journals[0], run.engine
        except BaseException as exc:
            self._error = exc
            self._ready.set()
            return
        self._ready.set()
        try:
            self.engine.run()
        except BaseException as exc:
            self._error = exc
        finally:
            journal.close(compact=False)
            with self._gate.cv:
                self._gate.where = "done"
                self._gate.cv.notify_all()

    def close(self) -> None:
        """Stop the engine (abort at its next checkpoint) and restore the journal's clock."""
        if self._thread.is_alive() and self.engine is not None:
            self.engine.request_abort()
            with self._gate.cv:
                self._gate.opened = True
                self._gate.cv.notify_all()
            self._thread.join(60)
        with contextlib.suppress(RuntimeError):
            self._clock_patch.__exit__(None, None, None)

    def _raise(self) -> None:
        if self._error is not None:
            raise RuntimeError(f"the test engine failed: {self._error!r}") from self._error

    # -- driving ------------------------------------------------------------------------------------
    @property
    def ended(self) -> bool:
        return self._gate.where == "done"

    def wait_quiet(self, timeout_s: float = 60.0, taken: int | None = None) -> None:
        """Until the engine waits (for an indent permit or the operator) or has ended."""
        deadline = time.monotonic() + timeout_s
        with self._gate.cv:
            while not (
                self._gate.where == "done"
                or (self._gate.where in ("gate", "sleep") and (taken is None or self._gate.taken >= taken))
            ):
                if time.monotonic() > deadline:
                    raise TimeoutError(f"the test engine did not settle (at {self._gate.where})")
                self._gate.cv.wait(0.01)
        self._raise()

    def advance(self, indents: int = 1, timeout_s: float = 60.0) -> int:
        """Let up to ``indents`` indents run; returns how many ran (fewer when the engine waits or ends)."""
        with self._gate.cv:
            before = self._gate.taken
            want = before + indents
            self._gate.permits += indents
            self._gate.cv.notify_all()
        deadline = time.monotonic() + timeout_s
        with self._gate.cv:
            while True:
                where, taken = self._gate.where, self._gate.taken
                if where == "done" or where == "sleep" or (where == "gate" and taken >= want):
                    break
                if time.monotonic() > deadline:
                    raise TimeoutError(f"the test engine did not settle (at {where})")
                self._gate.cv.wait(0.01)
            self._gate.permits = 0  # a waiting engine does not bank indents for later
            ran = self._gate.taken - before
        self._raise()
        return ran

    def finish_block(self) -> int:
        """Run the indents left in the current block (the engine then folds it in and decides again)."""
        snap = self.snapshot()
        left = sum(1 for q in snap.queue if snap.current_block and q.block_id == snap.current_block.block_id)
        return self.advance(max(left, 1))

    def send(self, command: Command, timeout_s: float = 60.0) -> dict[str, Any]:
        """A scripted operator: queue a command and wait until the engine has processed it; its journal row."""
        cid = _send(self.path, command)
        deadline = time.monotonic() + timeout_s
        while True:
            row = self.command(cid)
            if row is not None and row["processed"]:
                self.wait_quiet()
                return row
            if self.ended or time.monotonic() > deadline:
                self._raise()
                raise TimeoutError(f"command {command.kind.value} was not processed")
            with self._gate.cv:
                self._gate.cv.wait(0.01)

    def pass_wall_time(self, seconds: float) -> None:
        """Let ``seconds`` of wall time pass for the engine (an unanswered approval times out on them)."""
        self.waited_s += seconds

    def until_awaiting(self, max_indents: int = 2000) -> RunSnapshot:
        """Run until a proposal waits for the operator (an error if the run ends or never asks)."""
        self.advance(max_indents)
        snap = self.snapshot()
        if snap.state is not EngineState.AWAITING_APPROVAL:
            raise AssertionError(f"the engine is {snap.state} after {max_indents} indents, not asking")
        return snap

    # -- reading ------------------------------------------------------------------------------------
    def source(self, reader_user: str | int | None = None) -> JournalSource:
        """The console's source for this run, as ``aeni console`` opens it."""
        return JournalSource(self.path, reader_user)

    def replay(self) -> JournalReplay:
        return JournalReplay(self.path)

    def snapshot(self) -> RunSnapshot:
        """The run as the console reads it (with the sample and every indent)."""
        source = JournalSource(self.path)
        try:
            return source.snapshot()
        finally:
            source.close()

    def commands(self) -> list[dict[str, Any]]:
        """Every command in the journal, as the engine recorded it (kind, author, payload_json, outcome ...)."""

        with JournalReader(self.path) as reader:
            return reader.commands()

    def command(self, command_id: int) -> dict[str, Any] | None:
        return next((c for c in self.commands() if c["command_id"] == command_id), None)


class CannedSource:
    """A fixed snapshot and its map fields, for pure rendering tests of states a short run does not reach."""

    def __init__(self, snapshot: RunSnapshot, fields: MapFields | None = None) -> None:
        self._snapshot = snapshot
        self._fields = fields
        self.sent: list[Command] = []

    def snapshot(self) -> RunSnapshot:
        return self._snapshot

    def map_fields(self, snapshot_id: int) -> MapFields | None:
        return self._fields if self._fields is not None and self._fields.snapshot_id == snapshot_id else None

    def send(self, command: Command) -> None:
        self.sent.append(command)


def _send(path: Path, command: Command) -> int:

    return send_command(path, command)


async def wait_until(
    pilot: Pilot[None], cond: Callable[[], bool], timeout_s: float = 10.0, what: str = ""
) -> None:
    """Let the app run until ``cond()`` holds; a clear error instead of a hang when it never does."""
    deadline = time.monotonic() + timeout_s
    while not cond():
        if time.monotonic() > deadline:
            raise TimeoutError(f"console did not reach: {what or cond}")
        await pilot.pause(0.02)


def map_settled(app: object) -> bool:
    """The snapshot is shown and the heatmap drawn from the fields of its last fit, with nothing in flight."""
    snap = getattr(app, "snapshot", None)
    if snap is None:
        return False
    panel = app.query_one(MapPanel)  # type: ignore[attr-defined]
    sid = snap.gp.snapshot_id
    feed = getattr(app, "feed", None)
    if sid is not None:
        if feed is not None and feed.map_checked_id != sid:
            return False  # the fields of this fit are still being looked up
        if feed is None and getattr(app, "replay_loaded", None) != getattr(app, "replay_index", None):
            return False
        has_fields: set[int] = getattr(app, "fields_seen", set())
        if sid in has_fields and (panel.fields is None or panel.fields.snapshot_id != sid):
            return False
    if panel.builds == 0 or panel.applied_generation != panel.generation:
        return False
    view = panel.query_one("#heatmap")
    return (
        panel._want is not None
        and panel._want[5] == marks_for(snap)
        and panel._want[1:3] == (view.size.width, view.size.height)
    )


def in_sync(app: object) -> bool:
    """A live console shows its source's current snapshot (the wall time aside: an engine process's moves)."""
    source = getattr(app, "source", None)
    shown = getattr(app, "snapshot", None)
    if source is None or getattr(app, "replay_mode", False):
        return True
    if shown is None:
        return False
    now = source.snapshot()
    return bool(replace(shown, wall_s=0.0) == replace(now, wall_s=0.0))


def footer_synced(app: object) -> bool:
    """The footer shows exactly the keys that apply now (it recomposes a moment after a state change)."""
    from textual.widgets import Footer
    from textual.widgets._footer import FooterKey

    screen = app.screen  # type: ignore[attr-defined]
    try:
        footer = screen.query_one(Footer)
    except Exception:
        return True  # a modal screen without a footer
    shown = {k.action for k in footer.query(FooterKey)}
    want = {b.binding.action for b in screen.active_bindings.values() if b.binding.show}
    return shown == want


async def settle(pilot: Pilot[None], timeout_s: float = 20.0) -> None:
    """Wait until the console shows the source's current state completely (for snapshots and asserts)."""
    app = pilot.app
    feed = getattr(app, "feed", None)
    if feed is not None:
        feed.poke()
    await wait_until(pilot, lambda: in_sync(app), timeout_s, "the source's latest snapshot shown")
    await wait_until(pilot, lambda: map_settled(app), timeout_s, "snapshot and heatmap shown")
    await pilot.pause(0.05)
    await wait_until(pilot, lambda: map_settled(app), timeout_s, "snapshot and heatmap shown")
    await wait_until(pilot, lambda: footer_synced(app), timeout_s, "footer shows the valid keys")
    await pilot.pause()


def widget_text(widget: object) -> str:
    """What a widget shows on screen right now, as plain text (border and title included)."""
    from textual.geometry import Region

    region = widget.region  # type: ignore[attr-defined]
    strips = widget.render_lines(Region(0, 0, region.width, region.height))  # type: ignore[attr-defined]
    return "\n".join(strip.text for strip in strips)

"""The run engine: drives a campaign through a driver, block by block, along the state machine.

The engine's state lives in :class:`core.run.machine.Machine` and changes only along its transition
table. Between any two indents and between blocks the engine reaches a checkpoint: it reads the
operator commands queued in the journal, applies those the state allows (one handler per command
kind) and records the outcome. Everything it learns is journaled first, so a process killed at any
point can be resumed from the journal (:meth:`Engine.run` on a reopened journal continues where the
last one ended).

No wait goes unanswered: in ``auto`` supervision a block the interlock refuses is vetoed by the engine
and the planner asked again (``max_refusals`` consecutive refusals stop the run), and an approval
can time out (``approval_timeout_s``, ``on_timeout``).
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import os
import threading
import time
import traceback
from collections.abc import Callable, Iterable, Sequence
from datetime import datetime
from typing import TYPE_CHECKING, Any

from core.access import user_name
from core.describe import describe_block
from core.driver import (
    Driver,
    DriverAborted,
    InstrumentWait,
    LoadsStretches,
    PhysicsClock,
    Recoverable,
    Restorable,
    WaitsForOperator,
    WaitsFromAnswer,
)
from core.errors import InputError
from core.interlock import Interlock
from core.metrics import MapEvaluator
from core.operator import OperatorAvailability
from core.plan import STRETCH_PHASE, Block, Decision, IndentResult, StepRecord
from core.run.campaign import CampaignLike, PlansForAbsence, RaisesAlarms
from core.run.campaign import StageFrame as StageFrame
from core.run.commands import HANDLERS
from core.run.events import (
    ApprovalAsked,
    BlockEnded,
    BlockStarted,
    CommandDone,
    Decided,
    Indent,
    Logged,
    Observed,
    PlanState,
    Resolved,
    RunEvent,
    RunRecord,
    SessionBegan,
    SessionEnded,
    Sink,
    StateChanged,
    Steps,
    Waiting,
)
from core.run.machine import Machine, Trigger, allowed, refusal
from core.run.records import DriverState
from core.run.recovery import AWAY_UNTIL_KEY, recover
from core.run.refit import fit_summary, modulus_fit
from core.run.watcher import AbortWatcher
from core.runview import CommandKind, EngineState
from core.settings import ON_TIMEOUT, coerce_supervision
from core.visits import unattended_after

if TYPE_CHECKING:
    from datetime import datetime

    from core.operator import OperatorAvailability


def _same_block(a: Block, b: Block) -> bool:
    """The same block whatever its id: a re-proposal of a vetoed block counts as another refusal."""
    return dataclasses.replace(a, block_id=0) == dataclasses.replace(b, block_id=0)


class Engine:
    """Executes a campaign through a driver, emitting every step as an event; one engine per record.

    ``record`` is where the run goes and where its commands come from (the journal, or an in-memory
    record for a headless run); ``sinks`` receive every event too (a progress view, a test).
    """

    def __init__(
        self,
        record: RunRecord,
        campaign: CampaignLike,
        driver: Driver,
        supervision: str = "auto",
        *,
        poll_s: float = 0.1,
        sleep: Callable[[float], None] = time.sleep,
        progress: Callable[[str], None] | None = None,
        track_metrics: bool = True,
        owner_uid: int | None = None,
        watch_s: float | None = 0.2,
        map_display_n: int | None = 50,  # None: no map fields for a console (a headless run)
        interlock: Interlock | None = None,
        evaluator: MapEvaluator | None = None,
        max_refusals: int = 5,
        approval_timeout_s: float | None = None,
        on_timeout: str = "approve",
        wall_clock: Callable[[], float] = time.monotonic,
        sinks: Sequence[Sink] = (),
        operator: OperatorAvailability | None = None,
        local_now: Callable[[], datetime] | None = None,
    ) -> None:
        coerce_supervision(supervision)
        if not 0 < poll_s <= 5:
            raise InputError("poll_s", f"{poll_s!r} is not allowed: expected 0 < poll_s ≤ 5 s")
        if max_refusals < 1:
            raise InputError("max_refusals", f"{max_refusals!r} is not allowed: expected a whole number ≥ 1")
        if approval_timeout_s is not None and not approval_timeout_s > 0:
            raise InputError(
                "approval_timeout_s",
                f"{approval_timeout_s!r} is not allowed: expected a number of seconds > 0",
            )
        if on_timeout not in ON_TIMEOUT:
            raise InputError("on_timeout", f"{on_timeout!r} is not allowed: expected {', '.join(ON_TIMEOUT)}")
        self.record = record
        self.sinks: tuple[Sink, ...] = (record, *sinks)
        self.campaign = campaign
        self.driver = driver
        # the driver's optional capabilities, asked once
        self._restorable = driver if isinstance(driver, Restorable) else None
        self._recoverable = driver if isinstance(driver, Recoverable) else None
        self._physics = driver if isinstance(driver, PhysicsClock) else None
        # a driver that hands blocks to a person (KLA): its reports, and what it waits for now
        self._operator = driver if isinstance(driver, WaitsForOperator) else None
        self._stretch_loader = driver if isinstance(driver, LoadsStretches) else None
        self._waiting: InstrumentWait | None = None
        self.supervision = supervision
        self.poll_s = poll_s
        self.sleep = sleep
        self.progress = progress
        self.track_metrics = track_metrics
        self.owner_uid = record.owner_uid() if owner_uid is None else owner_uid
        self.watch_s = watch_s
        self.map_display_n = map_display_n
        # every block passes the interlock before the driver sees it; a simulated run's evaluator scores the map
        self.interlock = interlock
        self.evaluator = evaluator
        self.machine = Machine()
        self.stop_reason = ""
        self.completed = False
        # no wait without an answer: refusals in auto supervision, unanswered approvals
        self.max_refusals = max_refusals
        self.approval_timeout_s = approval_timeout_s
        self.on_timeout = on_timeout
        self.wall_clock = wall_clock
        self._refusals = 0  # consecutive refusals since the last block started
        # blocks vetoed since the last block started (a re-proposal is refused)
        self._vetoed: list[Block] = []
        self._approval_deadline: float | None = None  # wall clock
        self._stop_requested = ""  # why the run stops once no block is open (stop-after-block, request_stop)
        self._pending: tuple[int, Decision, str] | None = None  # decision id, decision, why it waits
        self._current: tuple[Block, int] | None = None  # block, first unfinished indent
        self._next_block_id = 0
        self._recovery_s = 0.0
        self._needs_recovery = False
        self._collapse_ack_snapshot: int | None = None
        self._last_snapshot: int | None = None
        self._decision_id = 0  # the last decision's number (the engine numbers them)
        self._snapshot_id = 0  # the last model snapshot's number
        self._results: list[IndentResult] = []  # the open block's indents so far
        self._last_collapse: tuple[int, str] | None = None  # snapshot id, reason of an unacknowledged alarm
        self._external_abort = threading.Event()
        self._watcher = AbortWatcher(record, self.owner_uid, driver, watch_s)
        # who answers, and when (the run file's [operator], an away-until): the planner plans for nobody
        # while nobody will come (core.visits.unattended_after); None: planned as if always attended
        self.operator = operator
        self._local_now = local_now
        if operator is not None:
            self._plan_for_operator()

    def _plan_for_operator(self) -> None:

        now = self._local_now or datetime.now
        operator = self.operator  # every change of the operator's availability binds these again
        assert operator is not None
        if isinstance(self.campaign, PlansForAbsence):
            self.campaign.attendance.follow(lambda _clock_s: unattended_after(operator, now()))
        # a ticket handed to the operator waits from when they can answer it (at night: from the morning)
        if isinstance(self.driver, WaitsFromAnswer):
            self.driver.wait_from_answer(lambda: operator.answer_delay_s(now()))

    # -- small helpers -----------------------------------------------------------------------------
    def _clock(self) -> float:
        return float(self.driver.clock_s())

    def _plan_clock(self) -> float:
        """The instrument clock the planner budgets against: crash-recovery time is not charged to the science."""
        return self._clock() - self._recovery_s

    def _driver_state(self, reason: str) -> DriverState:
        x, y = self.driver.position_um()
        return DriverState(
            clock_s=self._clock(),
            physics_clock_s=float(self._physics.physics_clock_s()) if self._physics is not None else None,
            position_um=(float(x), float(y)),
            program_open=bool(self.driver.program_open()),
            reason=reason,
        )

    def _emit(self, event: RunEvent) -> None:
        for sink in self.sinks:
            sink.emit(event)

    def _log(
        self,
        level: str,
        text: str,
        *,
        category: str = "engine",
        block_id: int | None = None,
        detail: str | None = None,
    ) -> None:
        self._emit(Logged(self._clock(), level, text, category, block_id, detail))

    def _plan_state(self, block_id: int, point: str) -> PlanState:
        state = self.campaign.export_state()
        if self.operator is not None and self.operator.away_until is not None:
            # the operator's word that nobody comes before then: a resumed run still plans for nobody
            state = {**state, AWAY_UNTIL_KEY: self.operator.away_until.isoformat()}
        return PlanState(block_id, point, state, self.campaign.settings)

    def _say(self, line: str) -> None:
        if self.progress is not None:
            self.progress(line)

    @property
    def state(self) -> EngineState:
        return self.machine.state

    def _fire(self, trigger: Trigger, **kw: Any) -> None:
        """Move the machine; a change of state (or of what the engine row holds) is journaled."""
        before = self.machine.state
        after = self.machine.fire(trigger)
        asked = after is EngineState.AWAITING_APPROVAL and (
            before is not EngineState.AWAITING_APPROVAL or trigger is Trigger.ASK
        )
        if asked:
            self._approval_deadline = (
                None if self.approval_timeout_s is None else self.wall_clock() + self.approval_timeout_s
            )
        if after != before or kw:
            self._emit(StateChanged(self._clock(), after, **kw))
        if asked and self._approval_deadline is not None and self._pending is not None:
            did, decision, _ = self._pending
            assert self.approval_timeout_s is not None
            self._emit(
                ApprovalAsked(
                    self._clock(),
                    did,
                    decision.block.block_id,
                    self.approval_timeout_s,
                    self._timeout_action(),
                )
            )

    @property
    def _stopping(self) -> bool:
        return self.machine.state is EngineState.STOPPING

    def request_stop(self, reason: str) -> None:
        """Stop once the current block is done (before the next is planned), with ``reason``."""
        if not self._stop_requested:
            self._stop_requested = reason

    def request_abort(self) -> None:
        """Thread- and signal-safe: stop at the next checkpoint (finish the indent, lift, stop)."""
        self._external_abort.set()

    # -- the run -----------------------------------------------------------------------------------
    def run(self) -> EngineState:
        """Run (or resume) until the planner is done, the operator stops it, or it fails."""
        history = self.record.history()
        if history is not None and history.completed:
            self.completed = True
            self.stop_reason = history.stop_reason or "finished"
            self.machine = Machine(EngineState.STOPPED)
            return self.state
        self._emit(
            SessionBegan(0.0 if history is not None else self._clock(), "resume" if history else "start")
        )
        self._watcher.start()
        try:
            if history is not None:
                recover(self, history)
            else:
                self._log(
                    "info",
                    f"run started by {user_name(os.getuid())}: supervision {self.supervision}, PID {os.getpid()}",
                )
            self._fire(Trigger.START, supervision=self.supervision)
            if self._pending is not None:
                self._fire(Trigger.ASK)
            self._loop()
            self._finish()
        except BaseException as exc:
            self._fail(exc)
            raise
        finally:
            self._watcher.stop()
        return self.state

    def _fail(self, exc: BaseException) -> None:
        with contextlib.suppress(Exception):
            what = "interrupted" if isinstance(exc, KeyboardInterrupt) else f"{type(exc).__name__}: {exc}"
            self._log("error", f"engine failed: {what}", category="error", detail=traceback.format_exc())
            self.machine.fire(Trigger.FAIL)
            self._emit(StateChanged(self._clock(), EngineState.FAILED, stop_reason=what))
            self._emit(SessionEnded(self._clock(), EngineState.FAILED))

    def _loop(self) -> None:
        while True:
            self._checkpoint()
            state = self.machine.state
            if state is EngineState.STOPPING:
                self.stop_reason = self.stop_reason or "aborted by the operator"
                return
            if state is EngineState.PAUSED:
                self.sleep(self.poll_s)
                continue
            if state is EngineState.AWAITING_APPROVAL:
                if not self._approval_timed_out():
                    self.sleep(self.poll_s)
                continue
            if self._current is None:
                if not self._decide():
                    self._fire(Trigger.STOP)
                    return
                continue
            block, start = self._current
            if not self._execute(block, start):
                return
            self._observe(block, self._results)
            self._results = []
            self._current = None
            self._next_block_id = block.block_id + 1
            self._pause_on_alarm(block.block_id)

    def _pause_on_alarm(self, block_id: int) -> None:
        """A campaign's alarm (a tray's failed tip check) pauses the run before the next block is planned."""
        alarm = self.campaign.take_alarm() if isinstance(self.campaign, RaisesAlarms) else None
        if alarm:
            self._log("error", f"{alarm}: run paused", category="alarm", block_id=block_id)
            self._say(f"{alarm}: run paused")
            if self.machine.can(Trigger.PAUSE):
                self._fire(Trigger.PAUSE)

    def _finish(self) -> None:
        if not self._stopping:
            self._fire(Trigger.STOP)
        if self._pending is not None:
            did, _, _ = self._pending
            self._emit(Resolved(self._clock(), did, "dropped", "engine"))
            self._pending = None
        if self._needs_recovery and self._restorable is not None:
            # the tip was engaged when the last engine died: make sure the comeback lifts it
            ds = self._driver_state("stop")
            self._set_driver(ds.clock_s, ds.position_um, True, ds.physics_clock_s)
            self._needs_recovery = False
        self._end_program("run ended: tip lifted and back under the lens")
        if self.completed:
            text = f"run finished: {self.stop_reason}"
        else:
            text = f"run stopped: {self.stop_reason or 'stopped'}"
        self._log("info", text)
        self._fire(Trigger.STOPPED, completed=self.completed, stop_reason=self.stop_reason)
        self._emit(SessionEnded(self._clock(), EngineState.STOPPED))
        self._say(text)

    # -- deciding ----------------------------------------------------------------------------------
    def _interlock_refusal(self, block: Block) -> str:
        if self.interlock is None:
            return ""
        pos = self.driver.position_um()
        refusal = self.interlock.check(
            block, (float(pos[0]), float(pos[1])), bool(self.driver.program_open())
        )
        return "" if refusal is None else f"safety interlock refused block {block.block_id}: {refusal}"

    def _approval_reason(self, decision: Decision) -> str:
        refusal = self._interlock_refusal(decision.block)
        if refusal:
            return refusal
        if self.supervision == "step":
            return "step mode: every block waits for the operator"
        if self.supervision == "supervised":
            if self._last_collapse is not None and self._last_collapse[0] != self._collapse_ack_snapshot:
                return f"length-scale collapse alarm: {self._last_collapse[1]}"
            if decision.block.kind == "global":
                return "global jump"
        return ""

    def _propose(self, block_id: int) -> Decision | None:
        pos = self.driver.position_um()
        return self.campaign.propose(
            self._plan_clock(), (float(pos[0]), float(pos[1])), bool(self.driver.program_open()), block_id
        )

    def _describe(self, d: Decision) -> str:
        b = d.block
        score = "" if d.score is None or math.isnan(d.score) else f", score {d.score:.4g}"
        words = describe_block(b, self.driver.profile.reconfig_threshold_um, self.driver.position_um())
        return (
            f"block {b.block_id}: {words}, ~{d.predicted_cost_s:,.0f} s{score}"
            + (f" [{d.phase}]" if d.phase else "")
            + (f": {d.reason}" if d.reason else "")
        )

    def _offer(self, decision: Decision | None) -> bool:
        """Journal a fresh decision; run it, hold it for the operator, or (refused, in auto) veto it and ask
        again. False: nothing left to do (the stop reason says why)."""
        while True:
            if decision is None:
                self.completed = True
                self.stop_reason = self.campaign.last_stop_reason or "the planner has nothing more to propose"
                return False
            why = self._approval_reason(decision)
            repeated = any(_same_block(decision.block, v) for v in self._vetoed)
            if repeated:
                why = f"block {decision.block.block_id} is a vetoed block proposed again"
            auto_veto = repeated or (self.supervision == "auto" and why.startswith("safety interlock"))
            self._decision_id += 1
            did = self._decision_id
            self._emit(
                Decided(
                    self._clock(),
                    did,
                    decision,
                    "pending" if why else "auto",
                    why,
                    ("awaiting approval (" + why + "): " if why else "decided ") + self._describe(decision),
                    None if why else self._plan_state(decision.block.block_id, "planned"),
                )
            )
            if why.startswith("safety interlock") or repeated:
                self._log("warn", why, block_id=decision.block.block_id)
            if not why:
                self._load_stretch(decision)
                self._current = (decision.block, 0)
                self._results = []
                self._refusals = 0
                self._vetoed.clear()
                return True
            self._pending = (did, decision, why)
            if not auto_veto:
                self._fire(Trigger.ASK)
                self._say(f"awaiting approval ({why}): {self._describe(decision)}")
                return True
            # nobody to ask (auto supervision), or the planner came back with a vetoed block
            self._say(f"refused ({why}): {self._describe(decision)}")
            if self._too_many_refusals(why):
                return False
            decision = self._veto_pending("engine", None, None, f"vetoed by the engine: {why}")

    def _too_many_refusals(self, why: str) -> bool:
        """Count one more refusal in a row; at ``max_refusals`` the pending decision is dropped and the run stops."""
        self._refusals += 1
        if self._refusals < self.max_refusals:
            return False
        assert self._pending is not None
        block_id = self._pending[1].block.block_id
        self._drop_pending(f"refused {self._refusals} times in a row: {why}")
        self.stop_reason = (
            f"{self._refusals} consecutive blocks refused (max_refusals {self.max_refusals}); the last: {why}"
        )
        self._log("warn", f"stopping: {self.stop_reason}", block_id=block_id)
        return True

    def _veto_pending(
        self, author: str, cid: int | None, hold: int | None, note: str = ""
    ) -> Decision | None:
        """Veto the pending decision (journaled with its reason) and ask the planner for the next block."""
        assert self._pending is not None
        did, decision, _ = self._pending
        if hold is None:
            self.campaign.veto(decision)
        else:
            self.campaign.veto(decision, hold_blocks=hold)
        self._vetoed.append(decision.block)
        plan = self._plan_state(decision.block.block_id, "veto")
        self._emit(Resolved(self._clock(), did, "vetoed", author, cid, plan))
        if note:
            self._log("info", note, block_id=decision.block.block_id)
        self._pending = None
        return self._propose(decision.block.block_id)

    def _drop_pending(self, note: str) -> None:
        if self._pending is None:
            return
        did, decision, _ = self._pending
        self._emit(Resolved(self._clock(), did, "dropped", "engine"))
        self._log("info", f"decision {did} dropped: {note}", block_id=decision.block.block_id)
        self._pending = None

    def _decide(self) -> bool:
        return self._offer(self._propose(self._next_block_id))

    def _timeout_action(self) -> str:
        """What an unanswered approval does when it times out: never approves a refused block or a collapse alarm."""
        assert self._pending is not None
        why = self._pending[2]
        if self.on_timeout == "approve" and (
            why.startswith("safety interlock") or why.startswith("length-scale collapse")
        ):
            return "veto"
        return self.on_timeout

    def _approval_timed_out(self) -> bool:
        """An approval nobody answered in time: do what ``on_timeout`` says (journaled). True when acted."""
        if self._approval_deadline is None or self._pending is None:
            return False
        if self.wall_clock() < self._approval_deadline:
            return False
        self._approval_deadline = None
        action = self._timeout_action()
        did, decision, why = self._pending
        note = (
            f"approval of decision {did} (block {decision.block.block_id}, {why}) timed out after "
            f"{self.approval_timeout_s:g} s: {action}"
        )
        self._log("warn", note, category="timeout", block_id=decision.block.block_id)
        self._say(note)
        if action == "approve":
            self._release(did, decision, ("approved", "timeout", None))
        elif action == "veto":
            # nobody answers: each vetoed timeout counts as a refusal, so an empty room ends the run cleanly
            if self._too_many_refusals(f"approval timed out ({why})") or not self._offer(
                self._veto_pending("timeout", None, None)
            ):
                self._fire(Trigger.STOP)
            elif self._pending is None:
                self._fire(Trigger.GO)
        elif action == "pause":
            self._fire(Trigger.PAUSE)
        else:  # stop
            self._stop_requested = "approval timed out"
            self.stop_reason = f"approval timed out after {self.approval_timeout_s:g} s (on_timeout stop)"
            self._fire(Trigger.STOP)
        return True

    def _release(self, decision_id: int, decision: Decision, resolution: tuple[str, str, int | None]) -> None:
        """A waiting decision goes ahead: its block starts."""
        self._start_block(decision_id, decision, resolution)
        self._fire(Trigger.GO)

    def _start_block(
        self, decision_id: int, decision: Decision, resolution: tuple[str, str, int | None]
    ) -> None:
        plan = self._plan_state(decision.block.block_id, "planned")
        self._emit(BlockStarted(self._clock(), decision.block, decision_id, plan, resolution))
        self._load_stretch(decision)
        self._current = (decision.block, 0)
        self._results = []
        self._pending = None
        self._refusals = 0
        self._vetoed.clear()

    def _load_stretch(self, decision: Decision) -> None:
        """The first array of a stretch starts: the driver hands the operator all of its arrays at once."""
        if self._stretch_loader is not None and decision.phase == STRETCH_PHASE:
            self._stretch_loader.load_stretch((decision.block, *self.campaign.queued_stretch()))

    # -- commands ----------------------------------------------------------------------------------
    def _checkpoint(self) -> None:
        if self._external_abort.is_set() and self.machine.can(Trigger.STOP) and not self._stopping:
            self.stop_reason = "aborted (signal)"
            self._log("command", "abort requested by a signal: finishing the indent, lifting, stopping")
            self._fire(Trigger.STOP)
        commands = self.record.pending_commands()
        # trust rests on who the OS lets write the journal, not on the uid a row claims (core.access)
        untrusted = self.record.command_channel_problem(self.owner_uid) if commands else ""
        for sc in commands:
            before = self.state
            try:
                if untrusted:
                    outcome, reason = "rejected", untrusted
                else:
                    outcome, reason = self._apply(sc.kind, sc.author, sc.uid, sc.payload, sc.command_id)
            except InputError as exc:
                outcome, reason = "rejected", str(exc)
            text = f"{sc.author}: {sc.kind} {outcome}" + (f" ({reason})" if reason else "")
            self._emit(CommandDone(self._clock(), sc.command_id, outcome, reason, before, text))
        if (
            self._stop_requested
            and self._current is None
            and self.machine.can(Trigger.STOP)
            and not self._stopping
        ):
            self.stop_reason = self.stop_reason or self._stop_requested
            self._fire(Trigger.STOP)

    def _apply(
        self, kind_s: str, author: str, uid: int, payload: dict[str, Any], cid: int
    ) -> tuple[str, str]:
        if uid != self.owner_uid:
            return "rejected", f"{user_name(uid)} is not the run's owner ({user_name(self.owner_uid)})"
        try:
            kind = CommandKind(kind_s)
        except ValueError:
            return "rejected", f"unknown command {kind_s!r}"
        if not allowed(self.state, kind):
            return "rejected", refusal(self.state, kind)
        return HANDLERS[kind](self, author, payload, cid)

    # -- executing ---------------------------------------------------------------------------------
    def _journal_steps(
        self, steps: Iterable[StepRecord], text: str, category: str, block_id: int | None
    ) -> None:
        buf: list[tuple[StepRecord, float]] = []
        for s in steps:
            buf.append((s, self._clock()))
            if s.category == "recovery":
                self._recovery_s += s.seconds
        self._emit(Steps(self._clock(), tuple(buf), self._driver_state(category), text, category, block_id))

    def _end_program(self, text: str) -> None:
        self._journal_steps(self.driver.end_program(), text, "engine", None)

    def _set_driver(
        self, clock_s: float, pos: tuple[float, float], is_open: bool, physics: float | None
    ) -> None:
        if self._restorable is None:
            raise InputError(
                self.record.name,
                f"the {type(self.driver).__name__} cannot be put back where the journal left the instrument, "
                "so this run cannot be resumed with it",
            )
        self._restorable.set_state(clock_s, pos, is_open, physics_clock_s=physics)

    def _execute(self, block: Block, start: int) -> bool:
        """Run a block from indent ``start``; False when the run must stop (aborted)."""
        must_engage = not self.driver.program_open() and (block.kind == "local" or start > 0)
        if self._needs_recovery or must_engage:
            if self._recoverable is not None:
                why = "tip state unknown after the crash" if self._needs_recovery else "tip was lifted"
                self._journal_steps(
                    self._recoverable.recover(block.block_id),
                    f"recovery: {why}; re-engaged and settled drift before block {block.block_id}",
                    "recovery",
                    block.block_id,
                )
            self._needs_recovery = False
        buf: list[tuple[StepRecord, float]] = []
        gen = self.driver.execute_block(block, start)
        try:
            for ev in gen:
                if isinstance(ev, InstrumentWait):
                    self._wait_for_instrument(ev)
                    if self._stopping:
                        gen.close()
                        self._stop_mid_block(block, buf)
                        return False
                    continue
                if self._waiting is not None:  # the array ended: its results follow
                    self._waiting = None
                    self._fire(Trigger.GO)
                if not isinstance(ev, IndentResult):
                    buf.append((ev, self._clock()))
                    if ev.category == "recovery":
                        self._recovery_s += ev.seconds
                    continue
                self._emit(Indent(self._clock(), ev, tuple(buf), self._driver_state("indent")))
                self._results.append(ev)
                buf = []
                self._current = (block, ev.indent_index + 1)
                if ev.indent_index >= block.n_indents - 1:
                    continue  # the block-level checkpoint follows
                self._checkpoint_while_paused()
                if self._stopping:
                    gen.close()
                    self._stop_mid_block(block, buf)
                    return False
        except DriverAborted:
            self._stop_mid_block(block, buf)
            self._checkpoint()  # consume the abort command that triggered it
            self.stop_reason = self.stop_reason or "aborted"
            if not self._stopping:
                self._fire(Trigger.STOP)
            return False
        if buf:
            self._journal_steps((s for s, _ in buf), "", "engine", block.block_id)
        self._emit(BlockEnded(self._clock(), block.block_id, "executed", finished=True))
        return True

    def _wait_for_instrument(self, wait: InstrumentWait) -> None:
        """A checkpoint while the driver waits for the instrument: journal what changed, take commands."""
        before = self._waiting
        self._waiting = wait
        changed = before is None or (before.waiting, before.started) != (wait.waiting, wait.started)
        if self.state is EngineState.RUNNING:
            self._fire(Trigger.WAIT_INSTRUMENT)
        self._emit(Waiting(self._clock(), wait))
        for note in wait.notes:
            self._log("info", note, category="instrument", block_id=wait.block_id)
        if changed:
            what = "waiting for the instrument" if before is None else "instrument"
            self._log(
                "info",
                f"block {wait.block_id}: {what}: {wait.waiting}"
                + ("" if wait.started else " (start not confirmed)"),
                category="instrument",
                block_id=wait.block_id,
            )
        self._checkpoint_while_paused()

    def _checkpoint_while_paused(self) -> None:
        """A checkpoint inside a block: a pause holds the block here until resumed (or stopped)."""
        self._checkpoint()
        while self.state is EngineState.PAUSED:
            self.sleep(self.poll_s)
            self._checkpoint()

    def _stop_mid_block(self, block: Block, buf: list[tuple[StepRecord, float]]) -> None:
        self._waiting = None
        if buf:
            self._emit(Steps(self._clock(), tuple(buf), self._driver_state("abort")))
        done = self._current[1] if self._current else 0
        self._emit(BlockEnded(self._clock(), block.block_id, "aborted", finished=False))
        self._log(
            "warn",
            f"block {block.block_id} stopped after {done} of {block.n_indents} indents",
            block_id=block.block_id,
        )

    def _observe(self, block: Block, indents: Sequence[IndentResult]) -> None:
        results = sorted(indents, key=lambda r: r.indent_index)
        if self.interlock is not None:
            self.interlock.passed(block, results)
        report = self.campaign.observe_block(block, results)
        self._snapshot_id += 1
        sid = self._snapshot_id
        mape, max_found = None, None
        if self.track_metrics and self.evaluator is not None:
            score = self.evaluator.score(self.campaign)
            self.campaign.note_score(score)
            mape, max_found = score.mape_pct, score.max_found_gpa
        fields = (
            self.campaign.map_fields(sid, self.map_display_n)
            if report is not None and self.map_display_n is not None
            else None
        )
        summary = fit_summary(
            self.campaign.calibration, report, mape, max_found, modulus_fit(self.campaign, report)
        )
        if summary.collapse_alarm:
            self._last_collapse = (sid, summary.collapse_reason)
        hyper = report.hyper if report is not None else None
        t = self._clock()
        unmeasured = sum(not r.measured for r in results)
        line = (
            f"block {block.block_id:>4}  {block.kind:<6}  g={block.grid_g}  hold {block.hold_s:>4g} s  "
            f"t={t:>10,.0f} s  indents {len(results)}"
            + (f" ({unmeasured} not measured)" if unmeasured else "")
            + (f"  MAPE {mape:.2f} %" if mape is not None else "")
            + ("  COLLAPSE ALARM" if summary.collapse_alarm else "")
        )
        plan = self._plan_state(block.block_id, "observed")
        self._emit(Observed(t, block.block_id, sid, hyper or {}, summary, fields, plan, line))
        self._last_snapshot = sid
        self._say(line)

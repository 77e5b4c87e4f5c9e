"""The run engine: an explicit state machine that drives a campaign through a driver, block by block.

Between any two indents and between blocks the engine reaches a checkpoint: it reads the operator
commands queued in the journal, applies them (pause, approve, veto, adjust, stop, abort) and records
the outcome. Everything it learns is journaled first, so a process killed at any point can be resumed
from the journal (:meth:`Engine.run` on a reopened journal continues where the last one ended).
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import os
import threading
import time
import traceback
from collections.abc import Callable, Iterable, Sequence
from typing import TYPE_CHECKING, Any, Protocol

from core.access import command_channel_problem
from core.describe import describe_block
from core.driver import (
    Driver,
    DriverAborted,
    InstrumentWait,
    PhysicsClock,
    Recoverable,
    Restorable,
    WaitsForOperator,
)
from core.errors import InputError
from core.interlock import Interlock
from core.journal import DriverState, Journal, user_name
from core.metrics import MapEvaluator, MapScore
from core.plan import Block, Decision, IndentResult, PlannerSettings, StepRecord
from core.runview import CommandKind, EngineState, MapFields
from core.settings import check_veto, coerce_supervision

if TYPE_CHECKING:
    from core.surrogate import FitReport  # the refit's report (torch stays out of the engine's import)


class StageFrame(Protocol):
    """The campaign's calibration, as far as the engine needs it: unit-square (u, v) to stage µm."""

    def to_stage(self, u: float, v: float) -> tuple[Any, Any]: ...


class CampaignLike(Protocol):
    """What the engine needs from core.campaign.Campaign (a fake in tests)."""

    settings: PlannerSettings
    calibration: StageFrame
    # why the last propose() returned None (budget, target, the policy has nothing left)
    last_stop_reason: str | None

    def propose(
        self, clock_s: float, position_um: tuple[float, float], program_open: bool, block_id: int
    ) -> Decision | None: ...

    def veto(self, decision: Decision, hold_blocks: int = ...) -> None: ...

    def adjust(self, **changes: Any) -> PlannerSettings: ...

    def observe_block(self, block: Block, results: Sequence[IndentResult]) -> FitReport | None: ...

    def map_fields(self, snapshot_id: int, display_n: int = ...) -> MapFields: ...

    def export_state(self) -> dict[str, Any]: ...

    # scored from outside by a simulated run's evaluator (core.metrics.ScoredMap), told back the verdict
    def has_map(self) -> bool: ...

    def predict_mean_stage(self, x_um: Any, y_um: Any) -> Any: ...

    def indented_xy_um(self) -> Any: ...

    def note_score(self, score: MapScore | None) -> None: ...

    def restore(
        self, state: dict[str, Any], blocks: Sequence[tuple[Block, Sequence[IndentResult]]]
    ) -> None: ...


class _Stop(Exception):
    """Internal: leave the main loop."""


class Engine:
    """Executes a campaign through a driver, journaling every step; one engine per journal."""

    def __init__(
        self,
        journal: Journal,
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
        map_display_n: int = 50,
        interlock: Interlock | None = None,
        evaluator: MapEvaluator | None = None,
    ) -> None:
        coerce_supervision(supervision)
        if not 0 < poll_s <= 5:
            raise InputError("poll_s", f"{poll_s!r} is not allowed: expected 0 < poll_s ≤ 5 s")
        self.journal = journal
        self.campaign = campaign
        self.driver = driver
        # the driver's optional capabilities, asked once
        self._restorable = driver if isinstance(driver, Restorable) else None
        self._recoverable = driver if isinstance(driver, Recoverable) else None
        self._physics = driver if isinstance(driver, PhysicsClock) else None
        # a driver that hands blocks to a person (KLA): its reports, and what it waits for now
        self._operator = driver if isinstance(driver, WaitsForOperator) else None
        self._waiting: InstrumentWait | None = None
        self.supervision = supervision
        self.poll_s = poll_s
        self.sleep = sleep
        self.progress = progress
        self.track_metrics = track_metrics
        self.owner_uid = os.stat(journal.path).st_uid if owner_uid is None else owner_uid
        self.watch_s = watch_s
        self.map_display_n = map_display_n
        # every block passes the interlock before the driver sees it; a simulated run's evaluator scores the map
        self.interlock = interlock
        self.evaluator = evaluator
        self.state = EngineState.IDLE
        self.stop_reason = ""
        self.completed = False
        # what the checkpoint flags
        self._paused = False
        self._abort = False
        self._stop_after_block = False
        self._pending: tuple[int, Decision, str] | None = None  # decision id, decision, why it waits
        self._current: tuple[Block, int] | None = None  # block, first unfinished indent
        self._next_block_id = 0
        self._recovery_s = 0.0
        self._needs_recovery = False
        self._collapse_ack_snapshot: int | None = None
        self._last_snapshot: int | None = None
        self._last_collapse: tuple[int, str] | None = None  # snapshot id, reason of an unacknowledged alarm
        self._external_abort = threading.Event()
        self._watcher: threading.Thread | None = None
        self._watch_stop = threading.Event()

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

    def _say(self, line: str) -> None:
        if self.progress is not None:
            self.progress(line)

    def _set_state(self, state: EngineState, **kw: Any) -> None:
        self.state = state
        self.journal.note_clock(self._clock())
        self.journal.set_state(state, **kw)

    def _settle_state(self) -> None:
        """The state the flags imply at a checkpoint."""
        if self._abort or (self._stop_after_block and self._current is None):
            want = EngineState.STOPPING
        elif self._paused:
            want = EngineState.PAUSED
        elif self._waiting is not None:
            want = EngineState.WAITING_FOR_INSTRUMENT
        elif self._pending is not None:
            want = EngineState.AWAITING_APPROVAL
        else:
            want = EngineState.RUNNING
        if want != self.state:
            self._set_state(want)

    def request_abort(self) -> None:
        """Thread- and signal-safe: stop at the next checkpoint (finish the indent, lift, stop)."""
        self._external_abort.set()

    # -- the run -----------------------------------------------------------------------------------
    def run(self) -> EngineState:
        """Run (or resume) until the planner is done, the operator stops it, or it fails."""
        resumed = self.journal.has_history()
        row = self.journal.q.engine_row()
        if resumed and row.get("completed"):
            self.completed = True
            self.stop_reason = str(row.get("stop_reason") or "finished")
            self.state = EngineState.STOPPED
            return self.state
        self.journal.begin_session("resume" if resumed else "start")
        self._start_watcher()
        try:
            if resumed:
                self._recover()
            else:
                self.journal.log(
                    "info",
                    f"run started by {user_name(os.getuid())}: supervision {self.supervision}, PID {os.getpid()}",
                )
            self._set_state(EngineState.RUNNING, supervision=self.supervision)
            self._loop()
            self._finish()
        except BaseException as exc:
            self._fail(exc)
            raise
        finally:
            self._stop_watcher()
        return self.state

    def _fail(self, exc: BaseException) -> None:
        with contextlib.suppress(Exception):
            what = "interrupted" if isinstance(exc, KeyboardInterrupt) else f"{type(exc).__name__}: {exc}"
            self.journal.note_clock(self._clock())
            self.journal.log(
                "error", f"engine failed: {what}", category="error", detail=traceback.format_exc()
            )
            self.state = EngineState.FAILED
            self.journal.set_state(EngineState.FAILED, stop_reason=what)
            self.journal.end_session(EngineState.FAILED)

    def _loop(self) -> None:
        while True:
            self._checkpoint()
            if self._abort:
                self.stop_reason = self.stop_reason or "aborted by the operator"
                return
            if self._stop_after_block and self._current is None:
                self.stop_reason = "stopped after the block by the operator"
                return
            if self._paused:
                self.sleep(self.poll_s)
                continue
            if self._current is None:
                if self._pending is not None:
                    self.sleep(self.poll_s)  # awaiting approval
                    continue
                if not self._decide():
                    return
                continue
            block, start = self._current
            if not self._execute(block, start):
                return
            self._observe(block)
            self._current = None
            self._next_block_id = block.block_id + 1

    def _finish(self) -> None:
        self._set_state(EngineState.STOPPING)
        if self._pending is not None:
            did, _, _ = self._pending
            self.journal.resolve_decision(did, "dropped", "engine")
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
        self.journal.note_clock(self._clock())
        self.journal.log("info", text)
        self._set_state(EngineState.STOPPED, completed=self.completed, stop_reason=self.stop_reason)
        self.journal.end_session(EngineState.STOPPED)
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
        """Journal a fresh decision; run it, or hold it for the operator. False: nothing left to do."""
        if decision is None:
            self.completed = True
            self.stop_reason = self.campaign.last_stop_reason or "the planner has nothing more to propose"
            return False
        why = self._approval_reason(decision)
        self.journal.note_clock(self._clock())
        did = self.journal.record_decision(
            decision,
            self._clock(),
            "pending" if why else "auto",
            why,
            text=("awaiting approval (" + why + "): " if why else "decided ") + self._describe(decision),
            plan=None if why else (self.campaign.export_state(), self.campaign.settings),
        )
        if why.startswith("safety interlock"):
            self.journal.log("warn", why, block_id=decision.block.block_id)
        if why:
            self._pending = (did, decision, why)
            self._settle_state()
            self._say(f"awaiting approval ({why}): {self._describe(decision)}")
        else:
            self._current = (decision.block, 0)
        return True

    def _decide(self) -> bool:
        return self._offer(self._propose(self._next_block_id))

    def _start_block(
        self, decision_id: int, decision: Decision, resolution: tuple[str, str, int | None] | None
    ) -> None:
        self.journal.record_block_planned(
            decision.block,
            decision_id,
            self._clock(),
            self.campaign.export_state(),
            self.campaign.settings,
            resolve=resolution,
        )
        self._current = (decision.block, 0)
        self._pending = None

    # -- commands ----------------------------------------------------------------------------------
    def _checkpoint(self) -> None:
        if self._external_abort.is_set() and not self._abort:
            self._abort = True
            self.stop_reason = "aborted (signal)"
            self.journal.log(
                "command", "abort requested by a signal: finishing the indent, lifting, stopping"
            )
        commands = self.journal.q.unprocessed_commands()
        # trust rests on who the OS lets write the journal, not on the uid a row claims (core.access)
        untrusted = command_channel_problem(self.journal.path, self.owner_uid) if commands else ""
        for sc in commands:
            before = self.state
            try:
                if untrusted:
                    outcome, reason = "rejected", untrusted
                else:
                    outcome, reason = self._apply(sc.kind, sc.author, sc.uid, sc.payload, sc.command_id)
            except InputError as exc:
                outcome, reason = "rejected", str(exc)
            self.journal.note_clock(self._clock())
            text = f"{sc.author}: {sc.kind} {outcome}" + (f" ({reason})" if reason else "")
            self.journal.mark_command(sc.command_id, outcome, reason, self._clock(), before, text)
        self._settle_state()

    def _apply(
        self, kind_s: str, author: str, uid: int, payload: dict[str, Any], cid: int
    ) -> tuple[str, str]:
        if uid != self.owner_uid:
            return "rejected", f"{user_name(uid)} is not the run's owner ({user_name(self.owner_uid)})"
        try:
            kind = CommandKind(kind_s)
        except ValueError:
            return "rejected", f"unknown command {kind_s!r}"
        if kind is CommandKind.PAUSE:
            if self._paused:
                return "rejected", "already paused"
            self._paused = True
            return "accepted", "pausing after the current indent" if self._current else ""
        if kind is CommandKind.RESUME:
            if not self._paused:
                return "rejected", "not paused"
            self._paused = False
            return "accepted", ""
        if kind in (CommandKind.APPROVE, CommandKind.STEP):
            return self._approve(author, payload, cid)
        if kind is CommandKind.VETO:
            return self._veto(author, payload, cid)
        if kind is CommandKind.ADJUST:
            return self._adjust(payload)
        if kind is CommandKind.STOP_AFTER_BLOCK:
            if self._stop_after_block:
                return "rejected", "already stopping after this block"
            self._stop_after_block = True
            return (
                "accepted",
                "stopping after the current block" if self._current else "stopping now (between blocks)",
            )
        if kind is CommandKind.ABORT:
            self._abort = True
            self.stop_reason = f"aborted by {author}"
            return "accepted", "finishing the current indent, lifting, stopping"
        if kind in (CommandKind.CONFIRM, CommandKind.REPORT, CommandKind.SKIP):
            return self._instrument_report(kind, author, payload)
        return "rejected", f"unhandled command {kind_s!r}"  # pragma: no cover

    def _instrument_report(self, kind: CommandKind, author: str, payload: dict[str, Any]) -> tuple[str, str]:
        """The operator's word on the instrument (started with the token, aborted, surface, skip a site)."""
        if self._operator is None:
            return "rejected", "this run's driver takes no instrument reports"
        if kind is CommandKind.CONFIRM:
            what, value = "started", payload.get("token", "")
        elif kind is CommandKind.REPORT:
            what, value = str(payload.get("kind", "")), payload.get("token", "")
        else:
            what, value = "skip", payload.get("site", "")
        ok, why = self._operator.operator_report(what, str(value), author)
        return ("accepted" if ok else "rejected"), why

    def _check_stale(self, payload: dict[str, Any]) -> str:
        assert self._pending is not None
        want = payload.get("decision_id")
        if want is not None and want != self._pending[0]:
            return f"stale: decision {self._pending[0]} is pending, not {want}"
        return ""

    def _approve(self, author: str, payload: dict[str, Any], cid: int) -> tuple[str, str]:
        if self._pending is None:
            return "rejected", "nothing is waiting for approval"
        stale = self._check_stale(payload)
        if stale:
            return "rejected", stale
        did, decision, why = self._pending
        refusal = self._interlock_refusal(decision.block)
        if refusal:
            return "rejected", f"{refusal}; veto it to let the planner offer another block"
        if why.startswith("length-scale collapse") and self._last_collapse is not None:
            self._collapse_ack_snapshot = self._last_collapse[0]
        self._start_block(did, decision, ("approved", author, cid))
        return "accepted", f"block {decision.block.block_id} approved"

    def _veto(self, author: str, payload: dict[str, Any], cid: int) -> tuple[str, str]:
        if self._pending is None:
            return "rejected", "nothing is waiting for approval"
        stale = self._check_stale(payload)
        if stale:
            return "rejected", stale
        did, decision, _ = self._pending
        try:
            hold = check_veto(payload)
        except InputError as exc:
            return "rejected", str(exc)
        if hold is None:
            self.campaign.veto(decision)
        else:
            self.campaign.veto(decision, hold_blocks=hold)
        state = (decision.block.block_id, "veto", self.campaign.export_state(), self.campaign.settings)
        self.journal.resolve_decision(did, "vetoed", author, cid, campaign_state=state)
        self._pending = None
        if not self._offer(self._propose(decision.block.block_id)):
            return "accepted", "vetoed; the planner has nothing else to offer, stopping"
        return "accepted", f"vetoed block {decision.block.block_id}; the next best is offered"

    def _adjust(self, payload: dict[str, Any]) -> tuple[str, str]:
        changes = dict(payload)
        if not changes:
            return "rejected", "nothing to adjust"
        supervision = changes.pop("supervision", None)
        if supervision is not None:
            supervision = coerce_supervision(supervision)  # InputError: rejected with its message
        if changes:
            try:
                self.campaign.adjust(**changes)
            except (InputError, TypeError) as exc:
                return "rejected", str(exc)
            self.journal.record_campaign_state(
                self._next_block_id if self._current is None else self._current[0].block_id,
                "adjust",
                self.campaign.export_state(),
                self.campaign.settings,
            )
        if supervision is not None and supervision != self.supervision:
            self.supervision = supervision
            self.journal.set_state(self.state, supervision=supervision)
            if self._pending is not None and not self._approval_reason(self._pending[1]):
                did, decision, _ = self._pending
                self._start_block(did, decision, ("auto", "engine", None))
        shown = ", ".join(f"{k}={v!r}" for k, v in payload.items())
        return "accepted", shown

    # -- executing ---------------------------------------------------------------------------------
    def _journal_steps(
        self, steps: Iterable[StepRecord], text: str, category: str, block_id: int | None
    ) -> None:
        buf: list[tuple[StepRecord, float]] = []
        for s in steps:
            buf.append((s, self._clock()))
            if s.category == "recovery":
                self._recovery_s += s.seconds
        self.journal.note_clock(self._clock())
        self.journal.record_steps(
            buf, self._driver_state(category), text=text, category=category, block_id=block_id
        )

    def _end_program(self, text: str) -> None:
        self._journal_steps(self.driver.end_program(), text, "engine", None)

    def _set_driver(
        self, clock_s: float, pos: tuple[float, float], is_open: bool, physics: float | None
    ) -> None:
        if self._restorable is None:
            raise InputError(
                str(self.journal.path),
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
                    if self._abort:
                        gen.close()
                        self._stop_mid_block(block, buf)
                        return False
                    continue
                if self._waiting is not None:  # the array ended: its results follow
                    self._waiting = None
                    self._settle_state()
                if not isinstance(ev, IndentResult):
                    buf.append((ev, self._clock()))
                    if ev.category == "recovery":
                        self._recovery_s += ev.seconds
                    continue
                self.journal.record_indent(ev, buf, self._driver_state("indent"))
                buf = []
                self._current = (block, ev.indent_index + 1)
                if ev.indent_index >= block.n_indents - 1:
                    continue  # the block-level checkpoint follows
                self._checkpoint()
                while self._paused and not self._abort:
                    self.sleep(self.poll_s)
                    self._checkpoint()
                if self._abort:
                    gen.close()
                    self._stop_mid_block(block, buf)
                    return False
        except DriverAborted:
            self._stop_mid_block(block, buf)
            self._checkpoint()  # consume the abort command that triggered it
            self._abort = True
            self.stop_reason = self.stop_reason or "aborted"
            return False
        if buf:
            self._journal_steps((s for s, _ in buf), "", "engine", block.block_id)
        self.journal.set_block_status(block.block_id, "executed", self._clock())
        return True

    def _wait_for_instrument(self, wait: InstrumentWait) -> None:
        """A checkpoint while the driver waits for the instrument: journal what changed, take commands."""
        before = self._waiting
        self._waiting = wait
        changed = before is None or (before.waiting, before.started) != (wait.waiting, wait.started)
        self.journal.note_clock(self._clock())
        for note in wait.notes:
            self.journal.log("info", note, category="instrument", block_id=wait.block_id)
        if changed:
            what = "waiting for the instrument" if before is None else "instrument"
            self.journal.log(
                "info",
                f"block {wait.block_id}: {what}: {wait.waiting}"
                + ("" if wait.started else " (start not confirmed)"),
                category="instrument",
                block_id=wait.block_id,
                detail=json.dumps(dataclasses.asdict(wait)),
            )
        self._checkpoint()
        while self._paused and not self._abort:
            self.sleep(self.poll_s)
            self._checkpoint()

    def _stop_mid_block(self, block: Block, buf: list[tuple[StepRecord, float]]) -> None:
        self._waiting = None
        if buf:
            self.journal.record_steps(buf, self._driver_state("abort"))
        done = self._current[1] if self._current else 0
        self.journal.set_block_status(block.block_id, "aborted")
        self.journal.note_clock(self._clock())
        self.journal.log(
            "warn",
            f"block {block.block_id} stopped after {done} of {block.n_indents} indents",
            block_id=block.block_id,
        )

    def _observe(self, block: Block) -> None:
        results = self.journal.q.results(block.block_id)
        if self.interlock is not None:
            self.interlock.passed(block, results)
        report = self.campaign.observe_block(block, results)
        sid = self.journal.next_snapshot_id()
        mape, max_found = None, None
        if self.track_metrics and self.evaluator is not None:
            score = self.evaluator.score(self.campaign)
            self.campaign.note_score(score)
            mape, max_found = score.mape_pct, score.max_found_gpa
        fields = self.campaign.map_fields(sid, self.map_display_n) if report is not None else None
        summary = self._fit_summary(report, mape, max_found)
        if report is not None and report.collapse:
            self._last_collapse = (sid, report.collapse_reason)
        hyper = report.hyper if report is not None else None
        t = self._clock()
        unmeasured = sum(not r.measured for r in results)
        line = (
            f"block {block.block_id:>4}  {block.kind:<6}  g={block.grid_g}  hold {block.hold_s:>4g} s  "
            f"t={t:>10,.0f} s  indents {len(results)}"
            + (f" ({unmeasured} not measured)" if unmeasured else "")
            + (f"  MAPE {mape:.2f} %" if mape is not None else "")
            + ("  COLLAPSE ALARM" if summary.get("collapse_alarm") else "")
        )
        self.journal.note_clock(t)
        self.journal.record_observation(
            block.block_id,
            t,
            sid,
            hyper or {},
            summary,
            fields,
            self.campaign.export_state(),
            self.campaign.settings,
            text=line,
        )
        self._last_snapshot = sid
        self._say(line)

    def _fit_summary(
        self, report: FitReport | None, mape: float | None, max_found: float | None
    ) -> dict[str, Any]:
        out: dict[str, Any] = {"mape_pct": mape, "max_found_gpa": max_found}
        if report is None:
            return out
        ls_uv = report.lengthscales_uv
        nls_uv = report.noise_lengthscales_uv
        out.update(
            lengthscales_um=list(self._uv_to_um(ls_uv)),
            noise_lengthscales_um=list(self._uv_to_um(nls_uv)) if nls_uv is not None else [],
            lengthscales_uv=list(ls_uv),
            collapse_alarm=bool(report.collapse),
            collapse_reason=str(report.collapse_reason),
            used_last_good=bool(report.used_last_good),
            refit_s=report.seconds,
            n_points=report.n_points,
            iterations=report.iterations,
            outputscale=report.outputscale,
            mean_const=report.mean_const,
        )
        return out

    def _uv_to_um(self, ls: Sequence[float]) -> tuple[float, ...]:
        to_stage = self.campaign.calibration.to_stage
        x0, y0 = to_stage(0.0, 0.0)
        xu, yu = to_stage(1.0, 0.0)
        xv, yv = to_stage(0.0, 1.0)
        su = math.hypot(float(xu) - float(x0), float(yu) - float(y0))
        sv = math.hypot(float(xv) - float(x0), float(yv) - float(y0))
        return tuple(float(v) * s for v, s in zip(ls, (su, sv), strict=False))

    # -- resume ------------------------------------------------------------------------------------
    def _recover(self) -> None:
        q = self.journal.q
        self.journal.note_clock(0.0)
        cs = q.latest_campaign_state()
        observed = q.observed_blocks()
        if self.interlock is not None:
            self.interlock.restore(observed)
        if cs is not None:
            self.campaign.restore(cs[0], observed)
        elif observed:
            raise InputError(str(self.journal.path), "journal has observed blocks but no planner state")
        ds = q.latest_driver_state()
        self._recovery_s = q.recovery_seconds()
        if ds is not None:
            # the tip state after a crash is unknown: the driver re-engages before it indents again
            self._set_driver(ds.clock_s, ds.position_um, False, ds.physics_clock_s)
            self._needs_recovery = ds.program_open
        open_blk = q.open_block()
        pending = q.pending_decision()
        last_state = str(q.engine_row().get("state", "idle"))
        parts = [f"the last engine stopped while {last_state}", f"{len(observed)} blocks observed"]
        if open_blk is not None:
            block, _status, done = open_blk
            self._current = (block, done)
            self._next_block_id = block.block_id
            if done >= block.n_indents:
                parts.append(f"block {block.block_id} was finished but not yet folded into the model")
            else:
                parts.append(f"block {block.block_id} continues at indent {done} of {block.n_indents}")
            if pending is not None:
                self.journal.resolve_decision(pending.decision_id, "dropped", "engine")
        else:
            self._next_block_id = max((b.block_id for b, _ in observed), default=-1) + 1
            if pending is not None:
                why = pending.needs_approval_reason or "awaiting approval"
                self._pending = (pending.decision_id, pending.decision, why)
                self._next_block_id = pending.decision.block.block_id
                parts.append(
                    f"decision {pending.decision_id} for block {pending.decision.block.block_id} still awaits approval"
                )
        n_cmd = len(q.unprocessed_commands())
        if n_cmd:
            parts.append(f"{n_cmd} commands sent before the stop are processed now")
        if ds is not None:
            parts.append(
                f"instrument restored to t={ds.clock_s:,.0f} s at ({ds.position_um[0]:.0f}, {ds.position_um[1]:.0f}) µm"
            )
        self.journal.note_clock(self._clock())
        self.journal.log("warn", "resumed: " + "; ".join(parts), category="recovery")
        self._say("resumed: " + "; ".join(parts))

    # -- the abort / pause watcher -------------------------------------------------------------------
    def _start_watcher(self) -> None:
        """A thread that sees pause and abort while a slow driver step runs (the main loop only sees them between indents)."""
        if self.watch_s is None:
            return
        self._watch_stop.clear()
        self._watcher = threading.Thread(target=self._watch, name="engine-watch", daemon=True)
        self._watcher.start()

    def _stop_watcher(self) -> None:
        if self._watcher is not None:
            self._watch_stop.set()
            self._watcher.join(timeout=5)
            self._watcher = None

    def _watch(self) -> None:
        assert self.watch_s is not None
        watch = self.journal.command_watch(self.owner_uid)
        if watch is None:
            return
        try:
            while not self._watch_stop.wait(self.watch_s):
                if command_channel_problem(self.journal.path, self.owner_uid):
                    continue  # the checkpoint rejects them, with the reason
                if watch.poll():
                    self.driver.abort()
        finally:
            watch.close()

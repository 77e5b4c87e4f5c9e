"""What a resumed engine starts from, as one fold: the run's events in, a RunHistory out.

The fold is the one definition of "the run so far". Two feeders use it: a record that sees the events
as the engine emits them (``HistoryFold.emit``, the headless record) and the journal, which replays the
rows each event became (``core.journal.sink.fold_history``) through the same steps. A test holds the
two to the same answer at every point of a run.

The fold's state per kind depends only on that kind's order (the latest plan, the latest instrument
state, a block's latest status, a decision's resolution). The console's view is the other fold over the
same log (core.journal.snapshot).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

from core.plan import Block, Decision, IndentResult, PlannerSettings, StepRecord
from core.run.events import (
    BlockEnded,
    BlockStarted,
    Decided,
    Indent,
    Observed,
    PlanChanged,
    PlanState,
    Resolved,
    RunEvent,
    RunHistory,
    StateChanged,
    Steps,
)
from core.run.records import DriverState

AWAITING = "awaiting approval"  # a pending decision's reason when its record gives none


@dataclass
class _Block:
    block: Block
    status: str = "planned"  # planned, running, executed, aborted, observed
    results: dict[int, IndentResult] = field(default_factory=dict)

    def ordered(self) -> list[IndentResult]:
        return [self.results[i] for i in sorted(self.results)]


class HistoryFold:
    """Folds a run's events (or the rows they became) into the RunHistory a resumed engine starts from."""

    def __init__(self) -> None:
        self.started = False
        self.state = "idle"
        self.completed = False
        self.stop_reason = ""
        self.plan: tuple[dict[str, Any], PlannerSettings] | None = None
        self.driver: DriverState | None = None
        self.recovery_s = 0.0
        self.blocks: dict[int, _Block] = {}
        self.pending: dict[int, tuple[Decision, str]] = {}
        self.last_decision_id = 0
        self.last_snapshot_id = 0

    # -- the fold's steps (the journal feeds its rows through these) ------------------------------
    def session(self) -> None:
        self.started = True

    def state_changed(self, state: str, completed: bool | None, stop_reason: str | None) -> None:
        self.state = state
        if completed is not None:
            self.completed = completed
        if stop_reason is not None:
            self.stop_reason = stop_reason

    def decided(self, decision_id: int, decision: Decision, status: str, why: str) -> None:
        """A proposal: ``auto`` plans its block at once, ``pending`` waits for an answer."""
        self.last_decision_id = max(self.last_decision_id, decision_id)
        if status == "auto":
            self.block_planned(decision.block)
        else:
            self.pending[decision_id] = (decision, why or AWAITING)

    def resolved(self, decision_id: int) -> None:
        """A waiting decision answered (approved, vetoed, dropped)."""
        self.pending.pop(decision_id, None)

    def block_planned(self, block: Block) -> None:
        self.blocks.setdefault(block.block_id, _Block(block))

    def indent(self, result: IndentResult) -> None:
        b = self.blocks[result.block_id]
        b.results[result.indent_index] = result
        if b.status == "planned":
            b.status = "running"

    def block_status(self, block_id: int, status: str) -> None:
        self.blocks[block_id].status = status

    def steps(self, steps: Iterable[StepRecord]) -> None:
        for s in steps:  # one by one, in order: the engine's own running sum, to the last bit
            if s.category == "recovery":
                self.recovery_s += s.seconds

    def instrument(self, driver: DriverState) -> None:
        self.driver = driver

    def planner(self, state: dict[str, Any], settings: PlannerSettings) -> None:
        self.plan = (state, settings)

    def observed(self, block_id: int, snapshot_id: int) -> None:
        self.last_snapshot_id = max(self.last_snapshot_id, snapshot_id)
        self.block_status(block_id, "observed")

    # -- the live feeder --------------------------------------------------------------------------
    def emit(self, event: RunEvent) -> None:
        """One event as the engine emits it: any event says an engine ran (a log whose first row is an
        instrument state still has that state restored)."""
        plan: PlanState | None = None
        self.session()
        if isinstance(event, StateChanged):
            self.state_changed(event.state.value, event.completed, event.stop_reason)
        elif isinstance(event, Decided):
            self.decided(event.decision_id, event.decision, event.status, event.why)
            plan = event.plan
        elif isinstance(event, Resolved):
            self.resolved(event.decision_id)
            plan = event.plan
        elif isinstance(event, BlockStarted):
            self.resolved(event.decision_id)
            self.block_planned(event.block)
            plan = event.plan
        elif isinstance(event, Indent):
            self.steps(s for s, _ in event.steps)
            self.indent(event.result)
            self.instrument(event.driver)
        elif isinstance(event, Steps):
            self.steps(s for s, _ in event.steps)
            self.instrument(event.driver)
        elif isinstance(event, BlockEnded):
            self.block_status(event.block_id, event.status)
        elif isinstance(event, Observed):
            self.observed(event.block_id, event.snapshot_id)
            plan = event.plan
        elif isinstance(event, PlanChanged):
            plan = event.plan
        if plan is not None:
            self.planner(plan.state, plan.settings)

    # -- the result ----------------------------------------------------------------------------------
    def history(self, queued_commands: int = 0) -> RunHistory | None:
        """The run so far (None: no engine has run on it yet)."""
        if not self.started:
            return None
        ordered = [self.blocks[k] for k in sorted(self.blocks)]
        observed = [(b.block, b.ordered()) for b in ordered if b.status == "observed"]
        still_open = [b for b in ordered if b.status != "observed"]
        open_block = None if not still_open else (still_open[-1].block, still_open[-1].ordered())
        pending = None
        if self.pending:
            did = max(self.pending)
            pending = (did, *self.pending[did])
        return RunHistory(
            completed=self.completed,
            stop_reason=self.stop_reason,
            last_state=self.state,
            plan=self.plan,
            observed=observed,
            driver=self.driver,
            recovery_s=self.recovery_s,
            open_block=open_block,
            pending=pending,
            queued_commands=queued_commands,
            last_decision_id=self.last_decision_id,
            last_snapshot_id=self.last_snapshot_id,
        )

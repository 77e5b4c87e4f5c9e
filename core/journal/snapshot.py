"""What a console shows of a run, as one fold over its event log: the typed events in, the run's view out.

This is the second fold over the log (the first is the resume's, core.run.history): the console, replay,
``aeni report`` and ``aeni runs`` read a run through it, so they decode the same events the resume does.
Replay is this fold stopped just after a block's ``Observed`` event. What is not an engine event stays
outside: who owns the file, whether an engine holds it, the sessions' wall time and the log panel's lines
(alerts are written beside the engine) are read by core.journal.reader.
"""

from __future__ import annotations

import dataclasses
import math
import statistics
from collections.abc import Iterable
from dataclasses import dataclass, field

from core.drift import AREA_ERROR_THRESHOLD_PCT, area_error_pct
from core.driver import InstrumentWait
from core.journal.codec import BlockRecord, StoredDecision
from core.plan import LEDGER_CATEGORIES, Block, Decision, IndentResult, PlannerSettings, StepRecord
from core.run.events import (
    ApprovalAsked,
    BlockEnded,
    BlockStarted,
    Decided,
    EngineDied,
    Indent,
    Observed,
    PlanChanged,
    PlanState,
    Resolved,
    RunEvent,
    StateChanged,
    Steps,
    Waiting,
)
from core.run.machine import EngineState
from core.run.records import DriverState
from core.runview import IndentMark, TestedCenter


@dataclass
class BlockView:
    """One planned block as the events told it (what a replay walks, what the report lists)."""

    block: Block
    decision_id: int | None
    planned_t_s: float
    status: str = "planned"  # planned, running, executed, aborted, observed
    results: list[IndentResult] = field(default_factory=list)
    steps: list[StepRecord] = field(default_factory=list)
    snapshot_id: int | None = None
    fit_summary: dict[str, object] = field(default_factory=dict)
    finished_t_s: float | None = None


@dataclass(frozen=True)
class Asked:
    """An approval's deadline as the engine emitted it, with the wall time its row was written."""

    decision_id: int
    wall_utc: str
    timeout_s: float
    on_timeout: str


class SnapshotFold:
    """Folds a run's events, in the order they were written, into what its console shows."""

    def __init__(self) -> None:
        self.seq = 0  # the last event folded
        self.state: EngineState | None = None
        self.supervision: str | None = None
        self.completed = False
        self.stop_reason = ""
        self.driver: DriverState | None = None
        self.plan: PlanState | None = None
        self.ledger: dict[str, float] = dict.fromkeys(LEDGER_CATEGORIES, 0.0)
        self.reconfigurations = 0
        self.decisions: dict[int, StoredDecision] = {}
        self.blocks: dict[int, BlockView] = {}
        self.indents: list[IndentMark] = []
        self.last_indent: IndentResult | None = None
        self.last_drift_rate_nm_s: float | None = None
        self.drift_events: list[tuple[float, float]] = []  # (t_s, rate) past the area-error threshold
        self.tested: list[TestedCenter] = []
        self.fit: tuple[int, dict[str, object]] | None = None  # the latest refit: snapshot id, summary
        self.wait: InstrumentWait | None = None
        self.asked: Asked | None = None
        self.observed_at: dict[int, int] = {}  # block id: the seq of its Observed event (replay's cut)

    # -- folding ----------------------------------------------------------------------------------
    def emit(self, event: RunEvent, seq: int = 0, wall_utc: str = "") -> None:
        """One event (``seq``: its place in the log; ``wall_utc``: when its row was written)."""
        self.seq = seq
        if isinstance(event, Decided | Resolved | BlockStarted | Observed | PlanChanged) and event.plan:
            self.plan = event.plan
        if isinstance(event, StateChanged):
            self.state = event.state
            if event.supervision is not None:
                self.supervision = event.supervision
            if event.completed is not None:
                self.completed = event.completed
            if event.stop_reason is not None:
                self.stop_reason = event.stop_reason
        elif isinstance(event, EngineDied):
            if not self.completed and self.state not in (EngineState.STOPPED, EngineState.FAILED):
                self.state, self.stop_reason = EngineState.FAILED, event.cause
        elif isinstance(event, Decided):
            status = "auto" if event.status == "auto" else "pending"
            self._decide(event.decision_id, event.decision, status, event.why, event.t_s)
            if status == "auto":
                self._plan_block(event.decision.block, event.decision_id, event.t_s)
        elif isinstance(event, Resolved):
            self._resolve(event.decision_id, event.status)
        elif isinstance(event, BlockStarted):
            waited = self.decisions.get(event.decision_id)
            if waited is not None and waited.status == "pending":  # (an auto decision planned at once)
                self._resolve(event.decision_id, event.resolution[0])
            self._plan_block(event.block, event.decision_id if event.decision_id >= 0 else None, event.t_s)
        elif isinstance(event, Indent):
            self._steps(s for s, _ in event.steps)
            self._indent(event.result)
            self.driver = event.driver
        elif isinstance(event, Steps):
            self._steps(s for s, _ in event.steps)
            self.driver = event.driver
        elif isinstance(event, BlockEnded):
            b = self.blocks.get(event.block_id)
            if b is not None:
                b.status = event.status
                if event.finished:
                    b.finished_t_s = event.t_s
        elif isinstance(event, Observed):
            self._observed(event, seq)
        elif isinstance(event, Waiting):
            self.wait = event.wait
        elif isinstance(event, ApprovalAsked):
            self.asked = Asked(event.decision_id, wall_utc, event.timeout_s, event.on_timeout)

    def _decide(self, did: int, decision: Decision, status: str, why: str, t_s: float) -> None:
        self.decisions[did] = StoredDecision(did, decision, status, why, t_s)

    def _resolve(self, did: int, status: str) -> None:
        d = self.decisions.get(did)
        if d is not None:
            self.decisions[did] = dataclasses.replace(d, status=status)

    def _plan_block(self, block: Block, decision_id: int | None, t_s: float) -> None:
        self.blocks.setdefault(block.block_id, BlockView(block, decision_id, t_s))

    def _steps(self, steps: Iterable[StepRecord]) -> None:
        for s in steps:
            self.ledger[s.category] = self.ledger.get(s.category, 0.0) + s.seconds
            if s.category == "reconfigure":
                self.reconfigurations += 1
            b = self.blocks.get(s.block_id)
            if b is not None:
                b.steps.append(s)

    def _indent(self, r: IndentResult) -> None:
        b = self.blocks.get(r.block_id)
        if b is not None:
            b.results.append(r)
            if b.status == "planned":
                b.status = "running"
        self.last_indent = r
        seen = math.isfinite(r.actual_x_um) and math.isfinite(r.actual_y_um)
        x, y = (r.actual_x_um, r.actual_y_um) if seen else (r.commanded_x_um, r.commanded_y_um)
        self.indents.append(IndentMark(float(x), float(y), r.block_id, str(r.status), str(r.channel)))
        rate = r.drift_rate_nm_s
        if rate is not None and math.isfinite(rate):
            self.last_drift_rate_nm_s = float(rate)
            if area_error_pct(rate) >= AREA_ERROR_THRESHOLD_PCT:
                self.drift_events.append((r.t_s, float(rate)))

    def _observed(self, e: Observed, seq: int) -> None:
        summary = e.fit.to_json_dict()
        self.fit = (e.snapshot_id, summary)
        self.observed_at[e.block_id] = seq
        b = self.blocks.get(e.block_id)
        if b is None:
            return
        b.status, b.snapshot_id, b.fit_summary = "observed", e.snapshot_id, summary
        if b.finished_t_s is None:
            b.finished_t_s = e.t_s
        hs = [r.hardness_gpa for r in b.results if r.status == "measured"]
        if hs:
            c = b.block
            self.tested.append(
                TestedCenter(c.center_x_um, c.center_y_um, c.block_id, float(statistics.median(hs)))
            )

    # -- what the console reads -------------------------------------------------------------------
    @property
    def n_indents(self) -> int:
        return len(self.indents)

    @property
    def n_blocks(self) -> int:
        return len({m.block_id for m in self.indents})

    def indents_upto(self, upto: int | None) -> tuple[IndentMark, ...]:
        return tuple(m for m in self.indents if upto is None or m.block_id <= upto)

    def rounded_ledger(self) -> dict[str, float]:
        return {k: round(v, 6) for k, v in self.ledger.items()}

    @property
    def settings(self) -> PlannerSettings | None:
        return None if self.plan is None else self.plan.settings

    def open_block(self) -> tuple[Block, str, int] | None:
        """The latest block planned but not yet observed, with its status and indents done."""
        still = [b for k, b in sorted(self.blocks.items()) if b.status != "observed"]
        if not still:
            return None
        b = still[-1]
        return b.block, b.status, len(b.results)

    def pending(self) -> StoredDecision | None:
        waiting = [d for d in self.decisions.values() if d.status == "pending"]
        return max(waiting, key=lambda d: d.decision_id, default=None)

    def last_accepted(self) -> StoredDecision | None:
        taken = [d for d in self.decisions.values() if d.status in ("approved", "auto")]
        return max(taken, key=lambda d: d.decision_id, default=None)

    def decision_of(self, block_id: int) -> StoredDecision | None:
        b = self.blocks.get(block_id)
        return None if b is None or b.decision_id is None else self.decisions.get(b.decision_id)

    def replay_blocks(self) -> list[int]:
        """The blocks a replay steps through: every observed block with indents, in order."""
        return [k for k, b in sorted(self.blocks.items()) if b.status == "observed" and b.results]

    def block_records(self) -> list[BlockRecord]:
        """Every planned block in order with its decision, indents, steps and fit."""
        out = []
        for k, b in sorted(self.blocks.items()):
            d = self.decision_of(k)
            out.append(
                BlockRecord(
                    block=b.block,
                    status=b.status,
                    decision=None if d is None else d.decision,
                    results=tuple(b.results),
                    steps=tuple(b.steps),
                    snapshot_id=b.snapshot_id,
                    fit_summary=dict(b.fit_summary),
                    planned_t_s=b.planned_t_s,
                    finished_t_s=b.finished_t_s,
                )
            )
        return out

"""A run with nobody at the console: the same Engine in auto supervision, its events kept in memory.

``aeni simulate``, the bench, the benchmarks and the tests run campaigns through :func:`run_headless` (a
spec, composed by ``core.run.compose``; :func:`run_auto` for a campaign built by hand), so they measure the
loop an operator runs: every block passes the interlock (a refused block is vetoed by
the engine and the planner asked again), and the tally counts refusals and approvals.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from core.cost import CostLedger
from core.metrics import MapEvaluator
from core.plan import Decision
from core.run.compose import HEADLESS, ComposedRun, Drivers, SinksFor, compose, engine_for
from core.run.events import (
    BlockStarted,
    CommandWatcher,
    Decided,
    Indent,
    Observed,
    RunEvent,
    RunHistory,
    Sink,
    Steps,
)
from core.run.history import HistoryFold
from core.run.records import StoredCommand
from core.run.spec import EngineRules, RunSpec
from core.runview import EngineState

if TYPE_CHECKING:
    from core.campaign import Campaign
    from core.driver import Driver
    from core.run.engine import Engine
    from core.run.tray import TrayCampaign


@dataclass
class RunTally:
    """What a headless run reports, folded from its events as they come."""

    ledger: CostLedger = field(default_factory=CostLedger)
    trajectory: list[tuple[float, float]] = field(default_factory=list)  # (t_s, MAPE %) after every refit
    instrument_s: float = 0.0
    indents: int = 0
    blocks: int = 0
    decisions: list[Decision] = field(default_factory=list)  # the decisions whose blocks ran
    refusals: int = 0  # blocks the interlock refused (or a vetoed block proposed again)
    approvals: int = 0  # blocks that waited and were approved (by an operator, or a timeout)
    stop_reason: str = ""
    _waiting: dict[int, Decision] = field(default_factory=dict)

    def emit(self, event: RunEvent) -> None:
        self.instrument_s = max(self.instrument_s, event.t_s)
        if isinstance(event, Indent):
            self.ledger.extend(s for s, _ in event.steps)
            self.indents += 1
        elif isinstance(event, Steps):
            self.ledger.extend(s for s, _ in event.steps)
        elif isinstance(event, Decided):
            if event.plan is not None:
                self.decisions.append(event.decision)
            else:
                self._waiting[event.decision_id] = event.decision
                if event.why.startswith("safety interlock") or "proposed again" in event.why:
                    self.refusals += 1
        elif isinstance(event, BlockStarted):
            self.decisions.append(self._waiting.pop(event.decision_id))
            self.approvals += int(event.resolution[0] == "approved")
        elif isinstance(event, Observed):
            self.blocks += 1
            if event.fit.fitted and event.fit.mape_pct is not None:
                self.trajectory.append((event.t_s, event.fit.mape_pct))


class MemoryRecord(RunTally):
    """A run record in memory: the tally of its events, their fold (core.run.history), no commands (nobody
    can send one)."""

    name = "headless run"

    def __init__(self) -> None:
        super().__init__()
        self._fold = HistoryFold()

    def emit(self, event: RunEvent) -> None:
        super().emit(event)
        self._fold.emit(event)

    def owner_uid(self) -> int:
        return os.getuid()

    def history(self) -> RunHistory | None:
        return self._fold.history()

    def pending_commands(self) -> list[StoredCommand]:
        return []

    def command_channel_problem(self, owner_uid: int) -> str:
        return ""

    def command_watch(self, owner_uid: int) -> CommandWatcher | None:
        return None


class _StopWhen:
    """Asks ``stop_when`` after every block; a reason stops the engine before it plans the next one."""

    def __init__(self, tally: RunTally, stop_when: Callable[[RunTally], str | None]) -> None:
        self.tally = tally
        self.stop_when = stop_when
        self.stop: Callable[[str], None] = lambda reason: None

    def emit(self, event: RunEvent) -> None:
        if isinstance(event, Observed):
            reason = self.stop_when(self.tally)
            if reason is not None:
                self.stop(reason)


def run_headless(
    spec: RunSpec,
    drivers: Drivers,
    *,
    sinks: Sequence[Sink] | SinksFor = (),
    stop_when: Callable[[RunTally], str | None] | None = None,
) -> tuple[RunTally, ComposedRun]:
    """Run ``spec`` to its end in memory, composed as every run is (``core.run.compose``), in the spec's
    supervision with nobody at a console.

    ``sinks`` see every event after the tally; ``stop_when`` may end the run after any block with a reason
    (the bench stops a run once its question is answered). Returns the tally and the composed run (its
    campaign, driver and evaluator, for the figures a caller computes at the end).
    """
    record = MemoryRecord()
    stopper = _StopWhen(record, stop_when) if stop_when is not None else None
    tail: list[Sink] = [stopper] if stopper is not None else []

    def all_sinks(campaign: Campaign, evaluator: MapEvaluator | None) -> Sequence[Sink]:
        return [*(sinks(campaign, evaluator) if callable(sinks) else sinks), *tail]

    engines: list[Engine] = []

    def nobody_resumes(seconds: float) -> None:
        # a pause (a tray's failed tip check) waits for an operator; headless, nobody comes: the run stops
        if engines and engines[0].state is EngineState.PAUSED:
            engines[0].request_stop("paused, and nobody at a console to resume it")
        else:
            HEADLESS.sleep(seconds)

    hosting = dataclasses.replace(HEADLESS, sleep=nobody_resumes)
    run = compose(spec, drivers, lambda _spec, _campaign: record, sinks=all_sinks, hosting=hosting)
    engines.append(run.engine)
    _drive(run.engine, run.tray or run.campaign, run.driver, record, stopper)
    return record, run


def run_auto(
    campaign: Campaign,
    driver: Driver,
    evaluator: MapEvaluator | None = None,
    *,
    sinks: Sequence[Sink] = (),
    stop_when: Callable[[RunTally], str | None] | None = None,
    max_refusals: int = 5,
) -> RunTally:
    """Run a campaign a caller built by hand (a test, a study of one part) to its end through the Engine in
    auto supervision, with the interlock, in memory. A run described by a spec: :func:`run_headless`.

    ``evaluator`` (a simulated instrument's) scores the map after each block; ``sinks`` and ``stop_when``
    as in :func:`run_headless`.
    """
    record = MemoryRecord()
    stopper = _StopWhen(record, stop_when) if stop_when is not None else None
    engine = engine_for(
        campaign,
        driver,
        record,
        EngineRules(max_refusals=max_refusals),
        evaluator=evaluator,
        sinks=[*sinks, *([stopper] if stopper is not None else [])],
    )
    _drive(engine, campaign, driver, record, stopper)
    return record


def _drive(
    engine: Engine,
    campaign: Campaign | TrayCampaign,
    driver: Driver,
    record: RunTally,
    stopper: _StopWhen | None,
) -> None:
    if stopper is not None:
        stopper.stop = engine.request_stop
    engine.run()
    record.instrument_s = float(driver.clock_s())
    if engine.completed:  # the planner's own reason, as the budget stands at the end
        record.stop_reason = (
            campaign.stop_reason(driver.clock_s()) or campaign.last_stop_reason or engine.stop_reason
        )
    else:  # stopped early (stop_when), or by max_refusals
        record.stop_reason = engine.stop_reason

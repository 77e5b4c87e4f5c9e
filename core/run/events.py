"""What a run tells the world: small frozen records the engine emits, one per thing that happened.

The engine does nothing else with the outside world: a sink (the journal, an in-memory record for a
headless run, a test) receives every event in order. Every event carries ``t_s``, the instrument
clock when it happened. Commands come back through a :class:`CommandSource`; a resumed run starts
from a :class:`RunHistory` its record folds from what it holds.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any, Protocol

from core.driver import InstrumentWait
from core.plan import Block, Decision, IndentResult, PlannerSettings, StepRecord
from core.run.machine import EngineState
from core.run.records import DriverState, StoredCommand
from core.runview import MapFields

TimedSteps = tuple[tuple[StepRecord, float], ...]  # each step with the instrument clock when it ended


@dataclass(frozen=True)
class PlanState:
    """The planner's state at one point of the run (what a resume restores it from)."""

    block_id: int
    point: str  # planned, observed, veto, adjust
    state: dict[str, Any]
    settings: PlannerSettings


@dataclass(frozen=True)
class FitSummary:
    """One refit as the console shows it (None fields: no fit yet, or not a simulated run's score)."""

    mape_pct: float | None
    max_found_gpa: float | None
    fitted: bool = False
    lengthscales_um: tuple[float, ...] = ()
    noise_lengthscales_um: tuple[float, ...] = ()
    lengthscales_uv: tuple[float, ...] = ()
    collapse_alarm: bool = False
    collapse_reason: str = ""
    used_last_good: bool = False
    refit_s: float | None = None
    n_points: int | None = None
    iterations: int | None = None
    outputscale: float | None = None
    mean_const: float | None = None

    def to_json_dict(self) -> dict[str, Any]:
        """The journal's summary_json (its keys are the journal format: kept as they were)."""
        d = asdict(self)
        fitted = d.pop("fitted")
        if not fitted:
            return {"mape_pct": self.mape_pct, "max_found_gpa": self.max_found_gpa}
        for key in ("lengthscales_um", "noise_lengthscales_um", "lengthscales_uv"):
            d[key] = list(d[key])
        return d


@dataclass(frozen=True)
class SessionBegan:
    t_s: float
    kind: str  # start | resume


@dataclass(frozen=True)
class SessionEnded:
    t_s: float
    state: EngineState


@dataclass(frozen=True)
class StateChanged:
    t_s: float
    state: EngineState
    supervision: str | None = None
    completed: bool | None = None
    stop_reason: str | None = None


@dataclass(frozen=True)
class Logged:
    t_s: float
    level: str  # info, warn, error, command
    text: str
    category: str = "engine"
    block_id: int | None = None
    detail: str | None = None


@dataclass(frozen=True)
class Decided:
    """A planner proposal; with ``plan`` it runs at once (an auto decision), else it waits (``why``)."""

    t_s: float
    decision_id: int
    decision: Decision
    status: str  # auto | pending
    why: str
    text: str
    plan: PlanState | None = None


@dataclass(frozen=True)
class Resolved:
    """A waiting decision closed without running (vetoed, dropped), with the planner state it leaves."""

    t_s: float
    decision_id: int
    status: str
    by: str
    command_id: int | None = None
    plan: PlanState | None = None


@dataclass(frozen=True)
class BlockStarted:
    """A waiting decision released: its block is the run's next (approved, or auto after an adjust)."""

    t_s: float
    block: Block
    decision_id: int
    plan: PlanState
    resolution: tuple[str, str, int | None]  # status, by, command id


@dataclass(frozen=True)
class BlockEnded:
    t_s: float
    block_id: int
    status: str  # executed | aborted
    finished: bool  # executed: the block's finishing time is t_s


@dataclass(frozen=True)
class Indent:
    """One finished indent with the steps that led to it and the instrument state after it."""

    t_s: float
    result: IndentResult
    steps: TimedSteps
    driver: DriverState


@dataclass(frozen=True)
class Steps:
    """Steps that end no indent (the comeback, crash recovery), with the instrument state after them."""

    t_s: float
    steps: TimedSteps
    driver: DriverState
    text: str = ""
    category: str = "engine"
    block_id: int | None = None


@dataclass(frozen=True)
class Waiting:
    """The driver waits for the instrument (a KLA ticket is out): what it sees now."""

    t_s: float
    wait: InstrumentWait


@dataclass(frozen=True)
class ApprovalAsked:
    """A decision waits for an answer for ``timeout_s`` from now (``approval_timeout_s``); if nobody answers,
    the engine does ``on_timeout`` (approve, veto, pause, stop) for it. The console counts down to it."""

    t_s: float
    decision_id: int
    block_id: int
    timeout_s: float
    on_timeout: str


@dataclass(frozen=True)
class PlanChanged:
    """The operator adjusted the planner's settings."""

    t_s: float
    plan: PlanState


@dataclass(frozen=True)
class Observed:
    """A block folded into the model: the refit, the map fields for the console, the planner state."""

    t_s: float
    block_id: int
    snapshot_id: int
    hyper: dict[str, Any]
    fit: FitSummary
    fields: MapFields | None
    plan: PlanState
    text: str


@dataclass(frozen=True)
class CommandDone:
    t_s: float
    command_id: int
    outcome: str  # accepted | rejected
    reason: str
    state_before: EngineState
    text: str


@dataclass(frozen=True)
class EngineDied:
    """The engine's process ended without ending its run (a signal, the out-of-memory killer, an uncaught
    exception), as its supervisor saw it: the engine cannot say this itself. ``t_s``: the last instrument
    time the journal holds; ``signal``: e.g. "SIGKILL" (None for an exit code)."""

    t_s: float
    cause: str  # in words, for the log and the alert: "engine killed by SIGKILL", "engine exited with code 1: ..."
    pid: int
    exit_code: int | None = None
    signal: str | None = None
    # what the supervisor does about it: "resuming (attempt 1 of 3) in 5 s", "not resumed: ..."
    action: str = ""


RunEvent = (
    SessionBegan
    | SessionEnded
    | StateChanged
    | Logged
    | Decided
    | Resolved
    | BlockStarted
    | BlockEnded
    | Indent
    | Steps
    | Waiting
    | ApprovalAsked
    | PlanChanged
    | Observed
    | CommandDone
    | EngineDied
)


class Sink(Protocol):
    """Receives every event of a run, in order (the journal writes each in one transaction)."""

    def emit(self, event: RunEvent) -> None: ...


class CommandWatcher(Protocol):
    def poll(self) -> bool: ...

    def close(self) -> None: ...


@dataclass(frozen=True)
class RunHistory:
    """What a resumed engine starts from: the run so far, folded by its record."""

    completed: bool
    stop_reason: str
    last_state: str
    plan: tuple[dict[str, Any], PlannerSettings] | None  # the latest planner state
    observed: Sequence[tuple[Block, Sequence[IndentResult]]]
    driver: DriverState | None
    recovery_s: float
    open_block: tuple[Block, Sequence[IndentResult]] | None  # planned, not observed: its indents so far
    pending: tuple[int, Decision, str] | None  # a decision that still waits (id, decision, why)
    queued_commands: int
    last_decision_id: int
    last_snapshot_id: int


class RunRecord(Sink, Protocol):
    """Where a run goes and where its commands come from: the journal, or an in-memory record."""

    @property
    def name(self) -> str: ...

    def owner_uid(self) -> int: ...

    def history(self) -> RunHistory | None:
        """None for a run no engine has started yet."""
        ...

    def pending_commands(self) -> list[StoredCommand]: ...

    def command_channel_problem(self, owner_uid: int) -> str:
        """Why commands cannot be trusted (another user can write the channel), or ''."""
        ...

    def command_watch(self, owner_uid: int) -> CommandWatcher | None: ...

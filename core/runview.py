"""The read side of a run: frozen snapshots that the console renders and replay steps through.

The engine writes a journal; a reader turns the journal into these records. The console never talks
to the engine directly, so it can attach to a live run, a finished run or a replay alike.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from datetime import datetime

import numpy as np

from core.driver import InstrumentWait
from core.plan import Block, Decision, IndentSpec, PlannerSettings

# the state machine's names, re-exported for the read side
from core.run.machine import CommandKind as CommandKind
from core.run.machine import EngineState as EngineState
from core.run.tray_view import SampleProgress
from core.sample.model import Sample


@dataclass(frozen=True)
class Command:
    """An operator command, as the console sends it and the journal records it."""

    kind: CommandKind
    author: str  # OS user
    payload: dict[str, object] = field(default_factory=dict)  # adjust: field -> value; veto: centre
    shown_scores: dict[str, float] = field(default_factory=dict)  # what the operator saw when deciding


@dataclass(frozen=True)
class QueueItem:
    block_id: int
    indent_index: int
    spec: IndentSpec
    grid_g: int
    eta_s: float  # instrument seconds from now until this indent finishes


@dataclass(frozen=True)
class DriftStatus:
    last_rate_nm_s: float | None
    hold_mode: str  # "fixed 80 s", "adaptive: fast", ...
    area_error_pct: float | None
    threshold_pct: float = 2.0
    events: tuple[tuple[float, float], ...] = ()  # (instrument t_s, drift rate nm/s) of detected events


@dataclass(frozen=True)
class GpStatus:
    lengthscales_um: tuple[float, ...] = ()
    noise_lengthscales_um: tuple[float, ...] = ()
    collapse_alarm: bool = False
    collapse_reason: str = ""
    refit_s: float | None = None
    snapshot_id: int | None = None  # id of the stored map fields for this fit


@dataclass(frozen=True)
class LogEvent:
    wall_utc: str
    t_s: float
    level: str  # info, warn, error, command, decision
    text: str


@dataclass(frozen=True)
class TestedCenter:
    x_um: float
    y_um: float
    block_id: int
    median_gpa: float


@dataclass(frozen=True)
class IndentMark:
    """One indent of the run where the map draws it: where the tip went (else where it was sent), and what
    became of it (``measured``, ``failed``, ``not_run``, or any later status, drawn as it is named), and its
    channel (``csm``, or ``fast``: an indent of a fast array, drawn apart)."""

    x_um: float
    y_um: float
    block_id: int
    status: str
    channel: str = "csm"


@dataclass(frozen=True)
class ApprovalDeadline:
    """A waiting decision's deadline (``approval_timeout_s``) and what happens at it (``on_timeout``)."""

    decision_id: int
    deadline_unix: float
    on_timeout: str  # approve | veto | pause | stop

    def remaining_s(self, now_unix: float) -> float:
        return max(self.deadline_unix - now_unix, 0.0)

    @staticmethod
    def from_record(wall_utc: str, detail: str) -> ApprovalDeadline:
        """An ApprovalAsked event as the journal logs it (its wall time and its fields as JSON): the wait
        began at its wall time."""
        d = json.loads(detail)
        began = datetime.fromisoformat(wall_utc.replace("Z", "+00:00")).timestamp()
        return ApprovalDeadline(int(d["decision_id"]), began + float(d["timeout_s"]), str(d["on_timeout"]))


@dataclass(frozen=True)
class RunSnapshot:
    """Everything the console shows, read at one moment."""

    run_name: str
    journal_path: str
    state: EngineState
    supervision: str  # auto | supervised | step
    policy: str
    profile_name: str
    owner: str
    can_command: bool  # the reader is the run's owner
    instrument_s: float
    wall_s: float
    n_indents: int
    n_blocks: int
    reconfigurations: int
    ledger: dict[str, float]
    grid_baseline_s: float
    queue: tuple[QueueItem, ...]
    current_block: Block | None
    pending: Decision | None  # waiting for approve / veto
    last_decision: Decision | None
    drift: DriftStatus
    gp: GpStatus
    mape_pct: float | None  # emulator runs only
    max_found_gpa: float | None
    tested: tuple[TestedCenter, ...]
    settings: PlannerSettings
    log: tuple[LogEvent, ...]
    stage_bounds_um: tuple[float, float, float, float]  # x_min, x_max, y_min, y_max of the calibrated area
    reverse_x: bool
    finished: bool  # the engine process has ended (stopped, failed, or done)
    allowed_holds_s: tuple[float, ...] = ()  # the instrument profile's holds (the adjust form checks them)
    # WAITING FOR INSTRUMENT: the ticket out and what the driver sees (the KLA driver), else None
    instrument_wait: InstrumentWait | None = None
    # the profile's safety rule and where the tip is: what says whether a block stays or reconfigures
    reconfig_threshold_um: float | None = None
    position_um: tuple[float, float] | None = None
    # the sample as the run has it (outline, exclusions, earlier indents) and every indent of the run so far
    sample: Sample | None = None
    indents: tuple[IndentMark, ...] = ()
    # AWAITING APPROVAL with an approval_timeout_s: when the wait ends and what the engine does then
    approval_deadline: ApprovalDeadline | None = None
    # a tray run: a line per sample (core.run.tray_view); empty for a single-sample run
    tray: tuple[SampleProgress, ...] = ()


@dataclass(frozen=True)
class MapFields:
    """The GP's four fields on the display lattice (Figure 8 a–d), in stage µm."""

    snapshot_id: int
    x_um: np.ndarray  # (nx,) column coordinates
    y_um: np.ndarray  # (ny,) row coordinates
    mean_gpa: np.ndarray  # (ny, nx)
    epistemic_sd_gpa: np.ndarray
    noise_sd_gpa: np.ndarray
    total_sd_gpa: np.ndarray
    next_candidate_um: tuple[float, float] | None = None
    # the modulus map (issue 27), where the run learns one: its mean and epistemic sd, GPa
    modulus_mean_gpa: np.ndarray | None = None
    modulus_sd_gpa: np.ndarray | None = None
    # the learnt bias of the fast channel, E[H_csm − H_fast] (GPa), where the run's two-fidelity map is active
    bias_gpa: np.ndarray | None = None

"""What the engine needs of a campaign (core.campaign.Campaign is the one the product composes): typed, so
the engine never probes it."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

from core.metrics import MapScore
from core.modulus import ModulusMap
from core.plan import Block, Decision, IndentResult, PlannerSettings
from core.runview import MapFields

if TYPE_CHECKING:
    from core.model import FitReport
    from core.operator import Attendance


class StageFrame(Protocol):
    """The campaign's calibration, as far as the engine needs it: unit-square (u, v) to stage µm."""

    def to_stage(self, u: float, v: float) -> tuple[Any, Any]: ...


@runtime_checkable
class RaisesAlarms(Protocol):
    """A campaign that can find the run must not go on by itself (a tray's failed tip check): the engine
    pauses the run and logs the alarm as an error (the alert watcher sends it)."""

    def take_alarm(self) -> str | None: ...


@runtime_checkable
class PlansForAbsence(Protocol):
    """A campaign that sizes its next load by when the operator will next come (core.visits): the engine
    tells its attendance what the operator says (it never reconfigures the campaign)."""

    @property
    def attendance(self) -> Attendance: ...


class CampaignLike(Protocol):
    """What the engine needs from core.campaign.Campaign (a fake in tests)."""

    settings: PlannerSettings
    modulus_map: ModulusMap  # read only where settings.map_weights aims at the modulus

    @property
    def calibration(self) -> StageFrame: ...

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

    def queued_stretch(self) -> tuple[Block, ...]: ...

    # scored from outside by a simulated run's evaluator (core.metrics.ScoredMap), told back the verdict
    def has_map(self) -> bool: ...

    def predict_mean_stage(self, x_um: Any, y_um: Any) -> Any: ...

    def indented_xy_um(self) -> Any: ...

    def note_score(self, score: MapScore | None) -> None: ...

    def restore(
        self, state: dict[str, Any], blocks: Sequence[tuple[Block, Sequence[IndentResult]]]
    ) -> None: ...

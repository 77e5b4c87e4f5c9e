"""The records the engine and the journal share: what the journal hands the engine (an operator's command as
stored) and what the engine checkpoints of its driver. They live with the run, and the journal imports them."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class StoredCommand:
    """A command row as the engine sees it (``kind`` stays a string: a bad row must be rejected, not crash)."""

    command_id: int
    kind: str
    author: str
    uid: int
    payload: dict[str, Any]
    shown_scores: dict[str, Any]
    wall_utc: str


@dataclass(frozen=True)
class DriverState:
    """Where the instrument was and what its clocks read when the engine last checkpointed (resume restores it)."""

    clock_s: float
    physics_clock_s: float | None
    position_um: tuple[float, float]
    program_open: bool
    reason: str

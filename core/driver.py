"""The block-level driver contract every instrument backend implements, and its optional capabilities.

A capability is a typed protocol a driver class either satisfies or not; the engine asks once, with
``isinstance``, when it is built, and never probes attributes afterwards.
"""

from __future__ import annotations

from collections.abc import Generator, Iterator
from typing import Protocol, runtime_checkable

from core.plan import Block, IndentResult, StepRecord
from core.profile import InstrumentProfile

DriverEvent = StepRecord | IndentResult


class DriverAborted(RuntimeError):
    """Raised inside ``execute_block`` when ``abort()`` was called: the tip is lifted, nothing more runs."""


@runtime_checkable
class Driver(Protocol):
    """Executes blocks and reports every step and indent as it happens.

    ``execute_block`` is a generator: the consumer (the engine) sees each step's duration and each
    finished indent in order, and may stop iterating after any ``IndentResult`` (a checkpoint).
    ``start_index`` resumes a block at its first unfinished indent; ``program_open`` says whether the
    tip is engaged on the surface (a local block continues from there).
    """

    profile: InstrumentProfile

    def position_um(self) -> tuple[float, float]: ...

    def clock_s(self) -> float: ...

    def program_open(self) -> bool: ...

    def execute_block(self, block: Block, start_index: int = 0) -> Generator[DriverEvent, None, None]: ...

    def end_program(self) -> Iterator[StepRecord]:
        """Lift and return to the optical lens (the comeback)."""
        ...

    def abort(self) -> None:
        """Finish the current indent, lift, stop: the running ``execute_block`` raises DriverAborted."""
        ...


@runtime_checkable
class Restorable(Protocol):
    """Can be put back where the journal says the instrument was (resume after a crash).

    ``physics_clock_s`` is the clock the sample's physics (drift) runs on, where the driver keeps one
    apart from the instrument clock; a driver without one ignores it.
    """

    def set_state(
        self,
        clock_s: float,
        position_um: tuple[float, float],
        program_open: bool,
        physics_clock_s: float | None = None,
    ) -> None: ...


@runtime_checkable
class Recoverable(Protocol):
    """Can re-engage a tip whose state is unknown (after a crash) or that was lifted, before indenting."""

    def recover(self, block_id: int) -> Iterator[StepRecord]: ...


@runtime_checkable
class PhysicsClock(Protocol):
    """Keeps the sample's physics (drift) on a clock without crash-recovery time (the simulated instrument)."""

    def physics_clock_s(self) -> float: ...

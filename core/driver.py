"""The block-level driver contract every instrument backend implements."""

from __future__ import annotations

from collections.abc import Iterator
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

    def execute_block(self, block: Block, start_index: int = 0) -> Iterator[DriverEvent]: ...

    def end_program(self) -> Iterator[DriverEvent]:
        """Lift and return to the optical lens (the comeback)."""
        ...

    def abort(self) -> None:
        """Finish the current indent, lift, stop: the running ``execute_block`` raises DriverAborted."""
        ...

"""The block-level driver contract every instrument backend implements, and its optional capabilities.

A capability is a typed protocol a driver class either satisfies or not; the engine asks once, with
``isinstance``, when it is built, and never probes attributes afterwards.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Generator, Iterator, Sequence
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

from core.plan import Block, IndentResult, StepRecord
from core.profile import InstrumentProfile


@dataclass(frozen=True)
class InstrumentWait:
    """A block waits for the instrument or its operator (a ticket is out): what the console shows.

    A driver that hands blocks to a person yields one of these every poll while it waits, so the engine
    stays at a checkpoint (commands, pause, abort) and can show WAITING FOR INSTRUMENT.
    """

    block_id: int
    ticket: str  # the ticket as a person reads it, without its token
    deadline_utc: str
    seconds_left: float
    waiting: str  # what the driver sees ("no export yet", "... is still being written", how it ended)
    started: bool  # the operator (or a helper's file) confirmed the start with the token
    notes: tuple[str, ...] = ()  # reports and refusals since the last one, for the journal
    panel: tuple[str, ...] = ()  # the ticket in short lines, for the console's ticket panel


DriverEvent = StepRecord | IndentResult | InstrumentWait


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


@runtime_checkable
class WaitsForOperator(Protocol):
    """Takes the operator's reports while a block waits for the instrument (the KLA driver).

    ``kind`` is started, aborted, surface-not-found (``value``: the ticket's token) or skip (``value``: the
    1-based site); the answer is (accepted, what happened or why not), journaled by the engine.
    """

    def operator_report(self, kind: str, value: str, author: str) -> tuple[bool, str]: ...


@runtime_checkable
class LoadsStretches(Protocol):
    """Hands the operator every array of a stretch at once (the KLA driver: all their tickets go out with
    the first), since nobody comes between them. ``arrays`` in load order, the current one first; arrays
    already handed out stay as they are (a resumed run)."""

    def load_stretch(self, arrays: Sequence[Block]) -> None: ...


@runtime_checkable
class WaitsFromAnswer(Protocol):
    """Lets a block's wait for the operator (the KLA ticket's deadline) count from when someone can answer,
    not from when the block was handed out: ``delay_s()`` is how long from now that is (the engine's
    [operator] calendar, core.operator.OperatorAvailability.answer_delay_s; 0 during the hours)."""

    def wait_from_answer(self, delay_s: Callable[[], float]) -> None: ...


class InstrumentState:
    """What every driver tracks for the engine between blocks: its clock, the stage position, whether a
    program is engaged, and the abort flag a blocking wait listens to. One home for ``Restorable.set_state``."""

    def __init__(self, start_um: tuple[float, float] = (0.0, 0.0), clock_s: float = 0.0) -> None:
        self._pos = start_um
        self._clock_s = clock_s
        self._open = False
        self._abort = threading.Event()

    def position_um(self) -> tuple[float, float]:
        return self._pos

    def clock_s(self) -> float:
        return self._clock_s

    def program_open(self) -> bool:
        return self._open

    def set_state(
        self,
        clock_s: float,
        position_um: tuple[float, float],
        program_open: bool,
        physics_clock_s: float | None = None,
    ) -> None:
        """Restore the model of the instrument after a crash (``physics_clock_s``: a simulated instrument's)."""
        self._clock_s, self._pos, self._open = clock_s, position_um, program_open

    def abort(self) -> None:
        self._abort.set()

"""A virtual iMicro: the emulator for measurements and the cost model for its clock.

Each step advances a virtual instrument clock by exactly what the profile prices it at, so the
planner's predicted cost and the executed cost agree. With a speed factor the driver also sleeps
``seconds / speed`` of wall time per step so a person can watch a run.
"""

from __future__ import annotations

from collections.abc import Generator, Iterator
from typing import TYPE_CHECKING

from core.cost import comeback_step, indent_steps
from core.driver import DriverAborted, DriverEvent, InstrumentState
from core.plan import Block, IndentResult, StepRecord
from core.profile import InstrumentProfile
from drivers.sim.failures import INVALID_VALUE, FailureModes
from drivers.sim.fast_channel import FastPhysics, FastReadings
from drivers.sim.fast_measure import read_fast_block

if TYPE_CHECKING:
    from drivers.sim.emulator import Emulator


class SimulatedDriver(InstrumentState):
    def __init__(
        self,
        emulator: Emulator,
        profile: InstrumentProfile,
        speed: float | None = None,
        start_um: tuple[float, float] = (0.0, 0.0),
        clock_s: float = 0.0,
        failures: FailureModes | None = None,
    ) -> None:
        if speed is not None and speed <= 0:
            raise ValueError(f"speed must be > 0, got {speed}")
        self.emulator = emulator
        self.failures = failures or FailureModes()
        self.profile = profile
        self.speed = speed
        super().__init__(start_um, clock_s)
        # the emulated physics (drift) runs on a clock without crash-recovery time, so a resumed run
        # measures what an uninterrupted one would have
        self._physics_s = clock_s
        # the emulator's fast channel (fast arrays), where the profile has a fast mode
        self.fast_physics = FastPhysics(profile.fast.peak_load_mn) if profile.fast is not None else None

    # -- state -----------------------------------------------------------------------------
    def physics_clock_s(self) -> float:
        return self._physics_s

    def set_state(
        self,
        clock_s: float,
        position_um: tuple[float, float],
        program_open: bool,
        physics_clock_s: float | None = None,
    ) -> None:
        """Restore the virtual instrument after a crash (from the journal), its physics clock too."""
        super().set_state(clock_s, position_um, program_open)
        self._physics_s = clock_s if physics_clock_s is None else physics_clock_s

    # -- execution -------------------------------------------------------------------------
    def _advance(self, step: StepRecord) -> StepRecord:
        if self.speed is not None and step.seconds > 0:
            # interruptible sleep: an abort wakes us at once
            self._abort.wait(step.seconds / self.speed)
        self._clock_s += step.seconds
        if step.category != "recovery":
            self._physics_s += step.seconds
        return step

    def recover(self, block_id: int) -> Iterator[StepRecord]:
        """After a crash the tip state is unknown: lift, re-engage and settle drift before continuing."""
        p = self.profile
        for seconds in (p.lift_s, p.engage_s, p.drift_settle_s):
            yield self._advance(StepRecord("recovery", seconds, block_id, -1))
        self._open = True

    def execute_block(self, block: Block, start_index: int = 0) -> Generator[DriverEvent, None, None]:
        if self._abort.is_set():
            raise DriverAborted("driver was aborted")
        if block.kind == "local" and not self._open and start_index == 0:
            raise ValueError(f"block {block.block_id} is local but the tip is not engaged")
        fault = self.failures.block_fault(block.block_id)
        if fault == "surface-not-found":
            # no indent at all: the instrument gives up on the array and lifts the tip
            yield from self.end_program()
            for i in range(start_index, block.n_indents):
                yield IndentResult.unmeasured(
                    block.block_id, i, block.indents[i], self._clock_s, "not_run",
                    "surface not found (simulated instrument fault)", block.channel,
                )  # fmt: skip
            return
        fast: FastReadings | None = None
        if block.channel == "fast":
            if self.fast_physics is None:
                raise ValueError(f"block {block.block_id} is a fast array but the profile has no fast mode")
            fast = read_fast_block(self.emulator, self.fast_physics, block)
        stop_after = block.n_indents // 2 if fault == "aborted" else block.n_indents
        if start_index > 0 and not self._open and start_index < stop_after:
            # resuming inside a block after a crash: re-engage where we are
            yield from self.recover(block.block_id)
        for i in range(start_index, block.n_indents):
            if i >= stop_after:  # the array stopped half way: the rest never ran
                yield IndentResult.unmeasured(
                    block.block_id, i, block.indents[i], self._clock_s, "not_run",
                    f"array aborted after {stop_after} of {block.n_indents} indents (simulated instrument fault)",
                    block.channel,
                )  # fmt: skip
                continue
            steps = indent_steps(self.profile, block, i, self._pos, self._open)
            for step in steps:
                yield self._advance(step)
            spec = block.indents[i]
            self._pos = (spec.x_um, spec.y_um)
            self._open = True
            if fast is not None:
                yield self._fast_result(block, i, fast)
            else:
                yield self._csm_result(block, i)
            if self._abort.is_set():
                # the current indent is finished: lift and stop
                yield from self.end_program()
                raise DriverAborted(f"aborted after indent {i} of block {block.block_id}")

    def _csm_result(self, block: Block, i: int) -> IndentResult:
        spec = block.indents[i]
        m = self.emulator.measure(spec.x_um, spec.y_um, spec.hold_s, self._physics_s, block.block_id, i)
        if self.failures.invalid(block.block_id, i):
            # the indent was made, its value is not: recorded as failed, never learned from
            return IndentResult.unmeasured(
                block.block_id, i, spec, self._clock_s, "failed",
                f"invalid value {INVALID_VALUE:g} (simulated instrument fault)",
            )  # fmt: skip
        return IndentResult(
            block_id=block.block_id,
            indent_index=i,
            commanded_x_um=spec.x_um,
            commanded_y_um=spec.y_um,
            actual_x_um=m.actual_x_um,
            actual_y_um=m.actual_y_um,
            hold_s=spec.hold_s,
            hardness_gpa=m.hardness_gpa,
            modulus_gpa=m.modulus_gpa,
            drift_rate_nm_s=m.drift_rate_nm_s,
            t_s=self._clock_s,
            depth_at_max_load_nm=m.depth_at_max_load_nm,
        )

    def _fast_result(self, block: Block, i: int, fast: FastReadings) -> IndentResult:
        """One fast indent of the array's readings: a failed one is recorded as failed, never as a number;
        a fast indent reports no drift rate (nothing measures it in a ~1 s test)."""
        spec = block.indents[i]
        if fast.failed[i] or self.failures.invalid(block.block_id, i):
            return IndentResult.unmeasured(
                block.block_id, i, spec, self._clock_s, "failed",
                "no valid unloading curve (simulated fast indent)", "fast",
            )  # fmt: skip
        return IndentResult(
            block_id=block.block_id,
            indent_index=i,
            commanded_x_um=spec.x_um,
            commanded_y_um=spec.y_um,
            actual_x_um=float(fast.x_um[i]),
            actual_y_um=float(fast.y_um[i]),
            hold_s=0.0,
            hardness_gpa=float(fast.hardness_gpa[i]),
            modulus_gpa=float(fast.modulus_gpa[i]),
            drift_rate_nm_s=float("nan"),
            t_s=self._clock_s,
            depth_at_max_load_nm=float(fast.depth_nm[i]),
            channel="fast",
        )

    def end_program(self) -> Iterator[StepRecord]:
        if self._open:
            yield self._advance(comeback_step(self.profile))
            self._open = False

"""The simulated instrument over a tray: one stage, one clock and one tip over several samples.

Each sample has its own truth (its scenario or truth CSV laid onto its placed sample; a reference block a flat
field at its nominal values) and its own profile (the method it is run with); the tip measures whatever
sample it stands on. The first block on a sample after a block on another one pays the sample change
(core.sample_change), as the planner priced it.

The tip can wear (``tip_wear_pct_per_h``, an option per run): a blunted Berkovich tip's real contact area is
larger than its calibrated area function says at the same depth, so hardness reads high by the wear fraction
w and the modulus (∝ 1/√A) by √(1 + w). The linear wear rate is a test device, not a wear model of any tip.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Generator, Mapping
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from core.driver import DriverEvent
from core.errors import InputError
from core.plan import Block, IndentResult
from core.profile import InstrumentProfile, load_profile
from core.sample.tray import Tray, TraySample
from core.sample_change import change_steps, tip_sample
from drivers.sim.drift import DriftModel
from drivers.sim.driver import SimulatedDriver
from drivers.sim.emulator import Emulator
from drivers.sim.failures import FailureModes
from drivers.sim.truth import Bounds, FloatArray, broadcast_xy

TRAY_OPTIONS = ("tip_wear_pct_per_h",)
# Fused-silica scatter per indent at ~100 nm depth: 1.5 % of H (the low end of what calibration round robins
# see at shallow depth; an assumption to check against the block's own certificate).
REFERENCE_REL_SD = 0.015


@dataclasses.dataclass
class UniformField:
    """A homogeneous reference block: the same hardness and modulus everywhere, with a relative scatter."""

    name: str
    bounds_um: Bounds
    hardness: float
    modulus: float
    rel_sd: float = REFERENCE_REL_SD

    def hardness_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        x, _ = broadcast_xy(x_um, y_um)
        return np.full(x.shape, self.hardness)

    def noise_sd_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        return self.rel_sd * self.hardness_gpa(x_um, y_um)

    def modulus_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        x, _ = broadcast_xy(x_um, y_um)
        return np.full(x.shape, self.modulus)

    def modulus_noise_sd_gpa(self, x_um: ArrayLike, y_um: ArrayLike) -> FloatArray:
        return self.rel_sd * self.modulus_gpa(x_um, y_um)


@dataclasses.dataclass(frozen=True)
class _Station:
    """One sample's physics on the shared stage."""

    name: str
    emulator: Emulator
    profile: InstrumentProfile
    failures: FailureModes


def _station(entry: TraySample, seed: int, scenario: Any) -> _Station:
    sample = entry.placed
    profile = load_profile(sample.profile)
    if entry.reference is not None:
        x0, x1, y0, y1 = sample.calibration.bounds_um
        truth = UniformField(
            entry.name, (x0, x1, y0, y1), entry.reference.hardness_gpa, entry.reference.modulus_gpa
        )
        emulator = Emulator(
            truth, DriftModel.scenario("none", seed), seed, t_measure_s=profile.drift_segment_s,
            full_correction_hold_s=max(profile.allowed_holds_s),
        )  # fmt: skip
        return _Station(entry.name, emulator, profile, FailureModes())
    laid = scenario(entry.sim, seed, sample)
    return _Station(entry.name, laid.make_emulator(profile), profile, laid.failures)


class TraySimDriver(SimulatedDriver):
    """A SimulatedDriver whose emulator, profile and faults are those of the sample under the tip."""

    def __init__(
        self,
        tray: Tray,
        stations: Mapping[str, _Station],
        *,
        speed: float | None = None,
        tip_wear_pct_per_h: float = 0.0,
    ) -> None:
        self.tray = tray
        self.stations = dict(stations)
        first = self.stations[tray.libraries[0].name]
        x0, x1, y0, y1 = tray.libraries[0].placed.calibration.bounds_um
        super().__init__(
            first.emulator,
            first.profile,
            speed,
            start_um=((x0 + x1) / 2, (y0 + y1) / 2),
            failures=first.failures,
        )
        if not (math.isfinite(tip_wear_pct_per_h) and tip_wear_pct_per_h >= 0):
            raise InputError("tip_wear_pct_per_h", f"{tip_wear_pct_per_h!r} is not allowed: a number ≥ 0")
        self.tip_wear_pct_per_h = float(tip_wear_pct_per_h)
        self.on: str | None = None  # the sample the last block ran on

    def wear_factor(self) -> float:
        """How much a hardness reads high on the worn tip now (1: a new tip)."""
        return 1.0 + self.tip_wear_pct_per_h / 100.0 * self.physics_clock_s() / 3600.0

    def set_state(
        self,
        clock_s: float,
        position_um: tuple[float, float],
        program_open: bool,
        physics_clock_s: float | None = None,
    ) -> None:
        super().set_state(clock_s, position_um, program_open, physics_clock_s)
        self.on = tip_sample(self.tray, clock_s, position_um)

    def execute_block(self, block: Block, start_index: int = 0) -> Generator[DriverEvent, None, None]:
        first = block.indents[0]
        entry = self.tray.sample_at(first.x_um, first.y_um)
        if entry is None:  # the interlock refuses such a block first; an instrument would find no surface
            raise ValueError(f"block {block.block_id} starts on no sample of the tray")
        station = self.stations[entry.name]
        self.emulator, self.profile, self.failures = station.emulator, station.profile, station.failures
        if self.failures.block_fault(block.block_id) == "surface-not-found":
            # nothing runs: the tip stays on the sample it was on, no change charged (as on the KLA driver,
            # where the operator's report is all the run learns)
            yield from super().execute_block(block, start_index)
            return
        if start_index == 0 and self.on is not None and self.on != entry.name:
            for step in change_steps(self.profile, block.block_id):
                yield self._advance(step)
        self.on = entry.name
        for ev in super().execute_block(block, start_index):
            if isinstance(ev, IndentResult) and ev.measured and self.tip_wear_pct_per_h > 0:
                f = self.wear_factor()
                ev = dataclasses.replace(
                    ev, hardness_gpa=ev.hardness_gpa * f, modulus_gpa=ev.modulus_gpa * math.sqrt(f)
                )
            yield ev


def make_tray_driver(
    tray: Tray, options: Mapping[str, Any], seed: int, scenario: Any, speed: float | None = None
) -> TraySimDriver:
    """The simulated instrument for ``tray``; ``scenario(options, seed, sample)`` lays a library's truth
    (drivers.registry.sim_scenario); ``options``: the run's tray options (tip_wear_pct_per_h)."""
    unknown = sorted(set(options) - set(TRAY_OPTIONS))
    if unknown:
        raise InputError(
            "tray driver options",
            f"unknown option(s) {', '.join(unknown)} (allowed: {', '.join(TRAY_OPTIONS)})",
        )
    stations = {s.name: _station(s, seed, scenario) for s in tray.samples}
    return TraySimDriver(
        tray, stations, speed=speed, tip_wear_pct_per_h=float(options.get("tip_wear_pct_per_h", 0.0))
    )

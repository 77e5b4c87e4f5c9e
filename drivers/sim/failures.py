"""The simulated instrument fails like the real one: the fake InView's failure modes, at set rates.

A real iMicro now and then writes an invalid value (1.797e308, InView's "no value") for an indent, does not
find the surface for an array (no indent at all), or stops an array half way (aborted). The simulated
instrument does the same, so a simulated run meets the cases that stall a real one. Every draw is keyed by
(seed, block, indent) with its own generator, never the emulator's: a resumed run fails where an
uninterrupted one did, and at rate 0 nothing is drawn, so every run is what it was without failures.
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass
from typing import Literal

from core.errors import InputError

BlockFault = Literal["surface-not-found", "aborted"]
MAX_FAILURE_RATE = 0.5
# what `aeni demo` and `aeni bench` run with: about what a real instrument does (1-2 % of indents invalid)
REALISTIC_FAILURE_RATE = 0.015
INVALID_VALUE = 1.797e308  # what InView writes where it has no value


@dataclass(frozen=True)
class FailureModes:
    """Rates of the three failure modes: per indent (invalid value) and per block (the other two)."""

    invalid_rate: float = 0.0
    surface_not_found_rate: float = 0.0
    aborted_rate: float = 0.0
    seed: int = 0

    @classmethod
    def at_rate(cls, rate: float, seed: int) -> FailureModes:
        """One knob: ``rate`` of the indents come back invalid, and a quarter of that share of the blocks
        each meets no surface or is aborted half way."""
        if not (isinstance(rate, int | float) and math.isfinite(rate) and 0.0 <= rate <= MAX_FAILURE_RATE):
            raise InputError(
                "failure_rate", f"{rate!r} is not allowed: expected a number from 0 to {MAX_FAILURE_RATE:g}"
            )
        return cls(float(rate), rate / 4.0, rate / 4.0, seed)

    @property
    def enabled(self) -> bool:
        return self.invalid_rate > 0 or self.surface_not_found_rate > 0 or self.aborted_rate > 0

    def _draw(self, *key: object) -> float:
        return random.Random("/".join(str(k) for k in (self.seed, *key))).random()

    def block_fault(self, block_id: int) -> BlockFault | None:
        if not self.enabled:
            return None
        u = self._draw(block_id, "block")
        if u < self.surface_not_found_rate:
            return "surface-not-found"
        if u < self.surface_not_found_rate + self.aborted_rate:
            return "aborted"
        return None

    def invalid(self, block_id: int, indent_index: int) -> bool:
        return self.invalid_rate > 0 and self._draw(block_id, indent_index) < self.invalid_rate

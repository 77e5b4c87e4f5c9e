"""The collapse guard part: what keeps the mean GP's length-scales from collapsing onto the noise.

Two settings, on in every recommended policy: a floor (half the candidate pitch) with a weak prior on the
length-scales, and keep-last-good (a fit that collapses keeps the last good kernel, SPEC §5). Turning both
off is the unguarded ablation: what a plain maximum-likelihood GP does.
"""

from __future__ import annotations

from dataclasses import dataclass

from core.surrogate import GuardName

UNGUARDED_FLOOR_UV = 0.001  # 1 µm on the 1000 µm square: a floor in name only (the unguarded ablation)
MIN_FLOOR_UV = 0.005


@dataclass(frozen=True)
class CollapseGuard:
    keep_last_good: bool = True
    floor: bool = True  # length-scale floor at half the candidate pitch, and its prior

    @property
    def mode(self) -> GuardName:
        return "keep-last-good" if self.keep_last_good else "off"

    def floor_uv(self, pitch_uv: float) -> float:
        return max(0.5 * pitch_uv, MIN_FLOOR_UV) if self.floor else UNGUARDED_FLOOR_UV

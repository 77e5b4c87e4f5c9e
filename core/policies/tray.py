"""Which sample of a tray next: information per second across the samples.

Each library's campaign offers its best next block. Its acquisition is in its own map's units, so the tray
compares them relative to each map's scale (acquisition / the map's mean |H|: the share of the map a block
would still learn), weighted by the sample's priority, per second of the block's predicted cost *including*
the sample change (core.sample_change) when the tip is elsewhere. A library with no map yet has everything
to learn (infinite value): every library gets its first blocks before any gets its hundredth. A library at
its goal makes no offer.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass


@dataclass(frozen=True)
class Offer:
    """One library's best next block, as the tray weighs it."""

    name: str
    relative_value: float  # acquisition / map scale (inf: no map yet)
    cost_s: float  # the block's predicted cost plus the sample change
    priority: float = 1.0

    @property
    def per_second(self) -> float:
        if math.isinf(self.relative_value):
            return math.inf
        return self.priority * max(self.relative_value, 0.0) / max(self.cost_s, 1e-9)


def relative_value(acquisition: float, map_scale: float | None) -> float:
    """The acquisition relative to the map's scale; inf before any map or for an acquisition without a value."""
    if map_scale is None or not math.isfinite(acquisition) or map_scale <= 0:
        return math.inf
    return acquisition / map_scale


def rank(offers: Sequence[Offer]) -> list[Offer]:
    """Best first: information per second; among libraries without a map, the higher priority, then the
    cheaper block; ties in the listed order."""
    order = sorted(
        enumerate(offers),
        key=lambda io: (-io[1].per_second, -io[1].priority, io[1].cost_s, io[0]),
    )
    return [o for _, o in order]

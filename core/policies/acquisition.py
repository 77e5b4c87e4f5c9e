"""The acquisition part: what a candidate is worth, and whether its block time divides that worth."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

AcquisitionKind = Literal["ue", "ucb", "ei", "ivr"]


@dataclass(frozen=True)
class AcquisitionPart:
    # ue: epistemic σ (the paper); ivr: integrated variance reduction of the relative map error (y-free)
    kind: AcquisitionKind = "ue"
    cost_aware: bool = True  # rank acquisition / block time (off: the acquisition alone, never stay)
    edge_penalty: bool = False  # scale by the operator's edge penalty (SPEC §6.5)

"""A policy's parts, held together: what the Campaign and the planners read instead of feature flags."""

from __future__ import annotations

from dataclasses import dataclass, field

from core.policies.acquisition import Acquisition, CostWeighted, UncertaintyExploration
from core.policies.blocks import BlockDesign, ReplicateGrid
from core.policies.fidelity import FastArrays
from core.policies.guard import CollapseGuard
from core.policies.hold import HoldRule
from core.policies.noise import NoiseModel
from core.policies.surrogate import SurrogatePart


@dataclass(frozen=True)
class PolicyParts:
    surrogate: SurrogatePart = field(default_factory=SurrogatePart)
    noise: NoiseModel = field(default_factory=NoiseModel)
    # σ per second of the block's time (the paper's cost-aware rule), unless a recipe says otherwise
    acquisition: Acquisition = field(default_factory=lambda: CostWeighted(UncertaintyExploration()))
    blocks: BlockDesign = field(default_factory=ReplicateGrid)
    hold: HoldRule = field(default_factory=HoldRule)
    guard: CollapseGuard = field(default_factory=CollapseGuard)
    # fast arrays priced beside the CSM blocks (core.policies.fidelity; the profile's [fast] mode); None: CSM only
    fast: FastArrays | None = None

    @property
    def needs_covariance(self) -> bool:
        """The planner reads the fitted kernel and the tested centres' noise (variance reduction, the
        bias-aware hold's aim, scattered singles' placement)."""
        return (
            self.acquisition.needs_covariance
            or self.hold.bias_aware
            or not isinstance(self.blocks, ReplicateGrid)
        )

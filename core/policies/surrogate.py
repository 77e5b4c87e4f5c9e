"""The surrogate part: which GP a policy learns its map with (the guard part sets its safety rails)."""

from __future__ import annotations

from dataclasses import dataclass

from core.model import HeteroskedasticGP, KernelName
from core.policies.guard import CollapseGuard


@dataclass(frozen=True)
class SurrogatePart:
    kernel: KernelName = "matern52"
    # the mean GP learns a site-to-site variance: scatter between centres that within-grid spreads cannot
    # see (indent-scale heterogeneity), at the price of smoothing real roughness
    nugget: bool = False

    def build(self, guard: CollapseGuard, pitch_uv: float, seed: int) -> HeteroskedasticGP:
        return HeteroskedasticGP(
            kernel=self.kernel,
            heteroskedastic=True,
            lengthscale_floor_uv=guard.floor_uv(pitch_uv),
            lengthscale_prior=guard.floor,
            seed=seed,
            guard=guard.mode,
            nugget=self.nugget,
        )

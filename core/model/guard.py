"""The length-scale collapse guard (SPEC §5): when a fit's length-scales collapse, keep the last good kernel.

keep-last-good: a fit whose length-scales reach their floor, or drop below a fraction of the previous fit's,
keeps the last good kernel; keep-last-good-unless-confirmed: ... except where a cold search on 1.5× more data
lands where the warm fit slid and both beat the kept kernel by more than COLD_WIN_NATS (a real short scale,
not a slide); off: a plain maximum-likelihood GP (the unguarded ablation).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal, get_args

import torch

from core.model.fitting import COLD_WIN_NATS, raw_for
from core.model.hyper import Hyperparameters
from core.model.kernels import DTYPE
from core.model.problem import Problem

GuardName = Literal["keep-last-good", "keep-last-good-unless-confirmed", "off"]
GUARDS: tuple[GuardName, ...] = get_args(GuardName)
FLOOR_MARGIN = 1.05  # a length-scale within 5 % of its floor counts as collapsed


@dataclass(frozen=True)
class CollapseRule:
    floor_uv: float
    drop_ratio: float  # a length-scale below this fraction of the previous fit's has collapsed
    min_points: int  # ... once the previous fit had at least this many points

    def check(self, hyper: Hyperparameters, prev: Hyperparameters | None) -> tuple[bool, str]:
        return self.check_lengthscales(
            hyper.lengthscales_uv,
            None if prev is None else prev.lengthscales_uv,
            0 if prev is None else prev.n_points,
        )

    def check_lengthscales(
        self, ls: tuple[float, float], prev_ls: tuple[float, float] | None, prev_n_points: int
    ) -> tuple[bool, str]:
        """The rule on any GP's length-scales (the two-fidelity model's bias GP too)."""
        reasons = []
        for axis, value in zip("uv", ls, strict=True):
            if value <= self.floor_uv * FLOOR_MARGIN:
                reasons.append(f"length-scale {axis} = {value:.4f} at its floor {self.floor_uv:.4f}")
        if prev_ls is not None and prev_n_points >= self.min_points:
            for axis, value, old in zip("uv", ls, prev_ls, strict=True):
                if value < self.drop_ratio * old:
                    reasons.append(
                        f"length-scale {axis} dropped from {old:.4f} to {value:.4f} "
                        f"(< {self.drop_ratio:g}× the previous fit)"
                    )
        return bool(reasons), "; ".join(reasons)


def cold_search_confirms(p: Problem, kept_raw: tuple[float, ...], warm: float, cold: float, n: int) -> bool:
    """Does a cold search confirm the warm fit against the kept kernel (objectives per point)?"""
    if (cold - warm) * n > COLD_WIN_NATS:
        return False  # the cold starts found nothing as good: the slide is the warm path's own
    kept = p.objective(torch.tensor(raw_for(p, kept_raw), dtype=DTYPE))
    return math.isfinite(kept) and (kept - min(warm, cold)) * n > COLD_WIN_NATS

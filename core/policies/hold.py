"""The hold rule part: fixed, or the paper's drift-aware 5 s / 80 s switch, optionally bias-aware.

SPEC §6.6: a fast hold when the drift rate's area error is below 2 %. The bias-aware rule goes further: a
fast hold leaves the drift in the hardness as a bias that more indents do not average out, so it is used
only where that bias stays well below the map precision aimed at.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from core.drift import AREA_ERROR_THRESHOLD_PCT, area_error_pct, typical_depth_nm
from core.profile import InstrumentProfile

if TYPE_CHECKING:
    from core.policies.base import PlanContext

DRIFT_WINDOW = 12  # drift readings whose median the bias-aware hold trusts
RECENT_READINGS = 3  # ... unless the newest readings agree that the drift has fallen below it


def choose_hold(
    last_drift_rate_nm_s: float | None,
    profile: InstrumentProfile,
    threshold_pct: float = AREA_ERROR_THRESHOLD_PCT,
    depth_nm: float | None = None,
) -> tuple[float, float | None]:
    """SPEC §6.6: the profile's fast hold (5 s) when the last drift rate's area error is below 2 %, else
    its default hold (80 s). The area error is priced over the profile's drift segment at the measured
    depth (``depth_nm``; the nominal depth when the instrument reported none)."""
    if last_drift_rate_nm_s is None:
        return profile.default_hold_s, None
    depth = typical_depth_nm(()) if depth_nm is None else depth_nm
    err = area_error_pct(last_drift_rate_nm_s, depth, profile.drift_segment_s)
    return (profile.fast_hold_s if err < threshold_pct else profile.default_hold_s), err


def robust_rate(readings: tuple[float, ...], depth_nm: float, segment_s: float) -> float:
    """One drift reading is noisy: the median of the last DRIFT_WINDOW, unless the last reading alone breaks
    the paper's 2 % rule at ``depth_nm`` over ``segment_s`` (an event shows at once; the readings' own noise
    never sends a quiet run slow), or the median of the last RECENT_READINGS is lower: a drift event decays
    over minutes, and the window's median lags it by half a window (six indents of a slow block, 12 min),
    which sent the next block slow too although the drift had already fallen. Two of the three newest
    readings must say so: one low reading is not trusted."""
    window = float(np.median(readings[-DRIFT_WINDOW:]))
    recent = float(np.median(readings[-RECENT_READINGS:]))
    last = float(readings[-1])
    breaks = area_error_pct(last, depth_nm, segment_s) >= AREA_ERROR_THRESHOLD_PCT
    return max(window, last) if breaks else min(window, recent)


@dataclass(frozen=True)
class HoldRule:
    adaptive: bool = False  # fast / slow from the drift rate (also when the operator sets hold_policy)
    bias_aware: bool = False  # fast hold only where its bias is small against the precision aimed at
    bias_fraction: float = 0.5  # "small": at most this fraction of the aimed map error
    # ... or below this area error (%) at all: the fitted model can aim at an error far below what any indenter
    # map reaches (0.01 % on a nearly flat film), and the drift readings' own noise on a still instrument then
    # sent every other program to the slow hold for a bias of a few hundredths of a percent
    bias_floor_pct: float = 0.1

    def choose(
        self, ctx: PlanContext, map_rel_err: float | None, drift_corrected: bool = False
    ) -> tuple[float, float | None, str]:
        """(hold s, area error % or None, the hold mode shown in the console); ``drift_corrected``: the noise
        model corrects fast indents by Eq. 7 (the mode says so). Holds are the profile's."""
        if not (self.adaptive or ctx.settings.hold_policy == "adaptive"):
            hold = ctx.fixed_hold_s
            return hold, None, f"fixed {hold:g} s"
        rate = ctx.last_drift_rate_nm_s
        depth = typical_depth_nm(ctx.recent_depths_nm[-DRIFT_WINDOW:])
        if self.bias_aware and ctx.recent_drift_rates_nm_s:
            rate = robust_rate(ctx.recent_drift_rates_nm_s, depth, ctx.profile.drift_segment_s)
        fast, slow = ctx.profile.fast_hold_s, ctx.profile.default_hold_s
        hold, err = choose_hold(rate, ctx.profile, depth_nm=depth)
        mode = f"adaptive: {'fast' if hold == fast else 'slow'} {hold:g} s"
        if self.bias_aware and hold == fast and err is not None and map_rel_err is None:
            # the precision to aim at is not known until the seeds have shaped a model
            hold = slow
            mode = f"bias-aware: slow {slow:g} s until a model sets the precision to aim at"
        elif self.bias_aware and hold == fast and err is not None and map_rel_err is not None:
            # a fast hold leaves the drift in the hardness (bias ≈ the area error) and bias does not
            # average out: worth it only where it stays well below the precision the map aims at
            if err > self.bias_floor_pct and err / 100.0 > self.bias_fraction * map_rel_err:
                hold = slow
                mode = f"bias-aware: slow {slow:g} s (bias {err:.2f} % vs aim {100 * map_rel_err:.2f} %)"
            else:
                mode = f"bias-aware: fast {fast:g} s (bias {err:.2f} % vs aim {100 * map_rel_err:.2f} %)"
        if drift_corrected and hold < slow:
            mode += "; drift-corrected"
        return hold, err, mode

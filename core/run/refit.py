"""What a refit tells the run's record: the fit summary (length scales in stage µm, one collapse alarm for
either map, the guard's verdict)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

from core.run.campaign import CampaignLike, StageFrame
from core.run.events import FitSummary

if TYPE_CHECKING:
    from core.model import FitReport  # the refit's report (torch stays out of the engine's import)


def modulus_fit(campaign: CampaignLike, report: FitReport | None) -> FitReport | None:
    """The modulus GP's fit of this refit, when the planner aims at the modulus (then it is refitted
    with the hardness map and its guard counts as much: the planner's decisions rest on it)."""
    if report is None or not campaign.settings.map_weights.maps_modulus:
        return None
    return campaign.modulus_map.last_fit


def fit_summary(
    frame: StageFrame,
    report: FitReport | None,
    mape: float | None,
    max_found: float | None,
    modulus: FitReport | None = None,
) -> FitSummary:
    if report is None:
        return FitSummary(mape, max_found)
    # one alarm for either map (the console, the approval gate and the journal show it as one); the
    # reason names the map
    reasons = [report.collapse_reason] if report.collapse else []
    if modulus is not None and modulus.collapse:
        reasons.append(f"modulus map: {modulus.collapse_reason}")
    ls_uv = report.lengthscales_uv
    nls_uv = report.noise_lengthscales_uv
    return FitSummary(
        mape,
        max_found,
        fitted=True,
        lengthscales_um=lengthscales_um(frame, ls_uv),
        noise_lengthscales_um=lengthscales_um(frame, nls_uv) if nls_uv is not None else (),
        lengthscales_uv=tuple(float(v) for v in ls_uv),
        collapse_alarm=bool(reasons),
        collapse_reason="; ".join(reasons),
        used_last_good=bool(report.used_last_good),
        refit_s=report.seconds,
        n_points=report.n_points,
        iterations=report.iterations,
        outputscale=report.outputscale,
        mean_const=report.mean_const,
    )


def lengthscales_um(frame: StageFrame, ls: Sequence[float]) -> tuple[float, ...]:
    to_stage = frame.to_stage
    x0, y0 = to_stage(0.0, 0.0)
    xu, yu = to_stage(1.0, 0.0)
    xv, yv = to_stage(0.0, 1.0)
    su = math.hypot(float(xu) - float(x0), float(yu) - float(y0))
    sv = math.hypot(float(xv) - float(x0), float(yv) - float(y0))
    return tuple(float(v) * s for v, s in zip(ls, (su, sv), strict=False))

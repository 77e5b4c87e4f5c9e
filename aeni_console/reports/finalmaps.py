"""A run's final hardness and modulus maps, rebuilt from its journal (what ``aeni export`` and ``aeni report`` show).

The campaign is rebuilt from the journal as a resume would (the recorded hyperparameters, no refit), so the
hardness map is the one the run planned with. The modulus map is the run's own where it planned for it
(``map_weights``); otherwise it is fitted once here from the same indents (failed and not-run indents and
indents without a reported modulus stay out of both).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from core.campaign import Campaign
from core.campaign_config import campaign_config_from_dict
from core.journal import JournalReader
from core.run.spec import run_spec_from_meta
from core.run.tray import TrayCampaign
from core.run.tray_view import journal_tray

FINAL_MAP_COLUMNS: tuple[str, ...] = (
    "x_um",
    "y_um",
    "hardness_mean_gpa",
    "hardness_epistemic_sd_gpa",
    "hardness_noise_sd_gpa",
    "modulus_mean_gpa",
    "modulus_epistemic_sd_gpa",
    "modulus_noise_sd_gpa",
    "h_over_e",
)


@dataclass(frozen=True)
class FinalMaps:
    """Both maps' predictions at the candidate lattice's points inside the sample (stage µm, GPa)."""

    x_um: np.ndarray
    y_um: np.ndarray
    hardness_mean_gpa: np.ndarray
    hardness_epistemic_sd_gpa: np.ndarray
    hardness_noise_sd_gpa: np.ndarray
    modulus_mean_gpa: np.ndarray  # NaN where the run has no modulus map (fewer than 2 centres with one)
    modulus_epistemic_sd_gpa: np.ndarray
    modulus_noise_sd_gpa: np.ndarray
    modulus_planned: bool  # the planner aimed at the modulus (map_weights), not only fitted afterwards
    # the fast channel's learnt bias E[H_csm − H_fast] (GPa) where the run's two-fidelity map is active; None:
    # the run learnt none (CSM only, or too few fast cells or CSM centres yet)
    fast_bias_gpa: np.ndarray | None = None

    @property
    def h_over_e(self) -> np.ndarray:
        e = self.modulus_mean_gpa
        return np.asarray(self.hardness_mean_gpa / np.where(e > 0, e, np.nan), dtype=float)

    def columns(self) -> dict[str, np.ndarray]:
        """The export's predictions table, in FINAL_MAP_COLUMNS order."""
        return {name: np.asarray(getattr(self, name), dtype=float) for name in FINAL_MAP_COLUMNS}


def final_maps(path: str | Path) -> FinalMaps | None:
    """Both maps of the run at ``path``, or None when it has no hardness map yet (fewer than 2 centres)."""

    with JournalReader(path) as r:
        if journal_tray(r.meta) is not None:
            return None  # a tray's maps are its libraries' own: tray_final_maps
        config = campaign_config_from_dict(dict(r.meta["config"]))
        history = r.history()  # the resume's fold of the run's events
    if history is None or history.plan is None or config.sample is None:
        return None  # nothing planned yet, or a journal that holds no sample (a test's scripted campaign)
    campaign = Campaign(config)
    campaign.restore(history.plan[0], history.observed)
    return _maps_of(campaign)


def tray_final_maps(path: str | Path) -> dict[str, FinalMaps | None]:
    """Each library's maps of the tray run at ``path`` (empty for a single-sample run)."""
    with JournalReader(path) as r:
        tray = journal_tray(r.meta)
        if tray is None:
            return {}
        spec = run_spec_from_meta(r.meta)
        history = r.history()
    if history is None or history.plan is None:
        return {s.name: None for s in tray.libraries}
    campaign = TrayCampaign(tray, spec.campaign)
    campaign.restore(history.plan[0], history.observed)
    return {name: _maps_of(lane.campaign) for name, lane in campaign.lanes.items()}


def _maps_of(campaign: Campaign) -> FinalMaps | None:
    if campaign.prediction is None:
        return None
    inside = (
        campaign.placement_mask
        if campaign.placement_mask.any()
        else np.ones(len(campaign.lattice.xy_um), bool)
    )
    xy = campaign.lattice.xy_um[inside]
    h = campaign.predict_stage(xy[:, 0], xy[:, 1])
    nan = np.full(len(xy), np.nan)
    e_mean, e_epi, e_noise = nan, nan, nan
    if campaign.has_modulus_map():
        e = campaign.predict_modulus_stage(xy[:, 0], xy[:, 1])
        e_mean, e_epi, e_noise = e.mean, e.epistemic_sd, e.noise_sd
    bias = None
    if campaign.fast is not None and campaign.fast.active:
        u, v = campaign.calibration.to_uv(xy[:, 0], xy[:, 1])
        bias = np.asarray(campaign.fast.bias_gpa(np.column_stack([u, v])), dtype=float)
    return FinalMaps(
        x_um=xy[:, 0],
        y_um=xy[:, 1],
        hardness_mean_gpa=h.mean,
        hardness_epistemic_sd_gpa=h.epistemic_sd,
        hardness_noise_sd_gpa=h.noise_sd,
        modulus_mean_gpa=e_mean,
        modulus_epistemic_sd_gpa=e_epi,
        modulus_noise_sd_gpa=e_noise,
        modulus_planned=campaign.settings.map_weights.maps_modulus,
        fast_bias_gpa=bias,
    )

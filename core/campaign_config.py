"""What defines a run: its sample, policy, settings and the driver's own options (the journal's record).

Apart from the campaign that runs it, so a run spec, the journal and the CLI read and write it without
importing the model.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

from core.errors import InputError
from core.plan import PlannerSettings
from core.policies.names import RECOMMENDED
from core.sample import Sample, sample_from_dict
from core.settings import settings_from_dict, settings_to_dict


@dataclass(frozen=True)
class CampaignConfig:
    """What defines a run (sample + policy + settings, and the driver's own options); stored in the journal.

    ``sample`` None means "the driver's built-in sample" (a simulated scenario's); the run resolves it
    before the journal is written, so a journal always holds the sample it ran on. ``driver_options`` are
    for the driver alone (the simulated instrument's scenario, noise, drift, truth CSV); the campaign
    never reads them.
    """

    policy: str = RECOMMENDED
    seed: int = 0
    profile: str | None = None
    lattice_n: int | None = None
    settings: PlannerSettings = field(default_factory=PlannerSettings)
    name: str = "run"
    sample: Sample | None = None
    driver_options: dict[str, Any] = field(default_factory=dict)


def campaign_config_to_dict(cfg: CampaignConfig) -> dict[str, Any]:
    d = {f.name: getattr(cfg, f.name) for f in dataclasses.fields(cfg)}
    d["settings"] = settings_to_dict(cfg.settings)
    d["sample"] = None if cfg.sample is None else cfg.sample.to_dict()
    d["driver_options"] = dict(cfg.driver_options)
    return d


def campaign_config_from_dict(data: dict[str, Any]) -> CampaignConfig:
    d = dict(data)
    if "scenario" in d and "driver_options" not in d:
        raise InputError(
            "journal",
            "written before runs had a sample (campaign config with an emulator scenario); "
            "this version cannot resume it: start the run again",
        )
    known = {f.name for f in dataclasses.fields(CampaignConfig)}
    unknown = sorted(set(d) - known)
    if unknown:
        raise InputError("campaign config", f"unknown field(s) {', '.join(unknown)}")
    d["settings"] = settings_from_dict(d.get("settings", {}))
    if d.get("sample") is not None:
        d["sample"] = sample_from_dict(d["sample"], "journal sample")
    d["driver_options"] = dict(d.get("driver_options") or {})
    return CampaignConfig(**d)

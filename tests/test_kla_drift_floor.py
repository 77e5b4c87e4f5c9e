"""The drift noise floor is the profile's: a campaign corrects fast indents only above it."""

from __future__ import annotations

from pathlib import Path

import pytest

from core.campaign import Campaign
from core.campaign_config import CampaignConfig
from core.plan import Block, IndentResult, local_grid
from drivers.sim.scenarios import make_scenario


def centre_value(tmp_path: Path, floor_nm_s: float) -> float:
    profile = tmp_path / f"floor-{floor_nm_s}.toml"
    profile.write_text(f'extends = "kla-imicro"\n[drift]\nnoise_floor_nm_s = {floor_nm_s}\n')
    campaign = Campaign(
        CampaignConfig(policy="adaptive-hold+drift-corr", profile=str(profile), lattice_n=20),
        make_scenario("ternary", 0).sample,
    )
    assert campaign.profile.drift_noise_floor_nm_s == floor_nm_s
    specs = local_grid(500.0, 500.0, 3, 5.0, 5.0)
    block = Block(0, "global", 500.0, 500.0, 3, 5.0, 5.0, specs)
    results = [
        IndentResult(0, i, s.x_um, s.y_um, s.x_um, s.y_um, 5.0, 5.0, 100.0, 0.2, 100.0 * i)
        for i, s in enumerate(specs)
    ]
    campaign._record(block, results)
    return campaign.centres[-1].value_gpa


def test_fast_indents_are_corrected_only_above_the_profiles_floor(tmp_path: Path) -> None:
    # 0.2 nm/s over 40 s on a 100 nm indent: h_true = 92 nm, H_true = H·(100/92)² (Eq. 7)
    assert centre_value(tmp_path, 0.005) == pytest.approx(5.0 * (100 / 92) ** 2)
    assert centre_value(tmp_path, 0.5) == pytest.approx(5.0)  # a quieter instrument's floor: left alone

"""Which link between the fast channel and the CSM map the emulator's physics allow (the model's diagnosis).

On each field (seed 0, a 60 × 60 lattice) the noiseless fast reading (drivers/sim/fast_channel.py's expected
reading) is regressed on by the CSM hardness H0 with the CSM level's mean shapes, by least squares: what is
left is what δ (the bias GP) must learn from CSM indents, however many fast indents there are:

- const ρ: H0 ≈ b·f + c;
- plane ρ (the first version): (b₀ + b₁u + b₂v)·f + c₀ + c₁u + c₂v;
- plane ρ + f, f²: ρ also a quadratic in the fast reading itself (a non-linear link in H_fast alone);
- plane ρ + E/H link (this version): ρ also a quadratic in the fast channel's E/H (Nix–Gao: h* ∝ (E/H)²).

    nice -n 10 .venv/bin/python benchmarks/two_fidelity_link.py
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from core.profile import load_profile
from drivers.sim.emulator import truth_modulus_gpa, truth_modulus_noise_sd_gpa
from drivers.sim.fast_channel import CsmAtSites, FastPhysics, expected_reading
from drivers.sim.scenarios import make_scenario

FIELDS = ("ternary", "film", "phase-boundary", "edge-spot", "rotated-quaternary")


def residual_sd(h0: np.ndarray, columns: list[np.ndarray]) -> float:
    a = np.column_stack(columns)
    coef, *_ = np.linalg.lstsq(a, h0, rcond=None)
    return float(np.std(h0 - a @ coef))


def main() -> None:
    rows = []
    for name in FIELDS:
        scenario = make_scenario(name, 0)
        profile = load_profile(scenario.profile_name)
        assert profile.fast is not None
        xy = scenario.evaluator(60).xy_um
        x, y, truth = xy[:, 0], xy[:, 1], scenario.truth
        csm = CsmAtSites(
            truth.hardness_gpa(x, y),
            truth.noise_sd_gpa(x, y),
            truth_modulus_gpa(truth, x, y),
            truth_modulus_noise_sd_gpa(truth, x, y),
        )
        f = expected_reading(FastPhysics(profile.fast.peak_load_mn), x, y, csm).hardness_gpa
        h0 = csm.hardness_gpa
        u, v = scenario.calibration.to_uv(x, y)
        u, v, one = u - 0.5, v - 0.5, np.ones_like(x)
        plane = [f, u * f, v * f, one, u, v]
        fc = f - f.mean()
        r = csm.modulus_gpa / f
        z = (r - r.mean()) / r.std()
        row = {
            "field": name,
            "sd_h0_gpa": float(h0.std()),
            "csm_noise_sd_gpa": float(np.median(csm.noise_sd_gpa)),
            "ratio_min": float(np.min(h0 / f)),
            "ratio_max": float(np.max(h0 / f)),
            "const_rho": residual_sd(h0, [f, one]),
            "plane_rho": residual_sd(h0, plane),
            "plane_rho_f_f2": residual_sd(h0, [*plane, fc * f, fc**2 * f]),
            "plane_rho_eh_link": residual_sd(h0, [*plane, z * f, z**2 * f]),
        }
        rows.append(row)
    lines = [
        "| field | sd H0 GPa | CSM noise sd GPa | H0/H_fast | residual sd GPa: const ρ | plane ρ | plane ρ + f, f² |"
        " plane ρ + E/H link |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['field']} | {r['sd_h0_gpa']:.3f} | {r['csm_noise_sd_gpa']:.3f} | {r['ratio_min']:.2f}–"
            f"{r['ratio_max']:.2f} | {r['const_rho']:.3f} | {r['plane_rho']:.3f} | {r['plane_rho_f_f2']:.3f} | "
            f"{r['plane_rho_eh_link']:.3f} |"
        )
    table = "\n".join(lines)
    print(table)
    out = Path("benchmarks/results/two_fidelity_plan/link_residuals")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(rows, indent=1), encoding="utf-8")
    out.with_suffix(".md").write_text(f"# What δ must learn, by link (seed 0)\n\n{table}\n", encoding="utf-8")


if __name__ == "__main__":
    main()

"""Wall time and peak memory of the two-fidelity model at 10,000 fast + 500 CSM indents (issue 36's scale).

On the ternary: a 100 × 100 fast array (10 µm pitch, drivers/sim/fast_channel.py) and 500 single CSM indents at
random sites; the candidates are the product's 100 × 100 lattice. Measured, one process, torch on one thread:

- the first fit (cold: every GP's hyperparameters searched) and its prediction;
- a decision after CSM indents arrive (5 more each time, 5 times): the CSM-only GP's warm refit (its noise
  model), the fast GP conditioned with its kept hyperparameters, the CSM level's warm refit, and the
  prediction of the CSM map's four fields on the 10,000 candidates;
- a decision after a new fast array arrives (1,000 more fast indents: the fast GP re-optimises, warm);
- the CSM-only GP's decision on the same 500 indents, for scale.

Peak memory is the process's peak resident set (ru_maxrss), the interpreter and torch included.

    nice -n 10 .venv/bin/python benchmarks/two_fidelity_scale.py
"""

from __future__ import annotations

import json
import os
import resource
import statistics
import time
from pathlib import Path

import numpy as np

from core.model.observations import Observations
from core.model.two_fidelity import TwoFidelityGP, fast_observations
from drivers.sim.emulator import TernaryField, truth_modulus_gpa, truth_modulus_noise_sd_gpa
from drivers.sim.fast_channel import CsmAtSites, FastPhysics, read_array

SIDE_UM = 1000.0


def fast_indents(
    truth: TernaryField, n_side: int, seed: int, array_id: int, offset_um: float
) -> tuple[np.ndarray, np.ndarray]:
    c = (np.arange(n_side) + 0.5) / n_side * SIDE_UM + offset_um
    gx, gy = np.meshgrid(np.clip(c, 0, SIDE_UM), np.clip(c, 0, SIDE_UM))
    x, y = gx.ravel(), gy.ravel()
    csm = CsmAtSites(
        truth.hardness_gpa(x, y),
        truth.noise_sd_gpa(x, y),
        truth_modulus_gpa(truth, x, y),
        truth_modulus_noise_sd_gpa(truth, x, y),
    )
    r = read_array(FastPhysics(peak_load_mn=5.0), seed, array_id, x, y, csm)
    return np.column_stack([x, y]) / SIDE_UM, r.hardness_gpa


def csm_singles(truth: TernaryField, m: int, seed: int) -> Observations:
    rng = np.random.default_rng([seed, 500])
    uv = rng.random((m, 2))
    x, y = uv[:, 0] * SIDE_UM, uv[:, 1] * SIDE_UM
    h = truth.hardness_gpa(x, y) + truth.noise_sd_gpa(x, y) * rng.standard_normal(m)
    return Observations(
        uv=uv, median_gpa=h, spread_var_gpa2=np.full(m, np.nan), n_indents=np.ones(m, dtype=np.int64)
    )


def peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def main() -> None:
    truth = TernaryField()
    c = (np.arange(100) + 0.5) / 100
    gu, gv = np.meshgrid(c, c)
    candidates = np.column_stack([gu.ravel(), gv.ravel()])
    fast_uv, fast_h = fast_indents(truth, 100, 0, 0, 0.0)
    all_csm = csm_singles(truth, 525, 0)

    def first(n: int) -> Observations:
        return Observations(
            uv=all_csm.uv[:n],
            median_gpa=all_csm.median_gpa[:n],
            spread_var_gpa2=all_csm.spread_var_gpa2[:n],
            n_indents=all_csm.n_indents[:n],
        )

    out: dict[str, object] = {
        "n_fast": int(np.isfinite(fast_h).sum()),
        "n_candidates": len(candidates),
        "load_average_start": os.getloadavg(),  # the machine is shared: wall times scale with this
    }
    t0 = time.perf_counter()
    fast = fast_observations(fast_uv, fast_h)
    out["fast_cells_s"] = time.perf_counter() - t0
    out["fast_cells"] = fast.n
    model = TwoFidelityGP()
    t0 = time.perf_counter()
    report = model.fit(first(500), fast)
    out["cold_fit_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    model.predict(candidates)
    out["predict_s"] = time.perf_counter() - t0
    out["fast_grid_per_side"] = model.fast_gp.latent_grid()[0].per_side
    out["rho_coef"] = report.rho_coef
    decisions = []
    fits, predicts = [], []
    for k in range(1, 6):
        t0 = time.perf_counter()
        model.fit(first(500 + 5 * k), fast)
        t1 = time.perf_counter()
        model.predict(candidates)
        fits.append(t1 - t0)
        predicts.append(time.perf_counter() - t1)
        decisions.append(time.perf_counter() - t0)
    out["decision_after_csm_fit_median_s"] = statistics.median(fits)
    out["decision_after_csm_predict_median_s"] = statistics.median(predicts)
    out["decision_after_csm_s"] = decisions
    out["decision_after_csm_median_s"] = statistics.median(decisions)
    more_uv, more_h = fast_indents(truth, 32, 0, 1, 5.0)  # a second array: ~1,000 more fast indents
    fast2 = fast_observations(np.vstack([fast_uv, more_uv]), np.concatenate([fast_h, more_h]))
    t0 = time.perf_counter()
    model.fit(first(525), fast2)
    model.predict(candidates)
    out["decision_after_fast_array_s"] = time.perf_counter() - t0
    out["fast_cells_after"] = fast2.n
    csm_only = TwoFidelityGP()
    csm_only.fit(first(500), None)
    t0 = time.perf_counter()
    csm_only.fit(first(505), None)
    csm_only.predict(candidates)
    out["csm_only_decision_s"] = time.perf_counter() - t0
    out["peak_rss_mb"] = peak_mb()
    out["load_average_end"] = os.getloadavg()
    print(json.dumps(out, indent=1, default=float))
    path = Path("benchmarks/results/two_fidelity_scale.json")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out, indent=1, default=float), encoding="utf-8")


if __name__ == "__main__":
    main()

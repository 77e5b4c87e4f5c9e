"""Wall time and peak memory of the two-fidelity model at 10,000 fast + 500 CSM indents (issue 36's scale).

On the ternary: two fast arrays of 10,000 indents in all (10 µm pitch, drivers/sim/fast_channel.py) and 500 single CSM indents at
random sites; the candidates are the product's 100 × 100 lattice. Measured, one process, torch on one thread:

- the first fit (cold: every GP's hyperparameters searched) on a first array of 7,000 fast indents (x < 700 µm);
- the decision after a second array of 3,000 (the rest of the square) arrives: the fast cells grow by 43 %, so
  the fast GP and the CSM level re-optimise, warm, and the CSM map's four fields are predicted on the 10,000
  candidates;
- decisions after CSM indents arrive (5 more each time, 5 times, at 10,000 fast): the CSM-only GP's warm refit
  (its noise model), the fast GP and the CSM level conditioned with their kept hyperparameters, the prediction;
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
    truth: TernaryField, x_range_um: tuple[float, float], seed: int, array_id: int
) -> tuple[np.ndarray, np.ndarray]:
    """One fast array at a 10 µm pitch over x in ``x_range_um`` and the whole y side."""
    xs = np.arange(x_range_um[0] + 5.0, x_range_um[1], 10.0)
    ys = np.arange(5.0, SIDE_UM, 10.0)
    gx, gy = np.meshgrid(xs, ys)
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
    uv0, h0 = fast_indents(truth, (0.0, 700.0), 0, 0)  # the first array: 7,000 indents
    uv1, h1 = fast_indents(truth, (700.0, SIDE_UM), 0, 1)  # the second: 3,000 more
    fast_uv, fast_h = np.vstack([uv0, uv1]), np.concatenate([h0, h1])
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
    model = TwoFidelityGP()
    t0 = time.perf_counter()
    report = model.fit(first(500), fast_observations(uv0, h0))
    out["cold_fit_first_array_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    fast = fast_observations(fast_uv, fast_h)
    out["fast_cells_s"] = time.perf_counter() - t0
    out["fast_cells"] = fast.n
    t0 = time.perf_counter()
    report = model.fit(first(500), fast)
    t1 = time.perf_counter()
    model.predict(candidates)
    out["decision_after_second_array_s"] = time.perf_counter() - t0
    out["decision_after_second_array_fit_s"] = t1 - t0
    out["decision_after_second_array_predict_s"] = time.perf_counter() - t1
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

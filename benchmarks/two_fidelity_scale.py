"""Wall time and peak memory of the two-fidelity model at 10,000 fast + 500 CSM indents (issue 36's scale).

On the ternary: two fast arrays of 10,000 indents in all (10 µm pitch, drivers/sim/fast_channel.py) and 500 single CSM indents at
random sites; the candidates are the product's 100 × 100 lattice. Measured, one process, torch on one thread:

- the first fit (cold: every GP's hyperparameters searched) on a first array of 7,000 fast indents (x < 700 µm);
- the decision after a second array of 3,000 (the rest of the square) arrives, as a run makes it: every level
  conditioned on the new cells with the hyperparameters it had, the CSM map's four fields predicted on the
  10,000 candidates and the planner's pricing; the fast cells grew by 43 %, so the fast GP and the CSM level
  re-optimise, warm, on a thread beside the next block (``core.model.deferred``): its wall time from the
  landing, and the same re-optimisation waited for (what the decision cost before);
- decisions after CSM indents arrive (5 more each time, 5 times, at 10,000 fast): the CSM-only GP's warm refit
  (its noise model), the fast GP and the CSM level conditioned with their kept hyperparameters (the first of
  them installs the re-optimisation), the prediction;
- the CSM-only GP's decision on the same 500 indents, for scale;
- the planner's pricing at 10,000 fast + 525 CSM (``core.policies.fidelity``'s what-ifs through the run's
  ``TwoFidelityView``, on the design's 12 × 12 reference lattice): the CSM block's (a block of 5 sites) and
  ``FastArrays.scored`` arrays' (950 µm and 475 µm at 50 µm pitch, binned into the model's cells), each
  decision repeated ``--repeat`` times: the median and the worst.

ρ's link (the fast cells' E/H, ``fast_link_observations``) is fitted as a run fits it.

Peak memory is the process's peak resident set (ru_maxrss), the interpreter and torch included.

    nice -n 10 .venv/bin/python benchmarks/two_fidelity_scale.py
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import resource
import statistics
import time
from pathlib import Path

import numpy as np

from core.fidelity import FastChannel, TwoFidelityView
from core.model import HeteroskedasticGP
from core.model.observations import Observations
from core.model.two_fidelity import fast_link_observations, fast_observations
from core.policies.fidelity import FastArrays, array_cells
from core.policies.variance import median_noise_var, reference_lattice
from drivers.sim.emulator import TernaryField, truth_modulus_gpa, truth_modulus_noise_sd_gpa
from drivers.sim.fast_channel import CsmAtSites, FastPhysics, read_array

SIDE_UM = 1000.0


def fast_indents(
    truth: TernaryField, x_range_um: tuple[float, float], seed: int, array_id: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
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
    return np.column_stack([x, y]) / SIDE_UM, r.hardness_gpa, r.modulus_gpa


def csm_singles(truth: TernaryField, m: int, seed: int) -> Observations:
    rng = np.random.default_rng([seed, 500])
    uv = rng.random((m, 2))
    x, y = uv[:, 0] * SIDE_UM, uv[:, 1] * SIDE_UM
    h = truth.hardness_gpa(x, y) + truth.noise_sd_gpa(x, y) * rng.standard_normal(m)
    return Observations(
        uv=uv, median_gpa=h, spread_var_gpa2=np.full(m, np.nan), n_indents=np.ones(m, dtype=np.int64)
    )


def to_uv(x_um: np.ndarray, y_um: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return x_um / SIDE_UM, y_um / SIDE_UM


def peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def array_sites_uv(centre_um: tuple[float, float], extent_um: float, pitch_um: float) -> np.ndarray:
    n = int(extent_um // pitch_um) + 1
    c = (np.arange(n) - (n - 1) / 2) * pitch_um
    gx, gy = np.meshgrid(centre_um[0] + c, centre_um[1] + c)
    xy = np.column_stack([gx.ravel(), gy.ravel()])
    inside = np.all((xy >= 0) & (xy <= SIDE_UM), axis=1)
    return xy[inside] / SIDE_UM


def pricing(view: TwoFidelityView, rng: np.random.Generator, design: FastArrays) -> dict[str, float]:
    """One decision's what-ifs as ``TwoFidelityPlanner`` makes them (the CSM block's and the scored arrays')."""
    ref = reference_lattice()
    t0 = time.perf_counter()
    var_now = view.variance(ref)
    t1 = time.perf_counter()
    sites = rng.random((5, 2))
    view.variance_after_csm(ref, sites, np.full(5, 0.074**2))
    t2 = time.perf_counter()
    arrays = [
        ((500.0, 500.0), 950.0),
        ((262.5, 262.5), 475.0),
        ((737.5, 737.5), 475.0),
        ((262.5, 737.5), 475.0),
    ]
    for centre, extent in arrays[: design.scored]:
        uv = array_sites_uv(centre, extent, 50.0)
        cells, counts = array_cells(uv, 50.0 / SIDE_UM)
        noise = median_noise_var(np.sqrt(view.fast_noise_var(cells)), counts)
        after = view.variance_after_fast(ref, cells, np.maximum(noise, 1e-12))
        assert np.all(after <= var_now + 1e-9)
    t3 = time.perf_counter()
    return {"variance_s": t1 - t0, "csm_whatif_s": t2 - t1, "arrays_whatif_s": t3 - t2, "pricing_s": t3 - t0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "--repeat", type=int, default=5, help="decisions after CSM indents to time (median, worst)"
    )
    ap.add_argument("--out", default="benchmarks/results/two_fidelity_scale.json")
    args = ap.parse_args()
    truth = TernaryField()
    c = (np.arange(100) + 0.5) / 100
    gu, gv = np.meshgrid(c, c)
    candidates = np.column_stack([gu.ravel(), gv.ravel()])
    uv0, h0, e0 = fast_indents(truth, (0.0, 700.0), 0, 0)  # the first array: 7,000 indents
    uv1, h1, e1 = fast_indents(truth, (700.0, SIDE_UM), 0, 1)  # the second: 3,000 more
    fast_uv, fast_h, fast_e = np.vstack([uv0, uv1]), np.concatenate([h0, h1]), np.concatenate([e0, e1])
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
    # the run's path (core.fidelity.FastChannel): the fast indents in stage µm, binned into cells at a fit,
    # the CSM level on the campaign's CSM-only GP, the held-out comparison of both maps
    channel = FastChannel(HeteroskedasticGP())
    channel.xy_um, channel.hardness_gpa, channel.modulus_gpa = (
        (uv0 * SIDE_UM).tolist(),
        h0.tolist(),
        e0.tolist(),
    )

    def decide(n_csm: int) -> dict[str, float]:
        """One decision as a run makes it after a block: refit, predict the candidates, price the plans."""
        t0 = time.perf_counter()
        csm = first(n_csm)
        channel.fit(csm, channel.model.csm_gp.fit(csm), to_uv)
        t1 = time.perf_counter()
        channel.predict(candidates)
        t2 = time.perf_counter()
        parts = pricing(TwoFidelityView(channel.model), rng, FastArrays())
        t3 = time.perf_counter()
        channel.model.start_reoptimisation()  # as the campaign does once its proposal is made
        return {"fit_s": t1 - t0, "predict_s": t2 - t1, "pricing_s": t3 - t2, "decision_s": t3 - t0, **parts}

    rng = np.random.default_rng(36)
    t0 = time.perf_counter()
    decide(500)
    out["cold_fit_first_array_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    fast = fast_observations(fast_uv, fast_h)
    link = fast_link_observations(fast_uv, fast_h, fast_e)
    out["fast_cells_s"] = time.perf_counter() - t0
    out["fast_cells"] = fast.n
    synchronous = copy.deepcopy(channel.model)
    channel.xy_um += (uv1 * SIDE_UM).tolist()
    channel.hardness_gpa += h1.tolist()
    channel.modulus_gpa += e1.tolist()
    after_array = decide(500)  # the re-optimisation starts on a thread at its end
    out["decision_after_second_array"] = after_array
    out["decision_after_second_array_s"] = after_array["decision_s"]
    t0 = time.perf_counter()
    while not channel.model.reoptimisation_done:
        time.sleep(0.01)
    out["reoptimisation_beside_the_block_s"] = time.perf_counter() - t0  # wall, from the decision
    t0 = time.perf_counter()
    csm = first(500)
    report = synchronous.fit_levels(csm, fast, synchronous.csm_gp.fit(csm), link=link)  # ... waited for
    out["reoptimisation_synchronous_s"] = time.perf_counter() - t0
    out["fast_grid_per_side"] = synchronous.fast_gp.latent_grid()[0].per_side
    out["rho_coef"] = report.rho_coef
    out["rho_link_coef"] = report.rho_link_coef
    runs = [decide(500 + 5 * k) for k in range(1, args.repeat + 1)]  # the first installs the re-optimisation
    fits = [r["fit_s"] for r in runs]
    predicts = [r["predict_s"] for r in runs]
    prices = [r["pricing_s"] for r in runs]
    decisions = [r["decision_s"] for r in runs]
    whatifs = runs
    out["decision_after_csm_fit_median_s"] = statistics.median(fits)
    out["decision_after_csm_predict_median_s"] = statistics.median(predicts)
    out["decision_after_csm_s"] = decisions
    out["decision_after_csm_pricing_median_s"] = statistics.median(prices)
    out["decision_after_csm_pricing_parts"] = whatifs
    out["decision_after_csm_median_s"] = statistics.median(decisions)
    out["decision_after_csm_worst_s"] = max(decisions)
    csm_only = HeteroskedasticGP()
    csm_only.fit(first(500))
    t0 = time.perf_counter()
    csm_only.fit(first(505))
    csm_only.predict(candidates)
    out["csm_only_decision_s"] = time.perf_counter() - t0
    out["peak_rss_mb"] = peak_mb()
    out["load_average_end"] = os.getloadavg()
    print(json.dumps(out, indent=1, default=float))
    path = Path(args.out)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out, indent=1, default=float), encoding="utf-8")


if __name__ == "__main__":
    main()

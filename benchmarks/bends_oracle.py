"""Does placing single indents where the map bends beat an even design? An oracle-style check, no instrument.

Like ``oracle_bound.py`` (no drift, travel or overhead; singles at the 5 s hold, fitted by the product's GP),
but the design is sequential: an 8×8 start at cell centres, then batches of singles picked greedily by the
relative-error IVR of ``core.policies.variance`` under the GP fitted so far, the reference points weighted by

- ``grad:B``: 1/μ² · (1 + B·min(|∇μ|/μ / 2, 1)), the gradient weight ``aeni`` uses (structure_weight = B);
- ``curv:B``: 1/μ² · (1 + B·κ/κ̄), κ = ‖∇²μ‖/μ the fitted mean's relative curvature (core.policies.bends);
- ``curv2:B``: 1/μ² · (1 + B·(κ/κ̄)²);

against ``even``: a k×k lattice of singles at cell centres. MAPE of the GP mean against the truth at each
checkpoint (number of singles), median and worst over the seeds.

Run: python benchmarks/bends_oracle.py ternary 0,1,2 even,grad:1,curv:3,curv2:3 320,400,464,529
(prints one line per variant; the run behind docs/benchmarks.md is results/bends/oracle_ternary_3seeds.log)
"""

from __future__ import annotations

import os
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from oracle_bound import field_scenario, lattice, measure_design  # noqa: E402
from scipy.interpolate import RegularGridInterpolator  # noqa: E402

from core.metrics import mape_pct  # noqa: E402
from core.model import HeteroskedasticGP  # noqa: E402
from core.policies.base import GPSummary  # noqa: E402
from core.policies.variance import PosteriorCov  # noqa: E402

N_CAND = 50  # candidates per side (cell centres)
N_REF = 24  # reference points per side, as the planner's
N_FINE = 48  # the fitted mean's lattice for its derivatives
MIN_SEP_UV = 0.012  # no two singles closer (the planner's 15 µm on 1000 µm, rounded up)


def _fit(obs: object) -> HeteroskedasticGP:
    gp = HeteroskedasticGP(heteroskedastic=True, lengthscale_floor_uv=0.005)
    gp.fit(obs)  # type: ignore[arg-type]
    return gp


def _weights(kind: str, beta: float, gp: HeteroskedasticGP, ref: np.ndarray) -> np.ndarray:
    f = (np.arange(N_FINE) + 0.5) / N_FINE
    fu, fv = np.meshgrid(f, f)
    mf = gp.predict_mean(np.column_stack([fu.ravel(), fv.ravel()])).reshape(N_FINE, N_FINE)
    gv, gu = np.gradient(mf, 1 / N_FINE)
    guv, guu = np.gradient(gu, 1 / N_FINE)
    gvv, _ = np.gradient(gv, 1 / N_FINE)

    def at(a: np.ndarray) -> np.ndarray:
        return np.asarray(
            RegularGridInterpolator((f, f), a, bounds_error=False, fill_value=None)(ref[:, ::-1])
        )

    mu = np.maximum(np.abs(gp.predict(ref).mean), 1e-6)
    w = 1 / mu**2
    if kind == "grad":
        w = w * (1 + beta * np.minimum(np.hypot(at(gu), at(gv)) / mu / 2.0, 1.0))
    elif kind in ("curv", "curv2"):
        hess = np.sqrt(at(guu) ** 2 + at(gvv) ** 2 + 2 * at(guv) ** 2) / mu
        r = hess / np.mean(hess)
        w = w * (1 + beta * (r if kind == "curv" else r**2))
    return np.asarray(w)


def run(field: str, seed: int, variant: str, checkpoints: list[int]) -> dict[int, float]:
    sc = field_scenario(field, seed)
    emu = sc.make_emulator()
    b = sc.calibration.bounds_um
    x0, x1, y0, y1 = b
    ev = sc.evaluator()
    tuv = (ev.xy_um - [x0, y0]) / [x1 - x0, y1 - y0]
    th = ev.truth_gpa
    out: dict[int, float] = {}
    if variant == "even":
        for n in checkpoints:
            k = round(n**0.5)
            obs = measure_design(emu, lattice(k, k, b, True), 1, 5.0, "median", b)
            out[n] = mape_pct(_fit(obs).predict_mean(tuv), th)
        return out
    kind, beta_s = variant.split(":")
    beta = float(beta_s)
    c = (np.arange(N_CAND) + 0.5) / N_CAND
    cand = np.column_stack([a.ravel() for a in np.meshgrid(c, c)])
    r = (np.arange(N_REF) + 0.5) / N_REF
    ref = np.column_stack([a.ravel() for a in np.meshgrid(r, r)])
    cen = lattice(8, 8, b, True)
    while True:
        obs = measure_design(emu, cen, 1, 5.0, "median", b)
        gp = _fit(obs)
        if len(cen) in checkpoints:
            out[len(cen)] = mape_pct(gp.predict_mean(tuv), th)
        if len(cen) >= max(checkpoints):
            return out
        h = gp.hyperparameters
        assert h is not None and gp.outputscale_gpa2 is not None
        summ = GPSummary(h.kernel, h.lengthscales_uv, float(gp.outputscale_gpa2), gp.site_var_gpa2)
        done = np.array(obs.uv)
        nv = gp.predict(done).noise_sd ** 2 + gp.site_var_gpa2
        cnv = gp.predict(cand).noise_sd ** 2 + gp.site_var_gpa2
        model = PosteriorCov.build(summ, done, nv, cand, ref, _weights(kind, beta, gp, ref))
        free = np.min(np.hypot(*(cand[:, None, :] - done[None]).transpose(2, 0, 1)), axis=1) > MIN_SEP_UV
        nxt = min(cp for cp in checkpoints if cp > len(cen))
        for _ in range(min(min(48, max(16, len(cen) // 4)), nxt - len(cen))):
            g = model.gain(cnv)
            g[~free] = -1
            j = int(np.argmax(g))
            model = model.condition_on(j, float(cnv[j]))
            free &= np.hypot(*(cand - cand[j]).T) > MIN_SEP_UV
            cen.append((x0 + (x1 - x0) * cand[j, 0], y0 + (y1 - y0) * cand[j, 1]))


def main() -> int:
    field, seeds_s, variants_s, checkpoints_s = sys.argv[1:5]
    seeds = [int(s) for s in seeds_s.split(",")]
    checkpoints = sorted(int(c) for c in checkpoints_s.split(","))
    for v in variants_s.split(","):
        t = time.time()
        res = [run(field, s, v, checkpoints) for s in seeds]
        med = {n: round(statistics.median(r[n] for r in res), 3) for n in checkpoints}
        worst = {n: round(max(r[n] for r in res), 3) for n in checkpoints}
        print(v, med, "worst", worst, f"{time.time() - t:.0f}s", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Decision latency of the surrogate: warm refit + scoring all 10,000 candidates of a 100×100 lattice.

For each size N (tested centres, 5×5 grids on the emulator's ternary field), the model is put in the state
after N − 1 centres (set_hyper, as on resume), then one more centre arrives and we time fit + predict.
Each run adds a different centre; the table gives the median and IQR over the runs. Also timed once:
the cold fit at N, and gpytorch's default predictive-variance path at 10,000 points.

    python -m benchmarks.decision_latency [--runs 9] [--threads 2] [--sizes 25 100 400] [--no-reference]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from core.model import HeteroskedasticGP, Observations  # noqa: E402
from drivers.sim.emulator import TernaryField  # noqa: E402

SIDE_UM = 1000.0
PITCH_UM = 5.0
GRID_G = 5
LATTICE_N = 100
RESULTS = ROOT / "benchmarks" / "results"


THREADS = 1


def new_gp() -> HeteroskedasticGP:
    return HeteroskedasticGP(threads=THREADS)


def lattice(n: int) -> np.ndarray:
    c = (np.arange(n) + 0.5) / n
    u, v = np.meshgrid(c, c)
    return np.column_stack([u.ravel(), v.ravel()])


def measure(centres_uv: np.ndarray, seed: int) -> Observations:
    """5×5 grids of indents at each centre on the emulator, collapsed to medians and spreads."""
    field = TernaryField(side_um=SIDE_UM)
    rng = np.random.default_rng(seed)
    offsets = (np.arange(GRID_G) - (GRID_G - 1) / 2) * PITCH_UM / SIDE_UM
    du, dv = (a.ravel() for a in np.meshgrid(offsets, offsets))
    uv = np.concatenate([np.column_stack([u + du, v + dv]) for u, v in centres_uv])
    ids = np.repeat(np.arange(len(centres_uv)), GRID_G * GRID_G)
    x_um, y_um = uv[:, 0] * SIDE_UM, uv[:, 1] * SIDE_UM
    h = field.hardness_gpa(x_um, y_um) + field.noise_sd_gpa(x_um, y_um) * rng.standard_normal(len(uv))
    return Observations.from_indents(uv, h, ids)


def take(obs: Observations, rows: np.ndarray) -> Observations:
    return Observations(obs.uv[rows], obs.median_gpa[rows], obs.spread_var_gpa2[rows], obs.n_indents[rows])


def quantiles(values: list[float]) -> dict[str, float]:
    a = np.asarray(values)
    return {
        "median": float(np.median(a)),
        "p25": float(np.percentile(a, 25)),
        "p75": float(np.percentile(a, 75)),
        "min": float(a.min()),
        "max": float(a.max()),
    }


def bench_size(n: int, runs: int, uv_lattice: np.ndarray) -> dict[str, object]:
    rng = np.random.default_rng(1000 + n)
    pool = measure(rng.uniform(0.02, 0.98, size=(n - 1 + runs, 2)), seed=n)
    base = np.arange(n - 1)
    state = new_gp()
    state.fit(take(pool, base))
    hyper = state.hyper
    assert hyper is not None
    full = take(pool, np.arange(n))
    t0 = time.perf_counter()
    cold = new_gp().fit(full)
    cold_s = time.perf_counter() - t0
    fit_s, predict_s, decision_s, iters = [], [], [], []
    gp = new_gp()
    for r in range(runs):
        obs = take(pool, np.append(base, n - 1 + r))
        gp.set_hyper(hyper, take(pool, base))
        t0 = time.perf_counter()
        report = gp.fit(obs)
        t1 = time.perf_counter()
        pred = gp.predict(uv_lattice)
        t2 = time.perf_counter()
        assert pred.mean.shape == (len(uv_lattice),)
        fit_s.append(t1 - t0)
        predict_s.append(t2 - t1)
        decision_s.append(t2 - t0)
        iters.append(report.iterations)
    return {
        "n_centres": n,
        "runs": runs,
        "decision_s": quantiles(decision_s),
        "fit_s": quantiles(fit_s),
        "predict_s": quantiles(predict_s),
        "iterations_median": float(np.median(iters)),
        "cold_fit_s": cold_s,
        "cold_iterations": cold.iterations,
    }


def reference_predict(n: int, uv_lattice: np.ndarray) -> dict[str, float]:
    """gpytorch's default path (joint covariance of all candidates) against the Cholesky diagonal, once."""
    obs = measure(np.random.default_rng(7).uniform(0.02, 0.98, size=(n, 2)), seed=7)
    gp = new_gp()
    gp.fit(obs)
    t0 = time.perf_counter()
    pred = gp.predict(uv_lattice)
    ours_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    _, ref_var = gp.reference_latent(uv_lattice)
    ref_s = time.perf_counter() - t0
    diff = float(np.max(np.abs(pred.epistemic_sd**2 - ref_var)))
    return {"n_centres": n, "diagonal_s": ours_s, "gpytorch_default_s": ref_s, "max_abs_var_diff_gpa2": diff}


def markdown(result: dict[str, object]) -> str:
    rows = result["sizes"]
    assert isinstance(rows, list)
    lines = [
        f"Decision latency (warm refit + predict on {LATTICE_N}×{LATTICE_N} = {LATTICE_N**2:,} candidates), "
        f"torch threads = {result['threads']}, {result['runs']} runs per size, "
        f"load average {result['load_before']} before / {result['load_after']} after.",
        "",
        "| centres | decision median (s) | IQR (s) | fit median (s) | predict median (s) | L-BFGS iters | cold fit (s) |",
        "|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        d, f, p = r["decision_s"], r["fit_s"], r["predict_s"]
        lines.append(
            f"| {r['n_centres']} | {d['median']:.3f} | {d['p25']:.3f}–{d['p75']:.3f} | {f['median']:.3f} | "
            f"{p['median']:.3f} | {r['iterations_median']:.0f} | {r['cold_fit_s']:.3f} |"
        )
    ref = result.get("reference")
    if isinstance(ref, dict):
        lines += [
            "",
            f"gpytorch default predictive variance at {LATTICE_N**2:,} points ({ref['n_centres']} centres): "
            f"{ref['gpytorch_default_s']:.2f} s, against {ref['diagonal_s']:.3f} s for the Cholesky diagonal "
            f"(max |Δvar| = {ref['max_abs_var_diff_gpa2']:.1e} GPa²).",
        ]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=9)
    parser.add_argument("--threads", type=int, default=1, choices=[1, 2])
    parser.add_argument("--sizes", type=int, nargs="+", default=[25, 100, 400])
    parser.add_argument("--no-reference", action="store_true", help="skip gpytorch's slow default path")
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    if args.runs < 7:
        parser.error("--runs must be at least 7")
    global THREADS
    THREADS = args.threads
    uv_lattice = lattice(LATTICE_N)
    load_before = ", ".join(f"{x:.2f}" for x in os.getloadavg())
    new_gp().fit(measure(lattice(3), seed=0))  # warm-up: imports and first-call set-up
    sizes = [bench_size(n, args.runs, uv_lattice) for n in args.sizes]
    reference = None if args.no_reference else reference_predict(100, uv_lattice)
    result: dict[str, object] = {
        "benchmark": "decision_latency",
        "threads": args.threads,
        "runs": args.runs,
        "lattice": LATTICE_N**2,
        "torch": torch.__version__,
        "python": platform.python_version(),
        "cpus": os.cpu_count(),
        "load_before": load_before,
        "load_after": ", ".join(f"{x:.2f}" for x in os.getloadavg()),
        "sizes": sizes,
        "reference": reference,
    }
    text = markdown(result)
    print(text, end="")
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "decision_latency.json").write_text(json.dumps(result, indent=2) + "\n")
    (args.out / "decision_latency.md").write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

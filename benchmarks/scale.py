"""Large designs: warm decision, cold fit and peak memory of the surrogate at 1,000–20,000 tested centres,
and the interpolated (KISS-GP) model's map error against the exact GP's where both run.

Centres are uniform on the unit square, each measured as a 2×2 grid on the emulator's field (so the noise GP
runs on n spreads too: the heavier case). For each size, in a fresh process (peak memory = its max RSS):
the cold fit at n; then, from the state after n − 1 centres (set_hyper, as on resume), one more centre and a
decision = refit + the predictive diagonal at the 10,000 candidates of a 100 × 100 lattice, repeated on
different centres (median); for the interpolated GP also a decision that re-optimises its hyperparameters
(every 10 % of growth: core/model/fitting.py), reported beside the median. The model is the one the product
chooses at each n; ``--exact-up-to`` also times the exact GP at sizes up to that, in the same run.

    python benchmarks/scale.py --sizes 2000 10000 --out DIR     # DIR/scale.json and DIR/scale_detail.json

Map error: MAPE of each model's mean against the truth on the lattice, on the ternary, the film and two
robustness fields, per seed (``--map-seeds``), with the median and the worst seed per size and field. The exact
GP's fit takes minutes at 2,000 centres on a loaded machine (36 min of wall time for 61 s of CPU once), and a
change to the interpolated GP does not touch it: ``--exact-maps-from FILE`` reuses the exact GP's figures of an
earlier run, ``--reused-only`` skips the seeds that file lacks, ``--maps-only`` writes DIR/scale_maps.json alone.
"""

from __future__ import annotations

import argparse
import json
import platform
import resource
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from core.model import SKI_ABOVE, HeteroskedasticGP, Observations  # noqa: E402
from core.model.hyper import Hyperparameters  # noqa: E402

GRID_G = 2
PITCH_UV = 0.004
LATTICE_N = 100
DEFAULT_SIZES = (1000, 2000, 5000, 10000, 20000)
MAP_FIELDS = ("ternary", "film", "rotated", "edge-spot")  # the paper's two, two of the robustness suite


def lattice(n: int = LATTICE_N) -> np.ndarray:
    c = (np.arange(n) + 0.5) / n
    u, v = np.meshgrid(c, c)
    return np.column_stack([u.ravel(), v.ravel()])


def field_of(name: str) -> tuple[Any, tuple[float, float, float, float]]:
    from drivers.sim.robust_fields import ROBUST_FIELDS, robust_scenario
    from drivers.sim.scenarios import make_scenario

    key = {"rotated": "rotated-quaternary"}.get(name, name)
    sc = robust_scenario(name, 0) if name in ROBUST_FIELDS else make_scenario(key, 0)
    return sc.truth, sc.truth.bounds_um


def measure(name: str, n: int, seed: int) -> Observations:
    """n centres, each a 2×2 grid of indents on the field, collapsed to medians and spreads (vectorised)."""
    truth, (x0, x1, y0, y1) = field_of(name)
    rng = np.random.default_rng(seed)
    centres = rng.uniform(0.01, 0.99, size=(n, 2))
    off = (np.arange(GRID_G) - (GRID_G - 1) / 2) * PITCH_UV
    du, dv = (a.ravel() for a in np.meshgrid(off, off))
    uv = centres[:, None, :] + np.stack([du, dv], axis=1)[None, :, :]  # (n, g², 2)
    x_um = x0 + uv[..., 0] * (x1 - x0)
    y_um = y0 + uv[..., 1] * (y1 - y0)
    h = truth.hardness_gpa(x_um, y_um) + truth.noise_sd_gpa(x_um, y_um) * rng.standard_normal(x_um.shape)
    return Observations(
        uv=uv.mean(axis=1),
        median_gpa=np.median(h, axis=1),
        spread_var_gpa2=np.var(h, axis=1, ddof=1),
        n_indents=np.full(n, GRID_G * GRID_G),
    )


def truth_on_lattice(name: str) -> np.ndarray:
    truth, (x0, x1, y0, y1) = field_of(name)
    uv = lattice()
    return np.asarray(truth.hardness_gpa(x0 + uv[:, 0] * (x1 - x0), y0 + uv[:, 1] * (y1 - y0)))


def take(obs: Observations, k: int) -> Observations:
    return Observations(obs.uv[:k], obs.median_gpa[:k], obs.spread_var_gpa2[:k], obs.n_indents[:k])


def new_gp(model: str) -> HeteroskedasticGP:
    return HeteroskedasticGP(ski_above=1 if model == "ski" else 10**9)


def one(n: int, model: str, repeats: int, seed: int) -> dict[str, Any]:
    """The timings at one size in this (fresh) process."""
    pool = measure("ternary", n + repeats, seed)
    cand = lattice()
    obs = take(pool, n)
    gp = new_gp(model)
    t, c = time.perf_counter(), time.process_time()
    gp.fit(obs)
    cold, cold_cpu = time.perf_counter() - t, time.process_time() - c
    assert gp.model == model, (gp.model, model)
    record = gp.hyperparameters
    assert record is not None
    warm: list[float] = []
    warm_cpu: list[float] = []
    for r in range(repeats):
        base = take(pool, n - 1 + r)
        state = new_gp(model)
        state.set_hyper(record, base)
        t, c = time.perf_counter(), time.process_time()
        state.fit(take(pool, n + r))
        state.predict(cand)
        warm.append(time.perf_counter() - t)
        warm_cpu.append(time.process_time() - c)
    row: dict[str, Any] = {
        "n": n,
        "model": model,
        "warm_decision_s": float(np.median(warm)),
        "warm_decision_worst_s": float(np.max(warm)),
        "cold_fit_s": cold,
        # CPU seconds of this process: what the wall time would be on an idle core (the machine is shared)
        "warm_decision_cpu_s": float(np.median(warm_cpu)),
        "cold_fit_cpu_s": cold_cpu,
    }
    row.update(pricing(state, take(pool, n + repeats - 1), cand))
    if model == "ski":  # the decision that re-optimises (once per 10 % of growth)
        due = Hyperparameters(**{**record.__dict__, "fit_n": 1})
        state = new_gp(model)
        state.set_hyper(due, take(pool, n - 1))
        t = time.perf_counter()
        report = state.fit(obs)
        state.predict(cand)
        row["reoptimising_decision_s"] = time.perf_counter() - t
        row["reoptimising_iterations"] = report.iterations
    row["peak_mem_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    return row


def map_one(name: str, n: int, seed: int, model: str) -> dict[str, Any]:
    """One model's map error (MAPE against the truth on the lattice) on one field, size and seed."""
    obs = measure(name, n, seed)
    truth = truth_on_lattice(name)
    gp = new_gp(model)
    t, c = time.perf_counter(), time.process_time()
    gp.fit(obs)
    fit_s, fit_cpu_s = time.perf_counter() - t, time.process_time() - c
    mape = float(100 * np.mean(np.abs(gp.predict_mean(lattice()) - truth) / truth))
    return {
        "field": name,
        "n": n,
        "seed": seed,
        "model": model,
        "mape_pct": mape,
        "fit_s": fit_s,
        "fit_cpu_s": fit_cpu_s,
    }


def exact_maps_from(path: Path | None) -> dict[tuple[str, int, int], dict[str, Any]]:
    """Exact-GP map errors of an earlier run (its scale_detail.json): the exact GP's fit at 2,000 centres
    takes minutes, and a change to the interpolated GP does not touch it."""
    if path is None:
        return {}
    try:
        rows = json.loads(path.read_text())["map_error"]
        return {
            (r["field"], int(r["n"]), int(r["seed"])): {
                "field": r["field"],
                "n": int(r["n"]),
                "seed": int(r["seed"]),
                "model": "exact",
                "mape_pct": float(r["exact_mape_pct"]),
                "fit_s": float(r["exact_fit_s"]),
                "fit_cpu_s": r.get("exact_fit_cpu_s"),
            }
            for r in rows
        }
    except (OSError, ValueError, KeyError, TypeError) as exc:
        print(f"scale.py: --exact-maps-from {path}: not a file of map errors ({exc!r})", file=sys.stderr)
        raise SystemExit(2) from None


def in_child(args: list[str]) -> dict[str, Any]:
    proc = subprocess.run(
        [sys.executable, __file__, *args], capture_output=True, text=True, check=False, cwd=str(ROOT)
    )
    if proc.returncode != 0:
        raise SystemExit(f"scale.py child {args} failed:\n{proc.stderr[-2000:]}")
    return dict(json.loads(proc.stdout.strip().splitlines()[-1]))


def pricing(gp: HeteroskedasticGP, obs: Observations, cand: np.ndarray) -> dict[str, float]:
    """The planner's part of a decision: its posterior covariance (``PosteriorCov``, the model's own:
    exact or interpolated as the model is) between the reference lattice and the 10,000 candidates, and the
    information gain of each (as ``aeni`` prices a block), from the fitted model's state."""
    from core.policies.base import GPSummary
    from core.policies.variance import PosteriorCov, median_noise_var, reference_lattice

    hyper, scale = gp.hyperparameters, gp.outputscale_gpa2
    assert hyper is not None and scale is not None
    summary = GPSummary(hyper.kernel, hyper.lengthscales_uv, float(scale), gp.site_var_gpa2)
    ref = reference_lattice()
    t, c = time.perf_counter(), time.process_time()
    pred = gp.predict(np.vstack([obs.uv, ref]))
    n = len(obs.uv)
    noise_var = median_noise_var(pred.noise_sd[:n], obs.n_indents) + gp.site_var_gpa2
    w = 1.0 / np.maximum(np.abs(pred.mean[n:]), 1e-6) ** 2
    model = PosteriorCov.build(summary, obs.uv, noise_var, cand, ref, w)
    gain = model.gain(float(np.median(noise_var)))
    model.condition_on(int(np.argmax(gain)), float(np.median(noise_var)))  # one pick of a block
    return {"pricing_s": time.perf_counter() - t, "pricing_cpu_s": time.process_time() - c}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=list(DEFAULT_SIZES))
    ap.add_argument("--repeats", type=int, default=5, help="warm decisions per size (median)")
    ap.add_argument("--exact-up-to", type=int, default=2000, help="also time the exact GP up to this n")
    ap.add_argument("--map-sizes", type=int, nargs="*", default=None, help="map error at these n (both GPs)")
    ap.add_argument("--map-seeds", type=int, default=1, help="map error on seeds 0 .. this − 1")
    ap.add_argument(
        "--exact-maps-from",
        type=Path,
        default=None,
        help="reuse the exact GP's map errors of this earlier file",
    )
    ap.add_argument(
        "--reused-only",
        action="store_true",
        help="map errors only where --exact-maps-from has the exact GP's",
    )
    ap.add_argument("--maps-only", action="store_true", help="only the map errors (DIR/scale_maps.json)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results")
    ap.add_argument("--one", nargs=2, metavar=("N", "MODEL"), help=argparse.SUPPRESS)
    ap.add_argument("--map-one", nargs=4, metavar=("FIELD", "N", "SEED", "MODEL"), help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.one:
        print(json.dumps(one(int(a.one[0]), a.one[1], a.repeats, a.seed)))
        return 0
    if a.map_one:
        print(json.dumps(map_one(a.map_one[0], int(a.map_one[1]), int(a.map_one[2]), a.map_one[3])))
        return 0
    if any(n < 2 for n in a.sizes):
        print("scale.py: --sizes must be >= 2", file=sys.stderr)
        return 2
    a.out.mkdir(parents=True, exist_ok=True)
    chosen: list[dict[str, Any]] = []
    beside: list[dict[str, Any]] = []
    for n in [] if a.maps_only else a.sizes:
        model = "ski" if n > SKI_ABOVE else "exact"
        row = in_child(["--one", str(n), model, "--repeats", str(a.repeats), "--seed", str(a.seed)])
        chosen.append(row)
        print(_line(row), flush=True)
        other = "exact" if model == "ski" else "ski"
        if other == "ski" or n <= a.exact_up_to:
            row2 = in_child(["--one", str(n), other, "--repeats", str(a.repeats), "--seed", str(a.seed)])
            beside.append(row2)
            print(_line(row2) + "  (beside)", flush=True)
    map_sizes = [n for n in a.sizes if n <= a.exact_up_to] if a.map_sizes is None else a.map_sizes
    reuse = exact_maps_from(a.exact_maps_from)
    maps: list[dict[str, Any]] = []
    for n in map_sizes:
        for name in MAP_FIELDS:
            for s in range(a.map_seeds):
                if a.reused_only and (name, n, s) not in reuse:
                    continue
                ex = reuse.get((name, n, s)) or in_child(["--map-one", name, str(n), str(s), "exact"])
                sk = in_child(["--map-one", name, str(n), str(s), "ski"])
                m = {
                    "field": name,
                    "n": n,
                    "seed": s,
                    "exact_mape_pct": ex["mape_pct"],
                    "ski_mape_pct": sk["mape_pct"],
                    "relative_diff_pct": 100 * (sk["mape_pct"] / ex["mape_pct"] - 1.0),
                    "exact_fit_s": ex["fit_s"],
                    "exact_fit_cpu_s": ex["fit_cpu_s"],
                    "ski_fit_s": sk["fit_s"],
                    "ski_fit_cpu_s": sk["fit_cpu_s"],
                    "exact_reused": (name, n, s) in reuse,
                }
                maps.append(m)
                print(
                    f"map n={n:>6} {name:<10} seed {s}: exact {m['exact_mape_pct']:.3f} %  ski "
                    f"{m['ski_mape_pct']:.3f} %  ({m['relative_diff_pct']:+.1f} % relative)",
                    flush=True,
                )
                if a.maps_only:  # written as it goes: the exact fits at 2,000 take minutes each
                    (a.out / "scale_maps.json").write_text(json.dumps({"map_error": maps}, indent=1) + "\n")
    _map_table(maps)
    if a.maps_only:
        return 0
    keys = ("n", "model", "warm_decision_s", "cold_fit_s", "peak_mem_mb")
    (a.out / "scale.json").write_text(json.dumps([{k: r[k] for k in keys} for r in chosen], indent=1) + "\n")
    detail = {
        "machine": f"{platform.machine()} {platform.processor() or ''}".strip(),
        "ski_above": SKI_ABOVE,
        "chosen": chosen,
        "beside": beside,
        "map_error": maps,
    }
    (a.out / "scale_detail.json").write_text(json.dumps(detail, indent=1) + "\n")
    print()
    print(
        "| n | model | warm decision s (median / worst) | planner pricing s | re-optimising decision s"
        " | cold fit s | peak MB |"
    )
    print("| ---: | --- | ---: | ---: | ---: | ---: | ---: |")
    for r in sorted(chosen + beside, key=lambda r: (r["n"], r["model"])):
        mark = "" if r in chosen else " (beside)"
        reopt = f"{r['reoptimising_decision_s']:.2f}" if "reoptimising_decision_s" in r else "–"
        print(
            f"| {r['n']} | {r['model']}{mark} | {r['warm_decision_s']:.3f} / {r['warm_decision_worst_s']:.3f} "
            f"| {r.get('pricing_s', float('nan')):.2f} | {reopt} | {r['cold_fit_s']:.1f} | {r['peak_mem_mb']:.0f} |"
        )
    return 0


def _map_table(maps: list[dict[str, Any]]) -> None:
    """Per size and field: the median relative difference over the seeds and the worst seed's."""
    if not maps:
        return
    print()
    print(
        "| n | field | seeds | exact % (median) | ski % (median) | relative, median | relative, worst seed |"
    )
    print("| ---: | --- | ---: | ---: | ---: | ---: | ---: |")
    for n, name in dict.fromkeys((m["n"], m["field"]) for m in maps):
        rows = [m for m in maps if m["n"] == n and m["field"] == name]
        worst = max(rows, key=lambda m: m["relative_diff_pct"])
        print(
            f"| {n} | {name} | {len(rows)} | {np.median([m['exact_mape_pct'] for m in rows]):.3f} "
            f"| {np.median([m['ski_mape_pct'] for m in rows]):.3f} "
            f"| {np.median([m['relative_diff_pct'] for m in rows]):+.1f} % "
            f"| {worst['relative_diff_pct']:+.1f} % (seed {worst['seed']}) |"
        )


def _line(r: dict[str, Any]) -> str:
    return (
        f"n={r['n']:>6} {r['model']:<5} warm {r['warm_decision_s']:.3f} s (worst {r['warm_decision_worst_s']:.3f})"
        f"  cold {r['cold_fit_s']:.1f} s  pricing {r.get('pricing_s', float('nan')):.2f} s"
        f"  peak {r['peak_mem_mb']:.0f} MB"
    )


if __name__ == "__main__":
    raise SystemExit(main())

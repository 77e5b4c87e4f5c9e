"""How much does a fast survey help the CSM map, at what instrument time, and does the model see when it misleads?

For each case and seed: a fast survey of N indents (arrays of at most 1 mm, priced by core.fast_array from the
sample's centre) read through drivers/sim/fast_channel.py, and M single CSM indents at an 80 s hold on a
random design (priced by core.cost as one program, read by the scenario's emulator). The CSM map's MAPE on
the 100 × 100 scoring lattice, against the CSM truth, of the two-fidelity model (fast + M CSM) and of the
CSM-only GP on the same M CSM indents (the two-fidelity model's own CSM-only part: same data, same fit).

Cases: ``ternary`` and ``film`` (the fast channel as physics makes it: a size effect whose h* follows E/H);
``phase-boundary`` (misleading: h* jumps with the material, so the fast channel's bias jumps at the boundary);
``edge-spot-layer`` (misleading: a 1 µm surface layer over the edge spot, as hard as its surroundings, hides
the spot from the ~200 nm fast indents). For the misleading ones, the region of interest (ROI: within 60 µm of
the boundary; within 100 µm of the spot's centre) gets its own MAPE, mean epistemic sd and 2σ coverage.

    nice -n 10 .venv/bin/python benchmarks/two_fidelity_study.py --seeds 5
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from core.cost import price_sequence
from core.fast_array import FastArray, price_fast_array
from core.model.observations import Observations
from core.model.two_fidelity import TwoFidelityGP, fast_link_observations, fast_observations
from core.plan import Block, IndentSpec
from core.profile import InstrumentProfile, load_profile
from drivers.sim.emulator import (
    EdgeSpotField,
    PhaseBoundaryField,
    truth_modulus_gpa,
    truth_modulus_noise_sd_gpa,
)
from drivers.sim.fast_channel import CsmAtSites, FastPhysics, SurfaceLayer, read_array
from drivers.sim.scenarios import Scenario, make_scenario

CSM_HOLD_S = 80.0
CASES = {
    "ternary": "ternary",
    "film": "film",
    "phase-boundary": "phase-boundary",
    "edge-spot-layer": "edge-spot",
}
MISLEADING = ("phase-boundary", "edge-spot-layer")
TILE_UM = 1000.0  # the profile's fast.max_extent_um: one array per tile


@dataclass
class Survey:
    uv: np.ndarray
    hardness_gpa: np.ndarray
    modulus_gpa: np.ndarray
    time_s: float
    end_um: tuple[float, float]
    n_failed: int


def physics_for(case: str, scenario: Scenario, profile: InstrumentProfile) -> FastPhysics:
    assert profile.fast is not None
    if case == "edge-spot-layer":
        truth = scenario.truth
        assert isinstance(truth, EdgeSpotField)
        sx, sy = truth.spot_um
        # as hard as the ternary around the spot: the layer hides the spot, nothing else
        under = float(truth.hardness_gpa(sx, sy) - truth.spot_gpa(sx, sy))
        layer = SurfaceLayer((sx, sy), 2.5 * truth.radius_um, thickness_nm=1000.0, hardness_gpa=under)
        return FastPhysics(peak_load_mn=profile.fast.peak_load_mn, layer=layer)
    return FastPhysics(peak_load_mn=profile.fast.peak_load_mn)


def fast_survey(
    scenario: Scenario, profile: InstrumentProfile, physics: FastPhysics, n_fast: int, seed: int
) -> Survey:
    """Tiles of at most TILE_UM, each one array of k × k at the pitch that fills it (N ≈ tiles·k²)."""
    x0, x1, y0, y1 = scenario.calibration.bounds_um
    nx, ny = int(np.ceil((x1 - x0) / TILE_UM - 1e-9)), int(np.ceil((y1 - y0) / TILE_UM - 1e-9))
    k = max(2, round(float(np.sqrt(n_fast / (nx * ny)))))
    tile_w, tile_h = (x1 - x0) / nx, (y1 - y0) / ny
    pos = ((x0 + x1) / 2.0, (y0 + y1) / 2.0)
    time_s, program_open = 0.0, False
    uvs: list[np.ndarray] = []
    values: list[np.ndarray] = []
    moduli: list[np.ndarray] = []
    failed = 0
    truth = scenario.truth
    for j in range(ny):
        cols = range(nx) if j % 2 == 0 else range(nx - 1, -1, -1)
        for i in cols:
            pitch = min(tile_w, tile_h) / k
            array = FastArray(x0 + (i + 0.5) * tile_w, y0 + (j + 0.5) * tile_h, k, k, pitch)
            cost = price_fast_array(profile, array, pos, program_open)
            time_s += cost.total_s
            program_open = True
            sites = array.sites_um()
            sx, sy = sites[:, 0], sites[:, 1]
            csm = CsmAtSites(
                truth.hardness_gpa(sx, sy),
                truth.noise_sd_gpa(sx, sy),
                truth_modulus_gpa(truth, sx, sy),
                truth_modulus_noise_sd_gpa(truth, sx, sy),
            )
            r = read_array(physics, seed, len(uvs), sx, sy, csm)
            u, v = scenario.calibration.to_uv(sx, sy)
            uvs.append(np.column_stack([u, v]))
            values.append(r.hardness_gpa)
            moduli.append(r.modulus_gpa)
            failed += int(r.failed.sum())
            pos = (float(sites[-1, 0]), float(sites[-1, 1]))
    return Survey(np.vstack(uvs), np.concatenate(values), np.concatenate(moduli), time_s, pos, failed)


def csm_design(scenario: Scenario, m: int, seed: int) -> np.ndarray:
    """M random sites (stage µm), in rows of a snake so one program visits them without back-tracking."""
    rng = np.random.default_rng([seed, 36])
    uv = rng.random((m, 2))
    rows = np.floor(uv[:, 1] * max(1, int(np.sqrt(m) / 2)))
    key = np.where(rows % 2 == 0, uv[:, 0], -uv[:, 0])
    uv = uv[np.lexsort((key, rows))]
    x, y = scenario.calibration.to_stage(uv[:, 0], uv[:, 1])
    return np.column_stack([x, y])


def csm_indents(
    scenario: Scenario, profile: InstrumentProfile, sites: np.ndarray, start: tuple[float, float], open_: bool
) -> tuple[Observations, float]:
    block = Block(
        block_id=0,
        kind="global",
        center_x_um=float(sites[0, 0]),
        center_y_um=float(sites[0, 1]),
        grid_g=1,
        pitch_um=0.0,
        hold_s=CSM_HOLD_S,
        indents=tuple(IndentSpec(float(x), float(y), CSM_HOLD_S) for x, y in sites),
    )
    time_s = price_sequence(profile, [block], start, open_).total_s
    emulator = scenario.make_emulator(profile)
    values = np.array(
        [
            emulator.measure(float(x), float(y), CSM_HOLD_S, 1000.0 + 130.0 * i, 0, i).hardness_gpa
            for i, (x, y) in enumerate(sites)
        ]
    )
    u, v = scenario.calibration.to_uv(sites[:, 0], sites[:, 1])
    obs = Observations(
        uv=np.column_stack([u, v]),
        median_gpa=values,
        spread_var_gpa2=np.full(len(values), np.nan),
        n_indents=np.ones(len(values), dtype=np.int64),
    )
    return obs, time_s


def roi_mask(case: str, scenario: Scenario, xy: np.ndarray) -> np.ndarray | None:
    truth = scenario.truth
    if case == "phase-boundary":
        assert isinstance(truth, PhaseBoundaryField)
        return np.abs(truth.signed_distance_um(xy[:, 0], xy[:, 1])) < 60.0
    if case == "edge-spot-layer":
        assert isinstance(truth, EdgeSpotField)
        return np.hypot(xy[:, 0] - truth.spot_um[0], xy[:, 1] - truth.spot_um[1]) < 100.0
    return None


def mape(pred: np.ndarray, truth: np.ndarray) -> float:
    return float(100.0 * np.mean(np.abs(pred - truth) / truth))


def run_case(
    case: str, seed: int, n_fast_list: list[int], m_list: list[int], use_link: bool = True
) -> list[dict[str, object]]:
    scenario = make_scenario(CASES[case], seed)
    profile = load_profile(scenario.profile_name)
    physics = physics_for(case, scenario, profile)
    ev = scenario.evaluator(100)
    xy, truth_gpa = ev.xy_um, ev.truth_gpa
    u, v = scenario.calibration.to_uv(xy[:, 0], xy[:, 1])
    lattice_uv = np.column_stack([u, v])
    roi = roi_mask(case, scenario, xy)
    rows: list[dict[str, object]] = []
    for n_fast in n_fast_list:
        survey = fast_survey(scenario, profile, physics, n_fast, seed)
        fast = fast_observations(survey.uv, survey.hardness_gpa)
        link = (
            fast_link_observations(survey.uv, survey.hardness_gpa, survey.modulus_gpa) if use_link else None
        )
        model = TwoFidelityGP()
        for m in m_list:
            sites = csm_design(scenario, m, seed)
            obs, csm_after_fast_s = csm_indents(scenario, profile, sites, survey.end_um, True)
            centre = (
                (sites[:, 0].min() + sites[:, 0].max()) / 2,
                (sites[:, 1].min() + sites[:, 1].max()) / 2,
            )
            _, csm_alone_s = csm_indents(scenario, profile, sites, centre, False)
            t0 = time.perf_counter()
            report = model.fit(obs, fast, link)
            two = model.predict(lattice_uv)
            fit_s = time.perf_counter() - t0
            one = model.csm_gp.predict(lattice_uv)
            row: dict[str, object] = {
                "case": case,
                "seed": seed,
                "n_fast_requested": n_fast,
                "n_fast": int(np.isfinite(survey.hardness_gpa).sum()),
                "n_fast_failed": survey.n_failed,
                "fast_cells": fast.n,
                "m_csm": m,
                "mape_two_fidelity_pct": mape(two.mean, truth_gpa),
                "mape_csm_only_pct": mape(one.mean, truth_gpa),
                "fast_time_s": survey.time_s,
                "csm_time_s": csm_alone_s,
                "total_time_two_fidelity_s": survey.time_s + csm_after_fast_s,
                "rho_coef": report.rho_coef,
                "rho_link_coef": report.rho_link_coef,
                "link": use_link,
                "delta_share": report.delta_share,
                "delta_lengthscales_uv": report.delta_lengthscales_uv,
                "delta_collapse": report.collapse,
                "fit_predict_s": fit_s,
                "mean_epistemic_sd_two_gpa": float(two.epistemic_sd.mean()),
                "mean_epistemic_sd_csm_gpa": float(one.epistemic_sd.mean()),
            }
            if roi is not None:
                for name, pred in (("two", two), ("csm", one)):
                    z = np.abs(pred.mean - truth_gpa) / np.maximum(pred.epistemic_sd, 1e-12)
                    row[f"roi_mape_{name}_pct"] = mape(pred.mean[roi], truth_gpa[roi])
                    row[f"roi_sd_{name}_gpa"] = float(pred.epistemic_sd[roi].mean())
                    row[f"out_sd_{name}_gpa"] = float(pred.epistemic_sd[~roi].mean())
                    row[f"roi_cover2_{name}"] = float(np.mean(z[roi] < 2.0))
                    row[f"out_cover2_{name}"] = float(np.mean(z[~roi] < 2.0))
                bias = model.bias_gpa(lattice_uv)
                row["roi_abs_bias_gpa"] = float(np.abs(bias[roi]).mean())
                row["out_abs_bias_gpa"] = float(np.abs(bias[~roi]).mean())
            rows.append(row)
            shown = (
                "case",
                "seed",
                "n_fast",
                "m_csm",
                "mape_two_fidelity_pct",
                "mape_csm_only_pct",
                "fit_predict_s",
            )
            print(json.dumps({k: row[k] for k in shown}, default=float), flush=True)
    return rows


def add_equal_time(rows: list[dict[str, object]]) -> None:
    """Each row's CSM-only MAPE at the same instrument time: as many more CSM indents as the fast survey took
    (at the run's own seconds per CSM indent), on that seed's design of that size."""
    cache: dict[tuple[str, int, int], tuple[float, float]] = {}
    for row in rows:
        case, seed, m = str(row["case"]), int(str(row["seed"])), int(str(row["m_csm"]))
        per_indent_s = float(str(row["csm_time_s"])) / m
        m_eq = m + int(float(str(row["total_time_two_fidelity_s"])) - float(str(row["csm_time_s"]))) // int(
            per_indent_s
        )
        key = (case, seed, m_eq)
        if key not in cache:
            scenario = make_scenario(CASES[case], seed)
            profile = load_profile(scenario.profile_name)
            sites = csm_design(scenario, m_eq, seed)
            centre = (
                (sites[:, 0].min() + sites[:, 0].max()) / 2,
                (sites[:, 1].min() + sites[:, 1].max()) / 2,
            )
            obs, time_s = csm_indents(scenario, profile, sites, centre, False)
            ev = scenario.evaluator(100)
            u, v = scenario.calibration.to_uv(ev.xy_um[:, 0], ev.xy_um[:, 1])
            model = TwoFidelityGP()
            model.fit(obs, None)
            cache[key] = (mape(model.predict(np.column_stack([u, v])).mean, ev.truth_gpa), time_s)
        row["m_csm_equal_time"] = m_eq
        row["mape_csm_only_equal_time_pct"], row["csm_equal_time_s"] = cache[key]
        print(case, seed, m, "->", m_eq, f"{cache[key][0]:.3f} %", flush=True)


def _key(row: dict[str, object]) -> tuple[str, int, int]:
    return (str(row["case"]), int(str(row["n_fast_requested"])), int(str(row["m_csm"])))


def _equal_time_cells(sel: list[dict[str, object]]) -> str:
    if any("mape_csm_only_equal_time_pct" not in r for r in sel):
        return " | | |"
    eq = np.array([float(str(r["mape_csm_only_equal_time_pct"])) for r in sel])
    two = np.array([float(str(r["mape_two_fidelity_pct"])) for r in sel])
    m_eq = np.median([int(str(r["m_csm_equal_time"])) for r in sel])
    gain = eq / two
    return f" {m_eq:.0f} | {np.median(eq):.2f} | {np.median(gain):.2f}× / {gain.min():.2f}× |"


def summarise(rows: list[dict[str, object]]) -> str:
    def f(key: str, sel: list[dict[str, object]]) -> np.ndarray:
        return np.array([float(r[key]) for r in sel])  # type: ignore[arg-type]

    out = [
        "| case | N fast | M CSM | MAPE CSM-only % | MAPE two-fidelity % | gain (median) | gain (worst seed) |"
        " fast survey s | CSM s | δ share | M' CSM at equal time | MAPE CSM-only at equal time % |"
        " gain at equal time (median / worst) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    groups: dict[tuple[str, int, int], list[dict[str, object]]] = {}
    for r in rows:
        groups.setdefault(_key(r), []).append(r)
    for (case, n_fast, m), sel in sorted(groups.items()):
        gain = f("mape_csm_only_pct", sel) / f("mape_two_fidelity_pct", sel)
        out.append(
            f"| {case} | ~{n_fast:,} | {m} | {np.median(f('mape_csm_only_pct', sel)):.2f} | "
            f"{np.median(f('mape_two_fidelity_pct', sel)):.2f} | {np.median(gain):.2f}× | {gain.min():.2f}× | "
            f"{np.median(f('fast_time_s', sel)):,.0f} | {np.median(f('csm_time_s', sel)):,.0f} | "
            f"{np.median(f('delta_share', sel)):.3f} |" + _equal_time_cells(sel)
        )
    mis = [r for r in rows if "roi_mape_two_pct" in r]
    out.append("")
    out.append(
        "gain = MAPE CSM-only / MAPE two-fidelity per seed (median, and the worst seed); the two-fidelity run "
        "takes the fast survey's time on top. At equal time: the CSM-only GP given M' = M + (fast survey s / s "
        "per CSM indent) CSM indents instead."
    )
    if mis:
        out += [
            "",
            "Misleading cases, region of interest (ROI) against the rest (medians over seeds):",
            "",
            "| case | N fast | M CSM | ROI MAPE CSM-only % | ROI MAPE two-fid % | ROI sd / rest sd (two-fid) |"
            " ROI sd / rest sd (CSM-only) | ROI 2σ cover two-fid | ROI 2σ cover CSM-only | |bias| ROI / rest GPa |",
            "|---|---|---|---|---|---|---|---|---|---|",
        ]
        groups = {}
        for r in mis:
            groups.setdefault(_key(r), []).append(r)
        for (case, n_fast, m), sel in sorted(groups.items()):
            out.append(
                f"| {case} | ~{n_fast:,} | {m} | {np.median(f('roi_mape_csm_pct', sel)):.2f} | "
                f"{np.median(f('roi_mape_two_pct', sel)):.2f} | "
                f"{np.median(f('roi_sd_two_gpa', sel) / f('out_sd_two_gpa', sel)):.2f} | "
                f"{np.median(f('roi_sd_csm_gpa', sel) / f('out_sd_csm_gpa', sel)):.2f} | "
                f"{np.median(f('roi_cover2_two', sel)):.2f} | {np.median(f('roi_cover2_csm', sel)):.2f} | "
                f"{np.median(f('roi_abs_bias_gpa', sel)):.2f} / {np.median(f('out_abs_bias_gpa', sel)):.2f} |"
            )
    return "\n".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--n-fast", default="2500,10000")
    ap.add_argument("--m-csm", default="50,150")
    ap.add_argument("--out", default="benchmarks/results/two_fidelity_study")
    ap.add_argument("--no-link", action="store_true", help="ρ a plane only (the first version's model)")
    ap.add_argument(
        "--equal-time-from",
        help="a results JSON of this script: add the CSM-only MAPE at equal time, rewrite",
    )
    args = ap.parse_args()
    if args.equal_time_from:
        source = Path(args.equal_time_from)
        loaded: list[dict[str, object]] = json.loads(source.read_text(encoding="utf-8"))
        add_equal_time(loaded)
        table = summarise(loaded)
        print(table)
        source.write_text(json.dumps(loaded, indent=1, default=float), encoding="utf-8")
        md = source.with_suffix(".md")
        head = md.read_text(encoding="utf-8").split("\n\n")[0] if md.exists() else "# Two-fidelity study"
        md.write_text(f"{head}\n\n{table}\n", encoding="utf-8")
        return
    n_fast = [int(s) for s in args.n_fast.split(",")]
    m_csm = [int(s) for s in args.m_csm.split(",")]
    rows: list[dict[str, object]] = []
    t0 = time.perf_counter()
    for case in args.cases.split(","):
        for seed in range(args.seeds):
            ns = n_fast if case not in MISLEADING else n_fast[-1:]
            rows.extend(run_case(case, seed, ns, m_csm, use_link=not args.no_link))
    table = summarise(rows)
    print(table)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(rows, indent=1, default=float), encoding="utf-8")
    out.with_suffix(".md").write_text(
        f"# Two-fidelity study ({args.seeds} seeds, {time.perf_counter() - t0:,.0f} s wall)\n\n{table}\n",
        encoding="utf-8",
    )


if __name__ == "__main__":
    main()

"""The policy benchmark's runner: policies × scenarios × seeds on the emulator, each run composed from its RunSpec.

Protocol (the same for every policy, so the comparison is fair):

- For each scenario and seed the ``grid`` baseline runs first, in full. Its final MAPE is that seed's
  target and its instrument time the budget of every other policy on that scenario and seed.
- Every other policy runs on the same emulated sample (same seed: same noise draws per block and indent,
  same drift events) until it has reached the target and then run on for ``margin`` of the time it took
  (to show that it stays there), or until the budget or the block cap ends it.
- MAPE is measured after every refit, on the 100×100 truth lattice, from the GP mean. Speed-ups are
  paired per seed: reference time / policy time to reach the target, a run that never reaches it counting
  as infinitely slow. Medians and quartiles are over seeds.

Runs go to worker processes (joblib) with one torch thread each. ``core`` stays free of plotting: the
report (figures, RESULTS.md) is ``aeni_console.reports.bench``.
"""

from __future__ import annotations

import os
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from aeni_console.bench.catalogue import (
    GRID_REFIT_EVERY,
    MAP_DISPLAY_N,
    MAX_CENTRES,
    BenchConfig,
    BenchScenario,
)
from core.campaign_config import CampaignConfig
from core.errors import InputError
from core.plan import Block, IndentResult
from core.run.events import BlockStarted, Decided, Indent, Observed, RunEvent, Sink, Steps
from core.run.headless import RunTally, run_headless
from core.run.spec import RunSpec
from core.runconfig import make_campaign_config
from drivers.registry import DRIVERS
from drivers.sim.emulator import RoughField
from drivers.sim.evaluator import TruthEvaluator
from drivers.sim.robust_fields import ROBUST_FIELDS, robust_scenario
from drivers.sim.scenarios import make_scenario

if TYPE_CHECKING:
    from core.visits import OperatorCalendar


@dataclass(frozen=True)
class BenchRun:
    """One run of the bench's sweep: a policy on a scenario and seed, under the bench's protocol."""

    scenario: BenchScenario
    policy: str
    seed: int
    lattice_n: int
    truth_csv: str | None = None
    budget_s: float | None = None  # None: the grid baseline's time
    target_mape_pct: float | None = None  # None: the grid run that defines it
    margin: float = 0.25
    max_blocks: int = 350
    max_centres: int = MAX_CENTRES
    keep_maps: bool = False
    failure_rate: float = 0.0
    map_weights: dict[str, float] | None = None  # None: the default (both); modulus scored where aimed at
    target_mape_modulus_pct: float | None = None  # None: the grid run that defines it (or no modulus)
    calendar: OperatorCalendar | None = None


@dataclass
class RunRecord:
    scenario: str
    policy: str
    seed: int
    target_mape_pct: float | None
    t_hit_s: float | None  # instrument time at which MAPE first reached the target
    final_mape_pct: float | None
    max_found_gpa: float | None
    true_max_gpa: float
    instrument_s: float
    budget_s: float
    indents: int
    blocks: int
    reconfigurations: int
    ledger: dict[str, float]
    stop_reason: str
    wall_s: float
    trajectory: list[tuple[float, float]]  # (t_s, MAPE %)
    max_found: list[tuple[float, float]]  # (t_s, max true H among indented points)
    collapse_alarms: int = 0
    grid_sizes: dict[int, int] = field(default_factory=dict)
    fast_hold_blocks: int = 0
    local_blocks: int = 0
    peak_mape_after_hit_pct: float | None = None
    maps: dict[str, Any] | None = None  # seed-0 final maps for the report (not stored in results.json)
    interlock_refusals: int = 0  # blocks the interlock refused (the engine vetoed them and asked again)
    approvals: int = 0  # blocks that waited for an approval (none in the bench's auto supervision)
    failed_indents: int = 0  # indents the simulated instrument failed or never made (never learnt from)
    # the fast channel (issue 36): fast indents made (measured or failed) and the instrument time spent in fast
    # arrays (the ledger's steps of each: opening, moves, surface find, drift settle, indents); 0 for a CSM-only
    # run, None in a results.json written before they were recorded
    fast_indents: int | None = 0
    fast_array_s: float | None = 0.0
    # with map_weights (issue 27): the modulus map's target, final MAPE, trajectory and time to its target
    target_mape_modulus_pct: float | None = None
    final_mape_modulus_pct: float | None = None
    t_hit_modulus_s: float | None = None
    trajectory_modulus: list[tuple[float, float]] = field(default_factory=list)

    @property
    def t_hit_both_s(self) -> float | None:
        """When both maps had reached their targets (None if either never did)."""
        if self.t_hit_s is None or self.t_hit_modulus_s is None:
            return None
        return max(self.t_hit_s, self.t_hit_modulus_s)

    # with a calendar (--operator-hours ...): wall clock from the start to the target (the grid: its own final
    # MAPE) and the operator's visits by then; None: no calendar, or the target was never reached
    wall_clock_h: float | None = None
    operator_visits: int | None = None
    # the same to both maps' targets (the later of the two hits), where both are scored
    wall_clock_both_h: float | None = None
    operator_visits_both: int | None = None


# -- one run -------------------------------------------------------------------------------------------


def _set_threads() -> None:
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    import torch

    torch.set_num_threads(1)


def flat_mape_pct(sc: BenchScenario) -> float | None:
    """MAPE of the best constant map on a bench field (seed 0's truth): what a map that resolves nothing of
    the field scores, against which the grid's own final MAPE says how much of the field it resolves."""
    if sc.truth_csv is not None:
        return None

    sim = robust_scenario(sc.scenario, 0) if sc.scenario in ROBUST_FIELDS else make_scenario(sc.scenario, 0)
    return sim.evaluator().flat_mape_pct()


def bench_run_spec(spec: BenchRun) -> RunSpec:
    """The run a bench run is: its scenario (a robustness field is a sim scenario of its own), policy and
    seed on the emulator, auto supervision, the bench's budget and refit rhythm."""

    scen = spec.scenario
    cfg: CampaignConfig = make_campaign_config(
        f"bench-{scen.key}-{spec.policy}-{spec.seed}",
        policy=spec.policy,
        scenario=scen.scenario,
        truth_csv=spec.truth_csv,
        seed=spec.seed,
        lattice_n=spec.lattice_n,
        settings={"budget_s": spec.budget_s, "map_weights": spec.map_weights},
        failure_rate=spec.failure_rate or None,
    )
    return RunSpec(
        campaign=cfg,
        calendar=spec.calendar,
        refit_every=GRID_REFIT_EVERY if spec.policy == "grid" else 1,
    )


def run_one(spec: BenchRun) -> RunRecord:
    """One campaign under the bench protocol, composed and run as ``aeni simulate`` runs one
    (``core.run.headless.run_headless``): every block passes the interlock; refusals and approvals are
    counted."""
    _set_threads()

    start = time.monotonic()
    scen = spec.scenario
    is_grid = spec.policy == "grid"
    composed: list[tuple[Any, TruthEvaluator]] = []  # the campaign and its scorer, once composed
    max_found: list[tuple[float, float]] = []
    hit: list[float] = []  # the first time MAPE reached the target
    modulus: list[tuple[float, float]] = []  # (t_s, modulus MAPE %) after every refit, with map_weights
    hit_e: list[float] = []  # the first time the modulus MAPE reached its target
    peak_after: list[float] = []
    alarms = 0
    sizes: dict[int, int] = {}
    fast = local = 0
    top: float | None = None

    def parts() -> tuple[Any, TruthEvaluator]:
        return composed[0]

    class BlockWatch(RunTally):
        """The bench's per-block figures, folded from the run's events (a tally of its own)."""

        def __init__(self) -> None:
            super().__init__()
            self.block: dict[int, Block] = {}
            self.results: list[IndentResult] = []
            self.failed = 0  # indents the simulated instrument failed or never made
            self.fast_indents = 0
            self.fast_array_s = 0.0

        def emit(self, event: RunEvent) -> None:
            super().emit(event)
            if isinstance(event, Decided) and event.plan is not None:
                self.block[event.decision.block.block_id] = event.decision.block
            elif isinstance(event, BlockStarted):
                self.block[event.block.block_id] = event.block
            if isinstance(event, Indent | Steps):  # the ledger's steps of fast arrays: their time
                for step, _ in event.steps:
                    b = self.block.get(step.block_id)
                    self.fast_array_s += step.seconds if b is not None and b.channel == "fast" else 0.0
            if isinstance(event, Indent):
                self.results.append(event.result)
                self.failed += int(event.result.status != "measured")
                self.fast_indents += int(event.result.channel == "fast")
            elif isinstance(event, Observed):
                campaign, evaluator = parts()
                if campaign.settings.map_weights.maps_modulus and event.fit.fitted:  # scored where aimed at
                    mape_e = evaluator.score_modulus(campaign)
                    if mape_e is not None:
                        modulus.append((event.t_s, mape_e))
                        target_e = spec.target_mape_modulus_pct
                        if target_e is not None and not hit_e and mape_e <= target_e:
                            hit_e.append(event.t_s)
                self.observed(self.block[event.block_id], event.fit.collapse_alarm, event.t_s)
                self.results = []

        def observed(self, b: Block, collapse: bool, t_s: float) -> None:
            nonlocal alarms, fast, local, top
            campaign, evaluator = parts()
            sizes[b.grid_g] = sizes.get(b.grid_g, 0) + 1
            fast += int(b.hold_s < campaign.profile.default_hold_s)
            local += int(b.kind == "local")
            alarms += int(collapse)
            results = [r for r in self.results if r.status == "measured"]  # what the run learnt
            if results:
                h_true = evaluator.truth.hardness_gpa(
                    np.array([r.actual_x_um for r in results]), np.array([r.actual_y_um for r in results])
                )
                top = float(np.max(h_true)) if top is None else max(top, float(np.max(h_true)))
                max_found.append((t_s, top))
            if spec.target_mape_pct is not None and self.trajectory and self.trajectory[-1][0] == t_s:
                mape = self.trajectory[-1][1]
                if not hit and mape <= spec.target_mape_pct:
                    hit.append(t_s)
                elif hit:
                    peak_after.append(mape)

    def stop_when(res: RunTally) -> str | None:
        if spec.target_mape_modulus_pct is not None:  # both maps: run on past the later of the two hits
            if hit and hit_e and res.instrument_s >= max(hit[0], hit_e[0]) * (1.0 + spec.margin):
                return (
                    f"reached both target MAPEs at {max(hit[0], hit_e[0]):,.0f} s and ran on "
                    f"{100 * spec.margin:.0f} %"
                )
        elif hit and res.instrument_s >= hit[0] * (1.0 + spec.margin):
            return f"reached the target MAPE at {hit[0]:,.0f} s and ran on {100 * spec.margin:.0f} %"
        if res.blocks >= spec.max_blocks:
            return f"block cap ({spec.max_blocks} blocks)"
        if len(parts()[0].centres) >= spec.max_centres and not is_grid:
            return f"centre cap ({spec.max_centres} tested centres)"
        return None

    watch = BlockWatch()

    def sinks(campaign: Any, evaluator: Any) -> list[Sink]:
        assert isinstance(evaluator, TruthEvaluator)  # the simulated instrument's
        composed.append((campaign, evaluator))
        return [watch]

    result, run = run_headless(bench_run_spec(spec), DRIVERS, sinks=sinks, stop_when=stop_when)
    campaign, evaluator = parts()
    budget = float(campaign.settings.budget_s or campaign.grid_baseline_s)
    operator = run.visits
    trajectory = list(result.trajectory)
    if (
        is_grid
        and (not trajectory or trajectory[-1][0] < result.instrument_s - 1.0)
        and len(campaign.centres) >= 2
    ):
        campaign.surrogate.fit(campaign.observations())
        mape = evaluator.score(campaign).mape_pct
        if mape is not None:
            trajectory.append((result.instrument_s, mape))
    final = evaluator.score(campaign).mape_pct
    t_hit: float | None = hit[0] if hit else None
    if is_grid and final is not None:
        t_hit = next(t for t, m in trajectory if m <= final)
    final_e: float | None = None
    t_hit_e: float | None = hit_e[0] if hit_e else None
    if (
        campaign.settings.map_weights.maps_modulus
    ):  # the modulus map is scored wherever the planner aims at it
        if (
            is_grid
            and (not modulus or modulus[-1][0] < result.instrument_s - 1.0)
            and campaign.modulus_map.n >= 2
        ):
            campaign.modulus_map.fit(
                campaign.calibration.to_uv
            )  # the grid's final modulus map on all its indents
            mape_e = evaluator.score_modulus(campaign)
            if mape_e is not None:
                modulus.append((result.instrument_s, mape_e))
        final_e = modulus[-1][1] if modulus else None
        if is_grid and final_e is not None:
            t_hit_e = next(t for t, m in modulus if m <= final_e)
    wall_h: float | None = None
    visits: int | None = None
    if operator is not None and t_hit is not None:
        wall = operator.wall_at(t_hit)
        wall_h = None if wall is None else wall / 3600.0
        visits = operator.visits_at(t_hit)
    wall_both_h: float | None = None
    visits_both: int | None = None
    if operator is not None and t_hit is not None and t_hit_e is not None:
        wall_both = operator.wall_at(max(t_hit, t_hit_e))
        wall_both_h = None if wall_both is None else wall_both / 3600.0
        visits_both = operator.visits_at(max(t_hit, t_hit_e))
    h = evaluator.truth_gpa
    maps = _maps(campaign) if spec.keep_maps and campaign.prediction is not None else None
    return RunRecord(
        scenario=scen.key,
        policy=spec.policy,
        seed=spec.seed,
        target_mape_pct=final if is_grid else spec.target_mape_pct,
        t_hit_s=t_hit,
        final_mape_pct=final,
        max_found_gpa=top,
        true_max_gpa=float(h.max()),
        instrument_s=result.instrument_s,
        budget_s=budget,
        indents=result.indents,
        blocks=result.blocks,
        reconfigurations=result.ledger.reconfigurations,
        ledger=result.ledger.as_dict(),
        stop_reason=result.stop_reason,
        interlock_refusals=result.refusals,
        approvals=result.approvals,
        failed_indents=watch.failed,
        fast_indents=watch.fast_indents,
        fast_array_s=watch.fast_array_s,
        wall_s=time.monotonic() - start,
        trajectory=trajectory,
        max_found=max_found,
        collapse_alarms=alarms,
        grid_sizes=sizes,
        fast_hold_blocks=fast,
        local_blocks=local,
        peak_mape_after_hit_pct=max(peak_after) if peak_after else None,
        maps=maps,
        target_mape_modulus_pct=final_e if is_grid else spec.target_mape_modulus_pct,
        final_mape_modulus_pct=final_e,
        t_hit_modulus_s=t_hit_e,
        trajectory_modulus=modulus,
        wall_clock_h=wall_h,
        operator_visits=visits,
        wall_clock_both_h=wall_both_h,
        operator_visits_both=visits_both,
    )


def _maps(campaign: Any) -> dict[str, Any]:
    f = campaign.map_fields(0, MAP_DISPLAY_N)
    centres = np.array([(c.x_um, c.y_um) for c in campaign.centres])
    kind_of = {b.block_id: b.kind for b in campaign.blocks}
    kinds = [kind_of.get(c.block_id, "global") for c in campaign.centres]  # singles: one centre per indent
    return {
        "x_um": np.asarray(f.x_um),
        "y_um": np.asarray(f.y_um),
        "mean": np.asarray(f.mean_gpa),
        "epistemic_sd": np.asarray(f.epistemic_sd_gpa),
        "noise_sd": np.asarray(f.noise_sd_gpa),
        "total_sd": np.asarray(f.total_sd_gpa),
        "centres_um": centres,
        "local": np.array([k == "local" for k in kinds]),
        "reverse_x": bool(campaign.profile.reverse_x),
    }


# -- the whole bench -----------------------------------------------------------------------------------


def write_truth_csv(
    path: Path, x_um: np.ndarray, y_um: np.ndarray, hardness_gpa: np.ndarray, noise_sd_gpa: np.ndarray
) -> Path:
    """A truth as a CSV lattice (what a user would load with ``--truth``): one row per point."""
    lines = ["x_um,y_um,hardness_gpa,noise_sd_gpa"]
    lines += [
        f"{x:.3f},{y:.3f},{hv:.6f},{sv:.6f}"
        for x, y, hv, sv in zip(
            np.ravel(x_um), np.ravel(y_um), np.ravel(hardness_gpa), np.ravel(noise_sd_gpa), strict=True
        )
    ]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def write_rough_truth(path: Path, seed: int = 11, n: int = 101) -> Path:
    """A rough real-looking map as a CSV lattice."""

    field_ = RoughField(seed=seed)
    xs = np.linspace(0.0, field_.side_um, n)
    gx, gy = np.meshgrid(xs, xs)
    return write_truth_csv(path, gx, gy, field_.hardness_gpa(gx, gy), field_.noise_sd_gpa(gx, gy))


def _parallel(
    specs: Sequence[BenchRun],
    jobs: int,
    progress: Callable[[RunRecord], None] | None,
    dask_address: str | None = None,
) -> list[RunRecord]:
    if dask_address is None and jobs <= 1:
        out = []
        for s in specs:
            r = run_one(s)
            if progress is not None:
                progress(r)
            out.append(r)
        return out
    import joblib
    from joblib import Parallel, delayed

    # slowest first, so the pool does not end waiting on one long run
    order = sorted(range(len(specs)), key=lambda i: -_expected_cost(specs[i]))
    results: dict[int, RunRecord] = {}
    if dask_address is not None:
        # the same sweep on a Dask cluster, through joblib's Dask backend (the `dask` extra)
        client = _dask_client(dask_address)
        try:
            with joblib.parallel_config(backend="dask"):
                tagged = Parallel(n_jobs=-1, return_as="generator_unordered")(
                    delayed(_run_tagged)(i, specs[i]) for i in order
                )
                for i, rec in tagged:
                    results[i] = rec
                    if progress is not None:
                        progress(rec)
        finally:
            client.close()
        return [results[i] for i in range(len(specs))]
    runner = Parallel(n_jobs=jobs, backend="loky", return_as="generator_unordered")
    with warnings.catch_warnings():
        # loky takes a worker's memory after its first run as the reference and replaces the worker when a
        # later run leaves it 300 MB above: a long `aeni` run's high-water mark does (a grid run 485 MB, then
        # an `aeni` run 672 MB, 584 MB after gc and the same after another, in one process): a restart, not
        # a leak, and its "worker stopped ... memory leak" warning on every bench told the user nothing
        warnings.filterwarnings(
            "ignore", message="A worker stopped while some jobs were given to the executor"
        )
        tagged = runner(delayed(_run_tagged)(i, specs[i]) for i in order)
        for i, rec in tagged:
            results[i] = rec
            if progress is not None:
                progress(rec)
    return [results[i] for i in range(len(specs))]


def _dask_client(address: str) -> Any:
    try:
        from distributed import Client
    except ImportError:
        raise InputError(
            "--dask", "needs the dask extra: pip install -e '.[dask]' (dask and distributed)"
        ) from None
    try:
        return Client(address, timeout="10s")
    except (OSError, TimeoutError, ValueError) as exc:
        raise InputError("--dask", f"cannot reach the scheduler at {address!r} ({exc})") from None


def _run_tagged(i: int, spec: BenchRun) -> tuple[int, RunRecord]:
    return i, run_one(spec)


def _expected_cost(spec: BenchRun) -> float:
    return {"grid": 0.4, "uncertainty": 0.6, "cost-aware": 0.8, "adaptive-grid": 0.8, "aeni": 2.0}.get(
        spec.policy, 1.5
    )


def run_bench(
    config: BenchConfig,
    work_dir: Path,
    progress: Callable[[RunRecord], None] | None = None,
    dask_address: str | None = None,
) -> list[RunRecord]:
    """Grid baselines first (they set each seed's target and budget), then every other policy.

    ``work_dir`` receives the files that runs read (the rough truth CSV); nothing is written elsewhere.
    """
    if config.seeds < 1:
        raise InputError("--seeds", f"must be at least 1, got {config.seeds}")
    if config.jobs < 1:
        raise InputError("--jobs", f"must be at least 1, got {config.jobs}")
    work_dir.mkdir(parents=True, exist_ok=True)
    csv_paths: dict[str, str] = {}
    for sc in config.scenarios:
        if sc.truth_csv is not None:
            csv_paths[sc.key] = str(write_rough_truth(work_dir / sc.truth_csv))
    seeds = range(config.seeds)

    def spec(sc: BenchScenario, policy: str, seed: int, **kw: Any) -> BenchRun:
        return BenchRun(
            scenario=sc,
            policy=policy,
            seed=seed,
            lattice_n=config.lattice_n,
            truth_csv=csv_paths.get(sc.key),
            margin=config.margin if sc.margin is None else sc.margin,
            max_blocks=config.max_blocks,
            max_centres=config.max_centres,
            keep_maps=seed == 0 and policy in sc.maps_for,
            failure_rate=config.failure_rate,
            map_weights=config.map_weights,
            calendar=config.calendar,
            **kw,
        )

    def seeds_of(sc: BenchScenario) -> range:
        return seeds if sc.max_seeds is None else range(min(config.seeds, sc.max_seeds))

    grids = _parallel(
        [spec(sc, "grid", s) for sc in config.scenarios for s in seeds_of(sc)],
        config.jobs,
        progress,
        dask_address,
    )
    by_key = {(r.scenario, r.seed): r for r in grids}
    rest = [
        spec(
            sc,
            p,
            s,
            budget_s=by_key[(sc.key, s)].instrument_s,
            target_mape_pct=by_key[(sc.key, s)].final_mape_pct,
            target_mape_modulus_pct=by_key[(sc.key, s)].final_mape_modulus_pct,
        )
        for sc in config.scenarios
        for p in sc.policies
        if p != "grid"
        for s in seeds_of(sc)
    ]
    return grids + _parallel(rest, config.jobs, progress, dask_address)

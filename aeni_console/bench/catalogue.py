"""The bench's catalogue: its scenarios (paper fields, provocations, the robustness suite, scale) and its
configuration (seeds, lattice, margin, caps, failures, the operator's calendar).

The protocol (aeni_console.bench.runner) runs it; the report is aeni_console.reports.bench.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

from core.errors import InputError
from core.policies.registry import policy_names, policy_parts
from drivers.sim.failures import REALISTIC_FAILURE_RATE

if TYPE_CHECKING:
    from core.visits import OperatorCalendar

MAX_CENTRES = 2000
GRID_REFIT_EVERY = 9  # the grid baseline never looks at the model: fit it once per row of blocks
MAP_DISPLAY_N = 50


@dataclass(frozen=True)
class BenchScenario:
    key: str  # label in tables and figures
    scenario: str  # an emulator scenario name, or a robustness field of drivers.sim.robust_fields
    title: str
    policies: tuple[str, ...]
    group: str = "paper"  # "paper", "provocation" (drift, collapse), "robustness" (not tuned on) or "scale"
    truth_csv: str | None = None  # for scenario "csv": written by the bench into the output folder
    maps_for: tuple[str, ...] = ()  # policies whose final maps (seed 0) are drawn
    margin: float | None = None  # run-on after the target for this scenario (None: the bench's)
    max_seeds: int | None = None  # at most this many of the bench's seeds (None: all of them)


def _all_policies() -> tuple[str, ...]:

    return policy_names()


# the paper's references that every field is scored against, and the recommended policy
CORE = ("grid", "uncertainty", "aeni-paper", "aeni")


SUITE_SEEDS = 5  # the robustness suite and every provocation: median and worst of 5 seeds


def _robust(key: str, title: str, scenario: str | None = None, **kw: Any) -> BenchScenario:
    return BenchScenario(
        key,
        scenario or key,
        title,
        _all_policies(),
        group="robustness",
        max_seeds=SUITE_SEEDS,
        **kw,
    )


FULL_SCENARIOS: tuple[BenchScenario, ...] = (
    BenchScenario(
        "ternary",
        "ternary",
        "Ternary library, heteroskedastic noise (paper Figs 3, 6)",
        _all_policies(),
        maps_for=("uncertainty", "aeni-paper", "aeni"),
    ),
    BenchScenario(
        "film",
        "film",
        "Quaternary film, film profile with the 520 s jump, good drift (paper Figs 7, 8)",
        _all_policies(),
        maps_for=("aeni-paper", "aeni"),
        # the targets are medians of 10 seeds, the film's among them: its noise (7–10 % per indent)
        # makes one seed's time to the grid's MAPE vary more than 3× with the same policy
    ),
    BenchScenario(
        "good-drift",
        "ternary-good-drift",
        "Provocation: ternary library, good drift (paper Fig 5)",
        ("grid", "aeni-paper", "aeni"),
        group="provocation",
        max_seeds=SUITE_SEEDS,
    ),
    BenchScenario(
        "bad-drift",
        "ternary-bad-drift",
        "Provocation: ternary library, bad drift (paper Fig 5)",
        ("grid", "aeni-paper", "aeni"),
        group="provocation",
        max_seeds=SUITE_SEEDS,
    ),
    BenchScenario(
        "collapse",
        "collapse",
        "Provocation: length-scale collapse (indent-scale texture a tight grid shares)",
        _all_policies(),
        group="provocation",
        max_seeds=SUITE_SEEDS,
        maps_for=("aeni-paper", "aeni"),
        margin=2.0,  # divergence shows after the target: run on for twice the time it took
    ),
    _robust("phase-boundary", "Sharp curved phase boundary"),
    _robust("edge-spot", "Small hot spot near an edge"),
    _robust("rotated", "Rotated quaternary gradient", "rotated-quaternary"),
    _robust("grains", "Multiphase grain texture, 20–60 µm grains", maps_for=("aeni",)),
    _robust("step", "Step discontinuity"),
    _robust("stripe", "Nearly flat film with one narrow stripe", maps_for=("aeni",)),
    _robust("phase-noise", "Noise tied to one phase (8 % against 1 %)"),
    _robust("outliers", "Outliers: 5 % of indents on pores read 50 % low"),
)
# rough map loaded with --truth: `aeni bench --scenarios rough-csv` (not in the default sweep, which fits in 45 min);
# the 50 mm wafer library with fast indents: thousands of centres, the interpolated GP (core/model/ski.py)
EXTRA_SCENARIOS: tuple[BenchScenario, ...] = (
    _robust("rough-csv", "Rough real-looking map loaded with --truth", "csv", truth_csv="rough_truth.csv"),
    BenchScenario(
        "wafer",
        "wafer-library",
        "Large design: 50 × 50 mm ternary library, 200 × 200 lattice, NanoBlitz-class indents",
        ("grid", "aeni"),
        group="scale",
        max_seeds=2,
    ),
)
QUICK_SCENARIOS: tuple[BenchScenario, ...] = (
    BenchScenario(
        "ternary",
        "ternary",
        "Ternary library, heteroskedastic noise (quick)",
        ("grid", "uncertainty", "cost-aware", "aeni-paper", "aeni"),
        maps_for=("aeni",),
    ),
)


@dataclass(frozen=True)
class BenchConfig:
    quick: bool = False
    seeds: int = 10
    jobs: int = 2
    lattice_n: int = 50  # candidate lattice per side (the product default is 100 on the 1000 µm square)
    margin: float = 0.1  # after reaching the target, run on for this fraction of the time it took
    max_blocks: int = 350
    # tested centres a run may reach: a model of single indents that has not reached the target by then grows
    # too slow to fit (O(n³)); replicate-grid policies stay far below it
    max_centres: int = MAX_CENTRES
    scenarios: tuple[BenchScenario, ...] = FULL_SCENARIOS
    # the simulated instrument fails like a real one (drivers.sim.failures); 0: never
    failure_rate: float = REALISTIC_FAILURE_RATE
    # the planner's [planner] map_weights (issue 27); None: the product's default (both maps, issue 37). The
    # modulus map is scored wherever the planner aims at it
    map_weights: dict[str, float] | None = None
    calendar: OperatorCalendar | None = (
        None  # a simulated operator loads the blocks (core.visits); None: none
    )

    @classmethod
    def make(
        cls,
        quick: bool,
        seeds: int | None = None,
        jobs: int = 2,
        only: str | None = None,
        policies: str | None = None,
    ) -> BenchConfig:
        """``only``: a comma-separated subset of the scenario keys (an unknown key is an error);
        ``policies``: only these policies (and the grid, which sets every target) on each scenario."""
        config = cls._make(quick, seeds, jobs)
        if only is not None:
            keys = [k.strip() for k in only.split(",") if k.strip()]
            known = {s.key: s for s in (*config.scenarios, *([] if quick else EXTRA_SCENARIOS))}
            unknown = [k for k in keys if k not in known]
            if unknown or not keys:
                raise InputError(
                    "--scenarios",
                    f"unknown scenario key(s) {', '.join(unknown) or '(none given)'} (known: {', '.join(known)})",
                )
            config = replace(config, scenarios=tuple(known[k] for k in dict.fromkeys(keys)))
        if policies is None:
            return config

        keep = list(dict.fromkeys(p.strip() for p in policies.split(",") if p.strip()))
        for p in keep:
            try:
                policy_parts(p)
            except InputError as exc:
                raise InputError("--policies", exc.problem) from None
        # a named policy runs where the scenario runs it; an ablation (BASE+modifier) runs on every scenario
        ablations = tuple(p for p in keep if p not in policy_names())
        return replace(
            config,
            scenarios=tuple(
                replace(sc, policies=(*(p for p in sc.policies if p == "grid" or p in keep), *ablations))
                for sc in config.scenarios
            ),
        )

    @classmethod
    def _make(cls, quick: bool, seeds: int | None, jobs: int) -> BenchConfig:
        if quick:
            return cls(
                quick=True,
                seeds=2 if seeds is None else seeds,
                jobs=jobs,
                lattice_n=30,
                margin=0.0,
                max_blocks=250,
                scenarios=QUICK_SCENARIOS,
            )
        return cls(quick=False, seeds=10 if seeds is None else seeds, jobs=jobs)

"""Policies by name: the one table the CLI, the run file, the console, the bench and its report read (the
names and their descriptions alone are :mod:`core.policies.names`, light enough for ``aeni --help``).

``aeni`` is the recommended policy and the default everywhere. The paper's policies stay as references, each
idea measurable against the one before it (``adaptive-grid`` and ``meta-grid`` against ``uncertainty``,
``adaptive-hold`` against ``cost-aware``, ``aeni-paper`` against ``grid`` and ``uncertainty``).

Anything else is an ablation: a base name followed by ``+modifier``s, each of which changes one setting of
one part (``aeni-paper+huber+bias-hold+drift-corr`` is the paper's workflow with Huber centre values, the
bias-aware hold and drift-corrected fast indents). Ablations are not policies a user is asked to choose from.

``aeni`` reads the run instead (:func:`run_recipe`, the one home of those rules): with an operator calendar it
plans every load to the operator's next visit (stretches); where the profile's program change is dearer than
its own itemised steps, it prices a program over its life. The ablations ``+attended`` and ``+first-block``
turn each rule off, for the bench.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

from core.errors import InputError
from core.policies.acquisition import (
    CostWeighted,
    EdgePenalised,
    IntegratedVarianceReduction,
    LatticeSubset,
    UncertaintyExploration,
)
from core.policies.blocks import ReplicateGrid, ScatteredSingles
from core.policies.fidelity import FastArrays, TwoFidelityPlanner
from core.policies.grid import GridPolicy
from core.policies.guard import CollapseGuard
from core.policies.hold import HoldRule
from core.policies.names import POLICY_DESCRIPTIONS, RECOMMENDED, policy_names
from core.policies.noise import NoiseModel
from core.policies.parts import PolicyParts
from core.policies.planner import BayesPlanner
from core.policies.scattered import ScatteredPlanner

if TYPE_CHECKING:
    from core.policies.base import Policy
    from core.profile import InstrumentProfile

BENDS_WEIGHT = 1.0  # aeni+bends: curvature weight (core.policies.bends), measured in docs/benchmarks.md
_PAPER_GRID = ReplicateGrid(adaptive_grid=True, local_hop_um=500.0, exploratory_iterations=4)


def _parts() -> dict[str, PolicyParts]:
    fixed = ReplicateGrid()
    return {
        "aeni": PolicyParts(
            noise=NoiseModel(drift_correction=True, outliers="student-t"),
            acquisition=CostWeighted(IntegratedVarianceReduction(LatticeSubset(), structure_weight=1.0)),
            blocks=ScatteredSingles(),
            hold=HoldRule(adaptive=True, bias_aware=True),
            guard=CollapseGuard(yield_to_confirmed=True),
        ),
        "uncertainty": PolicyParts(acquisition=UncertaintyExploration(), blocks=replace(fixed, stay=False)),
        "cost-aware": PolicyParts(blocks=fixed),
        "adaptive-grid": PolicyParts(blocks=ReplicateGrid(stay=False, adaptive_grid=True)),
        "meta-grid": PolicyParts(blocks=ReplicateGrid(adaptive_grid=True, local_hop_um=500.0)),
        "adaptive-hold": PolicyParts(blocks=fixed, hold=HoldRule(adaptive=True)),
        "aeni-paper": PolicyParts(
            acquisition=CostWeighted(EdgePenalised(UncertaintyExploration())),
            blocks=_PAPER_GRID,
            hold=HoldRule(adaptive=True),
        ),
    }


def _grid(parts: PolicyParts, **changes: object) -> PolicyParts:
    if not isinstance(parts.blocks, ReplicateGrid):
        raise InputError("--policy", "this modifier changes replicate grids, and the base has none")
    return replace(parts, blocks=replace(parts.blocks, **changes))  # type: ignore[arg-type]


# one setting of one part each; applied left to right after the base name
MODIFIERS: dict[str, tuple[str, Callable[[PolicyParts], PolicyParts]]] = {
    "drift-corr": (
        "fast indents drift-corrected by Eq. 7 (noise model)",
        lambda p: replace(p, noise=replace(p.noise, drift_correction=True)),
    ),
    "huber": (
        "Huber centre values instead of the median (noise model)",
        lambda p: replace(p, noise=replace(p.noise, centre_estimator="huber")),
    ),
    "gaussian": (
        "no outlier rule: every value trusted as the noise model says (noise model)",
        lambda p: replace(p, noise=replace(p.noise, outliers="none")),
    ),
    "bias-hold": (
        "fast hold only where its bias is small against the aimed precision (hold rule)",
        lambda p: replace(p, hold=replace(p.hold, bias_aware=True)),
    ),
    "nugget": (
        "the GP learns a site-to-site variance (surrogate)",
        lambda p: replace(p, surrogate=replace(p.surrogate, nugget=True)),
    ),
    "ivr": (
        "integrated variance reduction, programs planned jointly (acquisition, block design)",
        lambda p: _grid(
            replace(p, acquisition=CostWeighted(IntegratedVarianceReduction())), joint_program=True
        ),
    ),
    "tight": (
        "many tight 2×2 local grids from the first program on (block design)",
        lambda p: _grid(
            p, exploratory_iterations=0, adaptive_grid=False, fixed_g=2, local_hop_um=60.0, local_limit=20
        ),
    ),
    "unguarded": (
        "no length-scale floor, prior or keep-last-good (collapse guard)",
        lambda p: replace(p, guard=CollapseGuard(keep_last_good=False, floor=False)),
    ),
    "strict-guard": (
        "keep-last-good even where a cold search on 1.5× more data confirms the drop (collapse guard)",
        lambda p: replace(p, guard=replace(p.guard, yield_to_confirmed=False)),
    ),
    "attended": (
        "no stretches even with a calendar: every load planned as if someone were always there (block design)",
        lambda p: _singles(p, stretch_min_s=None),
    ),
    "first-block": (
        "a new program's overhead charged to its first block, even where the profile's program change is "
        "dear (block design)",
        lambda p: _singles(p, program_life=False),
    ),
    "stretch": (
        "before an absence (the next load runs unattended > 3 h) one stretch of arrays fills it (block design)",
        lambda p: _singles(p, stretch_min_s=3 * 3600.0),
    ),
    "stretch-visits": (
        "every load is a stretch that fills the time to the operator's next visit (block design)",
        lambda p: _singles(p, stretch_min_s=0.0),
    ),
    "program-life": (
        "a new program's overhead priced over the indents it will serve, not its first block (block design)",
        lambda p: _singles(p, program_life=True),
    ),
    "bends": (
        "more indents where the fitted map bends (its relative curvature), the bias a stationary GP leaves "
        "there (acquisition)",
        lambda p: _ivr(p, bend_weight=BENDS_WEIGHT),
    ),
    "fast": (
        "fast (NanoBlitz-class) arrays priced beside the CSM blocks, learnt by the two-fidelity model "
        "(block design; the profile's [fast] mode)",
        lambda p: replace(_singles(p), fast=FastArrays()),
    ),
    "even": (
        "no weighting to the map's structure: pure variance reduction (acquisition)",
        lambda p: _ivr(p, structure_weight=0.0),
    ),
}


@dataclass(frozen=True)
class RunFacts:
    """What ``aeni`` reads off the run before it plans (the run file, the profile, the operator)."""

    # the run knows when its operator is there: an [operator] section, a simulated operator or an away-until
    has_calendar: bool = False
    # a new program's fixed seconds as the profile prices them (what a global jump pays) ...
    program_change_s: float = 0.0
    # ... and the same program's itemised steps (comeback, setup, lens travel, lift, engage, drift settle)
    program_steps_s: float = 0.0

    @classmethod
    def of(cls, profile: InstrumentProfile, has_calendar: bool = False) -> RunFacts:
        return cls(has_calendar, profile.global_overhead_s, profile.itemised_program_s)

    @property
    def dear_program_change(self) -> bool:
        """The profile prices a program change above its own itemised steps (the real-film workflow's 520 s
        against 470 s): measured on the film, pricing a program over its life pays there (4.49× against
        3.41×, 10 seeds) and costs on the ternary's itemised profile (docs/benchmarks.md)."""
        return self.program_change_s > self.program_steps_s + 1e-9


def run_recipe(parts: PolicyParts, facts: RunFacts) -> PolicyParts:
    """``aeni`` as the run asks: the one home of the rules that key on the run (measured in docs/RESULTS.md).

    - a calendar: every load is a stretch that fills the time to the operator's next visit (ternary, 10 seeds:
      16.9 h and 4 visits to the grid's MAPE against 27.0 h and 29 visits planned as if always attended);
    - a dear program change (:attr:`RunFacts.dear_program_change`): its overhead priced over its life.
    Parts other than scattered singles are returned as they are.
    """
    if not isinstance(parts.blocks, ScatteredSingles):
        return parts
    changes: dict[str, object] = {}
    if facts.has_calendar:
        changes["stretch_min_s"] = 0.0
    if facts.dear_program_change:
        changes["program_life"] = True
    return _singles(parts, **changes) if changes else parts


def _singles(parts: PolicyParts, **changes: object) -> PolicyParts:
    if not isinstance(parts.blocks, ScatteredSingles):
        raise InputError("--policy", "this modifier changes scattered singles, and the base has none")
    return replace(parts, blocks=replace(parts.blocks, **changes))  # type: ignore[arg-type]


def _ivr(parts: PolicyParts, **changes: object) -> PolicyParts:
    """One weight of the base's variance reduction changed (the same wrappers around it)."""
    acq = parts.acquisition
    if not isinstance(acq, CostWeighted) or not isinstance(acq.base, IntegratedVarianceReduction):
        raise InputError(
            "--policy", "this modifier changes variance reduction, and the base ranks by another"
        )
    return replace(parts, acquisition=CostWeighted(replace(acq.base, **changes)))  # type: ignore[arg-type]


def describe(name: str) -> str:
    """One line for a policy or an ablation (tables, the report)."""
    base, *mods = name.split("+")
    text = POLICY_DESCRIPTIONS.get(base, base)
    return text if not mods else f"{base} with " + "; ".join(MODIFIERS[m][0] for m in mods if m in MODIFIERS)


def policy_parts(name: str, facts: RunFacts | None = None) -> PolicyParts:
    """The parts of a policy or an ablation ``BASE+modifier+...`` on a run with these ``facts`` (``aeni``
    reads them first, :func:`run_recipe`; None: a run with none of them); an unknown name is a one-line error."""
    base, *mods = name.split("+")
    table = _parts()
    if base == "grid" and not mods:
        return PolicyParts()
    if base not in table:
        raise InputError("--policy", f"unknown policy {base!r} (known: {', '.join(policy_names())})")
    parts = table[base]
    if base == RECOMMENDED and facts is not None:
        parts = run_recipe(parts, facts)
    for m in mods:
        if m not in MODIFIERS:
            raise InputError(
                "--policy", f"unknown modifier {m!r} in {name!r} (known: {', '.join(MODIFIERS)})"
            )
        parts = MODIFIERS[m][1](parts)
    return parts


def make_policy(name: str, facts: RunFacts | None = None) -> Policy:

    parts = policy_parts(name, facts)
    if name == "grid":
        return GridPolicy()
    if isinstance(parts.blocks, ScatteredSingles):
        if parts.fast is not None:
            return TwoFidelityPlanner(name, parts, ScatteredPlanner(name, parts), parts.fast)
        return ScatteredPlanner(name, parts)
    return BayesPlanner(name, parts)

"""Policies by name, as the CLI, the config and the bench select them.

Each paper idea has its own name so that its contribution can be measured against its reference:
``adaptive-grid`` and ``meta-grid`` against ``uncertainty`` (fixed 5×5 grids, a new program every block),
``adaptive-hold`` against ``cost-aware`` (fixed 80 s) and ``adaptive-hold-corrected`` against
``adaptive-hold``, ``aeni`` against ``grid`` and ``uncertainty``;
``aeni-plus`` is the same workflow with the improvements of this product (``aeni-ivr`` adds the
variance-reduction planner to it); ``aeni-tight`` and ``aeni-unguarded`` are the pair that the length-scale
collapse provocation compares (the same tight planner with and without the guard).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from core.errors import InputError

if TYPE_CHECKING:
    from core.policies.base import Policy
    from core.policies.planner import PlannerFeatures

POLICY_DESCRIPTIONS: dict[str, str] = {
    "grid": "fixed 9×9 blocks of 5×5 (the paper's baseline)",
    "uncertainty": "jump to the highest-σ centre after every block, fixed 5×5, cost ignored",
    "cost-aware": "σ/cost with staying engaged priced against a global jump, fixed 5×5",
    "adaptive-grid": "σ/cost, a new program every block, grid size 2×2…5×5 from the noise and the target SEM",
    "meta-grid": "adaptive grid + sub-grids ≤ 500 µm apart in the safe band, stay-vs-jump after each",
    "adaptive-hold": "cost-aware with a drift-aware 5 s / 80 s hold and the g²·(80 − 5) switch rule",
    "adaptive-hold-corrected": "adaptive-hold whose fast indents are drift-corrected by Eq. 7 (measured drift rate)",
    "aeni": "the paper's real-film workflow: seeds, exploratory phase, meta-grid, adaptive grid and hold",
    "aeni-bias-hold": "aeni with the bias-aware hold of aeni-plus only (ablation: that improvement alone)",
    "aeni-plus": "aeni with Huber centre values, the bias-aware hold and drift-corrected fast indents",
    "aeni-nugget": "aeni-plus whose GP learns a site-to-site variance: for indent-scale heterogeneity",
    "aeni-ivr": "aeni-plus with variance-reduction acquisition and jointly planned programs (ablation)",
    "aeni-tight": "ablation: aeni with tight 2×2 local grids and no exploratory phase, guard on",
    "aeni-unguarded": "ablation: aeni-tight with no length-scale floor, prior or collapse guard",
}


def _features() -> dict[str, PlannerFeatures]:
    from core.policies.planner import PlannerFeatures

    aeni = PlannerFeatures(
        cost_aware=True,
        stay=True,
        adaptive_grid=True,
        adaptive_hold=True,
        edge_penalty=True,
        local_hop_um=500.0,
        exploratory_iterations=4,
        exploratory_local_limit=1,
    )
    from dataclasses import replace

    # what this product adds to the paper's workflow, each measured on its own in the bench
    plus = replace(aeni, centre_estimator="huber", bias_aware_hold=True, drift_correction=True)
    # the collapse provocation's planner: many tight local grids from the first program on
    tight = replace(
        aeni, exploratory_iterations=0, adaptive_grid=False, fixed_g=2, local_hop_um=60.0, local_limit=20
    )
    return {
        "uncertainty": PlannerFeatures(cost_aware=False, stay=False),
        "cost-aware": PlannerFeatures(cost_aware=True, stay=True),
        "adaptive-grid": PlannerFeatures(cost_aware=True, stay=False, adaptive_grid=True),
        "meta-grid": PlannerFeatures(cost_aware=True, stay=True, adaptive_grid=True, local_hop_um=500.0),
        "adaptive-hold": PlannerFeatures(cost_aware=True, stay=True, adaptive_hold=True),
        "adaptive-hold-corrected": PlannerFeatures(
            cost_aware=True, stay=True, adaptive_hold=True, drift_correction=True
        ),
        "aeni": aeni,
        "aeni-bias-hold": replace(aeni, bias_aware_hold=True),
        "aeni-plus": plus,
        "aeni-nugget": replace(plus, surrogate_nugget=True),
        "aeni-ivr": replace(plus, acquisition="ivr", edge_penalty=False, joint_program=True),
        "aeni-tight": tight,
        "aeni-unguarded": replace(tight, surrogate_guard="off", surrogate_floor=False),
    }


def policy_names() -> tuple[str, ...]:
    return tuple(POLICY_DESCRIPTIONS)


def make_policy(name: str) -> Policy:
    from core.policies.grid import GridPolicy
    from core.policies.planner import BayesPlanner

    if name == "grid":
        return GridPolicy()
    features = _features()
    if name in features:
        return BayesPlanner(name, features[name])
    raise InputError("--policy", f"unknown policy {name!r} (known: {', '.join(policy_names())})")

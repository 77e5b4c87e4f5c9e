"""Policies by name, as the CLI, the config and the bench select them."""

from __future__ import annotations

from core.errors import InputError
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from core.policies.base import Policy
    from core.policies.planner import PlannerFeatures

POLICY_DESCRIPTIONS: dict[str, str] = {
    "grid": "fixed 9×9 blocks of 5×5 (the paper's baseline)",
    "uncertainty": "jump to the highest-σ centre after every block, fixed 5×5, cost ignored",
    "cost-aware": "σ/cost with staying engaged priced against a global jump, fixed 5×5",
}

def _features() -> dict[str, PlannerFeatures]:
    from core.policies.planner import PlannerFeatures

    return {
        "uncertainty": PlannerFeatures(cost_aware=False),
        "cost-aware": PlannerFeatures(cost_aware=True),
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

"""Which hold settings a policy honours, and the refusal of those it would ignore without a word.

It is a fact of the policy's parts (its hold rule), so it lives beside the registry that composes them; the
settings' own rules (``core.settings``) know no policy and import no planner.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Literal

from core.errors import InputError
from core.policies.registry import policy_parts


def policy_hold(policy: str) -> Literal["policy", "fixed", "either"]:
    """Which hold settings a planning policy honours: ``policy`` (it chooses every hold from the drift, so
    neither hold_policy nor fixed_hold_s is in force), ``fixed`` (always fixed_hold_s: the grid) or
    ``either`` (hold_policy picks fixed or adaptive)."""

    if policy == "grid":
        return "fixed"
    try:
        adaptive = policy_parts(policy).hold.adaptive
    except InputError:
        return "either"  # an unknown policy is refused where it is named
    return "policy" if adaptive else "either"


def check_hold_in_force(policy: str, given: Mapping[str, Any], source: str = "planner") -> None:
    """Refuse hold settings the policy would ignore without a word (InputError naming the setting).

    ``given`` holds only the settings the user set (a run file's [planner], an adjust command).
    """
    honours = policy_hold(policy)
    where = f"{source}." if source else ""
    if honours == "policy":
        for name in ("hold_policy", "fixed_hold_s"):
            value = given.get(name)
            if value is not None and not (name == "hold_policy" and value == "adaptive"):
                raise InputError(
                    f"{where}{name}",
                    f"{value!r} is not honoured by policy {policy!r}: it chooses every hold from the measured "
                    "drift (leave hold_policy and fixed_hold_s out, or choose a policy with a fixed hold, "
                    "e.g. cost-aware)",
                )
    if honours == "fixed" and given.get("hold_policy") == "adaptive":
        raise InputError(
            f"{where}hold_policy",
            f"'adaptive' is not honoured by policy {policy!r}: its holds are always fixed_hold_s "
            "(choose adaptive-hold or aeni for holds from the drift)",
        )

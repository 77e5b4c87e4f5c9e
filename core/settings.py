"""Validated operator adjustments of the planner settings (the console's adjust form, the engine's adjust command)."""

from __future__ import annotations

import math
from dataclasses import fields, replace
from typing import Any

from core.errors import InputError
from core.plan import PlannerSettings

HOLD_POLICIES = ("fixed", "adaptive")

_RULES: dict[str, tuple[str, str]] = {
    # field: (kind, what is allowed)
    "target_sem_gpa": ("pos", "a number > 0 (GPa)"),
    "beta": ("nonneg", "a number ≥ 0"),
    "hold_policy": ("choice", "fixed or adaptive"),
    "fixed_hold_s": ("hold", "one of the profile's holds"),
    "local_center_limit": ("int0_20", "a whole number from 0 to 20"),
    "edge_penalty": ("unit", "a number from 0 to 0.95"),
    "budget_s": ("pos_or_none", "a number > 0 (s) or empty"),
    "indent_budget": ("posint_or_none", "a whole number > 0 or empty"),
    "sigma_target_gpa": ("pos_or_none", "a number > 0 (GPa) or empty"),
    "mape_target_pct": ("pos_or_none", "a number > 0 (%) or empty"),
}
ADJUSTABLE: tuple[str, ...] = tuple(_RULES)


def _bad(name: str, value: Any) -> InputError:
    return InputError(name, f"{value!r} is not allowed: expected {_RULES[name][1]}")


def _num(name: str, value: Any) -> float:
    if isinstance(value, bool):
        raise _bad(name, value)
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise _bad(name, value) from None
    if not math.isfinite(x):
        raise _bad(name, value)
    return x


def coerce_setting(name: str, value: Any, allowed_holds_s: tuple[float, ...] = (0.0, 5.0, 80.0)) -> Any:
    if name not in _RULES:
        raise InputError(name, f"is not an adjustable setting (adjustable: {', '.join(ADJUSTABLE)})")
    kind = _RULES[name][0]
    if kind.endswith("_or_none") and (value is None or (isinstance(value, str) and not value.strip())):
        return None
    if kind == "choice":
        if value not in HOLD_POLICIES:
            raise _bad(name, value)
        return value
    x = _num(name, value)
    if kind in ("pos", "pos_or_none") and x <= 0:
        raise _bad(name, value)
    if kind == "nonneg" and x < 0:
        raise _bad(name, value)
    if kind == "unit" and not 0.0 <= x <= 0.95:
        raise _bad(name, value)
    if kind in ("int0_20", "posint_or_none"):
        if x != int(x) or (kind == "int0_20" and not 0 <= x <= 20) or (kind == "posint_or_none" and x < 1):
            raise _bad(name, value)
        return int(x)
    if kind == "hold" and not any(math.isclose(x, h) for h in allowed_holds_s):
        holds = ", ".join(f"{h:g}" for h in allowed_holds_s)
        raise InputError(name, f"{value!r} is not allowed: expected one of {holds} s")
    return x


def adjust_settings(
    settings: PlannerSettings, changes: dict[str, Any], allowed_holds_s: tuple[float, ...] = (0.0, 5.0, 80.0)
) -> PlannerSettings:
    """A new PlannerSettings with ``changes`` applied; InputError naming the first bad field."""
    clean = {name: coerce_setting(name, value, allowed_holds_s) for name, value in changes.items()}
    return replace(settings, **clean)


def settings_to_dict(settings: PlannerSettings) -> dict[str, Any]:
    out = {f.name: getattr(settings, f.name) for f in fields(settings)}
    out["avoid_centers_um"] = [list(p) for p in settings.avoid_centers_um]
    return out


def settings_from_dict(data: dict[str, Any]) -> PlannerSettings:
    d = dict(data)
    d["avoid_centers_um"] = tuple(tuple(p) for p in d.get("avoid_centers_um", ()))
    return PlannerSettings(**d)

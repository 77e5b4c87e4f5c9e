"""The one home of the planner settings' rules, and the one codec that reads and writes them.

Every way a setting enters a run goes through :func:`coerce_setting`: the run file's ``[planner]``
section, ``aeni send adjust`` (before it queues anything), the console's adjust form and the engine's
adjust command. The journal and the run file read settings back through :func:`settings_from_dict`.
The allowed holds are the instrument profile's; where no profile is known yet (the run file is read
before the campaign picks its profile) a hold is checked as a number and again when the campaign
starts.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields, replace
from typing import Any, Literal

from core.errors import InputError
from core.plan import MAPS, MapWeights, PlannerSettings
from core.run.machine import SUPERVISION_MODES

HOLD_POLICIES: tuple[str, ...] = ("fixed", "adaptive")
# what an approval nobody answered within approval_timeout_s does (a collapse alarm or a refused block: never approve)
ON_TIMEOUT: tuple[str, ...] = ("approve", "veto", "pause", "stop")

RuleKind = Literal["number", "whole", "choice", "hold", "clock"]


@dataclass(frozen=True)
class SettingRule:
    """What one adjustable knob may hold; the adjust form takes its labels and limits from here."""

    name: str
    label: str
    kind: RuleKind
    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False  # the lower bound itself is not allowed
    optional: bool = False  # None (or an empty text) means "none": budgets and targets
    choices: tuple[str, ...] = ()
    unit: str = ""

    def allowed(self, allowed_holds_s: Sequence[float] | None = None) -> str:
        """What is allowed, in words (the second half of every error message)."""
        if self.kind == "choice":
            text = " or ".join(self.choices)
        elif self.kind == "clock":
            text = 'a local time "HH:MM" (24 h)'
        elif self.kind == "hold":
            if allowed_holds_s is None:
                text = "a number ≥ 0 (s) that is one of the instrument profile's holds"
            else:
                text = "one of " + ", ".join(f"{h:g}" for h in allowed_holds_s) + " s (the profile's holds)"
        else:
            what = "a whole number" if self.kind == "whole" else "a number"
            if self.lo is not None and self.hi is not None:
                text = f"{what} from {self.lo:g} to {self.hi:g}"
            elif self.lo is not None:
                text = f"{what} {'>' if self.lo_open else '≥'} {self.lo:g}"
            else:
                text = what
            if self.unit:
                text += f" ({self.unit})"
        return text + (" or empty" if self.optional else "")


RULES: tuple[SettingRule, ...] = (
    SettingRule("target_sem_gpa", "target SEM (GPa)", "number", lo=0.0, lo_open=True, unit="GPa"),
    SettingRule("beta", "UCB β", "number", lo=0.0),
    SettingRule("hold_policy", "hold policy", "choice", choices=HOLD_POLICIES),
    SettingRule("fixed_hold_s", "fixed hold (s)", "hold"),
    SettingRule("local_center_limit", "local centres", "whole", lo=0, hi=20),
    SettingRule("edge_penalty", "edge penalty", "number", lo=0.0, hi=0.95),
    SettingRule("budget_s", "time budget (s)", "number", lo=0.0, lo_open=True, optional=True, unit="s"),
    SettingRule("indent_budget", "indent budget", "whole", lo=1, optional=True),
    SettingRule(
        "sigma_target_gpa", "σ target (GPa)", "number", lo=0.0, lo_open=True, optional=True, unit="GPa"
    ),
    SettingRule(
        "mape_target_pct", "MAPE target (%)", "number", lo=0.0, lo_open=True, optional=True, unit="%"
    ),
)
# stopping rules a real sample can use: set in the run file's [planner] table or by ``aeni send adjust``
# (not in the console's adjust form, which shows RULES)
STOP_RULES: tuple[SettingRule, ...] = (
    SettingRule("stop_at", "stop at (local time)", "clock", optional=True),
    SettingRule(
        "stop_rel_sd_pct",
        "stop at relative sd (%)",
        "number",
        lo=0.0,
        lo_open=True,
        hi=100.0,
        optional=True,
        unit="%",
    ),
)
RULE_BY_NAME: dict[str, SettingRule] = {r.name: r for r in RULES + STOP_RULES}
ADJUSTABLE: tuple[str, ...] = tuple(RULE_BY_NAME)


def _bad(rule: SettingRule, value: Any, allowed_holds_s: Sequence[float] | None) -> InputError:
    return InputError(rule.name, f"{value!r} is not allowed: expected {rule.allowed(allowed_holds_s)}")


def _number(rule: SettingRule, value: Any, allowed_holds_s: Sequence[float] | None) -> float:
    if isinstance(value, bool):
        raise _bad(rule, value, allowed_holds_s)
    try:
        x = float(value.strip() if isinstance(value, str) else value)
    except (TypeError, ValueError):
        raise _bad(rule, value, allowed_holds_s) from None
    if not math.isfinite(x):
        raise _bad(rule, value, allowed_holds_s)
    return x


def coerce_setting(name: str, value: Any, allowed_holds_s: Sequence[float] | None) -> Any:
    """The clean value of one setting (text from a form or a flag is parsed); InputError naming it if not allowed.

    ``allowed_holds_s`` is the instrument profile's list; None where the profile is not known yet.
    """
    rule = RULE_BY_NAME.get(name)
    if rule is None:
        raise InputError(name, f"is not an adjustable setting (adjustable: {', '.join(ADJUSTABLE)})")
    if rule.optional and (value is None or (isinstance(value, str) and not value.strip())):
        return None
    if rule.kind == "choice":
        if value not in rule.choices:
            raise _bad(rule, value, allowed_holds_s)
        return value
    if rule.kind == "clock":
        return _clock(rule, value)
    x = _number(rule, value, allowed_holds_s)
    if rule.kind == "hold":
        ok = x >= 0 if allowed_holds_s is None else any(math.isclose(x, h) for h in allowed_holds_s)
        if not ok:
            raise _bad(rule, value, allowed_holds_s)
        return x
    too_low = rule.lo is not None and (x < rule.lo or (rule.lo_open and x == rule.lo))
    too_high = rule.hi is not None and x > rule.hi
    if too_low or too_high or (rule.kind == "whole" and x != int(x)):
        raise _bad(rule, value, allowed_holds_s)
    return int(x) if rule.kind == "whole" else x


def _clock(rule: SettingRule, value: Any) -> str:
    """A local wall-clock time "HH:MM", normalised to two digits each."""
    hh, sep, mm = value.strip().partition(":") if isinstance(value, str) else ("", "", "")
    if not (sep and hh.isdigit() and mm.isdigit() and len(mm) == 2 and len(hh) <= 2):
        raise _bad(rule, value, None)
    h, m = int(hh), int(mm)
    if not (0 <= h <= 23 and 0 <= m <= 59):
        raise _bad(rule, value, None)
    return f"{h:02d}:{m:02d}"


def coerce_supervision(value: Any) -> str:
    """A supervision mode (the adjust command may switch it); InputError otherwise."""
    if value not in SUPERVISION_MODES:
        raise InputError("supervision", f"{value!r} is not allowed: expected {', '.join(SUPERVISION_MODES)}")
    return str(value)


def check_adjust(changes: Mapping[str, Any], allowed_holds_s: Sequence[float] | None) -> dict[str, Any]:
    """An adjust command's payload, cleaned: settings by their rules, plus an optional supervision mode.

    What ``aeni send adjust`` checks before it queues, and what the engine applies.
    """
    if not changes:
        raise InputError("adjust", "nothing to adjust")
    return {
        k: coerce_supervision(v) if k == "supervision" else coerce_setting(k, v, allowed_holds_s)
        for k, v in changes.items()
    }


def check_veto(payload: Mapping[str, Any]) -> int | None:
    """A veto's ``hold_blocks`` (how many blocks to avoid the vetoed centre), or None for the default.

    What ``aeni send veto`` checks before it queues, and what the engine applies.
    """
    hold = payload.get("hold_blocks")
    if hold is not None and (isinstance(hold, bool) or not isinstance(hold, int) or hold < 1):
        raise InputError("hold_blocks", f"{hold!r} is not allowed: expected a whole number ≥ 1")
    return hold


def adjust_settings(
    settings: PlannerSettings, changes: Mapping[str, Any], allowed_holds_s: Sequence[float] | None
) -> PlannerSettings:
    """A new PlannerSettings with ``changes`` applied; InputError naming the first bad field."""
    clean = {name: coerce_setting(name, value, allowed_holds_s) for name, value in changes.items()}
    return replace(settings, **clean)


def check_holds(settings: PlannerSettings, allowed_holds_s: Sequence[float], source: str = "planner") -> None:
    """Once the profile is known: the fixed hold must be one of its holds (InputError ``source.fixed_hold_s``)."""
    if settings.fixed_hold_s is None:
        return
    try:
        coerce_setting("fixed_hold_s", settings.fixed_hold_s, allowed_holds_s)
    except InputError as exc:
        raise InputError(f"{source}.fixed_hold_s", exc.problem) from None


# --------------------------------------------------------------------------------------------------
# the codec: what the journal stores and what a run file's [planner] table holds

_FIELDS = tuple(f.name for f in fields(PlannerSettings))


def settings_to_dict(settings: PlannerSettings) -> dict[str, Any]:
    out = {name: getattr(settings, name) for name in _FIELDS}
    out["avoid_centers_um"] = [list(p) for p in settings.avoid_centers_um]
    out["map_weights"] = {name: getattr(settings.map_weights, name) for name in MAPS}
    return out


def _map_weights(value: Any) -> MapWeights:
    """``{ hardness = 1.0, modulus = 1.0 }``: a table of the maps' weights (a missing map keeps its default)."""
    if not isinstance(value, Mapping):
        raise InputError(
            "map_weights",
            f"{value!r} is not allowed: expected a table such as {{ hardness = 1.0, modulus = 1.0 }}",
        )
    unknown = sorted(set(value) - set(MAPS))
    if unknown:
        raise InputError(
            "map_weights", f"unknown map(s) {', '.join(map(repr, unknown))} (known: {', '.join(MAPS)})"
        )
    clean: dict[str, float] = {}
    for name, w in value.items():
        if isinstance(w, bool) or not isinstance(w, int | float) or not math.isfinite(w) or w < 0:
            raise InputError(f"map_weights.{name}", f"{w!r} is not allowed: expected a number ≥ 0")
        clean[name] = float(w)
    try:
        return MapWeights(**clean)
    except ValueError as exc:
        raise InputError("map_weights", str(exc).removeprefix("map_weights: ")) from None


def _avoid(value: Any) -> tuple[tuple[float, float], ...]:
    try:
        pts = tuple((float(x), float(y)) for x, y in value)
    except (TypeError, ValueError):
        raise InputError(
            "avoid_centers_um", f"{value!r} is not allowed: expected a list of [x, y] pairs in µm"
        ) from None
    if not all(math.isfinite(c) for p in pts for c in p):
        raise InputError("avoid_centers_um", f"{value!r} is not allowed: coordinates must be finite")
    return pts


def settings_from_dict(
    data: Mapping[str, Any], allowed_holds_s: Sequence[float] | None = None
) -> PlannerSettings:
    """PlannerSettings from a stored or written table, every field through its rule; missing fields take
    the defaults. InputError naming the field for an unknown field or a bad value."""
    clean: dict[str, Any] = {}
    for name, value in data.items():
        if name == "avoid_centers_um":
            clean[name] = _avoid(value)
        elif name == "map_weights":
            clean[name] = _map_weights(value)
        elif name == "fixed_hold_s" and value is None:
            clean[name] = None  # not chosen: the profile's default hold
        elif name in RULE_BY_NAME:
            clean[name] = coerce_setting(name, value, allowed_holds_s)
        else:
            raise InputError(name, f"is not a planner setting (allowed: {', '.join(_FIELDS)})")
    return PlannerSettings(**clean)

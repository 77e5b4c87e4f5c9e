"""The adjust form: edit the planner's settings, checked by the engine's own validator before anything is sent.

Every field goes through ``core.settings.coerce_setting`` with the run's instrument holds, so the form
refuses exactly what the engine would refuse (one rule set, in ``core/settings.py``).
"""

from __future__ import annotations

import contextlib
from collections.abc import Sequence
from typing import ClassVar

from textual.app import ComposeResult
from textual.binding import Binding, BindingType
from textual.containers import Grid, Horizontal, Vertical
from textual.screen import ModalScreen
from textual.widgets import Button, Input, Label, Select, Static

from core.errors import InputError
from core.plan import PlannerSettings
from core.policies.hold_settings import policy_hold
from core.settings import (
    HOLD_POLICIES,
    RULE_BY_NAME,
    RULES,
    SUPERVISION_MODES,
    SettingRule,
    coerce_setting,
    coerce_supervision,
)

# the text inputs, with core's labels, in core's order; the hold policy (a choice) is a Select
FIELDS: tuple[SettingRule, ...] = tuple(r for r in RULES if r.kind != "choice")


def _fmt(value: object) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return f"{value:g}"
    return str(value)


def _problem(rule: SettingRule, name: str, value: object, holds: Sequence[float] | None) -> str | None:
    """core's verdict on one value, as the form's message (the label, then what is wrong); None if allowed."""
    try:
        coerce_setting(name, value, holds)
    except InputError as exc:
        return f"{rule.label}: {exc.problem}"
    return None


def parse_field(
    rule: SettingRule, raw: str, allowed_holds_s: Sequence[float] | None = None
) -> tuple[object, str | None]:
    """(value, error): the text of one input, checked by the engine's rule for that setting.

    ``allowed_holds_s`` is the run's instrument profile's list (None: not known, any hold ≥ 0).
    """
    text = raw.strip()
    if not text and not rule.optional:
        return None, f"{rule.label}: a value is required"
    value: object = text or None
    with contextlib.suppress(ValueError):
        value = float(text)  # the message then shows the number as typed, not a quoted string
    error = _problem(rule, rule.name, value, allowed_holds_s)
    if error is not None:
        return None, error
    return coerce_setting(rule.name, value, allowed_holds_s), None


def parse_adjust(
    values: dict[str, str],
    hold_policy: str,
    current: PlannerSettings,
    supervision: str | None = None,
    current_supervision: str | None = None,
    allowed_holds_s: Sequence[float] | None = None,
    fields: Sequence[SettingRule] = FIELDS,
) -> tuple[dict[str, object], list[str]]:
    """The changed settings and the errors, from the form's raw texts. Unchanged fields are left out; only
    ``fields`` (those the form shows) are read: a hidden one is not the operator's to fill in."""
    changes: dict[str, object] = {}
    errors: list[str] = []
    for rule in fields:
        raw = values.get(rule.name, _fmt(getattr(current, rule.name)))
        value, error = parse_field(rule, raw, allowed_holds_s)
        if error:
            errors.append(error)
            continue
        if value != getattr(current, rule.name):
            changes[rule.name] = value
    hold_error = _problem(RULE_BY_NAME["hold_policy"], "hold_policy", hold_policy, allowed_holds_s)
    if hold_error is not None:
        errors.append(hold_error)
    elif hold_policy != current.hold_policy:
        changes["hold_policy"] = hold_policy
    if supervision is not None:
        try:
            coerce_supervision(supervision)
        except InputError as exc:
            errors.append(str(exc))
        else:
            if supervision != current_supervision:
                changes["supervision"] = supervision
    return changes, errors


class AdjustScreen(ModalScreen[dict[str, object] | None]):
    """Returns the changed settings, or None when cancelled."""

    BINDINGS: ClassVar[list[BindingType]] = [
        Binding("escape", "cancel", "Cancel"),
        Binding("ctrl+s", "submit", "Apply"),
    ]

    def __init__(
        self,
        settings: PlannerSettings,
        supervision: str = "supervised",
        cursor_blink: bool = True,
        allowed_holds_s: Sequence[float] | None = None,
        policy: str = "",
    ) -> None:
        super().__init__()
        self.settings = settings
        self.supervision = supervision
        self.cursor_blink = cursor_blink
        self.allowed_holds_s = allowed_holds_s  # the run's instrument holds (None: not known)
        # which hold settings are in force: only those are shown (a policy that picks every hold shows none)
        self.honours = policy_hold(policy) if policy else "either"
        self.fields = tuple(r for r in FIELDS if not (r.name == "fixed_hold_s" and self.honours == "policy"))

    def compose(self) -> ComposeResult:
        with Vertical(id="adjust-dialog"):
            yield Static("Adjust the planner (applies from the next decision)", id="adjust-title")
            with Grid(id="adjust-grid"):
                for rule in self.fields:
                    yield Label(rule.label)
                    yield Input(
                        _fmt(getattr(self.settings, rule.name)),
                        id=f"f-{rule.name}",
                        compact=True,
                        placeholder="none" if rule.optional else "",
                    )
                yield Label("hold policy")
                if self.honours == "either":
                    yield Select(
                        [(p, p) for p in HOLD_POLICIES],
                        value=self.settings.hold_policy,
                        allow_blank=False,
                        id="f-hold_policy",
                        compact=True,
                    )
                else:
                    what = (
                        "from the drift (the policy's)"
                        if self.honours == "policy"
                        else "fixed (the policy's)"
                    )
                    yield Static(what, id="f-hold-fixed-by-policy")
                yield Label("supervision")
                yield Select(
                    [(m, m) for m in SUPERVISION_MODES],
                    value=self.supervision if self.supervision in SUPERVISION_MODES else "supervised",
                    allow_blank=False,
                    id="f-supervision",
                    compact=True,
                )
            yield Static("", id="adjust-error")
            with Horizontal(id="adjust-buttons"):
                yield Button("Apply", variant="primary", id="apply", compact=True)
                yield Button("Cancel", id="cancel", compact=True)

    def on_mount(self) -> None:
        for inp in self.query(Input):
            inp.cursor_blink = self.cursor_blink
        self.query_one(f"#f-{self.fields[0].name}", Input).focus()

    def _values(self) -> tuple[dict[str, str], str, str]:
        values = {rule.name: self.query_one(f"#f-{rule.name}", Input).value for rule in self.fields}
        selects = self.query("#f-hold_policy")
        hold = selects.first(Select).value if selects else self.settings.hold_policy
        sup = self.query_one("#f-supervision", Select).value
        return values, str(hold), str(sup)

    def validate_form(self) -> tuple[dict[str, object], list[str]]:
        values, hold, sup = self._values()
        changes, errors = parse_adjust(
            values, hold, self.settings, sup, self.supervision, self.allowed_holds_s, self.fields
        )
        bad = {e.split(":", 1)[0] for e in errors}
        for rule in self.fields:
            self.query_one(f"#f-{rule.name}", Input).set_class(rule.label in bad, "-invalid")
        self.query_one("#adjust-error", Static).update(errors[0] if errors else "")
        return changes, errors

    def on_input_changed(self) -> None:
        self.validate_form()

    def on_input_submitted(self) -> None:
        self.action_submit()

    def on_button_pressed(self, event: Button.Pressed) -> None:
        if event.button.id == "apply":
            self.action_submit()
        else:
            self.action_cancel()

    def action_submit(self) -> None:
        changes, errors = self.validate_form()
        if errors:
            self.app.bell()
            return
        self.dismiss(changes)

    def action_cancel(self) -> None:
        self.dismiss(None)

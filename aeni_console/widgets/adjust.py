"""The adjust form: edit the planner's settings with validation before anything reaches the engine."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from textual.app import ComposeResult
from textual.binding import Binding, BindingType
from textual.containers import Grid, Horizontal, Vertical
from textual.screen import ModalScreen
from textual.widgets import Button, Input, Label, Select, Static

from core.plan import PlannerSettings


@dataclass(frozen=True)
class FieldSpec:
    name: str
    label: str
    kind: type  # float or int
    lo: float | None
    hi: float | None
    optional: bool = False  # blank means "none" (budgets and targets)
    lo_open: bool = False  # the lower bound itself is not allowed


FIELDS: tuple[FieldSpec, ...] = (
    FieldSpec("target_sem_gpa", "target SEM (GPa)", float, 0.0, 10.0, lo_open=True),
    FieldSpec("beta", "UCB β", float, 0.0, 100.0),
    FieldSpec("fixed_hold_s", "fixed hold (s)", float, 0.0, 600.0),
    FieldSpec("local_center_limit", "local centres", int, 0, 50),
    FieldSpec("edge_penalty", "edge penalty", float, 0.0, 1.0),
    FieldSpec("budget_s", "time budget (s)", float, 0.0, None, optional=True, lo_open=True),
    FieldSpec("indent_budget", "indent budget", int, 1, None, optional=True),
    FieldSpec("sigma_target_gpa", "σ target (GPa)", float, 0.0, None, optional=True, lo_open=True),
    FieldSpec("mape_target_pct", "MAPE target (%)", float, 0.0, 100.0, optional=True, lo_open=True),
)
HOLD_POLICIES = ("fixed", "adaptive")
SUPERVISION_MODES = ("auto", "supervised", "step")


def _fmt(value: object) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return f"{value:g}"
    return str(value)


def parse_field(spec: FieldSpec, raw: str) -> tuple[object, str | None]:
    """(value, error): the text of one input parsed and range-checked."""
    text = raw.strip()
    if not text:
        if spec.optional:
            return None, None
        return None, f"{spec.label}: a value is required"
    try:
        value: float | int = int(text) if spec.kind is int else float(text)
    except ValueError:
        what = "a whole number" if spec.kind is int else "a number"
        return None, f"{spec.label}: {text!r} is not {what}"
    if value != value or value in (float("inf"), float("-inf")):
        return None, f"{spec.label}: {text!r} is not finite"
    if spec.lo is not None and (value < spec.lo or (spec.lo_open and value == spec.lo)):
        return None, f"{spec.label}: must be {'>' if spec.lo_open else '≥'} {spec.lo:g}"
    if spec.hi is not None and value > spec.hi:
        return None, f"{spec.label}: must be ≤ {spec.hi:g}"
    return value, None


def parse_adjust(
    values: dict[str, str],
    hold_policy: str,
    current: PlannerSettings,
    supervision: str | None = None,
    current_supervision: str | None = None,
) -> tuple[dict[str, object], list[str]]:
    """The changed settings and the errors, from the form's raw texts. Unchanged fields are left out."""
    changes: dict[str, object] = {}
    errors: list[str] = []
    for spec in FIELDS:
        value, error = parse_field(spec, values.get(spec.name, _fmt(getattr(current, spec.name))))
        if error:
            errors.append(error)
            continue
        if value != getattr(current, spec.name):
            changes[spec.name] = value
    if hold_policy not in HOLD_POLICIES:
        errors.append(f"hold policy: {hold_policy!r} is not one of {', '.join(HOLD_POLICIES)}")
    elif hold_policy != current.hold_policy:
        changes["hold_policy"] = hold_policy
    if supervision is not None:
        if supervision not in SUPERVISION_MODES:
            errors.append(f"supervision: {supervision!r} is not one of {', '.join(SUPERVISION_MODES)}")
        elif supervision != current_supervision:
            changes["supervision"] = supervision
    return changes, errors


class AdjustScreen(ModalScreen[dict[str, object] | None]):
    """Returns the changed settings, or None when cancelled."""

    BINDINGS: ClassVar[list[BindingType]] = [
        Binding("escape", "cancel", "Cancel"),
        Binding("ctrl+s", "submit", "Apply"),
    ]

    def __init__(
        self, settings: PlannerSettings, supervision: str = "supervised", cursor_blink: bool = True
    ) -> None:
        super().__init__()
        self.settings = settings
        self.supervision = supervision
        self.cursor_blink = cursor_blink

    def compose(self) -> ComposeResult:
        with Vertical(id="adjust-dialog"):
            yield Static("Adjust the planner (applies from the next decision)", id="adjust-title")
            with Grid(id="adjust-grid"):
                for spec in FIELDS:
                    yield Label(spec.label)
                    yield Input(
                        _fmt(getattr(self.settings, spec.name)),
                        id=f"f-{spec.name}",
                        compact=True,
                        placeholder="none" if spec.optional else "",
                    )
                yield Label("hold policy")
                yield Select(
                    [(p, p) for p in HOLD_POLICIES],
                    value=self.settings.hold_policy,
                    allow_blank=False,
                    id="f-hold_policy",
                    compact=True,
                )
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
        self.query_one(f"#f-{FIELDS[0].name}", Input).focus()

    def _values(self) -> tuple[dict[str, str], str, str]:
        values = {spec.name: self.query_one(f"#f-{spec.name}", Input).value for spec in FIELDS}
        hold = self.query_one("#f-hold_policy", Select).value
        sup = self.query_one("#f-supervision", Select).value
        return values, str(hold), str(sup)

    def validate_form(self) -> tuple[dict[str, object], list[str]]:
        values, hold, sup = self._values()
        changes, errors = parse_adjust(values, hold, self.settings, sup, self.supervision)
        bad = {e.split(":", 1)[0] for e in errors}
        for spec in FIELDS:
            self.query_one(f"#f-{spec.name}", Input).set_class(spec.label in bad, "-invalid")
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

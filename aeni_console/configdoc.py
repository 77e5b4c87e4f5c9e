"""docs/config.md, generated from the validators themselves so that it cannot drift from them.

Every field, its type, its default and what is allowed come from the pydantic models that validate the
run file; where a field is checked by a custom validator (a policy or a scenario name), the allowed
values are that validator's own answer to a value it must refuse. Only the one-line meanings are
written here, and a test fails when a field has none or when a meaning names a field that is gone.

Regenerate with ``python -m aeni_console.configdoc`` (``--check`` exits 1 when the file is stale).
"""

from __future__ import annotations

import sys
import types
import typing
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ValidationError
from pydantic_core import PydanticUndefined

DOC_PATH = Path(__file__).resolve().parents[1] / "docs" / "config.md"
_REFUSED_PROBE = "\x00not-a-value"

# What each run-file field means (dotted name: one line). Everything else is read from the validators.
MEANINGS: dict[str, str] = {
    "name": "the run's name: the journal file is ./runs/<UTC time>-<name>.sqlite",
    "campaign.policy": "the planning policy",
    "campaign.scenario": "the emulator scenario (`aeni scenarios` lists them); `csv` reads truth_csv",
    "campaign.noise": "override the scenario's measurement noise",
    "campaign.drift": "override the scenario's drift",
    "campaign.truth_csv": "ground truth CSV (x_um, y_um, hardness_gpa[, noise_sd_gpa]), relative to the run file",
    "campaign.seed": "random seed: the same seed gives the same run",
    "campaign.profile": "instrument profile: a built-in name or a TOML file (default: the scenario's)",
    "campaign.lattice_n": "candidate centres per side of the lattice (default: the scenario's)",
    "planner.target_sem_gpa": "target standard error of a centre's value: sets the adaptive grid size",
    "planner.beta": "UCB exploration weight",
    "planner.hold_policy": "fixed holds, or adaptive holds from the measured drift",
    "planner.fixed_hold_s": "the hold of every indent with the fixed hold policy",
    "planner.local_center_limit": "local centres after a global jump before the planner must jump again",
    "planner.edge_penalty": "how strongly the acquisition is damped near the sample's edges",
    "planner.budget_s": "stop before the instrument time would pass this (default: the grid baseline's time)",
    "planner.indent_budget": "stop before the number of indents would pass this",
    "planner.sigma_target_gpa": "stop when the mean epistemic sd falls below this",
    "planner.mape_target_pct": "stop when the map error against truth falls below this (emulator only)",
    "planner.avoid_centers_um": "stage (x, y) centres the planner must not choose, e.g. [[120.0, 340.0]]",
    "run.driver": "the instrument driver",
    "run.supervision": "auto: every decision approved; supervised: global jumps wait; step: every block waits",
    "run.journal": "journal path (default: a new file in runs_dir)",
    "run.speed": "simulated instrument speed-up over real time (default: as fast as possible)",
    "run.runs_dir": "the folder for new journals",
    "run.group": "the OS group that may watch the run (journal 0640; only the owner commands): docs/security.md",
}


def _type_name(annotation: Any) -> str:
    origin = typing.get_origin(annotation)
    args = typing.get_args(annotation)
    if origin is typing.Literal:
        return "text"
    if origin in (typing.Union, types.UnionType):
        inner = [a for a in args if a is not type(None)]
        return " or ".join(_type_name(a) for a in inner) + (" (optional)" if len(inner) < len(args) else "")
    if origin in (list, tuple):
        if origin is tuple:
            return "(" + ", ".join(_type_name(a) for a in args) + ")"
        return f"list of {_type_name(args[0])}" if args else "list"
    return {str: "text", int: "whole number", float: "number", bool: "true/false"}.get(
        annotation, getattr(annotation, "__name__", str(annotation))
    )


def _literal_values(annotation: Any) -> list[Any]:
    if typing.get_origin(annotation) is typing.Literal:
        return list(typing.get_args(annotation))
    for a in typing.get_args(annotation):
        values = _literal_values(a)
        if values:
            return values
    return []


def _bounds(metadata: list[Any]) -> list[str]:
    out = []
    for m in metadata:
        for attr, sym in (("gt", ">"), ("ge", "≥"), ("lt", "<"), ("le", "≤")):
            v = getattr(m, attr, None)
            if v is not None:
                out.append(f"{sym} {v}")
        for attr, what in (("min_length", "at least {} characters"), ("max_length", "at most {} characters")):
            v = getattr(m, attr, None)
            if v is not None:
                out.append(what.format(v))
    return out


def _custom_rule(model: type[BaseModel], name: str) -> str:
    """What a field's own validator says when it refuses a value (e.g. the list of policy names)."""
    try:
        model.model_validate({name: _REFUSED_PROBE})
    except ValidationError as exc:
        for err in exc.errors():
            if tuple(err["loc"]) == (name,) and err["type"] == "value_error":
                return str(err["msg"]).replace("Value error, ", "").removeprefix("expected ")
    return ""


def _default(field: Any) -> str:
    if field.default_factory is not None:
        value = field.default_factory()
        return "empty" if not value else f"`{value!r}`"
    if field.default is PydanticUndefined:
        return "required"
    if field.default is None:
        return "none"
    return f"`{field.default!r}`".replace("'", '"')


def _setting_rule(name: str) -> Any | None:
    from core.settings import RULE_BY_NAME

    return RULE_BY_NAME.get(name)


def _rule_row(dotted: str, rule: Any, meaning: str) -> tuple[str, str, str, str, str]:
    """A planner knob from its rule (core.settings) and the PlannerSettings default."""
    from core.plan import PlannerSettings

    kind = {"number": "number", "whole": "whole number", "choice": "text", "hold": "number"}[rule.kind]
    default = getattr(PlannerSettings(), rule.name)
    shown = "none" if default is None else f"`{default!r}`".replace("'", '"')
    if default is None and rule.kind == "hold":
        shown = "the profile's default hold"
    optional = " (optional)" if rule.optional else ""
    return (dotted, kind + optional, shown, rule.allowed(None), meaning)


def field_rows(model: type[BaseModel], prefix: str = "") -> list[tuple[str, str, str, str, str]]:
    """(dotted name, type, default, allowed, meaning) for every leaf field, in the model's order."""
    rows: list[tuple[str, str, str, str, str]] = []
    for name, field in model.model_fields.items():
        dotted = f"{prefix}{name}"
        ann = field.annotation
        if isinstance(ann, type) and issubclass(ann, BaseModel):
            rows += field_rows(ann, dotted + ".")
            continue
        rule = _setting_rule(name) if ann is Any else None
        if rule is not None:  # a planner knob: its one rule lives in core.settings
            rows.append(_rule_row(dotted, rule, field.description or MEANINGS.get(dotted, "")))
            continue
        literals = _literal_values(ann)
        allowed = [", ".join(f"`{v}`" for v in literals)] if literals else []
        allowed += _bounds(field.metadata)
        if not literals and _type_name(ann).startswith("text"):
            rule = _custom_rule(model, name)
            if rule:
                allowed.append(rule)
        meaning = field.description or MEANINGS.get(dotted, "")
        rows.append((dotted, _type_name(ann), _default(field), "; ".join(allowed) or "any", meaning))
    return rows


def _table(rows: list[tuple[str, str, str, str, str]]) -> list[str]:
    out = ["| field | type | default | allowed | meaning |", "| --- | --- | --- | --- | --- |"]
    for name, typ, default, allowed, meaning in rows:
        out.append(f"| `{name}` | {typ} | {default} | {allowed} | {meaning} |")
    return out


def render() -> str:
    """The whole of docs/config.md."""
    from core.runconfig import RunFile

    rows = field_rows(RunFile)
    sections: dict[str, list[tuple[str, str, str, str, str]]] = {}
    for row in rows:
        head = row[0].split(".")[0] if "." in row[0] else ""
        sections.setdefault(head, []).append(row)
    lines = [
        "# Configuration files",
        "",
        "<!-- generated by `python -m aeni_console.configdoc` from the validators; do not edit by hand -->",
        "",
        "## The run file (`aeni run RUN.toml`)",
        "",
        "Every section and field is optional. Command-line flags (`--policy`, `--seed`, `--budget-s`, ...)",
        "override the file through the same validation, so a bad flag and a bad field get the same one-line",
        "message naming the field. An unknown field is refused (a typo never passes silently).",
        "",
        "```toml",
        'name = "ternary-demo"',
        "[campaign]",
        'policy = "cost-aware"',
        'scenario = "ternary"',
        "[planner]",
        "budget_s = 40000",
        "[run]",
        'supervision = "supervised"',
        "```",
    ]
    for head, part in sections.items():
        lines += ["", f"### {f'[{head}]' if head else 'top level'}", ""]
        lines += _table(part)
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    text = render()
    if "--check" in args:
        current = DOC_PATH.read_text(encoding="utf-8") if DOC_PATH.exists() else ""
        if current != text:
            print(f"{DOC_PATH} is stale: run python -m aeni_console.configdoc", file=sys.stderr)
            return 1
        return 0
    DOC_PATH.write_text(text, encoding="utf-8")
    print(f"wrote {DOC_PATH}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

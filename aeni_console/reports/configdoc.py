"""docs/config.md, generated from the validators themselves so that it cannot drift from them.

The run file: every field, its type, its default and what is allowed come from the pydantic models that
validate it; where a field is checked by a custom validator (a policy name), the allowed values are that
validator's own answer to a value it must refuse. The sample file: its fields are what its validator
names when it refuses an unknown one, its defaults are what the validator fills in for a minimal
sample, and the meanings are the comments of the template that ``aeni sample new`` writes. Only the
meanings the template lacks are written here, and a test fails when a field has none or when a meaning
names a field that is gone.

Regenerate with ``python -m aeni_console.reports.configdoc`` (``--check`` exits 1 when the file is stale).
"""

from __future__ import annotations

import re
import sys
import tomllib
import types
import typing
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ValidationError
from pydantic_core import PydanticUndefined

from core.errors import InputError
from core.plan import PlannerSettings
from core.runconfig import RunFile
from core.sample import SAMPLE_TEMPLATE, parse_sample
from core.settings import RULE_BY_NAME

DOC_PATH = Path(__file__).resolve().parents[2] / "docs" / "config.md"
_REFUSED_PROBE = "\x00not-a-value"

# What each run-file field means (dotted name: one line). Everything else is read from the validators.
MEANINGS: dict[str, str] = {
    "name": "the run's name: the journal file is ./runs/<UTC time>-<name>.sqlite",
    "campaign.policy": "the planning policy",
    "campaign.fast": "on: the plan prices the profile's fast (NanoBlitz-class) arrays beside CSM indents, one "
    "two-fidelity model learns from both (the policy's +fast; the profile needs a [fast] section); off: CSM "
    "indents only; unset: as the policy says (docs/two-fidelity.md)",
    "campaign.scenario": "the emulator scenario (`aeni scenarios` lists them); `csv` reads truth_csv",
    "campaign.noise": "override the scenario's measurement noise",
    "campaign.drift": "override the scenario's drift",
    "campaign.truth_csv": "ground truth CSV (x_um, y_um, hardness_gpa[, noise_sd_gpa]), relative to the run file",
    "campaign.seed": "random seed: the same seed gives the same run",
    "campaign.profile": "instrument profile: a built-in name or a TOML file, relative to the run file (default: the scenario's)",
    "campaign.lattice_n": "candidate centres per side of the lattice (default: the scenario's)",
    "campaign.failure_rate": "the simulated instrument's failures: this share of indents comes back invalid, "
    "and a quarter of it of the blocks each finds no surface or is aborted half way (default: the scenario's, "
    "0; `aeni demo` 0.015)",
    "notify.urls": "alert URLs (apprise's: mailto://, slack://, msteams://, matrix://, ntfy://, json:// ...); "
    "they carry secrets: better in urls_file. Never stored in the journal, a log or a command line",
    "notify.urls_file": "a file of alert URLs, one a line, that only its owner may read (chmod 600)",
    "notify.instrument_silence_s": "alert when the instrument has not answered for this long",
    "notify.repeat_s": "the same kind of alert at most once per this (the run's end is always sent)",
    "planner.target_sem_gpa": "target standard error of a centre's value: sets the adaptive grid size",
    "planner.beta": "UCB exploration weight",
    "planner.hold_policy": "fixed holds, or adaptive holds from the measured drift (a policy that picks every "
    "hold itself, e.g. aeni, refuses fixed ones and fixed_hold_s; grid refuses adaptive)",
    "planner.fixed_hold_s": "the hold of every indent with the fixed hold policy",
    "planner.local_center_limit": "local centres after a global jump before the planner must jump again",
    "planner.edge_penalty": "how strongly the acquisition is damped near the sample's edges",
    "planner.budget_s": "stop before the instrument time would pass this (default: the grid baseline's time)",
    "planner.indent_budget": "stop before the number of indents would pass this",
    "planner.sigma_target_gpa": "stop when the mean epistemic sd falls below this",
    "planner.mape_target_pct": "stop when the map error against truth falls below this (emulator only)",
    "planner.stop_at": "stop before this local time: the last block is the last one that ends before it "
    "(the next such time after the run starts; a resumed run keeps it)",
    "planner.stop_rel_sd_pct": "stop when the 95th percentile of the map's relative epistemic sd (sd / mean, %) "
    "over the sample's measurable area falls below this",
    "planner.avoid_centers_um": "stage (x, y) centres the planner must not choose, e.g. [[120.0, 340.0]]",
    "planner.map_weights": "how much each map's relative error counts when the planner chooses indents, "
    "e.g. { hardness = 1.0, modulus = 0.5 }; 0 drops a map (default: both, { hardness = 1.0, "
    "modulus = 1.0 }; policy aeni plans for both, the replicate-grid policies for hardness only)",
    "run.driver": "the instrument driver",
    "run.supervision": "auto: every decision approved; supervised: global jumps wait; step: every block waits",
    "run.journal": "journal path (default: a new file in runs_dir)",
    "run.speed": "simulated instrument speed-up over real time (default: as fast as possible)",
    "run.runs_dir": "the folder for new journals",
    "run.exchange": "driver kla: the folder shared with the instrument PC (InView's array import and export)",
    "run.group": "the OS group that may watch the run (journal 0640; only the owner commands): docs/security.md",
    "run.max_refusals": "refused blocks in a row (the interlock's, or a vetoed block proposed again) that stop the run",
    "run.approval_timeout_s": "an approval nobody answers times out after this (default: waits for the operator)",
    "run.on_timeout": "what a timed-out approval does; a collapse alarm or a refused block is vetoed, never approved",
    "run.auto_resume": "a detached engine (--detach, demo) that dies without ending its run (kill -9, out of "
    "memory, a crash) is alerted and resumed by its supervisor this many times in a row; 0: alert only",
    "run.resume_backoff_s": "the pause before the supervisor's first resume, doubled for each next one in a row",
    "sample.file": "the sample file the run indents (default: the simulated scenario's built-in sample)",
    "operator.hours": "when someone is at or near the instrument, local time: 'Mon-Fri 08:30-18:00', shifts "
    "separated by ';', 'always' or 'never'; outside them the run plans for nobody",
    "operator.response_min": "during the hours, how soon the operator answers a request (a block to load)",
    "operator.visit_every_min": "during the hours, how often the operator comes by the instrument unasked",
}

# What the sample template's comments do not say (dotted name: one line).
SAMPLE_MEANINGS: dict[str, str] = {
    "name": "the sample's name, shown in the console and the report",
    "corners.tl": "top-left corner { x_um, y_um, z_um } as read on the instrument",
    "corners.tr": "top-right corner",
    "corners.br": "bottom-right corner",
    "corners.bl": "bottom-left corner (the origin of the sample's unit square)",
    "exclusions": "a list of regions no indent may enter, each one [[exclusions]] table",
    "exclusions[].circle_um": "a round region: [x, y, radius] in µm",
    "exclusions[].polygon_um": "a polygonal region: [[x, y], ...] in µm, at least 3 vertices",
    "earlier": "indents of earlier work on this sample, kept r_excl_um away from",
    "earlier.indents_um": "earlier indents listed inline: [[x, y], ...] in µm",
    "earlier.indents_csv": "a CSV of earlier indents (x_um, y_um), relative to the sample file",
    "earlier.journals": "journals (.sqlite) of earlier runs on this sample",
    "corners": "the four calibrated corners",
    "safety": "the distances a run keeps",
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

    return RULE_BY_NAME.get(name)


def _rule_row(dotted: str, rule: Any, meaning: str) -> tuple[str, str, str, str, str]:
    """A planner knob from its rule (core.settings) and the PlannerSettings default."""

    kind = {"number": "number", "whole": "whole number", "choice": "text", "hold": "number", "clock": "text"}[
        rule.kind
    ]
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


def _refusal(data: dict[str, Any]) -> str:
    """The sample validator's one line for ``data`` (which must be refused)."""

    try:
        parse_sample(data, "probe")
    except InputError as exc:
        return exc.problem
    raise AssertionError(f"the sample validator accepted {data!r}")


def _allowed_keys(data: dict[str, Any]) -> list[str]:
    """The field names the sample validator lists when it refuses an unknown one."""
    found = re.search(r"\(allowed: ([^)]*)\)", _refusal(data))
    if found is None:
        raise AssertionError(f"the sample validator no longer lists the allowed fields: {_refusal(data)!r}")
    return [k.strip() for k in found.group(1).split(",")]


def _template_comments(template: str) -> dict[str, str]:
    """``key = value  # comment`` lines of the template, by dotted key (section headers included)."""
    out: dict[str, str] = {}
    section = ""
    for line in template.splitlines():
        head = re.match(r"^\[+([a-z_]+)\]+\s*(?:#\s*(.*))?$", line.strip())
        if head:
            section = head.group(1)
            if head.group(2):
                out[section] = head.group(2).strip()
            continue
        m = re.match(r"^#?\s*([a-z_]+)\s*=.*?#\s*(.+)$", line.strip())
        if m:
            out[f"{section}.{m.group(1)}" if section else m.group(1)] = m.group(2).strip()
    return out


def sample_rows() -> list[tuple[str, str, str]]:
    """(dotted name, default, meaning) for every field the sample validator accepts."""

    example = tomllib.loads(SAMPLE_TEMPLATE)
    minimal = {"name": "probe", "corners": example["corners"]}
    filled = parse_sample(minimal, "probe")  # what the validator fills in when a field is left out
    defaults = {
        "profile": filled.profile,
        "lattice_n": filled.lattice_n,
        "safety.dz_safe_um": filled.dz_safe_um,
        "safety.r_excl_um": filled.r_excl_um,
        "safety.edge_band_um": filled.edge_band_um,
        "safety.stage_rect_um": list(filled.stage_rect_um),
    }
    comments = _template_comments(SAMPLE_TEMPLATE)
    names: list[str] = []
    for top in _allowed_keys({**minimal, "zzz_unknown": 1}):
        names.append(top)
        if top in ("safety", "earlier"):
            names += [f"{top}.{k}" for k in _allowed_keys({**minimal, top: {"zzz_unknown": 1}})]
        elif top == "corners":
            names += [f"corners.{k}" for k in example["corners"]]
        elif top == "exclusions":
            names += [f"exclusions[].{k}" for k in ("circle_um", "polygon_um")]
    rows = []
    for name in names:
        default = defaults.get(name)
        shown = "required" if name in ("name", "corners") or name.startswith("corners.") else "—"
        if default is not None:
            shown = f"`{default!r}`".replace("'", '"')
        meaning = comments.get(name) or SAMPLE_MEANINGS.get(name, "")
        rows.append((name, shown, meaning))
    return rows


def render() -> str:
    """The whole of docs/config.md."""

    rows = field_rows(RunFile)
    sections: dict[str, list[tuple[str, str, str, str, str]]] = {}
    for row in rows:
        head = row[0].split(".")[0] if "." in row[0] else ""
        sections.setdefault(head, []).append(row)
    lines = [
        "# Configuration files",
        "",
        "<!-- generated by `python -m aeni_console.reports.configdoc` from the validators; do not edit by hand -->",
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
    lines += [
        "",
        "## The sample file (`sample.toml`: `aeni sample new` writes one, `aeni sample check` draws it)",
        "",
        "What is on the stage: its four corners as read on the instrument, the distances a run keeps, and",
        "what no indent may touch. Every coordinate is in stage µm; the validator refuses values that look like",
        "mm. A run names it in its run file (`[sample] file = ...`).",
        "",
        "| field | default | meaning |",
        "| --- | --- | --- |",
    ]
    lines += [f"| `{n}` | {d} | {m} |" for n, d, m in sample_rows()]
    lines += [
        "",
        "The template, which is itself a valid sample file:",
        "",
        "```toml",
        SAMPLE_TEMPLATE.rstrip(),
        "```",
    ]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    text = render()
    if "--check" in args:
        current = DOC_PATH.read_text(encoding="utf-8") if DOC_PATH.exists() else ""
        if current != text:
            print(f"{DOC_PATH} is stale: run python -m aeni_console.reports.configdoc", file=sys.stderr)
            return 1
        return 0
    DOC_PATH.write_text(text, encoding="utf-8")
    print(f"wrote {DOC_PATH}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""A run's TOML file, validated field by field, into a CampaignConfig plus the engine's run options.

Layout (every section and field is optional)::

    name = "ternary-demo"
    [sample]     # file: the sample.toml the run indents (default: the simulated scenario's built-in sample)
    [campaign]   # policy, seed, profile, lattice_n; scenario, noise, drift, truth_csv for the sim driver
    [planner]    # the PlannerSettings knobs: target_sem_gpa, beta, hold_policy, budgets ...
    [run]        # driver, supervision, journal, speed, runs_dir; max_refusals, approval_timeout_s, on_timeout
    [operator]   # hours ("Mon-Fri 08:30-18:00", local time), response_min, visit_every_min

Command-line flags override the file through the same validation, so a bad flag and a bad field
get the same one-line message naming the field, the value and what is allowed.
"""

from __future__ import annotations

import dataclasses
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, ValidationInfo, field_validator

from core.access import journal_gid
from core.campaign_config import CampaignConfig
from core.errors import InputError
from core.notifyconfig import (
    DEFAULT_INSTRUMENT_SILENCE_S,
    DEFAULT_REPEAT_S,
    NotifyConfig,
    make_notify_config,
)
from core.operator import OperatorAvailability, OperatorHours
from core.policies.hold_settings import check_hold_in_force
from core.policies.registry import policy_names, policy_parts
from core.profile import BUILTIN_PROFILES
from core.run.spec import EngineRules, RunSpec
from core.sample import check_avoided_centres, load_sample
from core.settings import (
    ADJUSTABLE,
    SUPERVISION_MODES,
    coerce_setting,
    coerce_supervision,
    settings_from_dict,
)

if TYPE_CHECKING:
    from core.campaign_config import CampaignConfig
    from core.operator import OperatorAvailability

__all__ = [
    "SUPERVISION_MODES",
    "RunConfig",
    "RunOptions",
    "load_run_config",
    "make_campaign_config",
    "parse_run_config",
    "policy_with_fast",
    "run_spec",
]
DRIVERS: tuple[str, ...] = ("sim", "kla")


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=False, allow_inf_nan=False)


class CampaignSection(_Strict):
    policy: str = "aeni"  # core.policies.registry.RECOMMENDED (a test keeps them equal)
    scenario: str = "ternary"
    noise: Literal["hetero", "homo", "10pct"] | None = None
    drift: Literal["none", "good", "bad"] | None = None
    truth_csv: str | None = None
    seed: int = Field(default=0, ge=0, le=2**32 - 1)
    profile: str | None = None
    lattice_n: int | None = Field(default=None, ge=5, le=400)
    failure_rate: float | None = Field(default=None, ge=0.0, le=0.5)
    # on: the plan prices the profile's fast arrays beside CSM indents (the policy's +fast); off: CSM only;
    # None: as the policy says
    fast: Literal["on", "off"] | None = None

    @field_validator("policy")
    @classmethod
    def _policy(cls, v: str) -> str:

        names = policy_names()
        if v.split("+")[0] not in names:
            raise ValueError(f"must be one of {', '.join(names)} (an ablation adds +modifiers)")
        try:
            policy_parts(v)  # a registered policy, or an ablation BASE+modifier (the bench's)
        except InputError as exc:
            raise ValueError(exc.problem) from None
        return v

    @field_validator("fast")
    @classmethod
    def _fast(cls, v: str | None, info: ValidationInfo) -> str | None:

        policy = info.data.get("policy")
        if v == "on" and policy is not None:
            if policy.split("+")[0] == "grid":
                raise ValueError("policy 'grid' plans no fast arrays (its grid is the comparison)")
            try:
                policy_parts(policy_with_fast(policy, v))
            except InputError as exc:
                raise ValueError(f"policy {policy!r} cannot plan fast arrays ({exc.problem})") from None
        return v


def policy_with_fast(policy: str, fast: str | None) -> str:
    """The policy with its fast arrays on or off (the ``+fast`` modifier, last); None: the policy as named."""
    if fast is None:
        return policy
    base, *mods = policy.split("+")
    return "+".join([base, *(m for m in mods if m != "fast"), *(["fast"] if fast == "on" else [])])


class SampleSection(_Strict):
    file: str | None = None


class PlannerSection(_Strict):
    """The PlannerSettings knobs, each checked by its rule in core.settings (the one validator)."""

    target_sem_gpa: Any = None
    beta: Any = None
    hold_policy: Any = None
    fixed_hold_s: Any = None
    local_center_limit: Any = None
    edge_penalty: Any = None
    budget_s: Any = None
    indent_budget: Any = None
    sigma_target_gpa: Any = None
    mape_target_pct: Any = None
    stop_at: Any = None
    stop_rel_sd_pct: Any = None
    avoid_centers_um: list[tuple[float, float]] = Field(default_factory=list)
    map_weights: dict[str, float] | None = None  # { hardness = 1.0, modulus = 1.0 }: checked by core.settings

    @field_validator(*ADJUSTABLE)
    @classmethod
    def _rule(cls, v: Any, info: ValidationInfo) -> Any:
        try:
            # the profile's holds are checked when the campaign starts (the profile may come from the scenario)
            return coerce_setting(str(info.field_name), v, None)
        except InputError as exc:
            raise ValueError(exc.problem.partition(" is not allowed: ")[2] or exc.problem) from None


class RunSection(_Strict):
    driver: Literal["sim", "kla"] = "sim"
    exchange: str | None = None  # the KLA driver's exchange folder (shared with the instrument PC)
    supervision: str = "auto"
    journal: str | None = None
    speed: float | None = Field(default=None, gt=0)
    runs_dir: str = "runs"
    group: str | None = Field(default=None, min_length=1)
    # no wait without an answer: refused blocks in a row before the run stops; unanswered approvals
    max_refusals: int = Field(default=5, ge=1, le=1000)
    approval_timeout_s: float | None = Field(default=None, gt=0)
    on_timeout: Literal["approve", "veto", "pause", "stop"] = "approve"
    # a detached engine that dies is resumed by its supervisor this many times in a row (0: alert only)
    auto_resume: int = Field(default=3, ge=0, le=100)
    resume_backoff_s: float = Field(default=5.0, gt=0)  # the first pause before it; doubled each time

    @field_validator("supervision")
    @classmethod
    def _supervision(cls, v: str) -> str:
        try:
            return coerce_supervision(v)
        except InputError as exc:
            raise ValueError(exc.problem.partition(" is not allowed: ")[2]) from None


class NotifySection(_Strict):
    urls: list[str] = Field(default_factory=list)
    urls_file: str | None = None
    instrument_silence_s: float = Field(default=DEFAULT_INSTRUMENT_SILENCE_S, gt=0)
    repeat_s: float = Field(default=DEFAULT_REPEAT_S, ge=0)


class OperatorSection(_Strict):
    """When someone comes to the instrument (core.operator); outside the hours the run plans for nobody."""

    hours: str = "always"
    response_min: float = Field(default=10.0, ge=0, le=24 * 60)
    visit_every_min: float = Field(default=120.0, gt=0, le=7 * 24 * 60)

    @field_validator("hours")
    @classmethod
    def _hours(cls, v: str) -> str:

        try:
            OperatorHours.parse(v)
        except InputError as exc:
            raise ValueError(exc.problem) from None
        return v

    def availability(self) -> OperatorAvailability:

        return OperatorAvailability(
            OperatorHours.parse(self.hours), self.response_min * 60.0, self.visit_every_min * 60.0
        )


class RunFile(_Strict):
    name: str = Field(default="run", min_length=1, max_length=80)
    sample: SampleSection = Field(default_factory=SampleSection)
    campaign: CampaignSection = Field(default_factory=CampaignSection)
    planner: PlannerSection = Field(default_factory=PlannerSection)
    run: RunSection = Field(default_factory=RunSection)
    notify: NotifySection = Field(default_factory=NotifySection)
    operator: OperatorSection = Field(default_factory=OperatorSection)


@dataclass(frozen=True)
class RunOptions:
    """How the engine runs (not what it plans)."""

    driver: str = "sim"
    supervision: str = "auto"
    journal: str | None = None
    speed: float | None = None  # None: as fast as possible; f: f× faster than the real instrument
    runs_dir: str = "runs"
    exchange: str | None = None  # driver kla: the exchange folder
    group: str | None = None  # the OS group that may watch the run (its journal is 0640); None: the owner's
    max_refusals: int = 5  # consecutive refused blocks (interlock, or a vetoed block again) that stop the run
    approval_timeout_s: float | None = None  # None: an approval waits for the operator however long it takes
    on_timeout: str = "approve"  # approve | veto | pause | stop (a collapse alarm or a refusal: veto instead)
    # who answers, and when (the [operator] section); None: no section, the run plans as if always attended
    operator: OperatorAvailability | None = None
    auto_resume: int = 3  # a detached engine that dies is resumed this many times in a row (the supervisor)
    resume_backoff_s: float = 5.0  # the pause before the first automatic resume, doubled for each next


@dataclass(frozen=True)
class RunConfig:
    campaign: Any  # core.campaign.CampaignConfig
    options: RunOptions
    notify: NotifyConfig = field(default_factory=NotifyConfig)  # never part of the campaign config

    def spec(self) -> RunSpec:
        """The run this file describes (where its journal goes, ``options.journal`` and ``runs_dir``, is not
        part of it)."""
        return run_spec(self.campaign, self.options, self.notify)


def run_spec(campaign: CampaignConfig, options: RunOptions, notify: NotifyConfig | None = None) -> RunSpec:
    """A campaign config and the engine's run options as one RunSpec (a KLA run's exchange folder is one of
    its driver's options)."""
    if options.exchange is not None and options.driver == "kla":
        opts = {**campaign.driver_options, "exchange": options.exchange}
        campaign = dataclasses.replace(campaign, driver_options=opts)
    return RunSpec(
        campaign=campaign,
        driver=options.driver,
        speed=options.speed,
        rules=EngineRules(
            supervision=options.supervision,
            max_refusals=options.max_refusals,
            approval_timeout_s=options.approval_timeout_s,
            on_timeout=options.on_timeout,
            auto_resume=options.auto_resume,
            resume_backoff_s=options.resume_backoff_s,
        ),
        operator=options.operator,
        notify=notify or NotifyConfig(),
        group=options.group,
    )


def _allowed(model: type[BaseModel], section: tuple[str | int, ...]) -> str:
    m: Any = model
    for part in section:
        field = m.model_fields.get(part) if isinstance(part, str) else None
        if field is None or not (
            isinstance(field.annotation, type) and issubclass(field.annotation, BaseModel)
        ):
            return ""
        m = field.annotation
    return ", ".join(m.model_fields)


def _message(exc: ValidationError) -> str:
    parts = []
    for err in exc.errors():
        loc = tuple(err["loc"])
        name = ".".join(str(p) for p in loc) or "(top level)"
        msg = str(err["msg"]).replace("Value error, ", "").replace("Input should be", "must be")
        if err["type"] == "extra_forbidden":
            allowed = _allowed(RunFile, loc[:-1])
            parts.append(f"unknown field {name} (allowed: {allowed})")
        elif err["type"] == "missing":
            parts.append(f"field {name} is missing")
        else:
            parts.append(f"field {name} = {err.get('input')!r} is not allowed: {msg}")
    return "; ".join(parts)


def _set_dotted(data: dict[str, Any], dotted: str, value: Any) -> None:
    node = data
    *parents, leaf = dotted.split(".")
    for p in parents:
        child = node.setdefault(p, {})
        if not isinstance(child, dict):
            raise InputError("config", f"{p} must be a table, got {child!r}")
        node = child
    node[leaf] = value


def parse_run_config(
    data: dict[str, Any],
    source: str = "config",
    overrides: dict[str, Any] | None = None,
    base_dir: Path | None = None,
) -> RunConfig:
    """Validate a parsed TOML table (plus dotted-key overrides such as ``campaign.seed``)."""

    merged = {k: (dict(v) if isinstance(v, dict) else v) for k, v in data.items()}
    for dotted, value in (overrides or {}).items():
        if value is not None:
            _set_dotted(merged, dotted, value)
    try:
        rf = RunFile.model_validate(merged)
    except ValidationError as exc:
        raise InputError(source, _message(exc)) from None
    given = rf.planner.model_dump(exclude_unset=True)
    settings = settings_from_dict(given)
    c = rf.campaign
    check_hold_in_force(c.policy, given)
    if c.scenario == "csv" and not c.truth_csv:
        raise InputError(source, "field campaign.truth_csv is missing: scenario 'csv' needs a truth CSV file")
    truth_csv = c.truth_csv
    if truth_csv is not None and base_dir is not None and not Path(truth_csv).is_absolute():
        truth_csv = str((base_dir / truth_csv).resolve())  # relative to the config file
    profile = c.profile
    if (
        profile is not None
        and profile not in BUILTIN_PROFILES
        and base_dir is not None
        and not Path(profile).is_absolute()
        and (overrides or {}).get("campaign.profile") is None
    ):
        profile = str((base_dir / profile).resolve())  # a profile file: relative to the config file too
    sample = None
    if rf.sample.file is not None:
        file = Path(rf.sample.file)
        if base_dir is not None and not file.is_absolute() and (overrides or {}).get("sample.file") is None:
            file = base_dir / file  # relative to the config file (a --sample flag: to the working directory)
        sample = load_sample(file)
        check_avoided_centres(sample, settings.avoid_centers_um, source)
    # the simulated instrument's truth: which scenario (or CSV) it lays onto the sample
    driver_options: dict[str, Any] = {"scenario": c.scenario}
    for key, value in (
        ("noise", c.noise),
        ("drift", c.drift),
        ("truth_csv", truth_csv),
        ("failure_rate", c.failure_rate),
    ):
        if value is not None:
            driver_options[key] = value
    r = rf.run
    if r.driver == "kla" and not r.exchange:
        raise InputError(
            source, "field run.exchange is missing: driver 'kla' needs an exchange folder (--exchange DIR)"
        )
    exchange = r.exchange
    if exchange is not None and base_dir is not None and not Path(exchange).is_absolute():
        exchange = str((base_dir / exchange).resolve())  # relative to the config file
    if r.driver == "kla":
        # a real instrument has no truth: the scenario counts only when it was named (a fake InView plays it)
        if "scenario" not in c.model_fields_set:
            driver_options.pop("scenario")
        driver_options["exchange"] = exchange
    campaign = CampaignConfig(
        policy=policy_with_fast(c.policy, c.fast),
        seed=c.seed,
        profile=profile,
        lattice_n=c.lattice_n,
        settings=settings,
        name=rf.name,
        sample=sample,
        driver_options=driver_options,
    )
    if r.group is not None:
        journal_gid(r.group, f"{source}: field run.group")  # an unusable group is refused before the run
    options = RunOptions(
        driver=r.driver,
        supervision=r.supervision,
        journal=r.journal,
        speed=r.speed,
        runs_dir=r.runs_dir,
        exchange=exchange,
        group=r.group,
        max_refusals=r.max_refusals,
        approval_timeout_s=r.approval_timeout_s,
        on_timeout=r.on_timeout,
        operator=rf.operator.availability() if "operator" in rf.model_fields_set else None,
        auto_resume=r.auto_resume,
        resume_backoff_s=r.resume_backoff_s,
    )
    n = rf.notify
    try:
        notify = make_notify_config(n.urls, n.urls_file, n.instrument_silence_s, n.repeat_s, base_dir)
    except InputError as exc:
        if not exc.source.startswith("notify."):
            raise  # the urls file's own errors name that file
        raise InputError(source, f"field {exc.source}: {exc.problem}") from None
    return RunConfig(campaign=campaign, options=options, notify=notify)


def make_campaign_config(
    name: str = "run",
    *,
    settings: Mapping[str, Any] | None = None,
    source: str = "arguments",
    **campaign: Any,
) -> CampaignConfig:
    """The one way to assemble a CampaignConfig outside a run file (simulate, bench, demo, benchmarks).

    ``campaign`` holds ``[campaign]`` fields and ``settings`` ``[planner]`` fields; None leaves a default.
    Everything passes the run file's validation, so a bad value gets the same one-line message.
    """
    overrides: dict[str, Any] = {f"campaign.{k}": v for k, v in campaign.items()}
    overrides.update({f"planner.{k}": v for k, v in (settings or {}).items()})
    overrides["name"] = name
    config: CampaignConfig = parse_run_config({}, source, overrides).campaign
    return config


def load_run_config(path: str | Path | None = None, overrides: dict[str, Any] | None = None) -> RunConfig:
    """Read and validate a run TOML file (None: all defaults), then apply command-line overrides."""
    if path is None:
        return parse_run_config({}, "command line", overrides)
    p = Path(path)
    src = str(p)
    try:
        text = p.read_text(encoding="utf-8-sig")  # a byte-order mark (Notepad's UTF-8) is not TOML's concern
    except FileNotFoundError:
        raise InputError(src, "no such config file") from None
    except IsADirectoryError:
        raise InputError(src, "is a folder, not a config file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(src, f"cannot read config ({exc})") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(src, f"not valid TOML ({exc})") from None
    return parse_run_config(data, src, overrides, base_dir=p.parent)

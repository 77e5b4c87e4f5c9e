"""What a run is: one typed, frozen description, and its one serialisation.

A :class:`RunSpec` is what ``aeni run`` reads from a run file, what a detached engine receives on its stdin,
what the journal keeps (``meta["run_spec"]``) and what ``aeni resume`` reads back; ``core.run.compose`` builds
the run from it. One JSON crosses every process boundary: :meth:`RunSpec.to_json` / :meth:`RunSpec.from_json`.

The alert URLs are secrets: the journal is readable by the run's group, so it keeps the spec without them
(:meth:`RunSpec.public`); they live owner-only beside it (``core.notifyconfig.notify_path_for``).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from datetime import datetime
from typing import Any

import numpy as np

from core.campaign_config import CampaignConfig, campaign_config_from_dict, campaign_config_to_dict
from core.errors import InputError
from core.notifyconfig import NotifyConfig
from core.operator import OperatorAvailability, OperatorHours
from core.sample.tray import Tray, tray_from_dict
from core.settings import ON_TIMEOUT, coerce_supervision
from core.visits import OperatorCalendar

SPEC_VERSION = 1


@dataclass(frozen=True)
class EngineRules:
    """How the engine supervises the run, and that no wait goes without an answer."""

    supervision: str = "auto"  # auto | supervised | step
    max_refusals: int = 5  # consecutive refused blocks (interlock, or a vetoed block again) that stop the run
    approval_timeout_s: float | None = None  # None: an approval waits for the operator however long it takes
    on_timeout: str = "approve"  # approve | veto | pause | stop
    # an engine that dies without ending its run is resumed by its supervisor this many times in a row (0:
    # alerted only), the first time after resume_backoff_s, doubled for each next (aeni_console.cli.supervisor)
    auto_resume: int = 3
    resume_backoff_s: float = 5.0

    def __post_init__(self) -> None:
        coerce_supervision(self.supervision)
        if self.max_refusals < 1:
            raise InputError("run.max_refusals", f"{self.max_refusals!r} is not allowed: expected ≥ 1")
        if self.approval_timeout_s is not None and not self.approval_timeout_s > 0:
            raise InputError("run.approval_timeout_s", f"{self.approval_timeout_s!r} is not allowed: > 0 s")
        if self.on_timeout not in ON_TIMEOUT:
            raise InputError("run.on_timeout", f"{self.on_timeout!r} is not allowed: {', '.join(ON_TIMEOUT)}")
        if not 0 <= self.auto_resume <= 100:
            raise InputError("run.auto_resume", f"{self.auto_resume!r} is not allowed: expected 0 to 100")
        if not self.resume_backoff_s > 0:
            raise InputError("run.resume_backoff_s", f"{self.resume_backoff_s!r} is not allowed: > 0 s")


@dataclass(frozen=True)
class RunSpec:
    """One run: what is indented and how it is planned (``campaign``: the sample, profile, policy, settings,
    seed and the driver's options), which driver indents it and how fast, the engine's rules, who answers
    when (``operator``, a real one; ``calendar``, a simulated one), the alerts and who may watch.

    The sample lives in ``campaign.sample`` (None: the driver's built-in one, resolved by ``compose`` before
    anything is journaled); a tray will extend it to several samples there.
    """

    campaign: CampaignConfig = field(default_factory=CampaignConfig)
    driver: str = "sim"  # sim | kla
    speed: float | None = None  # a simulated instrument's speed-up; None: as fast as possible
    rules: EngineRules = field(default_factory=EngineRules)
    operator: OperatorAvailability | None = None  # the run file's [operator]; None: planned as if attended
    calendar: OperatorCalendar | None = None  # a simulated operator who loads the blocks (simulate, bench)
    notify: NotifyConfig = field(default_factory=NotifyConfig)
    group: str | None = None  # the OS group that may watch the run (its journal is 0640); None: the owner's
    refit_every: int = 1  # refit only after every so many blocks (the bench's grid never looks at the model)
    # several samples in one run (core.run.tray); None: the one sample of ``campaign``. A tray's samples take
    # ``campaign``'s policy, seed, lattice and settings, each with its own sample, goal and driver options
    tray: Tray | None = None

    def __post_init__(self) -> None:
        if self.driver not in ("sim", "kla"):
            raise InputError("run.driver", f"{self.driver!r} is not allowed: expected sim or kla")
        if self.speed is not None and not self.speed > 0:
            raise InputError("run.speed", f"{self.speed!r} is not allowed: expected a number > 0")
        if self.refit_every < 1:
            raise InputError("refit_every", f"{self.refit_every!r} is not allowed: expected ≥ 1")

    @property
    def name(self) -> str:
        return self.campaign.name

    @property
    def fast(self) -> bool:
        """Whether the plan prices fast arrays beside CSM indents (the policy's ``+fast``: ``aeni run --fast on``,
        a run file's ``campaign.fast``); the spec carries it in its policy, one home for it."""
        return "fast" in self.campaign.policy.split("+")[1:]

    @property
    def driver_options(self) -> dict[str, Any]:
        return self.campaign.driver_options

    @property
    def wall_s_per_instrument_s(self) -> float:
        """Wall seconds an instrument second takes (``stop_at`` reads the wall clock): 1/speed on a sped-up
        simulation, none as fast as possible, 1 on a real instrument."""
        if self.speed:
            return 1.0 / self.speed
        return 0.0 if self.driver == "sim" else 1.0

    def public(self) -> RunSpec:
        """The spec without its secrets (the alert URLs), as the group-readable journal keeps it."""
        return replace(self, notify=replace(self.notify, urls=()))

    # -- the one serialisation ---------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        d = self._single_dict()
        if self.tray is not None:  # a single-sample spec's JSON stays as it always was
            d["tray"] = self.tray.to_dict()
        return d

    def _single_dict(self) -> dict[str, Any]:
        return {
            "version": SPEC_VERSION,
            "campaign": campaign_config_to_dict(self.campaign),
            "driver": self.driver,
            "speed": self.speed,
            "rules": {
                "supervision": self.rules.supervision,
                "max_refusals": self.rules.max_refusals,
                "approval_timeout_s": self.rules.approval_timeout_s,
                "on_timeout": self.rules.on_timeout,
                "auto_resume": self.rules.auto_resume,
                "resume_backoff_s": self.rules.resume_backoff_s,
            },
            "operator": None if self.operator is None else availability_to_dict(self.operator),
            "calendar": None if self.calendar is None else _calendar_to_dict(self.calendar),
            "notify": json.loads(self.notify.to_json()),
            "group": self.group,
            "refit_every": self.refit_every,
        }

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), default=_plain, separators=(",", ":"), sort_keys=True)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], source: str = "run spec") -> RunSpec:
        try:
            d = dict(data)
            version = int(d.pop("version", SPEC_VERSION))
            if version > SPEC_VERSION:
                raise InputError(source, f"written by a newer version (run spec {version}); upgrade aeni")
            known = {
                "campaign", "driver", "speed", "rules", "operator", "calendar", "notify", "group", "refit_every",
                "tray",
            }  # fmt: skip
            unknown = sorted(set(d) - known)
            if unknown:
                raise InputError(source, f"unknown field(s) {', '.join(unknown)}")
            rules = dict(d.get("rules") or {})
            speed = d.get("speed")
            return cls(
                campaign=campaign_config_from_dict(dict(d.get("campaign") or {})),
                driver=str(d.get("driver", "sim")),
                speed=None if speed is None else float(speed),
                rules=EngineRules(
                    supervision=str(rules.get("supervision", "auto")),
                    max_refusals=int(rules.get("max_refusals", 5)),
                    approval_timeout_s=(
                        None
                        if rules.get("approval_timeout_s") is None
                        else float(rules["approval_timeout_s"])
                    ),
                    on_timeout=str(rules.get("on_timeout", "approve")),
                    # a spec journaled before these rules: the defaults
                    auto_resume=int(rules.get("auto_resume", EngineRules.auto_resume)),
                    resume_backoff_s=float(rules.get("resume_backoff_s", EngineRules.resume_backoff_s)),
                ),
                operator=None if d.get("operator") is None else availability_from_dict(d["operator"]),
                calendar=None if d.get("calendar") is None else _calendar_from_dict(d["calendar"]),
                notify=NotifyConfig.from_mapping(d.get("notify") or {}, source),
                group=None if d.get("group") is None else str(d["group"]),
                refit_every=int(d.get("refit_every", 1)),
                tray=None if d.get("tray") is None else tray_from_dict(d["tray"], source),
            )
        except InputError as exc:
            if exc.source == source:
                raise
            raise InputError(source, f"{exc.source}: {exc.problem}") from None
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise InputError(source, f"not a run spec ({type(exc).__name__}: {exc})") from None

    @classmethod
    def from_json(cls, text: str, source: str = "run spec") -> RunSpec:
        try:
            data = json.loads(text)
        except ValueError as exc:
            raise InputError(source, f"not valid JSON ({exc})") from None
        if not isinstance(data, dict):
            raise InputError(source, "not a run spec (expected a JSON object)")
        return cls.from_dict(data, source)


def availability_to_dict(a: OperatorAvailability) -> dict[str, Any]:
    """An [operator] section as a run file writes it (away_until, an operator's word during a run, is not
    part of the spec: the engine keeps it in its plan state)."""
    return {
        "hours": a.hours.text,
        "response_min": a.response_s / 60.0,
        "visit_every_min": a.visit_every_s / 60.0,
    }


def availability_from_dict(d: Mapping[str, Any]) -> OperatorAvailability:
    return OperatorAvailability(
        OperatorHours.parse(str(d["hours"])),
        float(d["response_min"]) * 60.0,
        float(d["visit_every_min"]) * 60.0,
    )


def _calendar_to_dict(c: OperatorCalendar) -> dict[str, Any]:
    return {**availability_to_dict(c.availability), "start": c.start.isoformat()}


def _calendar_from_dict(d: Mapping[str, Any]) -> OperatorCalendar:
    return OperatorCalendar(availability_from_dict(d), datetime.fromisoformat(str(d["start"])))


def _plain(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")


def run_spec_from_meta(meta: Mapping[str, Any], supervision: str | None = None) -> RunSpec:
    """The spec a journal keeps; a journal written before the spec (``config`` + ``engine_rules`` + ``driver``
    and ``speed`` in its meta) is read as the spec it describes. ``supervision``: the engine row's (a journal
    before the spec kept the run's supervision there)."""
    stored = meta.get("run_spec")
    if stored is not None:
        return RunSpec.from_dict(stored, "journal run spec")
    rules = dict(meta.get("engine_rules") or {})  # a journal from before the rules: the defaults
    operator = rules.pop("operator", None)
    speed = meta.get("speed")
    return RunSpec.from_dict(
        {
            "campaign": meta["config"],
            "driver": str(meta.get("driver", "sim")),
            "speed": speed,
            "rules": {"supervision": supervision or "auto", **rules},
            "operator": operator,
        },
        "journal",
    )

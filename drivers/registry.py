"""Which driver runs a campaign: ``make_driver(kind, sample, profile, options)`` and its helpers, and
``DRIVERS``, what ``core.run.compose.compose`` asks for a run's sample, driver and map scorer.

A run is a sample, a driver, a policy and settings. The simulated driver ('sim') lays an emulator
scenario's truth (or a truth CSV) onto the run's sample and, having the truth, also supplies the
evaluator that scores the map; a real instrument supplies neither truth nor evaluator.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from core.driver import Driver
from core.errors import InputError
from core.metrics import MapEvaluator
from core.profile import InstrumentProfile
from core.run.tray import tray_profiles
from core.sample import Sample
from core.sample.tray import Tray, TraySample
from drivers.kla.driver import make_kla_driver
from drivers.kla.tray import KlaTray
from drivers.sim.failures import FailureModes
from drivers.sim.robust_fields import ROBUST_FIELDS, robust_scenario
from drivers.sim.scenarios import SCENARIOS, make_scenario
from drivers.sim.tray import make_tray_driver

if TYPE_CHECKING:
    from core.run.spec import RunSpec

DRIVER_KINDS: tuple[str, ...] = ("sim", "kla")
SIM_OPTIONS: tuple[str, ...] = ("scenario", "noise", "drift", "truth_csv", "lateral_sd_um", "failure_rate")
# the KLA driver's own options; the sim options beside them name the emulated sample a fake InView plays
KLA_OPTIONS: tuple[str, ...] = ("exchange",)


def _check_kind(kind: str) -> None:
    if kind not in DRIVER_KINDS:
        raise InputError("--driver", f"{kind!r} is not allowed: expected {', '.join(DRIVER_KINDS)}")


def sim_options(
    scenario: str = "ternary",
    noise: str | None = None,
    drift: str | None = None,
    truth_csv: str | None = None,
) -> dict[str, Any]:
    """The simulated instrument's options as a run stores them (``CampaignConfig.driver_options``)."""
    out: dict[str, Any] = {"scenario": scenario}
    for key, value in (("noise", noise), ("drift", drift), ("truth_csv", truth_csv)):
        if value is not None:
            out[key] = value
    return out


def sim_scenario(options: Mapping[str, Any], seed: int, sample: Sample | None = None) -> Any:
    """The emulator scenario named by ``options``, laid onto ``sample`` when one is given."""

    unknown = sorted(set(options) - set(SIM_OPTIONS))
    if unknown:
        raise InputError(
            "driver options",
            f"unknown sim option(s) {', '.join(unknown)} (allowed: {', '.join(SIM_OPTIONS)})",
        )
    name = str(options.get("scenario", "ternary"))
    if name in ROBUST_FIELDS:
        scenario = _robust(name, options, seed)
        return scenario if sample is None else scenario.on_sample(sample)
    if name not in SCENARIOS:
        raise InputError(
            "campaign.scenario",
            f"{name!r} is not allowed: must be one of {', '.join((*SCENARIOS, *ROBUST_FIELDS))}",
        )
    scenario = make_scenario(
        name,
        seed,
        noise=options.get("noise"),
        drift=options.get("drift"),
        truth_csv=options.get("truth_csv"),
        lateral_sd_um=options.get("lateral_sd_um"),
        failure_rate=options.get("failure_rate"),
    )
    return scenario if sample is None else scenario.on_sample(sample)


def _robust(name: str, options: Mapping[str, Any], seed: int) -> Any:
    """A robustness field of the bench (drivers.sim.robust_fields) on the ternary library's stage."""

    fixed = sorted(k for k in options if k not in ("scenario", "failure_rate"))
    if fixed:
        raise InputError(
            "driver options", f"the robustness field {name!r} fixes its own {', '.join(fixed)}: leave it out"
        )
    scenario = robust_scenario(name, seed)
    rate = options.get("failure_rate")
    if rate is not None:
        scenario = dataclasses.replace(scenario, failures=FailureModes.at_rate(float(rate), seed))
    return scenario


def _sim_part(kind: str, options: Mapping[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in options.items() if kind != "kla" or k not in KLA_OPTIONS}


def default_sample(kind: str, options: Mapping[str, Any], seed: int) -> Sample:
    """The sample a run uses when none is given: the simulated scenario's built-in one (for the KLA
    driver: the one a fake InView emulates; a real run gives its --sample)."""
    _check_kind(kind)
    sample: Sample = sim_scenario(_sim_part(kind, options), seed).sample
    return sample


def make_driver(
    kind: str,
    sample: Sample,
    profile: InstrumentProfile,
    options: Mapping[str, Any],
    *,
    seed: int = 0,
    speed: float | None = None,
    journal: str | Path | None = None,
) -> Driver:
    """The instrument driver for a run on ``sample`` (the KLA driver keeps its exports beside ``journal``)."""
    _check_kind(kind)
    if kind == "kla":
        if journal is None:
            raise InputError(
                "--journal", "the KLA driver needs the run's journal (its exports are kept beside it)"
            )
        x0, x1, y0, y1 = sample.calibration.bounds_um
        exchange = options.get("exchange")
        start = ((x0 + x1) / 2.0, (y0 + y1) / 2.0)
        return make_kla_driver(
            profile, journal, None if exchange is None else str(exchange), start_um=start, speed=speed
        )
    driver: Driver = sim_scenario(options, seed, sample).make_driver(profile, speed=speed)
    return driver


def make_evaluator(
    kind: str, sample: Sample, options: Mapping[str, Any], *, seed: int = 0
) -> MapEvaluator | None:
    """The map-error scorer where the driver knows a truth (the simulated instrument, or the emulated sample a
    fake InView plays when the KLA run names its scenario), else None."""
    _check_kind(kind)
    if kind == "kla" and "scenario" not in options:
        return None
    evaluator: MapEvaluator = sim_scenario(_sim_part(kind, options), seed, sample).evaluator()
    return evaluator


class Registry:
    """The drivers a run may name, as ``core.run.compose`` asks for them (:class:`core.run.compose.Drivers`)."""

    def default_sample(self, spec: RunSpec) -> Sample:
        return default_sample(spec.driver, spec.driver_options, spec.campaign.seed)

    def driver(
        self, spec: RunSpec, sample: Sample, profile: InstrumentProfile, journal: Path | None
    ) -> Driver:
        c = spec.campaign
        return make_driver(
            spec.driver, sample, profile, c.driver_options, seed=c.seed, speed=spec.speed, journal=journal
        )

    def evaluator(self, spec: RunSpec, sample: Sample) -> MapEvaluator | None:
        return make_evaluator(spec.driver, sample, spec.driver_options, seed=spec.campaign.seed)

    # -- a tray (core.run.tray.TrayDrivers) ---------------------------------------------------------------
    def tray_sample(self, spec: RunSpec, entry: TraySample) -> Sample:
        """A tray sample without a file: the sim driver's built-in one for its scenario (placed by the tray)."""
        _check_kind(spec.driver)
        if spec.driver != "sim" or not entry.sim:
            raise InputError(f"sample {entry.name!r}", "no sample file (a scenario needs --driver sim)")
        return default_sample("sim", entry.sim, spec.campaign.seed)

    def tray_driver(self, spec: RunSpec, tray: Tray, journal: Path | None) -> Driver:
        """One instrument over the tray: the simulated tray (drivers.sim.tray), or the KLA driver with the
        tray's samples (drivers.kla.tray), its exports beside ``journal``."""
        _check_kind(spec.driver)
        options = spec.campaign.driver_options
        if spec.driver == "kla":
            if journal is None:
                raise InputError(
                    "--journal", "the KLA driver needs the run's journal (its exports are kept beside it)"
                )
            kla = KlaTray(tray, tray_profiles(tray, spec.campaign))
            x0, x1, y0, y1 = tray.libraries[0].placed.calibration.bounds_um
            exchange = options.get("exchange")
            return make_kla_driver(
                kla.first_profile, journal, None if exchange is None else str(exchange),
                start_um=((x0 + x1) / 2.0, (y0 + y1) / 2.0), speed=spec.speed, tray=kla,
            )  # fmt: skip
        driver: Driver = make_tray_driver(tray, options, spec.campaign.seed, sim_scenario, spec.speed)
        return driver

    def tray_evaluator(self, spec: RunSpec, entry: TraySample) -> MapEvaluator | None:
        """A library's map scorer (its truth laid onto its placed sample) on the sim driver, else None."""
        if spec.driver != "sim" or entry.reference is not None:
            return None
        evaluator: MapEvaluator = sim_scenario(entry.sim, spec.campaign.seed, entry.placed).evaluator()
        return evaluator


DRIVERS = Registry()

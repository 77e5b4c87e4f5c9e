"""How a run is built: the one place that turns a :class:`~core.run.spec.RunSpec` into a running engine.

``compose(spec, drivers, record)`` resolves the sample, builds the campaign complete (its refit rhythm, its
wall clock and its simulated operator are constructor arguments, never set afterwards), the driver and the
map scorer (from ``drivers``: core never imports a driver, the application passes
``drivers.registry.DRIVERS``), the interlock, the sinks and the engine. ``aeni run``, a detached engine,
``aeni resume``, ``aeni simulate``, the demo, the bench, the benchmarks and the console tests all come here;
:func:`engine_for` is the one place an :class:`~core.run.engine.Engine` is constructed.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

from core.campaign import Campaign
from core.driver import Driver
from core.errors import InputError
from core.interlock import Interlock
from core.interlock_tray import TrayInterlock
from core.metrics import MapEvaluator
from core.operator import Attendance
from core.profile import InstrumentProfile
from core.run.engine import Engine
from core.run.events import RunRecord, Sink
from core.run.spec import EngineRules, RunSpec
from core.run.tray import TrayCampaign, TrayDrivers
from core.sample import Sample

if TYPE_CHECKING:
    from core.operator import OperatorAvailability
    from core.visits import SimulatedOperator


class Drivers(Protocol):
    """Where a run's instrument comes from (``drivers.registry.DRIVERS``), passed in: core imports no driver."""

    def default_sample(self, spec: RunSpec) -> Sample:
        """The sample a run indents when its spec names none (a simulated scenario's built-in one)."""
        ...

    def driver(
        self, spec: RunSpec, sample: Sample, profile: InstrumentProfile, journal: Path | None
    ) -> Driver:
        """The instrument for ``spec`` on ``sample`` (a KLA driver keeps its exports beside ``journal``)."""
        ...

    def evaluator(self, spec: RunSpec, sample: Sample) -> MapEvaluator | None:
        """The map-error scorer where the driver knows a truth (the simulated instrument), else None."""
        ...


@dataclass(frozen=True)
class Hosting:
    """How the process that hosts the engine runs it: not what the run is, so not in the spec."""

    progress: Callable[[str], None] | None = None  # a line per block (the engine process's log)
    watch_s: float | None = 0.2  # how often a thread watches the journal for commands; None: no watcher
    map_display_n: int | None = 50  # map fields for a console; None: none (nobody watches)
    sleep: Callable[[float], None] = time.sleep  # while paused or waiting for an approval
    wall_clock: Callable[[], float] = time.monotonic  # what approval_timeout_s is measured on
    local_now: Callable[[], datetime] | None = None  # the operator's local time (None: the machine's)


# sinks that need the run's campaign or its map scorer (a bench's figures) are made once those exist
SinksFor = Callable[[Campaign, MapEvaluator | None], Sequence[Sink]]

DEFAULT_RULES = EngineRules()
HEADLESS = Hosting(watch_s=None, map_display_n=None)  # nobody at a console: auto supervision, in memory


@dataclass
class ComposedRun:
    """A run put together, ready for ``engine.run()``."""

    spec: RunSpec  # with its sample resolved: the spec the journal keeps
    campaign: Campaign
    driver: Driver
    evaluator: MapEvaluator | None
    engine: Engine
    visits: SimulatedOperator | None  # the spec's simulated operator (its calendar), None without one
    # a tray run (spec.tray): what the engine drives; ``campaign`` is then its first library's
    tray: TrayCampaign | None = None


def resolve_sample(spec: RunSpec, drivers: Drivers) -> RunSpec:
    """The spec with its sample named (the driver's built-in one when none was given), so a journal always
    holds the sample its run indented."""
    if spec.campaign.sample is not None:
        return spec
    sample = drivers.default_sample(spec)
    return dataclasses.replace(spec, campaign=dataclasses.replace(spec.campaign, sample=sample))


def compose(
    spec: RunSpec,
    drivers: Drivers,
    record: Callable[[RunSpec, Campaign], RunRecord],
    *,
    journal: Path | None = None,
    sinks: Sequence[Sink] | SinksFor = (),
    hosting: Hosting = Hosting(),
    driver: Callable[[Driver], Driver] | None = None,
    prepare: Callable[[Campaign], None] | None = None,
) -> ComposedRun:
    """Build the run ``spec`` describes.

    ``record(spec, campaign)`` opens the run's record (a new journal, a reopened one for a resume, or memory):
    it is called once the campaign exists, before the driver is made. ``sinks`` see every event after the
    record (a function of the campaign and the map scorer makes them once those exist). ``driver`` may wrap the instrument (the console tests' gated one); ``prepare`` sees the campaign
    before the engine does (a test's stricter guard).
    """
    if spec.tray is not None:
        return _compose_tray(spec, drivers, record, journal, sinks, hosting, driver)
    spec = resolve_sample(spec, drivers)
    visits = spec.calendar.operator() if spec.calendar is not None else None
    campaign = Campaign(
        spec.campaign,
        refit_every=spec.refit_every,
        wall_s_per_instrument_s=spec.wall_s_per_instrument_s,
        attendance=Attendance(visits.unattended if visits is not None else None),
    )
    if prepare is not None:
        prepare(campaign)
    rec = record(spec, campaign)
    instrument = drivers.driver(spec, campaign.sample, campaign.profile, journal)
    if driver is not None:
        instrument = driver(instrument)
    evaluator = drivers.evaluator(spec, campaign.sample)
    extra = sinks(campaign, evaluator) if callable(sinks) else sinks
    engine = engine_for(
        campaign,
        instrument,
        rec,
        spec.rules,
        evaluator=evaluator,
        sinks=[*([visits] if visits is not None else []), *extra],
        hosting=hosting,
        operator=spec.operator,
    )
    return ComposedRun(spec, campaign, instrument, evaluator, engine, visits)


def _compose_tray(
    spec: RunSpec,
    drivers: Drivers,
    record: Callable[[RunSpec, Campaign], RunRecord],
    journal: Path | None,
    sinks: Sequence[Sink] | SinksFor,
    hosting: Hosting,
    driver: Callable[[Driver], Driver] | None,
) -> ComposedRun:
    """A tray (core.run.tray): its samples placed, one TrayCampaign over a campaign per library, one
    instrument over the whole stage, every block through the interlock of the sample it is on."""
    if not isinstance(drivers, TrayDrivers) or spec.tray is None:
        raise InputError("--tray", "these drivers cannot run a tray")
    tray = spec.tray.resolved(lambda entry: drivers.tray_sample(spec, entry))
    spec = dataclasses.replace(spec, tray=tray)
    visits = spec.calendar.operator() if spec.calendar is not None else None
    campaign = TrayCampaign(
        tray,
        spec.campaign,
        refit_every=spec.refit_every,
        wall_s_per_instrument_s=spec.wall_s_per_instrument_s,
        attendance=Attendance(visits.unattended if visits is not None else None),
        plans_unattended=spec.rules.supervision == "auto",
    )
    first = next(iter(campaign.lanes.values())).campaign
    rec = record(spec, first)
    instrument = drivers.tray_driver(spec, tray, journal)
    if driver is not None:
        instrument = driver(instrument)
    extra = sinks(first, None) if callable(sinks) else sinks
    engine = engine_for(
        campaign,
        instrument,
        rec,
        spec.rules,
        sinks=[*([visits] if visits is not None else []), *extra],
        hosting=hosting,
        operator=spec.operator,
        interlock=TrayInterlock(tray),
    )
    return ComposedRun(spec, first, instrument, None, engine, visits, campaign)


def engine_for(
    campaign: Campaign | TrayCampaign,
    driver: Driver,
    record: RunRecord,
    rules: EngineRules = DEFAULT_RULES,
    *,
    evaluator: MapEvaluator | None = None,
    sinks: Sequence[Sink] = (),
    hosting: Hosting = HEADLESS,
    operator: OperatorAvailability | None = None,
    interlock: Interlock | None = None,
) -> Engine:
    """The engine over parts already built (``compose``, and ``core.run.headless.run_auto`` for a campaign a
    test or a benchmark built by hand): the one place an Engine is constructed. Every block passes the
    interlock of the campaign's sample and profile (a tray's: of the sample the block is on)."""
    if interlock is None:
        assert isinstance(campaign, Campaign), "a tray's engine needs the tray's interlock"
        interlock = Interlock(campaign.sample, campaign.profile)
    return Engine(
        record,
        campaign,
        driver,
        rules.supervision,
        sleep=hosting.sleep,
        progress=hosting.progress,
        watch_s=hosting.watch_s,
        map_display_n=hosting.map_display_n,
        interlock=interlock,
        evaluator=evaluator,
        max_refusals=rules.max_refusals,
        approval_timeout_s=rules.approval_timeout_s,
        on_timeout=rules.on_timeout,
        wall_clock=hosting.wall_clock,
        sinks=sinks,
        operator=operator,
        local_now=hosting.local_now,
    )

"""Failed and not-run indents: journaled as such, never numbers the model learns from; and the driver's
optional capabilities, which the engine asks for by type."""

from __future__ import annotations

import math
from collections.abc import Generator, Iterator
from pathlib import Path

import pytest
from test_engine import FakeCampaign, make_driver, new_journal

from core.campaign import Campaign
from core.driver import Driver, DriverEvent, PhysicsClock, Recoverable, Restorable
from core.errors import InputError
from core.journal import DriverState, Journal, JournalReader
from core.plan import Block, IndentResult, IndentSpec, IndentStatus, StepRecord
from core.profile import InstrumentProfile
from core.run.engine import Engine
from core.run.events import Steps
from core.runconfig import make_campaign_config
from drivers.replay import ReplayDriver
from drivers.sim.driver import SimulatedDriver


class FlakyInstrument:
    """The simulated instrument, except that chosen indents come back failed or not run, as a real
    instrument reports them. It has none of the optional capabilities."""

    def __init__(self, driver: SimulatedDriver, bad: dict[tuple[int, int], IndentStatus]) -> None:
        self.driver = driver
        self.bad = bad
        self.profile: InstrumentProfile = driver.profile

    def position_um(self) -> tuple[float, float]:
        return self.driver.position_um()

    def clock_s(self) -> float:
        return self.driver.clock_s()

    def program_open(self) -> bool:
        return self.driver.program_open()

    def execute_block(self, block: Block, start_index: int = 0) -> Generator[DriverEvent, None, None]:
        for ev in self.driver.execute_block(block, start_index):
            status = self.bad.get((ev.block_id, ev.indent_index)) if isinstance(ev, IndentResult) else None
            if isinstance(ev, IndentResult) and status is not None:
                spec = block.indents[ev.indent_index]
                yield IndentResult.unmeasured(
                    ev.block_id, ev.indent_index, spec, ev.t_s, status, "no contact"
                )
            else:
                yield ev

    def end_program(self) -> Iterator[StepRecord]:
        return self.driver.end_program()

    def abort(self) -> None:
        self.driver.abort()


def test_capabilities_are_typed_protocols() -> None:
    sim = make_driver()
    assert isinstance(sim, Driver) and isinstance(sim, Restorable)
    assert isinstance(sim, Recoverable) and isinstance(sim, PhysicsClock)
    flaky = FlakyInstrument(sim, {})
    assert isinstance(flaky, Driver)
    assert not isinstance(flaky, Restorable | Recoverable | PhysicsClock)


def test_replay_is_restorable_but_cannot_recover(tmp_path: Path) -> None:
    j = new_journal(tmp_path)
    j.close()
    replay = ReplayDriver(j.path)
    assert isinstance(replay, Restorable) and not isinstance(replay, Recoverable | PhysicsClock)


def test_an_unmeasured_indent_carries_no_numbers() -> None:
    spec = IndentSpec(120.0, 340.0, 80.0)
    r = IndentResult.unmeasured(0, 1, spec, 12.0, "failed", "tip did not touch")
    assert not r.measured and (r.commanded_x_um, r.commanded_y_um, r.hold_s, r.t_s) == (
        120.0,
        340.0,
        80.0,
        12.0,
    )
    assert all(math.isnan(v) for v in (r.hardness_gpa, r.modulus_gpa, r.drift_rate_nm_s, r.actual_x_um))
    with pytest.raises(ValueError, match="failed, not_run or unverified"):
        IndentResult.unmeasured(0, 1, spec, 12.0, "measured", "")
    # a measured indent without a hardness is a driver's mistake, refused before it reaches the journal
    with pytest.raises(ValueError, match="report it as failed"):
        IndentResult(0, 0, 1.0, 1.0, 1.0, 1.0, 80.0, math.nan, 1.0, 0.0, 1.0)


def test_failed_and_not_run_indents_are_journaled_as_such(tmp_path: Path) -> None:
    camp = FakeCampaign(n_blocks=3)
    bad: dict[tuple[int, int], IndentStatus] = {(0, 1): "failed", (2, 3): "not_run"}
    bad.update({(1, i): "failed" for i in range(4)})  # block 1: every indent failed
    j = new_journal(tmp_path)
    eng = Engine(
        j, camp, FlakyInstrument(make_driver(), bad), poll_s=0.01, sleep=lambda s: None, watch_s=None
    )
    eng.run()
    j.close()
    assert eng.completed
    with JournalReader(j.path) as r:
        results = r.results()
        blocks = r.blocks()
        snap = r.snapshot()
    assert len(results) == 12
    got = {(x.block_id, x.indent_index): x.status for x in results if not x.measured}
    assert got == bad
    for x in results:
        assert x.measured == (not math.isnan(x.hardness_gpa))
        assert x.note == ("" if x.measured else "no contact")
    # a block that measured nothing has no centre value and is not a tested centre on the map
    assert [b.median_gpa is None for b in blocks] == [False, True, False]
    assert [t.block_id for t in snap.tested] == [0, 2]
    assert [e.text.split("indents ")[1].split("  ")[0] for e in snap.log if e.text.startswith("block ")] == [
        "4 (1 not measured)",
        "4 (4 not measured)",
        "4 (1 not measured)",
    ]
    # the campaign saw the statuses (the real Campaign skips what was not measured; see below)
    assert [r.status for r in camp.observed[1][1]] == ["failed"] * 4


def test_the_campaign_learns_only_from_measured_indents(tmp_path: Path) -> None:
    from drivers.sim.scenarios import make_scenario

    # a replicate-grid policy: each block is one centre (aeni would make one centre per indent)
    scenario = make_scenario("ternary", 4)
    campaign = Campaign(
        make_campaign_config(policy="cost-aware", seed=4, lattice_n=12, settings={"budget_s": 1e6}),
        scenario.sample,
    )
    driver = scenario.make_driver(campaign.profile)

    def run_block(block_id: int, bad: dict[int, IndentStatus]) -> list[IndentResult]:
        d = campaign.propose(driver.clock_s(), driver.position_um(), driver.program_open(), block_id)
        assert d is not None
        out = []
        for ev in driver.execute_block(d.block):
            if isinstance(ev, IndentResult):
                status = bad.get(ev.indent_index)
                spec = d.block.indents[ev.indent_index]
                out.append(
                    ev
                    if status is None
                    else IndentResult.unmeasured(block_id, ev.indent_index, spec, ev.t_s, status, "x")
                )
        campaign.observe_block(d.block, out)
        return out

    first = run_block(0, {0: "failed", 2: "not_run"})
    measured = [r for r in first if r.measured]
    assert len(campaign.centres) == 1 and campaign.centres[0].n_indents == len(measured) == len(first) - 2
    assert math.isfinite(campaign.centres[0].value_gpa)
    run_block(1, {})
    assert campaign.prediction is not None
    before = campaign.observations()
    everything_failed = run_block(2, dict.fromkeys(range(25), "failed"))
    assert not any(r.measured for r in everything_failed)
    # the fit goes on without the block: same training rows, the block itself counted as run
    assert len(campaign.centres) == 2 and len(campaign.blocks) == 3
    assert (campaign.observations().median_gpa == before.median_gpa).all()


def test_a_driver_that_cannot_be_restored_cannot_resume_a_run(tmp_path: Path) -> None:
    j = new_journal(tmp_path)
    j.begin_session(
        "start"
    )  # an engine ran here and left the tip engaged at t = 100 s (its event log says so)
    j.emit(Steps(100.0, (), DriverState(100.0, 100.0, (500.0, 500.0), True, "indent"), "", "engine", None))
    j.close()
    j2 = Journal.open_writer(j.path)
    eng = Engine(j2, FakeCampaign(n_blocks=1), FlakyInstrument(make_driver(), {}), poll_s=0.01, watch_s=None)
    with pytest.raises(InputError, match=r"FlakyInstrument cannot be put back .* cannot be resumed with it"):
        eng.run()
    j2.close()

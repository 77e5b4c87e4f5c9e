"""The simulated instrument fails like the real one: invalid values, no surface, aborted arrays, at set
rates, reproducible from the seed; at rate 0 every run is what it was."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from core.campaign import Campaign
from core.errors import InputError
from core.plan import IndentResult
from core.runconfig import make_campaign_config
from drivers.registry import sim_scenario
from drivers.sim.failures import FailureModes


def _run(failure_rate: float | None, seed: int = 0, blocks: int = 12) -> list[list[IndentResult]]:
    cfg = make_campaign_config(
        "f",
        policy="cost-aware",
        seed=seed,
        lattice_n=30,
        failure_rate=failure_rate,
        settings={"budget_s": 1e9},
    )
    scen = sim_scenario(cfg.driver_options, seed)
    campaign = Campaign(cfg, scen.sample)
    driver = scen.make_driver(campaign.profile)
    out = []
    for block_id in range(blocks):
        d = campaign.propose(driver.clock_s(), driver.position_um(), driver.program_open(), block_id)
        assert d is not None
        results = [e for e in driver.execute_block(d.block) if isinstance(e, IndentResult)]
        assert [r.indent_index for r in results] == list(range(d.block.n_indents))
        campaign.observe_block(d.block, results)
        out.append(results)
    return out


def _key(r: IndentResult) -> tuple[object, ...]:
    return tuple("nan" if isinstance(v, float) and math.isnan(v) else v for v in vars(r).values())


def test_rate_zero_changes_nothing() -> None:
    assert not FailureModes.at_rate(0.0, 3).enabled
    a, b = _run(None, blocks=4), _run(0.0, blocks=4)
    assert [[_key(r) for r in bl] for bl in a] == [[_key(r) for r in bl] for bl in b]
    assert all(r.status == "measured" for bl in a for r in bl)


def test_failures_come_as_the_real_instrument_gives_them_and_again_from_the_same_seed() -> None:
    runs = _run(0.2, seed=4, blocks=16)
    statuses = [r.status for bl in runs for r in bl]
    assert "failed" in statuses and "not_run" in statuses
    for block in runs:
        notes = {r.note for r in block if r.status == "not_run"}
        if any("surface not found" in n for n in notes):
            assert all(r.status == "not_run" for r in block)  # no indent at all
        elif any("aborted" in n for n in notes):
            half = len(block) // 2
            assert all(r.status != "not_run" for r in block[:half])
            assert all(r.status == "not_run" for r in block[half:])
    for r in (r for bl in runs for r in bl if r.status == "failed"):
        assert "1.797e+308" in r.note and math.isnan(r.hardness_gpa)  # never a number to learn from
    again = _run(0.2, seed=4, blocks=16)
    assert [[_key(r) for r in bl] for bl in runs] == [[_key(r) for r in bl] for bl in again]


def test_the_rate_is_the_share_of_invalid_indents() -> None:
    modes = FailureModes.at_rate(0.015, seed=7)
    n = 20_000
    invalid = sum(modes.invalid(b, i) for b in range(n // 25) for i in range(25))
    assert invalid / n == pytest.approx(0.015, abs=0.003)
    faults = [modes.block_fault(b) for b in range(20_000)]
    assert faults.count("surface-not-found") / 20_000 == pytest.approx(0.015 / 4, abs=0.0015)
    assert faults.count("aborted") / 20_000 == pytest.approx(0.015 / 4, abs=0.0015)
    other = FailureModes.at_rate(0.015, seed=8)
    assert [other.invalid(0, i) for i in range(2000)] != [modes.invalid(0, i) for i in range(2000)]


@pytest.mark.parametrize("rate", [-0.1, 0.6, math.nan])
def test_a_bad_rate_is_refused(rate: float) -> None:
    with pytest.raises(InputError, match="failure_rate"):
        make_campaign_config("f", failure_rate=rate)


def test_an_engine_run_with_failures_completes_its_budget_alone(tmp_path: Path) -> None:
    """auto supervision, the simulated instrument failing 10 % of indents: the run ends by its budget."""
    from aeni_console.cli.run import run_engine
    from core.journal import JournalReader
    from core.runconfig import RunOptions

    cfg = make_campaign_config(
        "fails", policy="cost-aware", seed=2, lattice_n=30, failure_rate=0.1, settings={"indent_budget": 300}
    )
    path = tmp_path / "fails.sqlite"
    assert run_engine(path, create=(cfg, RunOptions()), quiet=True) == 0
    with JournalReader(path) as r:
        row = r.q.engine_row()
        indents = r.results()
    assert row["completed"] and "indent budget" in row["stop_reason"]
    statuses = {i.status for i in indents}
    assert {"measured", "failed"} <= statuses

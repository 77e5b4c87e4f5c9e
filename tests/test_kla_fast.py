"""Fast (NanoBlitz-class) arrays through the KLA driver (issue 36): one ticket naming the profile's NanoBlitz
method, its peak load and its grid; the fake InView reads the emulator's fast channel and writes the NanoBlitz
CSV (BOM, units row, X/Y Position, blank cells on failed indents); the driver matches its rows to the sites by
position, and every indent comes back with the channel "fast", a failed one failed, never a number."""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_kla_driver import PROFILE, SEED, driver, run_block, running_fake

from core.campaign import Campaign
from core.campaign_config import campaign_config_to_dict
from core.fast_array import FastArray, fast_block, fast_block_cost_s
from core.journal import Journal, JournalReader
from core.plan import Block, Decision, IndentResult
from core.policies.base import PlanContext, Policy
from core.policies.fidelity import FastArrays, candidate_arrays
from core.run.compose import HEADLESS, engine_for
from core.runconfig import make_campaign_config
from drivers.kla.driver import KlaDriver
from drivers.kla.exchange import ExchangeFolder, MethodStep, Ticket, make_ticket, ticket_panel, ticket_text
from drivers.kla.export import read_kla_export
from drivers.kla.fake_nanoblitz import nanoblitz_csv
from drivers.kla.inbox import FAST_ORDER, match_rows, outcomes_for
from drivers.sim.driver import SimulatedDriver
from drivers.sim.scenarios import make_scenario

FAST = PROFILE.fast
assert FAST is not None


def array_block(block_id: int = 0, rows: int = 6, cols: int = 5, pitch_um: float = 10.0) -> Block:
    return fast_block(block_id, FastArray(500.0, 500.0, rows, cols, pitch_um))


@pytest.fixture
def exchange(tmp_path: Path) -> Path:
    root = tmp_path / "exchange"
    root.mkdir()
    return root


# ------------------------------------------------------------------------------------------ the ticket


def test_a_fast_array_is_one_ticket_naming_the_nanoblitz_method_its_load_and_grid(exchange: Path) -> None:
    b = array_block()
    t = make_ticket("r1", b, PROFILE.inview, expected_s=120.0, fast=FAST)
    assert t.methods == (MethodStep(0.0, "NanoBlitz 3D.nmt", 1, 30),)
    assert t.fast is not None
    assert (t.fast.method, t.fast.peak_load_mn, t.fast.rows, t.fast.cols, t.fast.pitch_um) == (
        "NanoBlitz 3D.nmt",
        5.0,
        6,
        5,
        10.0,
    )
    assert (t.fast.first_x_um, t.fast.first_y_um, t.fast.left_out) == (480.0, 475.0, 0)
    text = ticket_text(t)
    assert "NANOBLITZ FAST ARRAY (not CSM): 30 load-controlled indents" in text
    assert '4. Test method: "NanoBlitz 3D.nmt"' in text and "peak load\n   5 mN" in text
    assert "full grid of 6 rows (y) × 5 columns (x) at 10 µm" in text and f"inbox/{t.export_stem}.csv" in text
    assert "NANOBLITZ fast array: 30 sites" in ticket_panel(t)
    # the JSON ticket (the fake InView's trigger) carries it; a ticket written before it reads as CSM
    folder = ExchangeFolder(exchange, "r1", PROFILE.inview)
    folder.publish(t)
    assert folder.read_ticket(0) == t
    old = t.to_dict()
    del old["fast"]
    assert Ticket.from_dict(old, "old").fast is None
    # a fast block's ticket cannot be made without the fast mode: never as a CSM ticket
    with pytest.raises(ValueError, match="fast mode"):
        make_ticket("r1", b, PROFILE.inview, expected_s=120.0)


def test_an_array_with_sites_left_out_must_be_run_from_the_sites_file() -> None:
    keep = np.ones(30, dtype=bool)
    keep[[3, 17]] = False  # near an earlier indent, off the sample ...
    b = fast_block(0, FastArray(500.0, 500.0, 6, 5, 10.0), keep)
    t = make_ticket("r1", b, PROFILE.inview, expected_s=120.0, fast=FAST)
    assert t.fast is not None and t.fast.left_out == 2 and not t.fast.full_grid
    text = ticket_text(t)
    assert "28 of a grid of 6 rows (y) × 5 columns (x)" in text and "do NOT run the full grid" in text
    # a resumed array: what is left of it
    rest = make_ticket("r1", b, PROFILE.inview, expected_s=60.0, first_index=10, fast=FAST)
    assert rest.n_sites == 18 and rest.methods == (MethodStep(0.0, "NanoBlitz 3D.nmt", 1, 18),)


# ------------------------------------------------------------------------------ the array, end to end


def sim_fast(b: Block) -> tuple[list[IndentResult], float]:
    sim = SimulatedDriver(make_scenario("ternary", SEED).make_emulator(), PROFILE)
    results = [ev for ev in sim.execute_block(b) if isinstance(ev, IndentResult)]
    return results, sim.clock_s()


def test_a_fast_array_runs_through_the_fake_inview_as_the_simulator_reads_it(
    exchange: Path, tmp_path: Path
) -> None:
    d = driver(exchange, tmp_path)
    b = array_block(rows=12, cols=12)
    for _ in running_fake(exchange, rate=0.1):
        results, steps, waits = run_block(d, b)
    assert [r.indent_index for r in results] == list(range(144))
    assert {r.channel for r in results} == {"fast"}
    failed = [r for r in results if r.status == "failed"]
    assert failed and {r.status for r in results} == {"measured", "failed"}
    for r in failed:  # a blank cell is a failed indent with its reason, never a number
        assert math.isnan(r.hardness_gpa) and math.isnan(r.modulus_gpa) and "blank" in r.note
        assert r.depth_at_max_load_nm is None
    expect, sim_clock_s = sim_fast(b)
    for r, s in zip(results, expect, strict=True):
        if r.measured:  # what the emulator's fast channel read, to the export's decimals
            assert s.measured
            assert r.hardness_gpa == pytest.approx(s.hardness_gpa, abs=5e-5)
            assert r.modulus_gpa == pytest.approx(s.modulus_gpa, abs=5e-4)
            assert r.depth_at_max_load_nm == pytest.approx(s.depth_nm, abs=5e-3)
            assert math.isnan(r.drift_rate_nm_s) and r.hold_s == 0.0
    # the fast array's time, as the planner priced it and the simulator charges it
    assert d.clock_s() == pytest.approx(sum(s.seconds for s in steps)) == pytest.approx(sim_clock_s)
    assert d.clock_s() == pytest.approx(fast_block_cost_s(PROFILE, b, (0.0, 0.0), False))
    assert waits[-1].waiting.startswith("export r1-000-export.csv accepted")
    # the archived export is the NanoBlitz CSV, named so by the reader
    (archived,) = (tmp_path / "r1.sqlite.exports").glob("*-r1-000-export.csv")
    raw = archived.read_bytes()
    assert raw.startswith(b"\xef\xbb\xbfTest,X Position,Y Position,") and b"\r\n,\xc2\xb5m,\xc2\xb5m," in raw
    assert read_kla_export(archived).software == "NanoBlitz 3D"
    assert raw.count(b",,,,\r\n") == len(failed)  # a failed indent's row: its position, blank values
    manifest = [json.loads(line) for line in (tmp_path / "r1.sqlite.exports" / "manifest.jsonl").open()]
    assert manifest[-1]["format"] == "NanoBlitz 3D"


def test_a_resumed_fast_array_runs_only_its_rest_and_reads_what_the_whole_array_would(
    exchange: Path, tmp_path: Path
) -> None:
    d = driver(exchange, tmp_path)
    b = array_block()
    d.set_state(0.0, (b.indents[9].x_um, b.indents[9].y_um), True)  # indents 0-9 are in the journal
    for _ in running_fake(exchange):
        results = [ev for ev in d.execute_block(b, 10) if isinstance(ev, IndentResult)]
    assert [r.indent_index for r in results] == list(range(10, 30)) and {r.channel for r in results} == {
        "fast"
    }
    ticket = d.folder.read_ticket(0)
    assert ticket is not None and ticket.fast is not None and ticket.n_sites == 20
    whole, _ = sim_fast(b)
    both = [(r, whole[r.indent_index]) for r in results if r.measured and whole[r.indent_index].measured]
    assert len(both) >= 15  # the draws are keyed by the index in the array: the rest reads as the whole
    for r, w in both:
        assert r.hardness_gpa == pytest.approx(w.hardness_gpa, abs=5e-5)


@pytest.mark.parametrize("fault", ["aborted", "mm-um"])
def test_fast_array_faults_end_as_for_any_array(exchange: Path, tmp_path: Path, fault: str) -> None:
    d = driver(exchange, tmp_path)
    b = array_block()
    for _ in running_fake(exchange, fault):
        results, _steps, waits = run_block(d, b)
    assert [r.indent_index for r in results] == list(range(30)) and {r.channel for r in results} == {"fast"}
    if fault == "aborted":
        assert [r.status == "not_run" for r in results] == [False] * 15 + [True] * 15
    else:
        assert all(r.status in ("measured", "failed") for r in results)
        assert any("mm labelled as µm" in n for w in waits for n in w.notes)
        for r, s in zip(results, b.indents, strict=True):
            if r.measured:
                assert (r.actual_x_um, r.actual_y_um) == pytest.approx((s.x_um, s.y_um), abs=0.1)


def test_a_kla_driver_without_a_fast_mode_refuses_a_fast_array(exchange: Path, tmp_path: Path) -> None:
    d = driver(exchange, tmp_path, replace(PROFILE, fast=None))
    with pytest.raises(ValueError, match="is a fast array but profile kla-imicro has no fast mode"):
        next(iter(d.execute_block(array_block())))


# ------------------------------------------------------------------------------- reading and matching


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    hardness=st.lists(st.floats(0.5, 40.0), min_size=1, max_size=30),
    failed=st.lists(st.booleans(), min_size=30, max_size=30),
)
def test_the_fakes_nanoblitz_csv_reads_back(
    tmp_path: Path, hardness: list[float], failed: list[bool]
) -> None:
    b = array_block()
    results = [
        IndentResult(
            0, i, s.x_um, s.y_um, s.x_um, s.y_um, 0.0, h, 20 * h, math.nan, 0.0, "measured", "", 150.0, "fast"
        )
        for i, (s, h) in enumerate(zip(b.indents, hardness, strict=False))
    ]
    path = tmp_path / "nb.csv"
    path.write_bytes(nanoblitz_csv(results, 5.0, lambda r: failed[r.indent_index]))
    export = read_kla_export(path)
    assert export.software == "NanoBlitz 3D" and len(export.indents) == len(results)
    for got, r in zip(export.indents, results, strict=True):
        assert (got.x_um, got.y_um) == (r.commanded_x_um, r.commanded_y_um)
        if failed[r.indent_index]:
            assert got.failed and got.hardness_gpa is None and got.modulus_gpa is None
        else:
            assert got.hardness_gpa == pytest.approx(r.hardness_gpa, abs=5e-5)
            assert got.max_depth_nm == 150.0 and got.max_load_mn == 5.0


def _export_rows(tmp_path: Path, b: Block, order: list[int], dx_um: float = 0.0) -> Path:
    rows = [
        IndentResult(
            0, i, b.indents[i].x_um + dx_um, b.indents[i].y_um, 0, 0, 0.0, 5.0 + i / 100, 100.0, math.nan, 0.0
        )
        for i in order
    ]
    path = tmp_path / "nb.csv"
    path.write_bytes(nanoblitz_csv(rows, 5.0, lambda _r: False))
    return path


def test_rows_are_matched_to_sites_by_position_within_the_tolerance(tmp_path: Path) -> None:
    """NanoBlitz may make its grid in its own order (a raster here, not the plan's snake): each row goes to the
    site it lies on. Tolerance: the profile's 3 µm, but under half the pitch (0.45 × 5 µm = 2.25 µm), so no
    row can lie on two sites."""
    b = array_block(rows=4, cols=4, pitch_um=5.0)
    ticket = make_ticket("r1", b, PROFILE.inview, expected_s=60.0, fast=FAST)
    raster = sorted(range(16), key=lambda i: (b.indents[i].y_um, b.indents[i].x_um))
    export = read_kla_export(_export_rows(tmp_path, b, raster))
    match = match_rows(export, ticket, PROFILE.inview.position_tolerance_um)
    assert not match.refusal and match.notes == (FAST_ORDER,)
    outcomes = outcomes_for(export, ticket, match, "not run")
    assert [o.hardness_gpa for o in outcomes] == pytest.approx([5.0 + i / 100 for i in range(16)])
    near = read_kla_export(_export_rows(tmp_path, b, list(range(16)), dx_um=2.0))
    assert not match_rows(near, ticket, PROFILE.inview.position_tolerance_um).refusal
    off = read_kla_export(_export_rows(tmp_path, b, list(range(16)), dx_um=2.5))
    assert "off by (+2.5, +0.0) µm" in match_rows(off, ticket, PROFILE.inview.position_tolerance_um).refusal


def test_real_nanoblitz_exports_in_shared_read_with_failed_indents_failed(kla_dir: Path) -> None:
    found = []
    for path in sorted(p for p in kla_dir.iterdir() if p.suffix.lower() in (".csv", ".txt", ".xlsx", ".xls")):
        export = read_kla_export(path)
        if export.software.startswith("NanoBlitz"):
            found.append(export)
    if not found:
        pytest.skip(
            f"no NanoBlitz export in {kla_dir} (only InView/NanoSuite workbooks): nothing real to read"
        )
    for export in found:
        assert export.indents and export.has_positions
        for i in export.indents:
            assert (i.hardness_gpa is None) == i.failed


# --------------------------------------------------------------------------- a run with a fast array


class FastArrayFirst:
    """``aeni+fast`` with its first decision made by script: the smallest array the planner itself may propose
    (its own candidates, filtered by the interlock's rules), so a short test runs one; the planner's own
    decisions after it (the CSM space-filling start), then a stop."""

    def __init__(self, inner: Policy, blocks: int) -> None:
        self.inner, self.name, self.parts, self.blocks = inner, inner.name, inner.parts, blocks

    def propose(self, ctx: PlanContext) -> Decision | None:
        if ctx.blocks_done >= self.blocks:
            return None
        if ctx.blocks_done > 0:
            return self.inner.propose(ctx)
        array, keep = min(candidate_arrays(ctx, FastArrays()), key=lambda a: a[0].n_indents)
        block = fast_block(ctx.block_id, array, keep)
        cost_s = fast_block_cost_s(ctx.profile, block, ctx.position_um, ctx.program_open)
        return Decision(block, self.name, 0.0, 0.0, cost_s, reason="scripted fast array", phase="fast")


def test_an_aeni_fast_run_on_the_kla_driver_makes_a_fast_array_end_to_end(
    exchange: Path, tmp_path: Path
) -> None:
    scenario = make_scenario("ternary", SEED)
    config = make_campaign_config(policy="aeni+fast", seed=SEED, lattice_n=20, settings={"budget_s": 1e6})
    campaign = Campaign(config, scenario.sample)
    scripted = FastArrayFirst(campaign.policy, blocks=2)
    campaign._policies = (scripted, scripted)  # the registry's aeni+fast, its first decision by script
    path = tmp_path / "run.sqlite"
    journal = Journal.create(
        path, campaign_config_to_dict(campaign.config), PROFILE, campaign.calibration.to_dict(), driver="kla",
        grid_baseline_s=campaign.grid_baseline_s, stage_bounds_um=campaign.stage_bounds_um, name="run",
    )  # fmt: skip
    kla = KlaDriver(PROFILE, exchange, "run", tmp_path / "run.sqlite.exports", speed=1e6)
    served: Iterator[object] = running_fake(exchange, rate=0.05)
    next(served)
    try:
        engine = engine_for(campaign, kla, journal, hosting=HEADLESS)
        engine.run()
    finally:
        next(served, None)
        journal.close()
    assert engine.completed
    with JournalReader(path) as reader:
        got = reader.results()
    fast = [r for r in got if r.block_id == 0]
    csm = [r for r in got if r.block_id == 1]
    assert fast and {r.channel for r in fast} == {"fast"} and {r.hold_s for r in fast} == {0.0}
    assert csm and {r.channel for r in csm} == {"csm"}
    failed = [r for r in fast if r.status == "failed"]
    assert failed and all(math.isnan(r.hardness_gpa) for r in failed)
    assert all(math.isfinite(r.hardness_gpa) for r in fast if r.status == "measured")
    # the campaign learnt the fast indents as fast, never as CSM centres, and kept its CSM indents off them
    assert campaign.fast is not None and campaign.fast.n == sum(r.status == "measured" for r in fast)
    assert len(campaign.centres) == sum(r.status == "measured" for r in csm)
    fxy = np.array([(r.commanded_x_um, r.commanded_y_um) for r in fast])
    for r in csm:
        assert np.hypot(*(fxy - (r.commanded_x_um, r.commanded_y_um)).T).min() >= 20.0 - 1e-6
    assert (exchange / "outbox" / "run-000-ticket.txt").read_text().count("NANOBLITZ FAST ARRAY") == 1
    assert "NANOBLITZ" not in (exchange / "outbox" / "run-001-ticket.txt").read_text()

"""A tray on the KLA driver, end to end against the fake InView (in-process, at a high speed): every indent
inside its own sample, every ticket naming the sample its array is on, the sample change charged once per
change (what the planner priced, the ticket expected and the driver charged agree), a crashed run resumed
with the tip on the sample it was on, and a worn tip pausing the run at the reference."""

from __future__ import annotations

import itertools
import json
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from aeni_console.cli.host import create_run_journal, run_engine
from aeni_console.cli.main import main as cli_main
from aeni_console.cli.tray import resolve_tray, tray_spec
from core.campaign_config import CampaignConfig
from core.cost import indent_steps
from core.journal import JournalReader
from core.plan import Block, IndentResult, StepRecord, local_grid
from core.profile import load_profile
from core.run.compose import Hosting, compose
from core.run.spec import RunSpec
from core.run.tray import tray_profiles
from core.runview import EngineState
from core.sample.tray import Tray, parse_tray
from core.sample_change import change_s
from drivers.kla.array_run import ArrayEnd
from drivers.kla.driver import KlaDriver
from drivers.kla.exchange import Ticket, make_ticket, ticket_panel, ticket_text
from drivers.kla.fake_inview import FakeInView, Fault, parse_fault
from drivers.kla.inbox import SiteOutcome
from drivers.kla.tray import KlaTray
from drivers.registry import DRIVERS, sim_scenario
from drivers.sim.tray import make_tray_driver
from tests.test_kla_run import FAST_PROFILE
from tests.test_tray_cli import _crash_after

SEED = 0
# the built-in scenarios' samples as sample files (a KLA tray names a file per sample), on one profile
CORNERS = {
    "tern": ((0.0, 1000.0), (1000.0, 1000.0), (1000.0, 0.0), (0.0, 0.0)),
    "film": ((10000.0, 23000.0), (15000.0, 23000.0), (15000.0, 20000.0), (10000.0, 20000.0)),
}


def _sample_file(path: Path, name: str, profile: Path) -> None:
    tl, tr, br, bl = CORNERS[name]
    corners = "".join(
        f"{k} = {{ x_um = {x}, y_um = {y}, z_um = 1500.0 }}\n"
        for k, (x, y) in zip(("tl", "tr", "br", "bl"), (tl, tr, br, bl), strict=True)
    )
    path.write_text(
        f'name = "{name}"\nprofile = "{profile}"\nlattice_n = 20\n[corners]\n{corners}'
        "[safety]\nedge_band_um = 0.0\nstage_rect_um = [0.0, 0.0, 100000.0, 100000.0]\n",
        encoding="utf-8",
    )


def _write_tray(tmp_path: Path, goal_indents: int = 24) -> Path:
    profile = tmp_path / "fast.toml"
    profile.write_text(FAST_PROFILE, encoding="utf-8")
    for name in CORNERS:
        _sample_file(tmp_path / f"{name}.toml", name, profile)
    tray = tmp_path / "tray.toml"
    tray.write_text(
        f'name = "kt"\nprofile = "{profile}"\n'
        f'[[samples]]\nname = "tern"\nfile = "tern.toml"\nscenario = "ternary"\ngoal = {{ indents = {goal_indents} }}\n'
        f'[[samples]]\nname = "film"\nfile = "film.toml"\nscenario = "film"\ngoal = {{ indents = {goal_indents} }}\n'
        '[[samples]]\nname = "silica"\nrole = "reference"\nsize_um = [3000.0, 3000.0]\n'
        "offset_um = [30000.0, 0.0]\ncheck_every_h = 2.0\n",
        encoding="utf-8",
    )
    return tray


@pytest.fixture
def tray_file(tmp_path: Path) -> Path:
    return _write_tray(tmp_path)


def _own_s(profile: Any, block: Block, pos: tuple[float, float], is_open: bool) -> float:
    """A block's own steps from where the tip is (setup, moves, engage, settle, indents): the change left out."""
    own = 0.0
    for i in range(block.n_indents):
        own += sum(s.seconds for s in indent_steps(profile, block, i, pos, is_open))
        pos, is_open = (block.indents[i].x_um, block.indents[i].y_um), True
    return own


def _spec(tray_file: Path, exchange: Path) -> RunSpec:
    base = RunSpec(
        driver="kla",
        campaign=CampaignConfig(seed=SEED, lattice_n=20, driver_options={"exchange": str(exchange)}),
        speed=1e6,
    )
    return tray_spec(base, str(tray_file))


@contextmanager
def fake_inview(
    exchange: Path, tray_file: Path, wear: float = 0.0, faults: tuple[Fault, ...] = ()
) -> Iterator[FakeInView]:
    """The fake InView over the tray (as `aeni kla fake-inview --tray`), serving in a thread."""
    tray, problems = resolve_tray(parse_tray(tray_file), "sim", SEED)
    assert not problems
    options = {"tip_wear_pct_per_h": wear}
    fake = FakeInView(
        exchange, load_profile(tray.libraries[0].placed.profile), None, speed=1e6, invalid_rate=0.0,
        write_s=0.0, log=lambda _line: None, ledger=exchange.parent / "ledger.jsonl", faults=faults,
        tray_driver=lambda: make_tray_driver(tray, options, SEED, sim_scenario, 1e6),
    )  # fmt: skip
    stop = threading.Event()
    thread = threading.Thread(target=fake.serve_forever, kwargs={"poll_s": 0.01, "stop": stop.is_set})
    thread.start()
    try:
        yield fake
    finally:
        stop.set()
        thread.join()


def _tickets(exchange: Path) -> dict[int, Ticket]:
    out = {}
    for path in sorted((exchange / "outbox").glob("*-ticket.json")):
        t = Ticket.from_dict(json.loads(path.read_text(encoding="utf-8")), str(path))
        out[t.block_id] = t
    return out


def _sample_of(tray: Tray, block: Block) -> str:
    here = tray.sample_at(block.indents[0].x_um, block.indents[0].y_um)
    assert here is not None
    return here.name


def _check_run(journal: Path, exchange: Path, tray: Tray) -> None:
    """Every indent inside its own sample and its ticket's; the change charged once per change, and the
    planner's price, the ticket's expectation and the charge agree block by block."""
    tickets = _tickets(exchange)
    with JournalReader(journal) as r:
        records = [b for b in r.blocks() if b.status == "observed"]
    profile = load_profile(tray.libraries[0].placed.profile)
    on: str | None = None
    changes = 0
    for rec in records:
        block, name = rec.block, _sample_of(tray, rec.block)
        entry = tray.by_name(name)
        charged = sum(s.seconds for s in rec.steps)
        if all(res.status == "not_run" for res in rec.results):  # its surface not found: nothing ran, the
            assert charged == 0.0  # tip stayed where it was and no change was charged
            continue
        for res in rec.results:  # inside the sample the block is on (a library: where it may be indented)
            assert tray.sample_at(res.commanded_x_um, res.commanded_y_um) is entry
            xy = np.array([[res.commanded_x_um, res.commanded_y_um]])
            assert entry.role == "reference" or entry.placed.allowed(xy).all()
        ticket = tickets[block.block_id]
        assert ticket.sample == name
        text = (exchange / "outbox" / f"{ticket.run}-{block.block_id:03d}-ticket.txt").read_text("utf-8")
        assert f"1. Sample: {name} on the tray" in text
        assert rec.decision is not None
        assert charged == pytest.approx(rec.decision.predicted_cost_s) == pytest.approx(ticket.expected_s)
        own = _own_s(profile, block, ticket.from_um, ticket.program_open)
        switched = on is not None and on != name
        changes += switched
        assert charged - own == pytest.approx(change_s(profile) if switched else 0.0)
        on = name
    assert changes >= 3  # the reference, the libraries, the reference again (at least)
    ledger = [json.loads(line) for line in (exchange.parent / "ledger.jsonl").read_text().splitlines()]
    assert ledger and all(line["sample"] == tickets[line["block_id"]].sample for line in ledger)


def test_a_kla_tray_runs_to_every_goal_against_the_fake_inview(tray_file: Path, tmp_path: Path) -> None:
    exchange = tmp_path / "exchange"
    exchange.mkdir()
    spec = _spec(tray_file, exchange)
    journal = tmp_path / "runs" / "kt.sqlite"
    with fake_inview(exchange, tray_file):
        assert run_engine(journal, create=spec, quiet=True) == 0
    with JournalReader(journal) as r:
        row = r.q.engine_row()
        state = r.latest_campaign_state()
    assert row["completed"] and "every library reached its goal" in row["stop_reason"]
    assert state is not None and state[0]["tray_run"]["indents"] == {"tern": 24, "film": 24}
    assert spec.tray is not None
    _check_run(journal, exchange, spec.tray)


def test_a_surface_not_found_on_another_sample_leaves_the_tip_where_it_was(
    tray_file: Path, tmp_path: Path
) -> None:
    """Block 1 changes from the reference onto a library and its surface is not found: nothing ran, so the
    tip is still on the reference; the next block onto a library pays the change, priced so by the planner
    (the price, the ticket and the charge agree for every block: _check_run)."""
    exchange = tmp_path / "exchange"
    exchange.mkdir()
    spec = _spec(tray_file, exchange)
    journal = tmp_path / "runs" / "snf.sqlite"
    with fake_inview(exchange, tray_file, faults=(parse_fault("surface-not-found@1"),)):
        assert run_engine(journal, create=spec, quiet=True) == 0
    with JournalReader(journal) as r:
        blocks = [b for b in r.blocks() if b.status == "observed"]
    assert blocks[1].block.block_id == 1 and all(x.status == "not_run" for x in blocks[1].results)
    assert spec.tray is not None
    _check_run(journal, exchange, spec.tray)
    profile = load_profile(spec.tray.libraries[0].placed.profile)
    after = blocks[2]
    assert _sample_of(spec.tray, after.block) != "silica"
    assert after.decision is not None
    assert after.decision.predicted_cost_s >= change_s(profile)


@pytest.mark.parametrize(
    ("crash_after", "where"),
    [
        # the last indent of the first tip check: the resumed run's next block changes onto a library, so
        # the driver must know the tip is on the reference (else it charges no change the planner priced)
        (4, "reference"),
        # inside the first library's block (4 + 9 indents before it at the most): the block goes on where
        # it stopped, on the sample the tip is on, with no change
        (18, "library"),
    ],
)
def test_a_crashed_kla_tray_resumes_with_the_tip_on_its_sample(
    tray_file: Path, tmp_path: Path, crash_after: int, where: str
) -> None:
    exchange = tmp_path / "exchange"
    exchange.mkdir()
    spec = _spec(tray_file, exchange)
    journal = tmp_path / "runs" / "crash.sqlite"
    journal.parent.mkdir()
    opened: list[Any] = []

    def record(s: RunSpec, c: Any) -> Any:
        opened.append(create_run_journal(journal, s, c))
        return opened[0]

    with fake_inview(exchange, tray_file):
        run = compose(
            spec, DRIVERS, record, journal=journal, hosting=Hosting(watch_s=None),
            driver=_crash_after(crash_after),
        )  # fmt: skip
        with pytest.raises(RuntimeError, match="simulated engine crash"):
            run.engine.run()
        opened[0].close()
        with JournalReader(journal) as r:
            last = r.results()[-1]
        assert spec.tray is not None
        crashed_on = spec.tray.sample_at(last.commanded_x_um, last.commanded_y_um)
        assert crashed_on is not None and crashed_on.role == where
        assert run_engine(journal, quiet=True) == 0  # what `aeni resume` does: the same exchange folder
    with JournalReader(journal) as r:
        row = r.q.engine_row()
        results = r.results()
    assert row["completed"] and "every library reached its goal" in row["stop_reason"]
    keys = [(x.block_id, x.indent_index) for x in results]
    assert len(keys) == len(set(keys))  # nothing made twice, nothing lost
    # after the resume the tip was known to be on the sample it crashed on: the block it went on with paid no
    # change if it stayed there, one if it left (checked for every block, the resumed ones included)
    _check_run(journal, exchange, spec.tray)


def test_a_worn_tip_pauses_the_kla_tray_at_the_reference(tmp_path: Path) -> None:
    exchange = tmp_path / "exchange"
    exchange.mkdir()
    tray_file = _write_tray(tmp_path, goal_indents=400)  # goals far off: the worn tip ends the run
    spec = _spec(tray_file, exchange)
    journal = tmp_path / "runs" / "worn.sqlite"
    journal.parent.mkdir()
    engines: list[Any] = []

    def nobody_resumes(seconds: float) -> None:  # a headless engine: a pause is the end
        if engines and engines[0].state is EngineState.PAUSED:
            engines[0].request_stop("paused, and nobody at a console to resume it")

    with fake_inview(exchange, tray_file, wear=3.0):
        run = compose(
            spec, DRIVERS, lambda s, c: create_run_journal(journal, s, c), journal=journal,
            hosting=Hosting(watch_s=None, sleep=nobody_resumes),
        )  # fmt: skip
        engines.append(run.engine)
        run.engine.run()
    assert run.tray is not None
    failed = [c for c in run.tray.checks if not c.passed]
    assert len(failed) == 1 and failed[0].deviation_pct > 5.0
    with JournalReader(journal) as r:
        results = r.results()
        errors = [e.text for e in r.events() if e.level == "error"]
    assert max(x.block_id for x in results) == failed[0].block_id  # no library indented on the worn tip
    assert any("tip check failed" in e and "run paused" in e for e in errors)


# ------------------------------------------------------------------ the driver's charge, block by block


def _kla_tray(tray_file: Path) -> KlaTray:
    spec = tray_spec(RunSpec(driver="kla", campaign=CampaignConfig(seed=SEED)), str(tray_file))
    assert spec.tray is not None
    return KlaTray(spec.tray, tray_profiles(spec.tray, spec.campaign))


@pytest.fixture(scope="module")
def module_tray(tmp_path_factory: pytest.TempPathFactory) -> tuple[KlaTray, Path]:
    tmp = tmp_path_factory.mktemp("kla-tray")
    return _kla_tray(_write_tray(tmp)), tmp


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    visits=st.lists(
        st.tuples(st.sampled_from(["tern", "film", "silica"]), st.booleans()), min_size=1, max_size=8
    )
)
def test_the_change_is_charged_once_per_change_and_a_resumed_driver_knows_the_tips_sample(
    module_tray: tuple[KlaTray, Path], visits: list[tuple[str, bool]]
) -> None:
    """Blocks on any sequence of samples, the engine dying before any of them (a new driver put back where
    the journal left the instrument): each block is charged what its ticket expected, the change exactly when
    the sample differs from the last block's (never for the first block)."""
    kla, tmp = module_tray
    exchange = tmp / "exchange"
    exchange.mkdir(exist_ok=True)

    def new_driver() -> KlaDriver:
        return KlaDriver(kla.first_profile, exchange, "h", tmp / "h.exports", tray=kla)

    d = new_driver()
    charged_changes, last = 0, None
    for k, (name, crash) in enumerate(visits):
        if crash:  # a new engine process: the driver is put back where the journal left the instrument
            fresh = new_driver()
            fresh.set_state(d.clock_s(), d.position_um(), d.program_open())
            d = fresh
        x0, x1, y0, y1 = kla.tray.by_name(name).placed.calibration.bounds_um
        centre = ((x0 + x1) / 2 + 10.0 * k, (y0 + y1) / 2)
        block = Block(k, "global", *centre, 2, 5.0, 80.0, local_grid(*centre, 2, 5.0, 80.0))
        expected = d._expected_s(block, 0, d.position_um(), d.program_open(), d._on)
        end = ArrayEnd(
            tuple(SiteOutcome(i, "measured", hardness_gpa=5.0, modulus_gpa=100.0) for i in range(4)), "test"
        )
        before, pos, is_open = d.clock_s(), d.position_um(), d.program_open()
        events = list(d._results(block, end))
        assert [e.indent_index for e in events if isinstance(e, IndentResult)] == [0, 1, 2, 3]
        charged = sum(e.seconds for e in events if isinstance(e, StepRecord))
        assert charged == pytest.approx(d.clock_s() - before) == pytest.approx(expected)
        change = change_s(kla.profiles[name])
        paid = charged - _own_s(kla.profiles[name], block, pos, is_open)
        assert paid == pytest.approx(change if last is not None and last != name else 0.0)
        charged_changes += paid > 0
        last = name
    assert charged_changes == sum(1 for a, b in itertools.pairwise(visits) if a[0] != b[0])


def test_a_kla_tray_on_two_inview_conventions_is_refused_in_one_line(
    tray_file: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    flipped = tmp_path / "flipped.toml"
    flipped.write_text('extends = "kla-imicro"\n[inview]\narray_y_sign = 1\n', encoding="utf-8")
    _sample_file(tmp_path / "film.toml", "film", flipped)
    exchange = tmp_path / "exchange"
    exchange.mkdir()
    journal = tmp_path / "runs" / "two.sqlite"
    argv = ["run", "--driver", "kla", "--exchange", str(exchange), "--tray", str(tray_file), "--quiet"]
    assert cli_main([*argv, "--journal", str(journal)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert (
        len(err) == 1 and "tray sample 'film': its profile" in err[0] and "other [inview] settings" in err[0]
    )
    assert not journal.exists() and not list(exchange.iterdir())  # nothing half-written
    assert cli_main(["tray", "check", str(tray_file), "--no-plot"]) == 2  # said before any run, too
    assert "other [inview] settings" in capsys.readouterr().out
    # the fake InView over a tray takes its samples from the tray: a --sample beside it is refused
    fake = ["kla", "fake-inview", "--exchange", str(exchange), "--tray", str(tray_file)]
    assert cli_main([*fake, "--sample", str(tmp_path / "tern.toml")]) == 2
    assert "--sample" in capsys.readouterr().err


def test_a_ticket_names_its_sample_and_an_older_ticket_reads_as_the_runs_one(tray_file: Path) -> None:
    kla = _kla_tray(tray_file)
    x0, x1, y0, y1 = kla.tray.by_name("film").placed.calibration.bounds_um
    centre = ((x0 + x1) / 2, (y0 + y1) / 2)
    block = Block(3, "global", *centre, 2, 5.0, 80.0, local_grid(*centre, 2, 5.0, 80.0))
    ticket = make_ticket("r", block, kla.first_profile.inview, expected_s=100.0, sample=kla.sample_of(block))
    again = Ticket.from_dict(json.loads(json.dumps(ticket.to_dict())), "t")
    assert again == ticket and again.sample == "film"
    assert "1. Sample: film on the tray, as calibrated" in ticket_text(ticket)
    assert ticket_panel(ticket)[0] == "sample film (tray)"
    older = ticket.to_dict()
    del older["sample"]  # a ticket written before trays
    old = Ticket.from_dict(older, "t")
    assert old.sample == "" and "1. Sample: the run's sample, as calibrated" in ticket_text(old)
    assert not any(line.startswith("sample ") for line in ticket_panel(old))


def test_a_stretch_across_samples_names_each_arrays_sample_and_expects_its_change(
    tray_file: Path, tmp_path: Path
) -> None:
    """A load that goes from one library's stretch to the next: every array's ticket out with the first, each
    naming its sample, the change expected by the first array on the new sample, and charged there."""
    kla = _kla_tray(tray_file)
    exchange = tmp_path / "exchange"
    exchange.mkdir()
    d = KlaDriver(kla.first_profile, exchange, "s", tmp_path / "s.exports", tray=kla)
    d.set_state(1000.0, (100.0, 100.0), True)  # a resumed engine: the tip is on tern
    assert d._on == "tern"
    arrays = []
    for k, name in enumerate(["tern", "tern", "film", "film"]):
        x0, x1, y0, y1 = kla.tray.by_name(name).placed.calibration.bounds_um
        centre = ((x0 + x1) / 2 + 20.0 * k, (y0 + y1) / 2)
        arrays.append(Block(k, "global", *centre, 2, 5.0, 80.0, local_grid(*centre, 2, 5.0, 80.0)))
    d.load_stretch(arrays)
    d._ticket(arrays[0], 0)  # the first array's ticket publishes the stretch
    tickets = _tickets(exchange)
    assert [tickets[k].sample for k in range(4)] == ["tern", "tern", "film", "film"]
    assert [line.split(":")[0] for line in tickets[0].stretch_arrays] == [
        "1. block 0 on tern", "2. block 1 on tern", "3. block 2 on film", "4. block 3 on film",
    ]  # fmt: skip
    profile = kla.profiles["film"]
    for k, block in enumerate(arrays):
        t = tickets[k]
        own = _own_s(profile, block, t.from_um, t.program_open)
        assert t.expected_s - own == pytest.approx(change_s(profile) if k == 2 else 0.0)
        end = ArrayEnd(tuple(SiteOutcome(i, "measured", hardness_gpa=5.0) for i in range(4)), "test")
        charged = sum(e.seconds for e in d._results(block, end) if isinstance(e, StepRecord))
        assert charged == pytest.approx(t.expected_s)

"""Whole runs through the KLA driver: headless against a fake InView process, the same map as the sim
driver on the same seed, WAITING FOR INSTRUMENT with `aeni send RUN confirm TOKEN`, and kill -9 while
waiting followed by `aeni resume`."""

from __future__ import annotations

import csv
import hashlib
import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from aeni_console.cli.main import main as cli_main
from core.journal import JournalReader
from core.runview import EngineState

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
BUDGET_S = "7400"  # two 5×5 blocks of the cost-aware policy on the ternary library
FAST_PROFILE = 'extends = "kla-imicro"\n[inview]\nstable_polls = 2\npoll_s = 0.05\ndeadline_margin_s = 60.0\n'


def aeni(*args: str) -> list[str]:
    return [sys.executable, "-m", "aeni_console.cli.main", *args]


@pytest.fixture
def setup(tmp_path: Path) -> tuple[Path, Path, Path]:
    exchange = tmp_path / "exchange"
    exchange.mkdir()
    profile = tmp_path / "fast.toml"
    profile.write_text(FAST_PROFILE)
    config = tmp_path / "run.toml"
    config.write_text(
        f'name = "kla"\n[campaign]\npolicy = "cost-aware"\nscenario = "ternary"\nseed = 0\nprofile = "{profile}"\n'
    )
    return exchange, profile, config


def fake_inview(
    exchange: Path, profile: Path, *faults: str, extra: tuple[str, ...] = ()
) -> subprocess.Popen[str]:
    argv = aeni("kla", "fake-inview", "--exchange", str(exchange), "--speed", "1e6", "--invalid-rate", "0")
    argv += ["--profile", str(profile), "--seed", "0", *extra]
    for f in faults:
        argv += ["--fault", f]
    return subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=ENV)


def stop(proc: subprocess.Popen[str]) -> str:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
    out, _ = proc.communicate(timeout=60)
    return out or ""


def running(proc: subprocess.Popen[str]) -> Iterator[subprocess.Popen[str]]:
    try:
        yield proc
    finally:
        stop(proc)


def kla_run(config: Path, exchange: Path, journal: Path, *extra: str) -> list[str]:
    return aeni(
        "run", str(config), "--driver", "kla", "--exchange", str(exchange), "--budget-s", BUDGET_S,
        "--journal", str(journal), "--speed", "1e6", "--quiet", *extra,
    )  # fmt: skip


def manifest(journal: Path) -> list[dict[str, object]]:
    path = journal.with_name(journal.name + ".exports") / "manifest.jsonl"
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def indents(journal: Path) -> list[tuple[int, int, float]]:
    with sqlite3.connect(journal) as conn:
        return list(
            conn.execute(
                "SELECT block_id, indent_index, hardness_gpa FROM indents ORDER BY block_id, indent_index"
            )
        )


@pytest.mark.slow
def test_headless_run_has_one_hashed_export_per_block_and_the_sims_map(
    tmp_path: Path, setup: tuple[Path, Path, Path]
) -> None:
    exchange, profile, config = setup
    journal = tmp_path / "runs" / "kla.sqlite"
    for _ in running(fake_inview(exchange, profile)):
        proc = subprocess.run(
            kla_run(config, exchange, journal), capture_output=True, text=True, env=ENV, timeout=300
        )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    entries = manifest(journal)
    accepted = [e for e in entries if e["status"] == "accepted"]
    with JournalReader(journal) as r:
        snap = r.snapshot()
    assert snap.n_blocks == len(accepted) >= 2
    assert [e["block_id"] for e in accepted] == list(range(len(accepted)))
    folder = journal.with_name(journal.name + ".exports")
    for e in accepted:
        data = (folder / str(e["file"])).read_bytes()
        assert hashlib.sha256(data).hexdigest() == e["sha256"]
    rows = indents(journal)
    with sqlite3.connect(journal) as conn:  # the last block may be cut to fit the budget (issue 15)
        planned = sum(n for (n,) in conn.execute("SELECT n_indents FROM blocks WHERE status = 'observed'"))
    assert len(rows) == len({(b, i) for b, i, _ in rows}) == planned
    assert planned > 25 * (len(accepted) - 1)
    # the same map as the simulated driver on the same seed and budget (the fake InView measures on the
    # same emulator): final MAPE within 10 %
    sim_journal = tmp_path / "runs" / "sim.sqlite"
    assert (
        cli_main(["run", str(config), "--budget-s", BUDGET_S, "--journal", str(sim_journal), "--quiet"]) == 0
    )
    with JournalReader(sim_journal) as r:
        sim_mape = r.snapshot().mape_pct
    assert snap.mape_pct is not None and sim_mape is not None
    assert abs(snap.mape_pct - sim_mape) <= 0.10 * sim_mape


def wait_for(predicate: object, timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():  # type: ignore[operator]
            return
        time.sleep(0.05)
    raise AssertionError("timed out")


def engine_state(journal: Path) -> EngineState:
    with JournalReader(journal) as r:
        return r.state()[0]


def test_waiting_for_instrument_takes_the_token_by_aeni_send(
    tmp_path: Path, setup: tuple[Path, Path, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    exchange, _profile, config = setup
    journal = tmp_path / "runs" / "kla.sqlite"
    engine = subprocess.Popen(
        kla_run(config, exchange, journal),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=ENV,
    )
    try:
        ticket = exchange / "outbox" / "kla-000-ticket.json"
        wait_for(
            lambda: (
                ticket.exists()
                and journal.exists()
                and engine_state(journal) is EngineState.WAITING_FOR_INSTRUMENT
            )
        )
        token = json.loads(ticket.read_text())["token"]
        assert cli_main(["send", str(journal), "confirm"]) == 2
        assert "expected `aeni send RUN confirm TOKEN`" in capsys.readouterr().err
        for word in ("WRONG", token, token):
            assert cli_main(["send", str(journal), "confirm", word, "--no-wait"]) == 0
        with sqlite3.connect(journal) as conn:
            get = "SELECT outcome, reason FROM commands WHERE kind = 'confirm' AND processed = 1 ORDER BY command_id"
            wait_for(lambda: len(list(conn.execute(get))) == 3)
            outcomes = list(conn.execute(get))
        assert [o for o, _ in outcomes] == ["rejected", "accepted", "rejected"]
        assert "'WRONG' is not block 0's token" in outcomes[0][1] and "already reported" in outcomes[2][1]
        assert outcomes[1][1] == "block 0: array started (token confirmed)"

        # the ticket's text is in the journal for the console (the next poll shows the start), without its
        # token: the engine's Waiting events in the journal's event log
        def details() -> list[dict[str, object]]:
            with sqlite3.connect(journal) as conn:
                q = "SELECT body_json FROM run_events WHERE kind = 'Waiting' ORDER BY seq"
                return [json.loads(d)["wait"] for (d,) in conn.execute(q)]

        wait_for(lambda: details()[-1]["started"])
        assert details()[-1]["started"] and token not in str(details()[-1]["ticket"])
        assert " mm" in str(details()[0]["ticket"])
        assert cli_main(["send", str(journal), "abort"]) == 0
        engine.wait(timeout=60)
    finally:
        if engine.poll() is None:
            engine.kill()
        engine.communicate()
    assert engine_state(journal) is EngineState.STOPPED


@pytest.mark.slow
def test_kill_9_while_waiting_then_resume_picks_up_the_export(
    tmp_path: Path, setup: tuple[Path, Path, Path]
) -> None:
    exchange, profile, config = setup
    journal = tmp_path / "runs" / "kla.sqlite"
    engine = subprocess.Popen(
        kla_run(config, exchange, journal), stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT, env=ENV
    )
    ticket = exchange / "outbox" / "kla-000-ticket.json"
    try:
        wait_for(
            lambda: (
                ticket.exists()
                and journal.exists()
                and engine_state(journal) is EngineState.WAITING_FOR_INSTRUMENT
            )
        )
    finally:
        engine.send_signal(signal.SIGKILL)
        engine.wait()
    token = json.loads(ticket.read_text())["token"]
    # the instrument went on: the export arrives while no engine runs
    fake = fake_inview(exchange, profile)
    try:
        wait_for(lambda: any((exchange / "inbox").glob("kla-000-export.*")))
        resumed = subprocess.run(
            aeni("resume", str(journal), "--quiet"), capture_output=True, text=True, env=ENV, timeout=300
        )
        assert resumed.returncode == 0, resumed.stdout + resumed.stderr
    finally:
        log = stop(fake)
    assert log.count("kla block 0: started") == 1  # the array ran once
    assert json.loads(ticket.read_text())["token"] == token  # the resumed engine kept the ticket
    accepted = [e for e in manifest(journal) if e["status"] == "accepted"]
    assert [e["block_id"] for e in accepted].count(0) == 1
    rows = indents(journal)
    block0 = [h for b, _, h in rows if b == 0]
    assert len(block0) == 25
    recorded = [o["hardness_gpa"] for o in accepted[0]["outcomes"]]  # type: ignore[union-attr]
    assert block0 == pytest.approx(recorded)
    assert len(rows) == len({(b, i) for b, i, _ in rows})


def test_driver_kla_needs_an_exchange_folder(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from core.errors import InputError
    from core.runconfig import load_run_config

    with pytest.raises(
        InputError, match=r"field run.exchange is missing: driver 'kla' needs an exchange folder"
    ):
        load_run_config(None, {"run.driver": "kla"})
    config = tmp_path / "c.toml"
    config.write_text('[run]\ndriver = "kla"\nexchange = "shared/ex"\n')
    assert load_run_config(config).options.exchange == str(tmp_path / "shared" / "ex")
    journal = tmp_path / "j.sqlite"
    code = cli_main(
        ["run", "--driver", "kla", "--exchange", str(tmp_path / "nope"), "--journal", str(journal)]
    )
    err = capsys.readouterr().err
    assert code == 2 and "exchange folder does not exist" in err and err.count("\n") == 1
    assert not journal.exists()  # nothing half-made: the same command can be run again


def test_a_folder_that_vanishes_after_the_journal_is_made_leaves_no_journal(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The folder is checked before the journal is made, but a share can drop between the two."""
    import shutil

    from aeni_console.cli import host as run_cmd

    exchange = tmp_path / "exchange"
    exchange.mkdir()
    made = run_cmd.create_run_journal

    def made_then_folder_gone(*args: object, **kwargs: object) -> object:
        journal = made(*args, **kwargs)  # type: ignore[arg-type]
        shutil.rmtree(exchange)
        return journal

    monkeypatch.setattr(run_cmd, "create_run_journal", made_then_folder_gone)
    journal = tmp_path / "j.sqlite"
    code = cli_main(["run", "--driver", "kla", "--exchange", str(exchange), "--journal", str(journal)])
    err = capsys.readouterr().err
    assert code == 2 and str(exchange) in err and err.count("\n") == 1, err
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # no journal, no -wal/-shm, no notify file


@pytest.mark.slow
def test_every_fault_through_the_engine_is_journaled_as_specified(tmp_path: Path) -> None:
    exchange = tmp_path / "exchange"
    exchange.mkdir()
    profile = tmp_path / "fast.toml"  # a short deadline margin, so the missing export times out quickly
    profile.write_text(
        'extends = "kla-imicro"\n[inview]\nstable_polls = 2\npoll_s = 0.05\ndeadline_margin_s = 5.0\n'
    )
    config = tmp_path / "run.toml"
    config.write_text(
        f'name = "kla"\n[campaign]\npolicy = "cost-aware"\nscenario = "ternary"\nseed = 0\nprofile = "{profile}"\n'
    )
    journal = tmp_path / "runs" / "kla.sqlite"
    faults = (
        "aborted@0",
        "surface-not-found@1",
        "missing-export@2",
        "duplicate-export@3",
        "flipped-y@4",
        "mm-um@5",
    )
    argv = aeni("kla", "fake-inview", "--exchange", str(exchange), "--speed", "1e6", "--invalid-rate", "0.1")
    argv += ["--profile", str(profile), "--seed", "0"]
    for f in faults:
        argv += ["--fault", f]
    fake = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=ENV)
    try:
        run = kla_run(config, exchange, journal)
        run[run.index("--budget-s") + 1] = "14000"
        proc = subprocess.run(run, capture_output=True, text=True, env=ENV, timeout=600)
    finally:
        log = stop(fake)
    assert proc.returncode == 0, proc.stdout + proc.stderr + log
    with sqlite3.connect(journal) as conn:
        rows = list(conn.execute("SELECT block_id, indent_index, status, hardness_gpa, note FROM indents"))
        observed = [b for (b,) in conn.execute("SELECT block_id FROM blocks WHERE status = 'observed'")]
        refusals = [t for (t,) in conn.execute("SELECT text FROM events WHERE category = 'instrument'")]
    assert observed[:6] == list(range(6))
    # every planned indent exactly once, a number only where it was measured
    with sqlite3.connect(journal) as conn:  # the last block may be cut to fit the budget (issue 15)
        planned = sum(n for (n,) in conn.execute("SELECT n_indents FROM blocks WHERE status = 'observed'"))
    assert len(rows) == len({(b, i) for b, i, *_ in rows}) == planned
    for _b, _i, status, hardness, note in rows:
        assert (hardness is not None) == (status == "measured")
        assert status == "measured" or note

    def statuses(block: int) -> list[str]:
        return [s for b, _, s, *_ in sorted(rows) if b == block]

    assert statuses(0)[12:] == ["not_run"] * 13 and "measured" in statuses(0)[:12]  # aborted half way
    # no surface: free; no export after a confirmed start: held as taken, no value
    assert statuses(1) == ["not_run"] * 25 and statuses(2) == ["unverified"] * 25
    notes = {n for b, _, _, _, n in rows if b in (1, 2)}
    assert notes == {"surface not found"} | {n for n in notes if n.startswith("no export by the deadline")}
    assert len(notes) == 2
    for block in (3, 4, 5):  # duplicate refused, flipped Y and mm-as-µm still measured where they were
        # (block 5 may be cut by the budget: block 2's sites, held as taken, were priced as run)
        assert set(statuses(block)) <= {"measured", "failed"}
        assert statuses(block).count("measured") >= 0.6 * len(statuses(block))
    assert "failed" in {s for _, _, s, *_ in rows}  # 1.797e308 rows became failed indents
    assert any("refused: duplicate: same SHA-256 as the export accepted for block 3" in t for t in refusals)
    accepted = [e["block_id"] for e in manifest(journal) if e["status"] == "accepted"]
    assert len(accepted) == len(set(accepted))  # each export counted once


@pytest.mark.slow
def test_run_on_a_sample_file_through_the_fake_inview(tmp_path: Path, setup: tuple[Path, Path, Path]) -> None:
    """``aeni run --sample FILE --driver kla --exchange DIR``: the blocks land on the sample (stage µm), the
    fake InView measures the scenario laid onto the same sample, every export is archived with its hash,
    and the journal keeps the sample."""
    from core.sample import load_sample
    from drivers.sim.scenarios import make_scenario

    exchange, profile, config = setup
    sample_file = ROOT / "docs" / "examples" / "NiTiCu-library-07.toml"
    sample = load_sample(sample_file)
    journal = tmp_path / "runs" / "sample.sqlite"
    fake = fake_inview(exchange, profile, extra=("--sample", str(sample_file)))
    for _ in running(fake):
        # in-process: the engine's CLI without the `python -m aeni_console.cli.main` prefix
        code = cli_main(kla_run(config, exchange, journal, "--sample", str(sample_file))[3:])
    assert code == 0
    accepted = [e for e in manifest(journal) if e["status"] == "accepted"]
    folder = journal.with_name(journal.name + ".exports")
    assert accepted and all(
        hashlib.sha256((folder / str(e["file"])).read_bytes()).hexdigest() == e["sha256"] for e in accepted
    )
    with sqlite3.connect(journal) as conn:
        rows = list(
            conn.execute(
                "SELECT block_id, indent_index, commanded_x_um, commanded_y_um, hold_s, hardness_gpa, status "
                "FROM indents ORDER BY block_id, indent_index"
            )
        )
        planned = sum(n for (n,) in conn.execute("SELECT n_indents FROM blocks WHERE status = 'observed'"))
    # every planned indent once (the budget may cut the last block), each measured
    assert len(rows) == planned and len(accepted) >= 2 and {r[6] for r in rows} == {"measured"}
    xs, ys = [r[2] for r in rows], [r[3] for r in rows]
    # inside the sample's corners (stage µm, 11937–13498 × 8000–9272), not the scenario's own area
    assert min(xs) >= 11937.2 and max(xs) <= 13497.9 and min(ys) >= 8000.0 and max(ys) <= 9271.9
    # the fake InView measured the ternary truth laid onto this sample: the first block's values are the
    # emulator's on that sample (measured here at t = 0: the block's drift moves them by well under 5 %)
    emulator = make_scenario("ternary", 0).on_sample(sample).make_emulator()
    first = [r for r in rows if r[0] == 0]
    expect = [emulator.measure(r[2], r[3], r[4], 0.0, 0, r[1]).hardness_gpa for r in first]
    assert [r[5] for r in first] == pytest.approx(expect, rel=0.05)
    with JournalReader(journal) as r:
        assert r.meta["config"]["sample"]["name"] == "NiTiCu-library-07"


def _run_with_fake(
    tmp_path: Path, faults: tuple[str, ...], margin_s: float, budget_s: str, *fake_extra: str
) -> tuple[Path, subprocess.CompletedProcess[str], float]:
    exchange = tmp_path / "exchange"
    exchange.mkdir()
    profile = tmp_path / "fast.toml"
    profile.write_text(
        f'extends = "kla-imicro"\n[inview]\nstable_polls = 2\npoll_s = 0.05\ndeadline_margin_s = {margin_s}\n'
    )
    config = tmp_path / "run.toml"
    config.write_text(
        f'name = "kla"\n[campaign]\npolicy = "cost-aware"\nscenario = "ternary"\nseed = 0\nprofile = "{profile}"\n'
    )
    journal = tmp_path / "runs" / "kla.sqlite"
    for _ in running(fake_inview(exchange, profile, *faults, extra=fake_extra)):
        run = kla_run(config, exchange, journal)
        run[run.index("--budget-s") + 1] = budget_s
        started = time.monotonic()
        proc = subprocess.run(run, capture_output=True, text=True, env=ENV, timeout=600)
        took = time.monotonic() - started
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return journal, proc, took


def _block_rows(journal: Path, block: int) -> list[tuple[str, float, float, float, float, object, str]]:
    with sqlite3.connect(journal) as conn:
        return list(
            conn.execute(
                "SELECT status, commanded_x_um, commanded_y_um, actual_x_um, actual_y_um, hardness_gpa, note "
                "FROM indents WHERE block_id = ? ORDER BY indent_index",
                (block,),
            )
        )


@pytest.mark.slow
def test_a_refused_flipped_y_export_records_the_indents_as_made_unverified(tmp_path: Path) -> None:
    """A budget that cuts the first block to 16 sites: flipped Y is then no permutation of the plan, so the
    export is refused; its 16 indents are journaled as made (unverified) at the export's mirrored places,
    priced on the instrument clock, never learnt from."""
    journal, _, _ = _run_with_fake(tmp_path, ("flipped-y@0",), 5.0, "2500")
    rows = _block_rows(journal, 0)
    assert 0 < len(rows) < 25 and {r[0] for r in rows} == {"unverified"}
    origin_y = sum(r[2] for r in rows) / len(rows)
    with sqlite3.connect(journal) as conn:
        cy = conn.execute("SELECT center_y_um FROM blocks WHERE block_id = 0").fetchone()[0]
        indent_steps = conn.execute(
            "SELECT COUNT(*) FROM steps WHERE block_id = 0 AND category = 'indent'"
        ).fetchone()[0]
        snapshots = conn.execute("SELECT summary_json FROM gp_snapshots").fetchall()
    for _status, cx_, cy_, ax, ay, hardness, note in rows:
        assert hardness is None and "refused" in note and "not learnt from" in note
        assert ax == pytest.approx(cx_) and ay == pytest.approx(2 * cy - cy_)  # where the tip went
    assert any(abs(r[2] - r[4]) > 1.0 for r in rows) and origin_y == pytest.approx(cy, abs=20.0)
    assert indent_steps == len(rows)  # made, so priced
    # nothing else ran under this budget: the model never had a value to fit
    assert all(json.loads(s)["mape_pct"] is None for (s,) in snapshots)
    entries = manifest(journal)
    refused = [e for e in entries if e["status"] == "refused"]
    assert refused and refused[0]["format"] == "InView" and "Y axis is flipped" in str(refused[0]["reason"])
    closed = [e for e in entries if e["status"] == "closed"]
    assert closed and len(closed[0]["outcomes"]) == len(rows)  # kept for a resume
    # the tidy export tells them apart: status, note, depth and the refused file they came from
    out = tmp_path / "tidy"
    assert cli_main(["export", str(journal), "--out", str(out)]) == 0
    with (out / "indents.csv").open() as fh:
        tidy = [r for r in csv.DictReader(fh) if r["block_id"] == "0"]
    assert {r["status"] for r in tidy} == {"unverified"} and all(r["note"] for r in tidy)
    assert {r["export_file"] for r in tidy} == {refused[0]["file"]}
    assert all(float(r["depth_at_max_load_nm"]) > 0 for r in tidy)


@pytest.mark.slow
def test_an_aborted_report_closes_the_wait_at_once_with_the_rows_in_hand(tmp_path: Path) -> None:
    """The array is aborted half way and its (flipped) export refused: the accepted 'aborted' report ends
    the wait at once, with the exported rows as made and the rest not run (the deadline is 5 min away)."""
    journal, _, took = _run_with_fake(tmp_path, ("aborted@0", "flipped-y@0"), 300.0, "2500")
    assert took < 120.0
    statuses = [r[0] for r in _block_rows(journal, 0)]
    n = len(statuses)
    assert statuses == ["unverified"] * (n // 2) + ["not_run"] * (n - n // 2)
    with sqlite3.connect(journal) as conn:
        texts = [t for (t,) in conn.execute("SELECT text FROM events WHERE category = 'instrument'")]
    assert not any("no export by the deadline" in t for t in texts)
    assert any("array aborted" in t for t in texts)


@pytest.mark.slow
def test_exports_without_positions_are_matched_by_test_order(tmp_path: Path) -> None:
    """A lab template without X/Y columns: every row goes to its site in the sites file's order, the run
    completes with every measurement in the model, and the log and manifest say how it was matched."""
    journal, _, _ = _run_with_fake(tmp_path, (), 60.0, BUDGET_S, "--no-positions")
    order = "no positions in the export: matched by test order"
    with sqlite3.connect(journal) as conn:
        rows = list(conn.execute("SELECT status, actual_x_um, commanded_x_um FROM indents"))
        observed = conn.execute("SELECT COUNT(*) FROM blocks WHERE status = 'observed'").fetchone()[0]
        texts = [t for (t,) in conn.execute("SELECT text FROM events")]
    accepted = [e for e in manifest(journal) if e["status"] == "accepted"]
    assert observed == len(accepted) >= 2
    assert rows and {s for s, *_ in rows} == {"measured"}  # --invalid-rate 0: every indent measured
    assert all(ax == pytest.approx(cx) for _, ax, cx in rows)  # placed on the planned sites
    assert all(any(order in n for n in e["notes"]) for e in accepted)
    assert all(e["format"] == "InView" for e in accepted)
    assert any(order in t for t in texts)
    with JournalReader(journal) as r:
        snap = r.snapshot()
    assert snap.n_blocks == observed and snap.mape_pct is not None
    out = tmp_path / "tidy"
    assert cli_main(["export", str(journal), "--out", str(out)]) == 0
    with (out / "indents.csv").open() as fh:
        tidy = list(csv.DictReader(fh))
    assert len(tidy) == len(rows) and {r["status"] for r in tidy} == {"measured"}
    assert {r["export_file"] for r in tidy} == {str(e["file"]) for e in accepted}

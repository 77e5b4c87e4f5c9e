"""Unattended soak: headless KLA runs against the fake InView, with faults, a kill -9 and a vanished folder.

Each run: `aeni run --driver kla` (auto supervision, nobody at the keys) against `aeni kla fake-inview` with an
invalid-value rate, one or two faults at random blocks (every fault kind is used across the runs), a kill -9 of
the engine at a random moment followed by `aeni resume`, and the exchange folder taken away and brought back
while the run goes on. The run must end by its budget or a stopping rule. Then the journal is checked against
the fake InView's own ledger of every indent it made:

- stalled: no new journal row for ``--stall-x`` times the run's expected block time (the median wall time
  between observed blocks, at least ``--min-block-s``), or the run never ended;
- lost: an indent the instrument made and exported that the journal does not hold as made (measured,
  failed or unverified);
- duplicated: one indent of the instrument recorded twice, or a journal indent the instrument never made;
- changed: a recorded value or status that differs from what the instrument wrote.

    python benchmarks/unattended_soak.py --runs 50 --jobs 2 --out benchmarks/results/soak

writes ``soak.json`` (one row per run) and ``soak.md`` (the table) to ``--out`` and prints the table.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import os
import random
import signal
import sqlite3
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FAULTS = ("aborted", "surface-not-found", "missing-export", "duplicate-export", "mm-um", "flipped-y")
MADE = ("measured", "failed", "unverified")
# a fast exchange: short polls, a deadline margin short enough that a missing export is a brief wait
PROFILE = 'extends = "kla-imicro"\n[inview]\nstable_polls = 2\npoll_s = 0.05\ndeadline_margin_s = 8.0\n'


@dataclass
class RunOutcome:
    run: int
    seed: int
    faults: list[str]
    kill_at_s: float | None
    killed: bool
    folder_away_at_s: float
    folder_away_s: float
    folder_removed: bool
    # "refused": the kill comes once an export was refused (the moment that lost flipped-Y rows), or at
    # kill_at_s if none was; "": at kill_at_s
    kill_on: str = ""
    resumes_refused: int = 0  # `aeni resume` refused while the exchange folder was away (then tried again)
    end_state: str = ""
    stop_reason: str = ""
    wall_s: float = 0.0
    blocks: int = 0
    indents_made: int = 0  # in the fake InView's ledger
    indents_unexported: int = 0  # made, but the instrument wrote no export for them (a missing-export fault)
    recorded_made: int = 0  # journal rows measured / failed / unverified
    stalled: bool = False
    stall_note: str = ""
    lost: int = 0
    duplicated: int = 0
    changed: int = 0
    notes: list[str] = field(default_factory=list)


def _aeni(*args: str) -> list[str]:
    return [sys.executable, "-m", "aeni_console.cli", *args]


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}


def _progress(journal: Path) -> tuple[int, ...] | None:
    """A fingerprint of everything the engine writes; None while the journal cannot be read."""
    if not journal.exists():
        return None
    try:
        with sqlite3.connect(f"file:{journal}?mode=ro", uri=True, timeout=2) as conn:
            counts = tuple(
                int(conn.execute(f"SELECT count(*) FROM {t}").fetchone()[0])
                for t in ("indents", "events", "steps", "decisions", "commands", "blocks")
            )
            updated = conn.execute("SELECT updated_utc FROM engine_state").fetchone()
        return (*counts, hash(updated))
    except sqlite3.Error:
        return None


def _engine_row(journal: Path) -> tuple[str, int, str]:
    with sqlite3.connect(f"file:{journal}?mode=ro", uri=True, timeout=5) as conn:
        row = conn.execute("SELECT state, completed, stop_reason FROM engine_state").fetchone()
    return (str(row[0]), int(row[1]), str(row[2])) if row else ("", 0, "")


def _block_wall_s(journal: Path) -> list[float]:
    with sqlite3.connect(f"file:{journal}?mode=ro", uri=True, timeout=5) as conn:
        rows = conn.execute(
            "SELECT observed_utc FROM blocks WHERE observed_utc IS NOT NULL ORDER BY block_id"
        ).fetchall()
    from datetime import datetime

    stamps = [datetime.fromisoformat(r[0]).timestamp() for r in rows]
    return [b - a for a, b in itertools.pairwise(stamps) if b > a]


def _watch(
    proc: subprocess.Popen[str], journal: Path, stall_s: float, deadline: float, out: RunOutcome
) -> bool:
    """Wait for the engine process to end; False when it stalled (then it is killed)."""
    last, since = _progress(journal), time.monotonic()
    while proc.poll() is None:
        time.sleep(0.25)
        now = time.monotonic()
        fp = _progress(journal)
        if fp is not None and fp != last:
            last, since = fp, now
        if now - since > stall_s or now > deadline:
            out.stalled = True
            out.stall_note = (
                f"no journal progress for {now - since:.0f} s" if now - since > stall_s else "run wall limit"
            )
            proc.kill()
            proc.wait()
            return False
    return True


def _wait_for_kill(engine: subprocess.Popen[str], out: RunOutcome, journal: Path) -> None:
    """Return when the engine ended by itself; TimeoutExpired when the planned moment of the kill came."""
    assert out.kill_at_s is not None
    if out.kill_on != "refused":
        engine.wait(timeout=out.kill_at_s)
        return
    manifest = journal.with_name(journal.name + ".exports") / "manifest.jsonl"
    until = time.monotonic() + out.kill_at_s
    while engine.poll() is None:
        if manifest.exists() and '"status": "refused"' in manifest.read_text(encoding="utf-8"):
            raise subprocess.TimeoutExpired(engine.args, out.kill_at_s)
        if time.monotonic() > until:
            raise subprocess.TimeoutExpired(engine.args, out.kill_at_s)
        time.sleep(0.05)


def _compare(journal: Path, ledger: Path, run_name: str, out: RunOutcome) -> None:
    made: dict[tuple[int, int], list[dict[str, object]]] = {}
    if ledger.exists():
        for line in ledger.read_text(encoding="utf-8").splitlines():
            rec = json.loads(line)
            if rec["run"] != run_name:
                continue
            made.setdefault((int(rec["block_id"]), int(rec["indent_index"])), []).append(rec)
    out.indents_made = sum(len(v) for v in made.values())
    out.indents_unexported = sum(1 for v in made.values() for r in v if not r["exported"])
    with sqlite3.connect(f"file:{journal}?mode=ro", uri=True, timeout=5) as conn:
        rows = conn.execute(
            "SELECT block_id, indent_index, status, hardness_gpa, actual_x_um, actual_y_um, note FROM indents"
        ).fetchall()
        out.blocks = int(conn.execute("SELECT count(*) FROM blocks WHERE status = 'observed'").fetchone()[0])
    journal_made = {(int(b), int(i)): (s, h, x, y, n) for b, i, s, h, x, y, n in rows if s in MADE}
    out.recorded_made = len(journal_made)
    for key, recs in made.items():
        if len(recs) > 1:
            out.duplicated += len(recs) - 1
            out.notes.append(f"the instrument made block {key[0]} indent {key[1]} {len(recs)} times")
        rec = recs[-1]
        got = journal_made.get(key)
        if not rec["exported"]:
            # no file ever said what came of it: the journal may only hold it as taken, never as a value
            if got is not None and got[0] == "measured":
                out.changed += 1
                out.notes.append(f"block {key[0]} indent {key[1]}: measured without an export")
            continue
        if got is None:
            out.lost += 1
            out.notes.append(f"block {key[0]} indent {key[1]}: made and exported, not recorded as made")
            continue
        status, hardness = got[0], got[1]
        if status == "measured":
            want = rec["hardness_gpa"]
            if (
                rec["invalid"]
                or want is None
                or hardness is None
                or not math.isclose(float(hardness), float(want), rel_tol=1e-9)
            ):
                out.changed += 1
                out.notes.append(f"block {key[0]} indent {key[1]}: recorded {hardness}, instrument {want}")
        elif status == "failed" and not rec["invalid"]:
            # a valid value recorded as failed is a change only when the export was accepted; a refused
            # export's rows are unverified, never failed
            out.changed += 1
            out.notes.append(f"block {key[0]} indent {key[1]}: valid value recorded as failed ({got[4]})")
    for key in journal_made.keys() - made.keys():
        status, x_um = journal_made[key][0], journal_made[key][2]
        if status == "unverified" and x_um is None:
            continue  # held as taken because no export said what ran (no claim that it was made)
        out.duplicated += 1
        out.notes.append(f"block {key[0]} indent {key[1]}: recorded as made, the instrument never made it")


def plan_run(k: int, base_seed: int) -> RunOutcome:
    """Run ``k``'s random faults, kill moment and folder removal (its outcome fields still empty)."""
    rng = random.Random(base_seed * 100_003 + k)
    faults = [f"{FAULTS[k % len(FAULTS)]}@{rng.randrange(0, 3)}"]
    if rng.random() < 0.5:
        faults.append(f"{rng.choice(FAULTS)}@{rng.randrange(0, 4)}")
    return RunOutcome(
        run=k,
        seed=base_seed + k,
        faults=faults,
        kill_at_s=rng.uniform(1.0, 15.0),
        killed=False,
        folder_away_at_s=rng.uniform(1.0, 20.0),
        folder_away_s=rng.uniform(0.5, 4.0),
        folder_removed=False,
    )


def soak_one(out: RunOutcome, budget_s: float, invalid_rate: float, stall_x: float, min_block_s: float,
             run_wall_s: float) -> RunOutcome:  # fmt: skip
    """One run as planned by ``out`` (see :func:`plan_run`); fills in what came of it."""
    k, faults = out.run, out.faults
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix=f"soak{k}-") as tmp_s:
        tmp = Path(tmp_s)
        exchange, away = tmp / "exchange", tmp / "exchange.away"
        (exchange / "outbox").mkdir(parents=True)
        (exchange / "inbox").mkdir()
        profile = tmp / "fast.toml"
        profile.write_text(PROFILE)
        name = f"soak{k}"
        config = tmp / "run.toml"
        config.write_text(
            f'name = "{name}"\n[campaign]\nscenario = "ternary"\nseed = {out.seed}\nprofile = "{profile}"\n'
        )
        journal, ledger = tmp / "runs" / f"{name}.sqlite", tmp / "ledger.jsonl"
        fake_argv = _aeni(
            "kla", "fake-inview", "--exchange", str(exchange), "--speed", "1e6",
            "--invalid-rate", str(invalid_rate), "--profile", str(profile), "--seed", str(out.seed),
            "--ledger", str(ledger),
        )  # fmt: skip
        for f in faults:
            fake_argv += ["--fault", f]
        fake = subprocess.Popen(
            fake_argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=_env()
        )
        run_argv = _aeni(
            "run", str(config), "--driver", "kla", "--exchange", str(exchange), "--budget-s", str(budget_s),
            "--journal", str(journal), "--speed", "1e6", "--quiet",
        )  # fmt: skip
        log = (tmp / "engine.log").open("w")
        deadline = t0 + run_wall_s
        try:
            # the folder goes away and comes back while the run goes on
            def carry_away() -> None:
                while not any(exchange.glob("outbox/*-ticket.json")) and not stop_event.is_set():
                    time.sleep(0.1)  # away once a block is out (a folder missing at the start is refused)
                time.sleep(out.folder_away_at_s)
                if exchange.is_dir() and not stop_event.is_set():
                    os.rename(exchange, away)
                    out.folder_removed = True
                    time.sleep(out.folder_away_s)
                    os.rename(away, exchange)

            stop_event = threading.Event()
            mover = threading.Thread(target=carry_away, daemon=True)
            engine = subprocess.Popen(run_argv, stdout=log, stderr=subprocess.STDOUT, text=True, env=_env())
            mover.start()
            stall_s = stall_x * min_block_s
            # kill -9 at a random moment, then resume
            assert out.kill_at_s is not None
            while engine.poll() is None and _progress(journal) is None and time.monotonic() < deadline:
                time.sleep(0.1)  # the kill comes once the engine has started writing its journal
            try:
                _wait_for_kill(engine, out, journal)
            except subprocess.TimeoutExpired:
                engine.send_signal(signal.SIGKILL)
                engine.wait()
                out.killed = True
                # the operator resumes; refused while the stick is away (exit 2), again once it is back
                while True:
                    engine = subprocess.Popen(
                        _aeni("resume", str(journal), "--quiet"), stdout=log, stderr=subprocess.STDOUT,
                        text=True, env=_env(),
                    )  # fmt: skip
                    _watch(engine, journal, stall_s, deadline, out)
                    log.flush()
                    said = (tmp / "engine.log").read_text(errors="replace").splitlines()[-1:]
                    folder_away = bool(said) and "exchange folder does not exist" in said[0]
                    if (
                        out.stalled
                        or engine.returncode != 2
                        or not folder_away
                        or time.monotonic() > deadline
                    ):
                        break
                    out.resumes_refused += 1
                    while not exchange.is_dir() and time.monotonic() < deadline:
                        time.sleep(0.1)
            if not out.stalled and not out.killed:
                _watch(engine, journal, stall_s, deadline, out)
            stop_event.set()
            mover.join(timeout=10)
            if away.exists() and not exchange.exists():
                os.rename(away, exchange)
            if not out.stalled and not journal.exists():
                out.notes.append("the engine never wrote its journal")
            elif not out.stalled:
                state, completed, reason = _engine_row(journal)
                out.end_state, out.stop_reason = state + ("" if completed else " (not completed)"), reason
                if engine.returncode not in (0, None):
                    out.notes.append(f"engine exit {engine.returncode}")
                walls = _block_wall_s(journal)
                expected = max(statistics.median(walls) if walls else 0.0, min_block_s)
                out.notes.append(f"expected block wall time {expected:.1f} s")
        finally:
            log.close()
            if fake.poll() is None:
                fake.send_signal(signal.SIGTERM)
            try:
                fake.communicate(timeout=30)
            except subprocess.TimeoutExpired:
                fake.kill()
        if journal.exists():
            _compare(journal, ledger, name, out)
        if (
            out.stalled
            or out.lost
            or out.duplicated
            or out.changed
            or not out.end_state.startswith("stopped")
        ):
            tail = (tmp / "engine.log").read_text(errors="replace").splitlines()[-8:]
            out.notes.extend(f"engine: {line}" for line in tail)
    out.wall_s = time.monotonic() - t0
    return out


def table(rows: list[RunOutcome]) -> str:
    n = len(rows)
    walls = sorted(r.wall_s for r in rows)
    lines = [
        "| runs | stalled | lost | duplicated | changed | ended stopped | killed + resumed | resume refused "
        "(folder away) | folder away | "
        "indents made | recorded as made | unexported | faults used |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|",
        f"| {n} | {sum(r.stalled for r in rows)} | {sum(r.lost for r in rows)} | "
        f"{sum(r.duplicated for r in rows)} | {sum(r.changed for r in rows)} | "
        f"{sum(r.end_state.startswith('stopped') for r in rows)} | {sum(r.killed for r in rows)} | "
        f"{sum(r.resumes_refused for r in rows)} | "
        f"{sum(r.folder_removed for r in rows)} | {sum(r.indents_made for r in rows)} | "
        f"{sum(r.recorded_made for r in rows)} | {sum(r.indents_unexported for r in rows)} | "
        f"{', '.join(sorted({f.split('@')[0] for r in rows for f in r.faults}))} |",
        "",
        f"wall time per run: median {statistics.median(walls):.1f} s, longest {walls[-1]:.1f} s"
        if walls
        else "",
    ]
    reasons: dict[str, int] = {}
    for r in rows:
        reasons[r.stop_reason or r.stall_note or "?"] = (
            reasons.get(r.stop_reason or r.stall_note or "?", 0) + 1
        )
    lines.append("stop reasons: " + "; ".join(f"{k} ×{v}" for k, v in sorted(reasons.items())))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=50)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--budget-s", type=float, default=8000.0)
    ap.add_argument("--invalid-rate", type=float, default=0.05)
    ap.add_argument(
        "--stall-x", type=float, default=10.0, help="stalled: no progress for this × a block's time"
    )
    ap.add_argument("--min-block-s", type=float, default=6.0, help="the least expected wall time of a block")
    ap.add_argument("--run-wall-s", type=float, default=900.0, help="a run still going after this is stalled")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)
    started = time.monotonic()
    done = threading.Lock()

    def one(k: int) -> RunOutcome:
        out = soak_one(
            plan_run(k, args.seed), args.budget_s, args.invalid_rate, args.stall_x, args.min_block_s,
            args.run_wall_s,
        )  # fmt: skip
        with done:  # each run as it ends, so a soak cut short still says what it saw
            print(
                f"run {k}: {out.wall_s:.0f} s, stalled {out.stalled}, lost {out.lost}, duplicated "
                f"{out.duplicated}, changed {out.changed}, {out.end_state}",
                flush=True,
            )
            if args.out is not None:
                args.out.mkdir(parents=True, exist_ok=True)
                with (args.out / "soak.jsonl").open("a", encoding="utf-8") as fh:
                    fh.write(json.dumps(asdict(out)) + "\n")
        return out

    with ThreadPoolExecutor(max_workers=max(args.jobs, 1)) as pool:
        rows = list(pool.map(one, range(args.runs)))
    text = table(rows) + f"\ntotal wall time {time.monotonic() - started:.0f} s"
    print(text)
    for r in rows:
        if r.stalled or r.lost or r.duplicated or r.changed or not r.end_state.startswith("stopped"):
            print(f"run {r.run} (seed {r.seed}, faults {', '.join(r.faults)}): " + " | ".join(r.notes[:12]))
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "soak.json").write_text(json.dumps([asdict(r) for r in rows], indent=1))
        (args.out / "soak.md").write_text(text + "\n")
    bad = any(r.stalled or r.lost or r.duplicated or r.changed for r in rows)
    return 1 if bad else 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Unattended soak v2: detached KLA runs under their supervisor against the fake InView, with faults, a kill -9
nobody resumes, a vanished share, a share that turns read-only, a journal folder that fills up and an operator
calendar across a daylight-saving change.

Each run: `aeni run --driver kla --detach` (auto supervision, nobody at the keys; the engine runs under its
supervisor, alerts go to a json:// receiver on 127.0.0.1) against `aeni kla fake-inview` with an invalid-value
rate and one or two faults at random blocks (every fault kind is used across the runs). At a random moment the
engine is killed -9 and nobody resumes it: its supervisor must journal the death, alert and resume it. The
exchange folder is taken away and brought back while the run goes on. In some runs the share turns read-only
for a few seconds (a remount of its tmpfs), the journal's folder (a small tmpfs) fills up for a few seconds,
or the run's local time zone changes to daylight-saving time while it runs, with `[operator]` hours whose next
start lies across the change. Mounts need root; without them those parts are skipped with the reason. The run
must end by its budget or a stopping rule. Then the journal is checked against the fake InView's own ledger of
every indent it made:

- stalled: no new journal row for ``--stall-x`` times the run's expected block time (the median wall time
  between observed blocks, at least ``--min-block-s``), or the run never ended;
- lost: an indent the instrument made and exported that the journal does not hold as made (measured,
  failed or unverified);
- duplicated: one indent of the instrument recorded twice, or a journal indent the instrument never made;
- changed: a recorded value or status that differs from what the instrument wrote;
- held not run: an indent the instrument made (exported or not) that the journal holds as not run;
- deaths: every engine process that ended without ending its run (the supervisor's journal rows and
  alerts); each must be alerted (a `failure` alert naming the cause) and resumed (a new engine session).

    python benchmarks/unattended_soak.py --runs 50 --jobs 2 --out benchmarks/results/soak

writes ``soak.json`` (one row per run) and ``soak.md`` (the table) to ``--out`` and prints the table.
"""

from __future__ import annotations

import argparse
import contextlib
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
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field
from datetime import datetime, timedelta
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
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
    # v2: the supervisor, the read-only share, the full journal folder, the daylight-saving change
    share_ro_at_s: float | None = None  # the share turns read-only this long after the first ticket ...
    share_ro_s: float = 0.0  # ... for this long
    share_ro: str = ""  # "done" or why it was skipped
    disk_full_at_s: float | None = (
        None  # the journal's folder fills up this long after the journal exists ...
    )
    disk_full_s: float = 0.0  # ... for this long
    disk_full: str = ""
    dst: bool = False  # the run's local time changes to daylight-saving time a few seconds after it starts
    deaths: int = 0  # engine processes that ended without ending the run (the supervisor's rows)
    deaths_alerted: int = 0  # failure alerts the receiver got naming an engine's death
    resumed: int = 0  # engine sessions after the first (the supervisor's resumes)
    crash_loop: bool = False  # the supervisor stopped resuming
    held_not_run: int = 0  # made by the instrument, held as not run by the journal


def _aeni(*args: str) -> list[str]:
    return [sys.executable, "-m", "aeni_console.cli.main", *args]


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


def _retry(action: Callable[[], object], until_s: float = 10.0) -> bool:
    """``action`` until it does not raise OSError (a share read-only for a moment); False when it never did."""
    end = time.monotonic() + until_s
    while True:
        try:
            action()
            return True
        except OSError:
            if time.monotonic() > end:
                return False
            time.sleep(0.2)


def _read(path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8")
    except OSError:
        return ""


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
    not_run = {(int(b), int(i)) for b, i, s, *_ in rows if s == "not_run"}
    out.held_not_run = len(not_run & made.keys())
    for key in sorted(not_run & made.keys())[:5]:
        out.notes.append(f"block {key[0]} indent {key[1]}: made by the instrument, held as not run")
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
    """Run ``k``'s random faults, kill moment, folder removal, read-only share, full disk and calendar."""
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
        share_ro_at_s=rng.uniform(1.0, 20.0) if k % 3 == 1 else None,
        share_ro_s=rng.uniform(1.0, 4.0),
        disk_full_at_s=rng.uniform(2.0, 20.0) if k % 3 == 2 else None,
        disk_full_s=rng.uniform(1.0, 3.0),
        dst=k % 4 == 3,
    )


class AlertReceiver:
    """apprise's json:// posts on 127.0.0.1, kept by URL path (one path a run)."""

    def __init__(self) -> None:
        got: dict[str, list[dict[str, object]]] = {}
        lock = threading.Lock()

        class Handler(BaseHTTPRequestHandler):
            def do_POST(self) -> None:
                body = self.rfile.read(int(self.headers.get("Content-Length", 0)))
                with lock:
                    got.setdefault(self.path.strip("/"), []).append(json.loads(body or b"{}"))
                self.send_response(200)
                self.end_headers()

            def log_message(self, *args: object) -> None:
                pass

        self._got, self._lock = got, lock
        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        threading.Thread(target=self.server.serve_forever, daemon=True).start()

    def url(self, key: str) -> str:
        return f"json://127.0.0.1:{self.server.server_address[1]}/{key}"

    def got(self, key: str) -> list[dict[str, object]]:
        with self._lock:
            return list(self._got.get(key, []))


_RECEIVER: AlertReceiver | None = None


def _receiver() -> AlertReceiver:
    global _RECEIVER
    if _RECEIVER is None:
        _RECEIVER = AlertReceiver()
    return _RECEIVER


def _mount_tmpfs(path: Path, size: str) -> str:
    """'' when a tmpfs of ``size`` is mounted at ``path``, else why not."""
    path.mkdir(parents=True, exist_ok=True)
    if os.geteuid() != 0:
        return "skipped: mounting a tmpfs needs root"
    r = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={size},mode=0700", "tmpfs", str(path)],
        capture_output=True,
        text=True,
    )
    return "" if r.returncode == 0 else f"skipped: mount refused ({r.stderr.strip() or r.returncode})"


def _unmount(path: Path) -> None:
    subprocess.run(["umount", "-l", str(path)], capture_output=True)


def _fill(folder: Path) -> Path:
    """A ballast file that takes every free byte of ``folder``'s file system."""
    ballast = folder / "ballast"
    chunk = b"\0" * (1 << 20)
    with ballast.open("wb") as fh:
        try:
            while True:
                fh.write(chunk)
                fh.flush()
        except OSError:
            pass
    return ballast


def _dst_zone(delay_s: float) -> tuple[str, str]:
    """(a POSIX TZ whose daylight-saving time starts ``delay_s`` from now, operator hours that start ~20 s
    of wall time after the change). Local time jumps from standard (UTC+1) to summer time (UTC+2)."""
    std = datetime.utcnow() + timedelta(hours=1)
    change = std + timedelta(seconds=delay_s)
    yday = min(change.timetuple().tm_yday, 365)
    tz = f"SOK-1SOKD-2,J{yday}/{change:%H:%M:%S},J365/23:59:59"
    arrive = change + timedelta(hours=1, seconds=20)
    arrive += timedelta(seconds=60 - arrive.second)  # the next whole minute, in summer time
    leave = min(arrive + timedelta(hours=6), arrive.replace(hour=23, minute=59))
    return tz, f"Mon-Sun {arrive:%H:%M}-{leave:%H:%M}"


def _sessions(journal: Path) -> list[tuple[str, int]]:
    with sqlite3.connect(f"file:{journal}?mode=ro", uri=True, timeout=5) as conn:
        return [
            (str(k), int(p)) for k, p in conn.execute("SELECT kind, pid FROM sessions ORDER BY session_id")
        ]


def _supervisor_rows(journal: Path) -> list[str]:
    with sqlite3.connect(f"file:{journal}?mode=ro", uri=True, timeout=5) as conn:
        return [str(r[0]) for r in conn.execute("SELECT text FROM events WHERE category = 'supervisor'")]


def _engine_pid(journal: Path) -> int | None:
    from core.journal import engine_running

    if not engine_running(journal):
        return None
    try:
        with sqlite3.connect(f"file:{journal}?mode=ro", uri=True, timeout=2) as conn:
            row = conn.execute("SELECT pid FROM engine_state").fetchone()
    except sqlite3.Error:
        return None
    return int(row[0]) if row and row[0] else None


def _supervised_alive(journal: Path) -> bool:
    from aeni_console.cli.supervisor import supervisor_pid
    from core.journal import engine_running

    return supervisor_pid(journal) is not None or engine_running(journal)


def _kill_all(journal: Path) -> None:
    from aeni_console.cli.supervisor import supervisor_pid

    for pid in (supervisor_pid(journal), _engine_pid(journal)):
        if pid is not None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)


def soak_one(out: RunOutcome, budget_s: float, invalid_rate: float, stall_x: float, min_block_s: float,
             run_wall_s: float) -> RunOutcome:  # fmt: skip
    """One run as planned by ``out`` (see :func:`plan_run`); fills in what came of it."""
    k, faults = out.run, list(out.faults)
    t0 = time.monotonic()
    receiver = _receiver()
    with tempfile.TemporaryDirectory(prefix=f"soak{k}-") as tmp_s:
        tmp = Path(tmp_s)
        share, jfs = tmp / "share", tmp / "jfs"
        mounted: list[Path] = []
        if out.share_ro_at_s is not None:
            out.share_ro = _mount_tmpfs(share, "64m")
            if not out.share_ro:
                mounted.append(share)
        else:
            share.mkdir()
        if out.disk_full_at_s is not None:
            out.disk_full = _mount_tmpfs(jfs, "48m")
            if not out.disk_full:
                mounted.append(jfs)
        else:
            jfs.mkdir()
        exchange, away = share / "exchange", share / "exchange.away"
        (exchange / "outbox").mkdir(parents=True)
        (exchange / "inbox").mkdir()
        profile = tmp / "fast.toml"
        profile.write_text(PROFILE)
        name = f"soak{k}"
        env = _env()
        extra = ""
        if out.dst:
            tz, hours = _dst_zone(delay_s=8.0)
            env["TZ"] = tz
            extra = f'[operator]\nhours = "{hours}"\nresponse_min = 0\n'
            if not any(f.startswith("missing-export@0") for f in faults):
                faults.append("missing-export@0")  # block 0 then waits for its deadline: across the change
                out.faults = faults
            out.notes.append(f"TZ {tz}, operator hours {hours}")
        config = tmp / "run.toml"
        config.write_text(
            f'name = "{name}"\n[campaign]\nscenario = "ternary"\nseed = {out.seed}\nprofile = "{profile}"\n'
            f"[run]\nauto_resume = 3\nresume_backoff_s = 1.0\n"
            f'[notify]\nurls = ["{receiver.url(name)}"]\n{extra}'
        )
        journal, ledger = jfs / "runs" / f"{name}.sqlite", tmp / "ledger.jsonl"
        fake_argv = _aeni(
            "kla", "fake-inview", "--exchange", str(exchange), "--speed", "1e6",
            "--invalid-rate", str(invalid_rate), "--profile", str(profile), "--seed", str(out.seed),
            "--ledger", str(ledger),
        )  # fmt: skip
        for f in faults:
            fake_argv += ["--fault", f]
        fake = subprocess.Popen(
            fake_argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env
        )
        run_argv = _aeni(
            "run", str(config), "--driver", "kla", "--exchange", str(exchange), "--budget-s", str(budget_s),
            "--journal", str(journal), "--speed", "1e6", "--quiet", "--detach",
        )  # fmt: skip
        deadline = t0 + run_wall_s
        stop_event = threading.Event()
        stall_s = stall_x * min_block_s + (120.0 if out.dst else 0.0)

        def after_first_ticket(at_s: float) -> bool:
            """Wait for the first ticket, then ``at_s``; False when the run ended first."""
            while not any(exchange.glob("outbox/*-ticket.json")) and not stop_event.is_set():
                time.sleep(0.1)  # once a block is out (a folder missing or read-only at the start is refused)
            return not stop_event.wait(at_s)

        def carry_away() -> None:  # the folder goes away and comes back while the run goes on
            if after_first_ticket(out.folder_away_at_s) and exchange.is_dir():
                if not _retry(lambda: os.rename(exchange, away)):  # the share may be read-only just then
                    return
                out.folder_removed = True
                time.sleep(out.folder_away_s)
                _retry(lambda: os.rename(away, exchange), until_s=120.0)

        def read_only() -> None:  # the share turns read-only, then writable again
            assert out.share_ro_at_s is not None
            if after_first_ticket(out.share_ro_at_s):
                subprocess.run(["mount", "-o", "remount,ro", str(share)], check=True, capture_output=True)
                time.sleep(out.share_ro_s)
                subprocess.run(["mount", "-o", "remount,rw", str(share)], check=True, capture_output=True)
                out.share_ro = "done"

        def fill_up() -> None:  # the journal's folder fills up, then frees again
            assert out.disk_full_at_s is not None
            if not stop_event.wait(out.disk_full_at_s):
                ballast = _fill(jfs)
                time.sleep(out.disk_full_s)
                ballast.unlink()
                out.disk_full = "done"

        helpers = [threading.Thread(target=carry_away, daemon=True)]
        if out.share_ro_at_s is not None and not out.share_ro:
            helpers.append(threading.Thread(target=read_only, daemon=True))
        try:
            started = subprocess.run(run_argv, capture_output=True, text=True, env=env, timeout=300)
            if started.returncode != 0:
                out.notes.append(
                    f"aeni run --detach exit {started.returncode}: {started.stderr.strip()[-300:]}"
                )
            for h in helpers:
                h.start()
            if out.disk_full_at_s is not None and not out.disk_full:
                filler = threading.Thread(target=fill_up, daemon=True)
                filler.start()
                helpers.append(filler)
            # kill -9 at a random moment; nobody resumes: the supervisor must
            assert out.kill_at_s is not None
            kill_at = time.monotonic() + out.kill_at_s
            last, since = _progress(journal), time.monotonic()
            while _supervised_alive(journal) or (journal.exists() and time.monotonic() - t0 < 5):
                time.sleep(0.25)
                now = time.monotonic()
                fp = _progress(journal)
                if fp is not None and fp != last:
                    last, since = fp, now
                refused = out.kill_on == "refused" and '"status": "refused"' in _read(
                    journal.with_name(journal.name + ".exports") / "manifest.jsonl"
                )
                if not out.killed and (now >= kill_at or refused):
                    pid = _engine_pid(journal)
                    if pid is not None:
                        with contextlib.suppress(ProcessLookupError):
                            os.kill(pid, signal.SIGKILL)
                            out.killed = True
                if now - since > stall_s or now > deadline:
                    out.stalled = True
                    out.stall_note = (
                        f"no journal progress for {now - since:.0f} s"
                        if now - since > stall_s
                        else "run wall limit"
                    )
                    _kill_all(journal)
                    break
            stop_event.set()
            for h in helpers:
                h.join(timeout=15)
            if away.exists() and not exchange.exists():
                os.rename(away, exchange)
            if not out.stalled and not journal.exists():
                out.notes.append("the engine never wrote its journal")
            elif not out.stalled:
                state, completed, reason = _engine_row(journal)
                out.end_state, out.stop_reason = state + ("" if completed else " (not completed)"), reason
                walls = _block_wall_s(journal)
                expected = max(statistics.median(walls) if walls else 0.0, min_block_s)
                out.notes.append(f"expected block wall time {expected:.1f} s")
        finally:
            stop_event.set()
            if fake.poll() is None:
                fake.send_signal(signal.SIGTERM)
            try:
                fake.communicate(timeout=30)
            except subprocess.TimeoutExpired:
                fake.kill()
            if journal.exists():
                _compare(journal, ledger, name, out)
                rows = _supervisor_rows(journal)
                out.deaths = len(rows)
                out.crash_loop = any("crash loop" in r or "not resumed" in r for r in rows)
                out.resumed = sum(1 for kind, _ in _sessions(journal) if kind == "resume")
            alerts = [str(m.get("message", "")) for m in receiver.got(name) if m.get("type") == "failure"]
            out.deaths_alerted = sum(1 for a in alerts if "engine" in a and ("killed" in a or "exited" in a))
            if out.deaths_alerted > out.deaths:  # a death the full disk kept out of the journal: alerted
                out.notes.append(
                    f"{out.deaths_alerted - out.deaths} death(s) alerted but not journaled (disk full)"
                )
                out.deaths = out.deaths_alerted
            if (
                out.stalled or out.lost or out.duplicated or out.changed or out.held_not_run
                or not out.end_state.startswith("stopped") or out.deaths_alerted < out.deaths
                or _resumed(out) < out.deaths
            ):  # fmt: skip
                log = journal.with_name(journal.name + ".log")
                tail = log.read_text(errors="replace").splitlines()[-12:] if log.exists() else []
                out.notes.extend(f"log: {line}" for line in tail)
                out.notes.extend(f"alert: {a}" for a in alerts)
            for m in mounted:
                _unmount(m)
    out.wall_s = time.monotonic() - t0
    return out


def table(rows: list[RunOutcome]) -> str:
    n = len(rows)
    walls = sorted(r.wall_s for r in rows)

    def count(pred: object) -> int:
        return sum(1 for r in rows if pred(r))  # type: ignore[operator]

    lines = [
        "| runs | stalled | lost | duplicated | changed | held not run | ended stopped | killed -9, nobody resumed "
        "| engine deaths | alerted | resumed by the supervisor | crash loops | folder away | share read-only "
        "| journal folder full | across DST | indents made | recorded as made | unexported | faults used |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|",
        f"| {n} | {count(lambda r: r.stalled)} | {sum(r.lost for r in rows)} | {sum(r.duplicated for r in rows)} | "
        f"{sum(r.changed for r in rows)} | {sum(r.held_not_run for r in rows)} | "
        f"{count(lambda r: r.end_state.startswith('stopped'))} | {count(lambda r: r.killed)} | "
        f"{sum(r.deaths for r in rows)} | {sum(min(r.deaths_alerted, r.deaths) for r in rows)} | "
        f"{sum(_resumed(r) for r in rows)} | {count(lambda r: r.crash_loop)} | "
        f"{count(lambda r: r.folder_removed)} | {count(lambda r: r.share_ro == 'done')} | "
        f"{count(lambda r: r.disk_full == 'done')} | {count(lambda r: r.dst)} | {sum(r.indents_made for r in rows)} | "
        f"{sum(r.recorded_made for r in rows)} | {sum(r.indents_unexported for r in rows)} | "
        f"{', '.join(sorted({f.split('@')[0] for r in rows for f in r.faults}))} |",
        "",
        f"wall time per run: median {statistics.median(walls):.1f} s, longest {walls[-1]:.1f} s"
        if walls
        else "",
    ]
    skipped = sorted(
        {r.share_ro for r in rows if r.share_ro.startswith("skipped")}
        | {r.disk_full for r in rows if r.disk_full.startswith("skipped")}
    )
    if skipped:
        lines.append("skipped: " + "; ".join(skipped))
    reasons: dict[str, int] = {}
    for r in rows:
        key = r.stop_reason or r.stall_note or "?"
        key = (
            key.split(" left of ")[0].rstrip("0123456789, ")
            if key.startswith("instrument-time budget")
            else key
        )
        reasons[key] = reasons.get(key, 0) + 1
    lines.append("stop reasons: " + "; ".join(f"{k} ×{v}" for k, v in sorted(reasons.items())))
    return "\n".join(lines)


def _resumed(r: RunOutcome) -> int:
    """The run's engine deaths its supervisor resumed: all of them (a resume that did not start counts as a
    death, resumed by the next attempt) when a resumed engine ran and no crash loop stopped it, else none."""
    return r.deaths if r.resumed >= 1 and not r.crash_loop else 0


def _bad(r: RunOutcome) -> bool:
    return bool(
        r.stalled or r.lost or r.duplicated or r.changed or not r.end_state.startswith("stopped")
        or r.deaths_alerted < r.deaths or _resumed(r) < r.deaths
    )  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=50)
    ap.add_argument("--first", type=int, default=0, help="start at run K (a soak resumed; runs K..runs-1)")
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
    ap.add_argument(
        "--table-from", dest="table_from", type=Path, default=None,
        help="only print (and with --out write) the table of the runs in this soak.jsonl (a soak cut short)",
    )  # fmt: skip
    args = ap.parse_args(argv)
    if args.table_from is not None:
        fields = set(RunOutcome.__dataclass_fields__)
        done = [
            RunOutcome(**{k: v for k, v in json.loads(line).items() if k in fields})
            for line in args.table_from.read_text(encoding="utf-8").splitlines()
            if line.strip()
        ]
        text = table(sorted(done, key=lambda r: r.run))
        print(text)
        if args.out is not None:
            args.out.mkdir(parents=True, exist_ok=True)
            (args.out / "soak.json").write_text(json.dumps([asdict(r) for r in done], indent=1))
            (args.out / "soak.md").write_text(text + "\n")
        return 1 if any(_bad(r) for r in done) else 0
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
                f"{out.duplicated}, changed {out.changed}, held not run {out.held_not_run}, deaths {out.deaths} "
                f"(alerted {out.deaths_alerted}, resumed {out.resumed}), {out.end_state}",
                flush=True,
            )
            if args.out is not None:
                args.out.mkdir(parents=True, exist_ok=True)
                with (args.out / "soak.jsonl").open("a", encoding="utf-8") as fh:
                    fh.write(json.dumps(asdict(out)) + "\n")
        return out

    with ThreadPoolExecutor(max_workers=max(args.jobs, 1)) as pool:
        rows = list(pool.map(one, range(args.first, args.runs)))
    text = table(rows) + f"\ntotal wall time {time.monotonic() - started:.0f} s"
    print(text)
    for r in rows:
        if _bad(r) or r.held_not_run:
            print(f"run {r.run} (seed {r.seed}, faults {', '.join(r.faults)}): " + " | ".join(r.notes[:12]))
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "soak.json").write_text(json.dumps([asdict(r) for r in rows], indent=1))
        (args.out / "soak.md").write_text(text + "\n")
    return 1 if any(_bad(r) for r in rows) else 0


if __name__ == "__main__":
    raise SystemExit(main())

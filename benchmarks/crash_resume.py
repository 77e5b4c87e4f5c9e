"""SIGKILL the engine at random points, resume it, and count the runs that end identical to an uninterrupted one.

Each trial starts a real engine process on the simulated instrument, kills it with SIGKILL at a random
moment (after a random number of committed indents plus a random few milliseconds, or at a random
wall time), sometimes kills the resumed engine too, resumes until the run finishes, and compares the
journal with an uninterrupted run of the same seed: every measured indent identical, none repeated,
none missing, the same block plans, and the same non-recovery ledger.

    python benchmarks/crash_resume.py [--trials 100] [--workers 2]

writes benchmarks/results/crash_resume.md and .json. tests/test_crash_resume.py runs a few of the same
trials. Engine processes are forked from a preloaded fork server (start-up in milliseconds rather
than seconds); one trial kind also goes through the real ``aeni run`` / ``aeni resume`` commands.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import signal
import sqlite3
import statistics
import subprocess
import sys
import tempfile
import time
from collections import Counter
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
os.environ.setdefault("OMP_NUM_THREADS", "1")

RESULTS = ROOT / "benchmarks" / "results"
MEASURED = (
    "block_id, indent_index, commanded_x_um, commanded_y_um, actual_x_um, actual_y_um, hold_s, hardness_gpa, "
    "modulus_gpa, drift_rate_nm_s"
)


@dataclass(frozen=True)
class TrialRun:
    policy: str = "cost-aware"
    scenario: str = "ternary"
    seed: int = 3
    lattice_n: int = 30
    budget_s: float = 30000.0
    speed: float | None = 20000.0  # slow enough that kills land inside blocks, not only in GP fits

    def spec_json(self) -> str:
        """The run as the engine receives it (core.run.spec.RunSpec)."""
        from core.run.spec import RunSpec
        from core.runconfig import make_campaign_config

        cfg = make_campaign_config(
            f"crash-{self.policy}-{self.seed}",
            policy=self.policy,
            scenario=self.scenario,
            seed=self.seed,
            lattice_n=self.lattice_n,
            settings={"budget_s": self.budget_s},
        )
        return RunSpec(campaign=cfg, speed=self.speed).to_json()


# --------------------------------------------------------------------------------------------------
# engine processes


def _engine_child(journal: str, spec_json: str | None, speed: float | None) -> None:
    """Target of a forked engine: create (its RunSpec given) or resume the run, then exit."""
    from aeni_console.cli.run import run_engine
    from core.run.spec import RunSpec

    create = None if spec_json is None else RunSpec.from_json(spec_json)
    code = run_engine(journal, create=create, speed=speed, quiet=True)
    os._exit(code)


_CTX: Any = None


def _context() -> Any:
    """A fork server with the heavy imports done once; it never runs torch, so forking from it is safe."""
    global _CTX
    if _CTX is None:
        _CTX = mp.get_context("forkserver")
        _CTX.set_forkserver_preload(  # the engine host imports these where it runs (not at its top)
            [
                "core.campaign",
                "core.run.engine",
                "core.run.compose",
                "drivers.registry",
                "aeni_console.alerts",
                "aeni_console.cli.run",
                "benchmarks.crash_resume",
            ]
        )
    return _CTX


class EngineProc:
    """One engine process: forked (fast) or the real CLI (``aeni run`` / ``aeni resume``)."""

    def __init__(self, journal: Path, spec: TrialRun, create: bool, cli: bool = False) -> None:
        self.cli = cli
        if cli:
            env = dict(os.environ, PYTHONPATH=str(ROOT))
            if create:
                argv = [sys.executable, "-m", "aeni_console.cli.main", "run", "--quiet", "--journal", str(journal),
                        "--policy", spec.policy, "--scenario", spec.scenario, "--seed", str(spec.seed),
                        "--lattice-n", str(spec.lattice_n), "--budget-s", repr(spec.budget_s)]  # fmt: skip
                if spec.speed is not None:
                    argv += ["--speed", repr(spec.speed)]
            else:
                argv = [sys.executable, "-m", "aeni_console.cli.main", "resume", "--quiet", str(journal)]
            self.popen: subprocess.Popen[bytes] | None = subprocess.Popen(
                argv, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE
            )
            self.proc: Any = None
            self.pid = self.popen.pid
        else:
            self.popen = None
            self.proc = _context().Process(
                target=_engine_child, args=(str(journal), spec.spec_json() if create else None, spec.speed)
            )
            self.proc.start()
            self.pid = self.proc.pid

    def alive(self) -> bool:
        if self.popen is not None:
            return self.popen.poll() is None
        return bool(self.proc.is_alive())

    def kill(self) -> None:
        os.kill(self.pid, signal.SIGKILL)  # this engine's own PID, nothing else

    def wait(self, timeout: float = 300.0) -> int:
        if self.popen is not None:
            _, err = self.popen.communicate(timeout=timeout)
            if self.popen.returncode not in (0, -9):
                raise RuntimeError(
                    f"engine exited {self.popen.returncode}: {err.decode(errors='replace')[-2000:]}"
                )
            return int(self.popen.returncode)
        self.proc.join(timeout)
        if self.proc.exitcode is None:
            raise RuntimeError("engine did not finish in time")
        return int(self.proc.exitcode)


# --------------------------------------------------------------------------------------------------
# reading journals without the engine's help (plain sqlite: the comparison must not trust our reader)


def _rows(path: Path, sql: str) -> list[tuple[Any, ...]]:
    conn = sqlite3.connect(f"file:{path}?mode=ro", uri=True, timeout=30)
    try:
        return conn.execute(sql).fetchall()
    finally:
        conn.close()


def indent_count(path: Path) -> int:
    try:
        return int(_rows(path, "SELECT COUNT(*) FROM indents")[0][0])
    except sqlite3.Error:
        return 0


def where_killed(path: Path) -> str:
    """Where the engine was when it died, from what the journal holds."""
    if not path.exists():
        return "before the journal existed"
    try:
        blocks = _rows(path, "SELECT block_id, status, n_indents FROM blocks ORDER BY block_id")
        done = dict(_rows(path, "SELECT block_id, COUNT(*) FROM indents GROUP BY block_id"))
    except sqlite3.Error:
        return "journal being created"
    if not blocks:
        return "before the first block"
    bid, status, n = blocks[-1]
    k = int(done.get(bid, 0))
    if status == "observed":
        return "between blocks (deciding)"
    if 0 < k < n:
        return "inside a block"
    if k == n:
        return "after a block's last indent (fitting)"
    return "block planned, no indent yet"


@dataclass
class Comparison:
    identical: bool
    n_ref: int
    n_got: int
    duplicates: int
    missing: int
    extra: int
    differing: int
    plans_identical: bool
    ledger_identical: bool
    recovery_s: float
    t_offset_max_s: float
    detail: str = ""


def compare(ref: Path, got: Path) -> Comparison:
    a = _rows(ref, f"SELECT {MEASURED}, t_s FROM indents ORDER BY block_id, indent_index")
    b = _rows(got, f"SELECT {MEASURED}, t_s FROM indents ORDER BY block_id, indent_index")
    dup = _rows(got, "SELECT COUNT(*) FROM (SELECT commanded_x_um, commanded_y_um, block_id FROM indents "
                     "GROUP BY block_id, commanded_x_um, commanded_y_um HAVING COUNT(*) > 1)")[0][0]  # fmt: skip
    ka = {r[:2]: r for r in a}
    kb = {r[:2]: r for r in b}
    missing = len(ka.keys() - kb.keys())
    extra = len(kb.keys() - ka.keys())
    differing = sum(1 for k in ka.keys() & kb.keys() if ka[k][:-1] != kb[k][:-1])
    plans = _rows(ref, "SELECT block_json FROM blocks ORDER BY block_id") == _rows(
        got, "SELECT block_json FROM blocks ORDER BY block_id"
    )
    led_sql = (
        "SELECT category, ROUND(SUM(seconds), 6) FROM steps WHERE category != 'recovery' GROUP BY category"
    )
    ledger = dict(_rows(ref, led_sql)) == dict(_rows(got, led_sql))
    rec = float(_rows(got, "SELECT COALESCE(SUM(seconds), 0) FROM steps WHERE category = 'recovery'")[0][0])
    offset = max((abs(kb[k][-1] - ka[k][-1]) for k in ka.keys() & kb.keys()), default=0.0)
    ok = missing == 0 and extra == 0 and differing == 0 and dup == 0 and plans and ledger and len(a) == len(b)
    detail = (
        ""
        if ok
        else f"missing {missing}, extra {extra}, differing {differing}, dup {dup}, plans {plans}, ledger {ledger}"
    )
    return Comparison(
        ok, len(a), len(b), int(dup), missing, extra, differing, plans, ledger, rec, offset, detail
    )


# --------------------------------------------------------------------------------------------------
# one trial


@dataclass
class Trial:
    trial: int
    cli: bool
    kills: list[str] = field(default_factory=list)  # where each SIGKILL landed
    kills_landed: int = 0
    resumes: int = 0
    comparison: Comparison | None = None
    wall_s: float = 0.0
    error: str = ""
    journal: str = ""

    @property
    def identical(self) -> bool:
        return self.comparison is not None and self.comparison.identical and not self.error


def reference_run(workdir: Path, spec: TrialRun) -> Path:
    path = workdir / "reference.sqlite"
    if not path.exists():
        ref_spec = TrialRun(
            **{**asdict(spec), "speed": None}
        )  # as fast as possible: speed must not change results
        p = EngineProc(path, ref_spec, create=True)
        if p.wait() != 0:
            raise RuntimeError("the reference run failed")
    return path


def _kill_at_random(
    proc: EngineProc, journal: Path, rng: Any, ref_n: int, ref_wall_s: float, p_time: float
) -> str | None:
    """Kill ``proc`` at a random point; None when it finished before the kill fired."""
    t0 = time.monotonic()
    if rng.random() >= p_time:
        target = int(rng.integers(0, ref_n))
        while proc.alive() and indent_count(journal) < target:
            time.sleep(0.002)
        time.sleep(float(rng.uniform(0.0, 0.01)))
    else:
        deadline = t0 + float(rng.uniform(0.0, 0.8 * ref_wall_s))
        while proc.alive() and time.monotonic() < deadline:
            time.sleep(0.002)
    if not proc.alive():
        return None
    proc.kill()
    proc.wait()
    return where_killed(journal)


def crash_trial(
    workdir: Path,
    spec: TrialRun,
    trial: int,
    ref: Path,
    ref_wall_s: float,
    cli: bool = False,
    p_time: float = 0.3,
) -> Trial:
    """One run killed once or twice at random points (after k indents, or at a random time), resumed to the end.

    A first kill that comes too late (the run already finished) is drawn again on a fresh run, so that
    every trial is a crash trial.
    """
    import numpy as np

    rng = np.random.default_rng([20240601, trial])
    out = Trial(trial=trial, cli=cli)
    ref_n = len(_rows(ref, "SELECT 1 FROM indents"))
    t0 = time.monotonic()
    journal = workdir / f"trial-{trial:03d}.sqlite"
    try:
        max_kills = 1 + int(rng.random() < 0.35)  # a third of the trials also kill the resumed engine
        for attempt in range(3):
            journal = workdir / f"trial-{trial:03d}-{attempt}.sqlite"
            proc = EngineProc(journal, spec, create=True, cli=cli)
            for _ in range(max_kills):
                where = _kill_at_random(proc, journal, rng, ref_n, ref_wall_s, p_time)
                if where is None:
                    break
                out.kills.append(where)
                out.kills_landed += 1
                # resume; a run killed before its journal existed starts again
                proc = EngineProc(journal, spec, create=not journal.exists(), cli=cli)
                out.resumes += 1
            code = proc.wait()
            if code != 0:
                out.error = f"final engine exited {code}"
            if out.kills_landed:
                break
        out.comparison = compare(ref, journal)
        out.journal = journal.name
    except Exception as exc:  # reported in the table, never hidden
        out.error = f"{type(exc).__name__}: {exc}"
    out.wall_s = time.monotonic() - t0
    return out


def _noop() -> None:
    pass


def run_trials(
    workdir: Path,
    spec: TrialRun,
    trials: int,
    workers: int = 2,
    cli_every: int = 0,
    start: int = 0,
    p_time: float = 0.3,
) -> tuple[Path, float, list[Trial]]:
    from joblib import Parallel, delayed

    warm = _context().Process(target=_noop)  # start the fork server outside the timed reference run
    warm.start()
    warm.join()
    t0 = time.monotonic()
    ref = reference_run(workdir, spec)
    ref_wall = time.monotonic() - t0
    # the engines are separate processes; the workers only start, kill and compare them
    results = Parallel(n_jobs=workers, backend="threading")(
        delayed(crash_trial)(
            workdir, spec, i, ref, ref_wall, cli=bool(cli_every and i % cli_every == 0), p_time=p_time
        )
        for i in range(start, start + trials)
    )
    return ref, ref_wall, list(results)


# --------------------------------------------------------------------------------------------------
# report


def report(spec: TrialRun, trials: list[Trial], ref: Path, wall_s: float) -> dict[str, Any]:
    landed = [t for t in trials if t.kills_landed]
    ident = [t for t in landed if t.identical]
    where = Counter(w for t in trials for w in t.kills)
    rec = [t.comparison.recovery_s for t in landed if t.comparison]
    return {
        "spec": asdict(spec),
        "reference_indents": len(_rows(ref, "SELECT 1 FROM indents")),
        "trials": len(trials),
        "trials_with_a_kill": len(landed),
        "kills": sum(t.kills_landed for t in trials),
        "identical": len(ident),
        "not_identical": [asdict(t) for t in landed if not t.identical],
        "kill_points": dict(where.most_common()),
        "via_cli": sum(1 for t in landed if t.cli),
        "median_recovery_s": statistics.median(rec) if rec else 0.0,
        "median_trial_wall_s": statistics.median(t.wall_s for t in trials) if trials else 0.0,
        "wall_s": wall_s,
    }


def write_report(summary: dict[str, Any], out_dir: Path = RESULTS) -> None:
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "crash_resume.json").write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
    s = summary["spec"]
    lines = [
        "# Crash and resume: SIGKILL the engine, resume, compare with an uninterrupted run",
        "",
        f"Scenario `{s['scenario']}`, policy `{s['policy']}`, seed {s['seed']}, lattice {s['lattice_n']}, "
        f"budget {s['budget_s']:,.0f} s, simulated driver at {s['speed']}× (reference run: as fast as possible, "
        f"{summary['reference_indents']} indents).",
        "",
        "| trials | with a kill | kills | via the CLI | identical | median recovery | median trial wall |",
        "|---:|---:|---:|---:|---:|---:|---:|",
        f"| {summary['trials']} | {summary['trials_with_a_kill']} | {summary['kills']} | {summary['via_cli']} | "
        f"**{summary['identical']} / {summary['trials_with_a_kill']}** | {summary['median_recovery_s']:.0f} s | "
        f"{summary['median_trial_wall_s']:.1f} s |",
        "",
        "Identical means: the same measured indents (block, index, commanded and actual position, hold, hardness,",
        "modulus, drift rate; bit for bit), none repeated or missing, the same block plans, and the same ledger",
        "apart from the `recovery` steps (re-engage and drift settle after the crash), whose time shifts the",
        "instrument clock of later indents but is not charged to the planner's budget.",
        "",
        "Where the kills landed:",
        "",
        "| kill point | kills |",
        "|---|---:|",
        *[f"| {k} | {v} |" for k, v in summary["kill_points"].items()],
        "",
        f"Total wall time {summary['wall_s']:.0f} s. Re-run: `python benchmarks/crash_resume.py --trials {summary['trials']}`.",
    ]
    if summary["not_identical"]:
        lines += ["", "Trials that did not end identical:", ""]
        lines += [
            f"- trial {t['trial']}: {t['error'] or (t['comparison'] or {}).get('detail')}"
            for t in summary["not_identical"]
        ]
    (out_dir / "crash_resume.md").write_text("\n".join(lines) + "\n", encoding="utf-8")


def _run_frozen(argv: list[str], out: Path) -> int:
    """Re-run this script from a copy of the source, so edits made while it runs cannot mix two versions."""
    import shutil

    with tempfile.TemporaryDirectory(prefix="aeni-src-") as tmp:
        for name in ("core", "drivers", "aeni_console", "benchmarks"):
            shutil.copytree(
                ROOT / name, Path(tmp) / name, ignore=shutil.ignore_patterns("__pycache__", "results")
            )
        script = Path(tmp) / "benchmarks" / "crash_resume.py"
        env = dict(os.environ, PYTHONPATH=tmp)
        return subprocess.call(
            [sys.executable, str(script), *argv, "--frozen", "--out", str(out.resolve())], env=env
        )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=100)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--cli-every", type=int, default=10, help="every N-th trial uses the real aeni commands")
    ap.add_argument("--out", type=Path, default=RESULTS)
    ap.add_argument("--frozen", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if not args.frozen:
        return _run_frozen(list(sys.argv[1:] if argv is None else argv), args.out)  # the last --out wins
    spec = TrialRun()
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="aeni-crash-") as tmp:
        ref, _, trials = run_trials(Path(tmp), spec, args.trials, args.workers, args.cli_every)
        summary = report(spec, trials, ref, time.monotonic() - t0)
    write_report(summary, args.out)
    print(
        f"{summary['identical']} / {summary['trials_with_a_kill']} killed runs ended identical "
        f"({summary['kills']} kills; {args.out / 'crash_resume.md'})"
    )
    return 0 if summary["identical"] == summary["trials_with_a_kill"] else 1


if __name__ == "__main__":
    sys.exit(main())

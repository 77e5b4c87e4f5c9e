"""The engine's state machine against a tiny deterministic campaign and the real simulated driver.

Operator commands are sent through the journal exactly as a console sends them; the engine's injected
``sleep`` is where the scripted operator acts, so no test depends on thread timing.
"""

from __future__ import annotations

import dataclasses
import os
import sqlite3
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from core.errors import InputError
from core.journal import Journal, JournalReader, NotOwnerError, send_command
from core.metrics import MapScore
from core.plan import Block, Decision, IndentResult, MapWeights, PlannerSettings, local_grid
from core.profile import load_profile
from core.run.engine import Engine
from core.runview import Command, CommandKind, EngineState, MapFields
from core.settings import adjust_settings, settings_from_dict, settings_to_dict
from drivers.sim.driver import SimulatedDriver
from drivers.sim.scenarios import make_scenario

CENTRES = [(200.0, 200.0), (260.0, 200.0), (260.0, 260.0), (700.0, 700.0), (760.0, 700.0), (300.0, 800.0)]


@dataclasses.dataclass
class FakeFit:
    lengthscales_uv: tuple[float, float] = (0.2, 0.3)
    noise_lengthscales_uv: tuple[float, float] | None = None
    collapse: bool = False
    collapse_reason: str = ""
    used_last_good: bool = False
    seconds: float = 0.01
    n_points: int = 0
    iterations: int = 1
    outputscale: float = 1.0
    mean_const: float = 5.0
    hyper: dict[str, Any] = dataclasses.field(default_factory=dict)


class FakeCampaign:
    """Deterministic planner: walks CENTRES (skipping vetoed ones), 2×2 blocks, global every third block."""

    def __init__(self, n_blocks: int = 5, collapse_at: int | None = None) -> None:
        self.n_blocks = n_blocks
        self.collapse_at = collapse_at
        self.settings = PlannerSettings(map_weights=MapWeights(modulus=0.0))  # no modulus map here
        self.profile = load_profile("kla-imicro")
        self.calibration = make_scenario("ternary", 1).calibration  # the 1000 µm square
        self.observed: list[tuple[Block, list[IndentResult]]] = []
        self.vetoed: list[tuple[float, float]] = []
        self.proposals = 0
        self.last_stop_reason: str | None = None

    def propose(
        self, clock_s: float, position_um: tuple[float, float], program_open: bool, block_id: int
    ) -> Decision | None:
        self.proposals += 1
        if len(self.observed) >= self.n_blocks:
            return None
        free = [c for c in CENTRES if c not in self.vetoed]
        cx, cy = free[len(self.observed) % len(free)]
        kind = "global" if len(self.observed) % 3 == 0 or not program_open else "local"
        block = Block(block_id, kind, cx, cy, 2, 5.0, 80.0, local_grid(cx, cy, 2, 5.0, 80.0))
        return Decision(
            block=block, policy="fake", acquisition=1.0, score=1.0 / (1 + block_id), predicted_cost_s=999.0
        )

    def veto(self, decision: Decision, hold_blocks: int = 3) -> None:
        self.vetoed.append((decision.block.center_x_um, decision.block.center_y_um))

    def adjust(self, **changes: Any) -> PlannerSettings:
        self.settings = adjust_settings(self.settings, changes, self.profile.allowed_holds_s)
        return self.settings

    def observe_block(self, block: Block, results: Sequence[IndentResult]) -> FakeFit | None:
        self.observed.append((block, list(results)))
        if len(self.observed) < 2:
            return None
        collapse = self.collapse_at is not None and len(self.observed) == self.collapse_at
        return FakeFit(
            collapse=collapse,
            collapse_reason="length-scale below floor" if collapse else "",
            n_points=len(self.observed),
            hyper={"n": len(self.observed)},
        )

    def map_fields(self, snapshot_id: int, display_n: int = 50) -> MapFields:
        xs = np.linspace(0, 1000, 4)
        z = np.full((4, 4), float(len(self.observed)))
        return MapFields(snapshot_id, xs, xs, z, z, z, z)

    def metrics(self) -> tuple[float | None, float | None]:
        return 10.0 / (1 + len(self.observed)), 7.0

    def note_score(self, score: MapScore | None) -> None:
        self.score = score

    def export_state(self) -> dict[str, Any]:
        return {"vetoed": [list(v) for v in self.vetoed], "settings": settings_to_dict(self.settings)}

    def restore(self, state: dict[str, Any], blocks: Sequence[tuple[Block, Sequence[IndentResult]]]) -> None:
        self.observed = [(b, list(r)) for b, r in blocks]
        self.vetoed = [(float(x), float(y)) for x, y in state["vetoed"]]
        self.settings = settings_from_dict(state["settings"])


class FakeEvaluator:
    """Reports the fake campaign's made-up map error, as a simulated run's evaluator would report its own."""

    def score(self, campaign: Any) -> MapScore:
        mape, top = campaign.metrics()
        return MapScore(mape, top)


def make_driver(seed: int = 1) -> SimulatedDriver:
    sc = make_scenario("ternary", seed)
    return SimulatedDriver(sc.make_emulator(), load_profile("kla-imicro"), start_um=(500.0, 500.0))


def new_journal(tmp_path: Path, name: str = "run.sqlite", supervision: str = "auto") -> Journal:
    return Journal.create(
        tmp_path / name,
        {"name": "t", "policy": "fake"},
        load_profile("kla-imicro"),
        {"corners": []},
        supervision=supervision,
        grid_baseline_s=286392.0,
        stage_bounds_um=(0.0, 1000.0, 0.0, 1000.0),
        name="t",
    )


class Operator:
    """A scripted console: on each engine wait it looks at the engine and may send the next command."""

    def __init__(self, path: Path, rules: list[Callable[[Engine], Command | None]], limit: int = 500) -> None:
        self.path = path
        self.rules = list(rules)
        self.engine: Engine | None = None
        self.ticks = 0
        self.limit = limit

    def sleep(self, _s: float) -> None:
        self.ticks += 1
        assert self.ticks < self.limit, f"engine waited forever in state {self.engine and self.engine.state}"
        if self.rules and self.engine is not None:
            cmd = self.rules[0](self.engine)
            if cmd is not None:
                self.rules.pop(0)
                send_command(self.path, cmd)


def cmd(kind: CommandKind, **payload: Any) -> Command:
    return Command(kind=kind, author="tester", payload=payload, shown_scores={"score": 0.5})


def when(state: EngineState, command: Command) -> Callable[[Engine], Command | None]:
    return lambda e: command if e.state == state else None


def run_engine(
    tmp_path: Path,
    campaign: FakeCampaign,
    supervision: str = "auto",
    rules: list[Callable[[Engine], Command | None]] | None = None,
    name: str = "run.sqlite",
    driver: SimulatedDriver | None = None,
    **engine_kw: Any,
) -> tuple[Engine, Path]:
    j = new_journal(tmp_path, name, supervision)
    op = Operator(j.path, rules or [])
    eng = Engine(
        j,
        campaign,
        driver or make_driver(),
        supervision,
        poll_s=0.01,
        sleep=op.sleep,
        watch_s=None,
        evaluator=FakeEvaluator(),  # type: ignore[arg-type]
        **engine_kw,
    )
    op.engine = eng
    try:
        eng.run()
    finally:
        j.close()
    return eng, j.path


def indents_of(path: Path) -> list[tuple[Any, ...]]:
    with JournalReader(path) as r:
        return [
            (x.block_id, x.indent_index, x.commanded_x_um, x.commanded_y_um, x.hardness_gpa)
            for x in r.results()
        ]


def test_auto_run_journals_every_block_indent_and_step(tmp_path: Path) -> None:
    camp = FakeCampaign(n_blocks=5)
    driver = make_driver()
    eng, path = run_engine(tmp_path, camp, driver=driver)
    assert eng.state == EngineState.STOPPED and eng.completed
    with JournalReader(path) as r:
        snap = r.snapshot()
        blocks = r.blocks()
        decisions = r.decisions()
    assert [b.status for b in blocks] == ["observed"] * 5
    assert snap.n_indents == 20 and snap.n_blocks == 5
    assert all(d.status == "auto" for d in decisions) and len(decisions) == 5
    # the ledger is the driver's clock, to the microsecond, including the final comeback
    assert sum(snap.ledger.values()) == pytest.approx(driver.clock_s(), abs=1e-6)
    assert snap.ledger["comeback"] >= 35.0
    assert snap.instrument_s == pytest.approx(driver.clock_s())
    assert snap.state == EngineState.STOPPED and snap.finished
    assert snap.mape_pct == pytest.approx(10.0 / 6)
    assert [t.block_id for t in snap.tested] == [0, 1, 2, 3, 4]
    assert snap.gp.snapshot_id is not None
    assert snap.gp.lengthscales_um == pytest.approx((200.0, 300.0))  # 0.2, 0.3 of the 1000 µm square
    with JournalReader(path) as r:
        fields = r.map_fields(snap.gp.snapshot_id)
    assert fields.mean_gpa.shape == (4, 4) and float(fields.mean_gpa[0, 0]) == 5.0


def test_supervised_waits_for_global_jumps_only(tmp_path: Path) -> None:
    camp = FakeCampaign(n_blocks=4)
    approve = cmd(CommandKind.APPROVE)
    eng, path = run_engine(tmp_path, camp, "supervised", [when(EngineState.AWAITING_APPROVAL, approve)] * 2)
    with JournalReader(path) as r:
        decisions = r.decisions()
        commands = r.commands()
    kinds = [(d.decision.block.kind, d.status) for d in decisions]
    # blocks 0 and 3 are global jumps: approved by the operator; 1 and 2 stay local and run on their own
    assert kinds == [("global", "approved"), ("local", "auto"), ("local", "auto"), ("global", "approved")]
    assert [c["outcome"] for c in commands] == ["accepted", "accepted"]
    assert all(c["author"] == "tester" and c["processed"] == 1 for c in commands)
    assert eng.completed


def test_step_mode_waits_before_every_block(tmp_path: Path) -> None:
    camp = FakeCampaign(n_blocks=3)
    step = cmd(CommandKind.STEP)
    eng, path = run_engine(tmp_path, camp, "step", [when(EngineState.AWAITING_APPROVAL, step)] * 3)
    with JournalReader(path) as r:
        statuses = [d.status for d in r.decisions()]
        reasons = {c["state_before"] for c in r.commands()}
    assert statuses == ["approved"] * 3
    assert reasons == {"awaiting-approval"}
    assert eng.completed


def test_veto_offers_the_next_best_and_avoids_the_vetoed_centre(tmp_path: Path) -> None:
    camp = FakeCampaign(n_blocks=2)
    rules = [
        when(EngineState.AWAITING_APPROVAL, cmd(CommandKind.VETO)),
        when(EngineState.AWAITING_APPROVAL, cmd(CommandKind.APPROVE)),
    ]
    _, path = run_engine(
        tmp_path, camp, "step", [*rules, when(EngineState.AWAITING_APPROVAL, cmd(CommandKind.APPROVE))]
    )
    with JournalReader(path) as r:
        decisions = r.decisions()
        blocks = r.blocks()
        commands = r.commands()
    assert [d.status for d in decisions] == ["vetoed", "approved", "approved"]
    # the vetoed and the replacement decision are for the same block id, at different centres
    assert decisions[0].decision.block.block_id == decisions[1].decision.block.block_id == 0
    vetoed = (decisions[0].decision.block.center_x_um, decisions[0].decision.block.center_y_um)
    assert vetoed == CENTRES[0]
    assert all((b.block.center_x_um, b.block.center_y_um) != vetoed for b in blocks)
    assert "next best" in commands[0]["reason"]


def test_adjust_validates_each_field(tmp_path: Path) -> None:
    camp = FakeCampaign(n_blocks=2)
    rules = [
        when(EngineState.AWAITING_APPROVAL, cmd(CommandKind.ADJUST, beta=-1)),
        when(EngineState.AWAITING_APPROVAL, cmd(CommandKind.ADJUST, no_such_knob=3)),
        when(EngineState.AWAITING_APPROVAL, cmd(CommandKind.ADJUST, beta=2.5, target_sem_gpa=0.1)),
        when(EngineState.AWAITING_APPROVAL, cmd(CommandKind.ADJUST, supervision="auto")),
    ]
    eng, path = run_engine(tmp_path, camp, "step", rules)
    with JournalReader(path) as r:
        commands = r.commands()
        snap = r.snapshot()
    outcomes = [(c["outcome"], c["reason"]) for c in commands]
    assert outcomes[0][0] == "rejected" and "beta" in outcomes[0][1] and "-1" in outcomes[0][1]
    assert outcomes[1][0] == "rejected" and "no_such_knob" in outcomes[1][1]
    assert outcomes[2][0] == "accepted" and outcomes[3][0] == "accepted"
    assert snap.settings.beta == 2.5 and snap.settings.target_sem_gpa == 0.1
    # switching to auto released the pending block without an approve
    assert snap.supervision == "auto" and eng.completed


def test_pause_finishes_the_indent_then_waits_and_resume_continues(tmp_path: Path) -> None:
    camp = FakeCampaign(n_blocks=2)
    j = new_journal(tmp_path)
    driver = make_driver()
    seen: list[tuple[EngineState, int]] = []

    class PausingDriver:
        """Sends pause right after indent 1 of block 0 is measured (as an operator would mid-block)."""

        def __getattr__(self, name: str) -> Any:
            return getattr(driver, name)

        def execute_block(self, block: Block, start_index: int = 0) -> Any:
            for ev in driver.execute_block(block, start_index):
                if isinstance(ev, IndentResult) and ev.block_id == 0 and ev.indent_index == 1:
                    send_command(j.path, cmd(CommandKind.PAUSE))
                yield ev

    def sleep(_s: float) -> None:
        with JournalReader(j.path) as r:
            seen.append((eng.state, len(r.results())))
        if len(seen) == 3:
            send_command(j.path, cmd(CommandKind.RESUME))

    eng = Engine(j, camp, PausingDriver(), "auto", poll_s=0.01, sleep=sleep, watch_s=None)
    eng.run()
    j.close()
    # paused with exactly the two finished indents; nothing ran while paused
    assert seen == [(EngineState.PAUSED, 2)] * 3
    with JournalReader(j.path) as r:
        assert len(r.results()) == 8
        assert [c["outcome"] for c in r.commands()] == ["accepted", "accepted"]
    assert eng.completed


def test_abort_finishes_the_indent_lifts_and_stops(tmp_path: Path) -> None:
    camp = FakeCampaign(n_blocks=4)
    j = new_journal(tmp_path)
    driver = make_driver()

    class AbortingDriver:
        def __getattr__(self, name: str) -> Any:
            return getattr(driver, name)

        def execute_block(self, block: Block, start_index: int = 0) -> Any:
            for ev in driver.execute_block(block, start_index):
                if isinstance(ev, IndentResult) and ev.block_id == 1 and ev.indent_index == 2:
                    send_command(j.path, cmd(CommandKind.ABORT))
                yield ev

    eng = Engine(j, camp, AbortingDriver(), "auto", poll_s=0.01, sleep=lambda s: None, watch_s=None)
    assert eng.run() == EngineState.STOPPED
    j.close()
    assert not eng.completed and "aborted by tester" in eng.stop_reason
    with JournalReader(j.path) as r:
        blocks = r.blocks()
        snap = r.snapshot()
    assert [b.status for b in blocks] == ["observed", "aborted"]
    assert len(blocks[1].results) == 3
    assert not driver.program_open() and snap.ledger["comeback"] == pytest.approx(35.0)


def test_stop_after_block_then_resume_gives_the_uninterrupted_indents(tmp_path: Path) -> None:
    _, ref = run_engine(tmp_path, FakeCampaign(n_blocks=5), name="ref.sqlite")
    j = new_journal(tmp_path, "stopped.sqlite")
    driver = make_driver()

    class StoppingDriver:
        def __getattr__(self, name: str) -> Any:
            return getattr(driver, name)

        def execute_block(self, block: Block, start_index: int = 0) -> Any:
            for ev in driver.execute_block(block, start_index):
                if isinstance(ev, IndentResult) and ev.block_id == 1 and ev.indent_index == 0:
                    send_command(j.path, cmd(CommandKind.STOP_AFTER_BLOCK))
                yield ev

    eng = Engine(
        j, FakeCampaign(n_blocks=5), StoppingDriver(), poll_s=0.01, sleep=lambda s: None, watch_s=None
    )
    eng.run()
    j.close()
    assert not eng.completed
    with JournalReader(j.path) as r:
        assert [b.status for b in r.blocks()] == ["observed", "observed"]
    j2 = Journal.open_writer(j.path)
    eng2 = Engine(
        j2, FakeCampaign(n_blocks=5), make_driver(), poll_s=0.01, sleep=lambda s: None, watch_s=None
    )
    eng2.run()
    j2.close()
    assert eng2.completed
    got = indents_of(j.path)
    assert [g[:4] for g in got] == [g[:4] for g in indents_of(ref)]
    with JournalReader(j.path) as r:
        events = [e.text for e in r.events()]
        sessions = r.table("sessions")[1]
    assert any(t.startswith("resumed:") for t in events)
    assert len(sessions) == 2


def test_collapse_alarm_waits_in_supervised_mode(tmp_path: Path) -> None:
    camp = FakeCampaign(n_blocks=4, collapse_at=2)
    approve = cmd(CommandKind.APPROVE)
    eng, path = run_engine(tmp_path, camp, "supervised", [when(EngineState.AWAITING_APPROVAL, approve)] * 3)
    with JournalReader(path) as r:
        decisions = r.decisions()
        snaps = r.table("gp_snapshots")[1]
    # block 2 is local but follows the collapse alarm of the fit after block 1: it waits, once
    assert [(d.decision.block.block_id, d.status) for d in decisions] == [
        (0, "approved"),
        (1, "auto"),
        (2, "approved"),
        (3, "approved"),
    ]
    assert "collapse" in decisions[2].needs_approval_reason
    assert eng.completed and len(snaps) == 4


def test_commands_from_a_non_owner_are_refused_and_recorded(tmp_path: Path) -> None:
    camp = FakeCampaign(n_blocks=2)
    j = new_journal(tmp_path, supervision="step")
    other_uid = os.getuid() + 4242
    sent: list[str] = []

    def sleep(_s: float) -> None:
        if not sent:
            with pytest.raises(NotOwnerError, match="only the run's owner"):
                send_command(j.path, cmd(CommandKind.APPROVE), uid=other_uid)
            # a row written around the check (e.g. a shared file) is still rejected by the engine
            conn = sqlite3.connect(j.path)
            conn.execute(
                "INSERT INTO commands (kind, author, uid, payload_json, shown_scores_json, wall_utc) VALUES "
                "('abort', 'mallory', ?, '{}', '{}', 'now')",
                (other_uid,),
            )
            conn.commit()
            conn.close()
            sent.append("x")
        elif eng.state == EngineState.AWAITING_APPROVAL:
            send_command(j.path, cmd(CommandKind.APPROVE))

    eng = Engine(j, camp, make_driver(), "step", poll_s=0.01, sleep=sleep, watch_s=None)
    eng.run()
    j.close()
    assert eng.completed  # mallory's abort did nothing
    with JournalReader(j.path) as r:
        commands = r.commands()
    assert commands[0]["author"] == "mallory" and commands[0]["outcome"] == "rejected"
    assert "not the run's owner" in commands[0]["reason"]
    assert all(c["processed"] == 1 and c["processed_utc"] for c in commands)


def test_approve_and_veto_without_a_pending_decision_are_rejected(tmp_path: Path) -> None:
    camp = FakeCampaign(n_blocks=2)
    j = new_journal(tmp_path)
    driver = make_driver()

    class Sending:
        def __getattr__(self, name: str) -> Any:
            return getattr(driver, name)

        def execute_block(self, block: Block, start_index: int = 0) -> Any:
            for ev in driver.execute_block(block, start_index):
                if isinstance(ev, IndentResult) and ev.block_id == 0 and ev.indent_index == 0:
                    for kind in (CommandKind.APPROVE, CommandKind.VETO, CommandKind.RESUME):
                        send_command(j.path, cmd(kind))
                yield ev

    Engine(j, camp, Sending(), poll_s=0.01, sleep=lambda s: None, watch_s=None).run()
    j.close()
    with JournalReader(j.path) as r:
        reasons = [(c["kind"], c["outcome"], c["reason"]) for c in r.commands()]
    assert reasons == [
        ("approve", "rejected", "nothing is waiting for approval"),
        ("veto", "rejected", "nothing is waiting for approval"),
        ("resume", "rejected", "not paused"),
    ]


def test_a_failing_campaign_leaves_a_failed_journal_with_the_error(tmp_path: Path) -> None:
    class Broken(FakeCampaign):
        def observe_block(self, block: Block, results: Sequence[IndentResult]) -> FakeFit | None:
            raise RuntimeError("surrogate exploded")

    j = new_journal(tmp_path)
    eng = Engine(j, Broken(), make_driver(), poll_s=0.01, sleep=lambda s: None, watch_s=None)
    with pytest.raises(RuntimeError, match="exploded"):
        eng.run()
    j.close()
    with JournalReader(j.path) as r:
        snap = r.snapshot()
        assert len(r.results()) == 4  # the measured indents are kept
    assert snap.state == EngineState.FAILED
    assert any("surrogate exploded" in e.text and e.level == "error" for e in snap.log)


def test_engine_rejects_a_bad_supervision_mode(tmp_path: Path) -> None:
    j = new_journal(tmp_path)
    with pytest.raises(InputError, match="supervision"):
        Engine(j, FakeCampaign(), make_driver(), "sometimes")
    j.close()


def test_watcher_aborts_a_slow_driver_mid_step(tmp_path: Path) -> None:
    """With a real-time driver the abort must not wait for the 300 s drift settle to pass."""
    import threading
    import time

    camp = FakeCampaign(n_blocks=3)
    j = new_journal(tmp_path)
    sc = make_scenario("ternary", 1)
    slow = SimulatedDriver(
        sc.make_emulator(), load_profile("kla-imicro"), speed=10.0, start_um=(500.0, 500.0)
    )
    eng = Engine(j, camp, slow, poll_s=0.01, watch_s=0.02)

    def operator() -> None:
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and eng.state != EngineState.RUNNING:
            time.sleep(0.01)
        time.sleep(0.2)
        send_command(j.path, cmd(CommandKind.ABORT))

    t = threading.Thread(target=operator)
    t.start()
    t0 = time.monotonic()
    eng.run()
    t.join()
    j.close()
    # the first block needs 20+ s at 10×; the abort cut it short and the tip was lifted
    assert time.monotonic() - t0 < 15
    assert not slow.program_open() and not eng.completed
    with JournalReader(j.path) as r:
        assert r.commands()[0]["outcome"] == "accepted"
        assert r.snapshot().state == EngineState.STOPPED


class Crash(BaseException):
    """Stands in for the process dying (the real SIGKILL tests are in test_crash_resume.py)."""


def test_a_pending_decision_survives_a_crash_and_is_not_re_planned(tmp_path: Path) -> None:
    j = new_journal(tmp_path, supervision="supervised")

    def die(_s: float) -> None:
        raise Crash

    first = FakeCampaign(n_blocks=3)
    with pytest.raises(Crash):
        Engine(j, first, make_driver(), "supervised", poll_s=0.01, sleep=die, watch_s=None).run()
    j.close()
    with JournalReader(j.path) as r:
        assert r.q.pending_decision() is not None
    j2 = Journal.open_writer(j.path)
    second = FakeCampaign(n_blocks=3)
    op = Operator(j2.path, [when(EngineState.AWAITING_APPROVAL, cmd(CommandKind.APPROVE))])
    eng = Engine(j2, second, make_driver(), "supervised", poll_s=0.01, sleep=op.sleep, watch_s=None)
    op.engine = eng
    eng.run()
    j2.close()
    with JournalReader(j.path) as r:
        decisions = r.decisions()
    # one decision for block 0 (approved after the restart), then blocks 1 and 2 locally
    assert [(d.decision.block.block_id, d.status) for d in decisions] == [
        (0, "approved"),
        (1, "auto"),
        (2, "auto"),
    ]
    assert second.proposals == 3  # blocks 1, 2 and the final "nothing left": block 0 was not proposed again
    assert eng.completed


def test_replay_driver_reproduces_a_recorded_run(tmp_path: Path) -> None:
    from drivers.replay import ReplayDriver

    _, recorded = run_engine(tmp_path, FakeCampaign(n_blocks=4), name="recorded.sqlite")
    replay = ReplayDriver(recorded)
    _, again = run_engine(tmp_path, FakeCampaign(n_blocks=4), name="again.sqlite", driver=replay)  # type: ignore[arg-type]
    assert indents_of(again) == indents_of(recorded)
    with JournalReader(recorded) as a, JournalReader(again) as b:
        assert a.snapshot().ledger == b.snapshot().ledger
        assert a.snapshot().instrument_s == b.snapshot().instrument_s
    # a plan the recording never ran is refused, not invented
    other = Block(0, "global", 1.0, 1.0, 1, 5.0, 80.0, local_grid(1.0, 1.0, 1, 5.0, 80.0))
    with pytest.raises(InputError, match="differs from the recorded plan"):
        next(iter(ReplayDriver(recorded).execute_block(other)))
    with pytest.raises(InputError, match="not in the recorded run"):
        next(iter(ReplayDriver(recorded).execute_block(dataclasses.replace(other, block_id=99))))


def test_cli_status_replay_and_export(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import pandas as pd

    from aeni_console.cli.main import main

    _, path = run_engine(tmp_path, FakeCampaign(n_blocks=3), name="cli.sqlite")
    assert main(["status", str(path)]) == 0
    line = capsys.readouterr().out.strip()
    assert line.startswith("t: STOPPED") and "3 blocks, 12 indents" in line and "\n" not in line
    assert main(["replay", str(path)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0] == "replay of t: 3 blocks" and len(out) == 2 + 3
    assert main(["replay", str(path), "--block", "1"]) == 0
    assert len(capsys.readouterr().out.splitlines()) == 1 + 1 + 1 + 4  # block, decision, header, 4 indents
    assert main(["export", str(path), "--format", "csv", "--out", str(tmp_path / "out")]) == 0
    ind = pd.read_csv(tmp_path / "out" / "indents.csv")
    assert list(ind.columns[:6]) == ["block_id", "x_um", "y_um", "hold_s", "hardness_gpa", "t_s"]
    assert len(ind) == 12 and ind["block_id"].tolist() == [0] * 4 + [1] * 4 + [2] * 4
    # every indent's status, channel (issue 36), note, depth and export file (none: a simulated run has no
    # instrument exports)
    assert list(ind.columns[6:11]) == ["status", "channel", "note", "depth_at_max_load_nm", "export_file"]
    assert set(ind["channel"]) == {"csm"}
    assert set(ind["status"]) <= {"measured", "failed", "not_run"} and ind["export_file"].isna().all()
    assert (tmp_path / "out" / "decisions.csv").exists() and (tmp_path / "out" / "ledger.csv").exists()
    assert main(["export", str(path), "--format", "parquet", "--out", str(tmp_path / "pq")]) in (0, 2)
    assert main(["status", str(tmp_path / "missing.sqlite")]) == 2
    assert "no such journal" in capsys.readouterr().err


# -- no wait without an answer (issue 23): refusals in auto supervision, approval timeouts ------------


class RefusingInterlock:
    """An interlock that refuses every block centred on one of ``refused`` (the real one's verdict, scripted)."""

    def __init__(self, refused: list[tuple[float, float]]) -> None:
        self.refused = refused

    def check(self, block: Block, position_um: tuple[float, float], program_open: bool) -> str | None:
        if (block.center_x_um, block.center_y_um) in self.refused:
            return "an indent is already there"
        return None

    def passed(self, block: Block, results: Sequence[IndentResult]) -> None:
        pass

    def restore(self, observed: Any) -> None:
        pass


class StubbornCampaign(FakeCampaign):
    """A planner that ignores vetoes: it proposes the same block again (what the engine must not run or wait on)."""

    def propose(
        self, clock_s: float, position_um: tuple[float, float], program_open: bool, block_id: int
    ) -> Decision | None:
        self.vetoed.clear()
        return super().propose(clock_s, position_um, program_open, block_id)


def test_auto_vetoes_a_refused_block_journals_why_and_asks_again(tmp_path: Path) -> None:
    camp = FakeCampaign(n_blocks=3)
    eng, path = run_engine(
        tmp_path,
        camp,
        "auto",
        interlock=RefusingInterlock([CENTRES[1]]),  # type: ignore[arg-type]
    )
    assert eng.completed
    with JournalReader(path) as r:
        decisions = r.decisions()
        log = [e.text for e in r.events()]
    refused = [d for d in decisions if d.status == "vetoed"]
    assert len(refused) == 1 and refused[0].needs_approval_reason.startswith(
        "safety interlock refused block 1"
    )
    ran = [
        (d.decision.block.center_x_um, d.decision.block.center_y_um) for d in decisions if d.status == "auto"
    ]
    assert CENTRES[1] not in ran and len(ran) == 3
    assert any("vetoed by the engine: safety interlock refused block 1" in t for t in log)
    assert camp.vetoed == [CENTRES[1]]


def test_a_vetoed_block_proposed_again_is_refused_and_max_refusals_stops_the_run(tmp_path: Path) -> None:
    camp = StubbornCampaign(n_blocks=3)
    eng, path = run_engine(
        tmp_path,
        camp,
        "auto",
        interlock=RefusingInterlock([CENTRES[0]]),  # type: ignore[arg-type]
        max_refusals=4,
    )
    assert eng.state == EngineState.STOPPED and not eng.completed
    assert "4 consecutive blocks refused (max_refusals 4)" in eng.stop_reason
    with JournalReader(path) as r:
        decisions = r.decisions()
        snap = r.snapshot()
        indents = r.results()
    assert not indents  # the refused block never ran
    reasons = [d.needs_approval_reason for d in decisions]
    assert len(decisions) == 4 and reasons[0].startswith("safety interlock")
    assert all("a vetoed block proposed again" in why for why in reasons[1:])
    assert [d.status for d in decisions] == ["vetoed"] * 3 + ["dropped"]
    assert snap.state == EngineState.STOPPED and snap.pending is None


def test_a_veto_never_brings_back_the_same_block_in_supervised_mode(tmp_path: Path) -> None:
    camp = StubbornCampaign(n_blocks=2)
    veto = cmd(CommandKind.VETO)
    eng, path = run_engine(
        tmp_path, camp, "supervised", [when(EngineState.AWAITING_APPROVAL, veto)], max_refusals=2
    )
    # vetoed block 0 comes back: the engine refuses it itself twice in a row and stops, nobody is asked again
    assert not eng.completed and "max_refusals 2" in eng.stop_reason
    with JournalReader(path) as r:
        commands = r.commands()
    assert [c["kind"] for c in commands] == ["veto"]


class FakeWall:
    """A wall clock the operator's sleep advances: timeouts without waiting."""

    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def run_with_timeout(
    tmp_path: Path, camp: FakeCampaign, on_timeout: str, supervision: str = "supervised", **kw: Any
) -> tuple[Engine, Path]:
    j = new_journal(tmp_path, "t.sqlite", supervision)
    wall = FakeWall()

    def sleep(s: float) -> None:
        wall.t += 10.0  # nobody there: each poll is ten seconds of nobody answering
        assert wall.t < 10_000, "the engine waited forever"

    eng = Engine(
        j,
        camp,
        make_driver(),
        supervision,
        poll_s=0.01,
        sleep=sleep,
        watch_s=None,
        approval_timeout_s=60.0,
        on_timeout=on_timeout,
        wall_clock=wall,
        **kw,
    )
    try:
        eng.run()
    finally:
        j.close()
    return eng, j.path


def test_an_unanswered_approval_times_out_and_the_run_goes_on(tmp_path: Path) -> None:
    eng, path = run_with_timeout(tmp_path, FakeCampaign(n_blocks=4), "approve")
    assert eng.completed
    with JournalReader(path) as r:
        decisions = r.decisions()
        log = [e.text for e in r.events()]
    assert [d.status for d in decisions] == ["approved", "auto", "auto", "approved"]
    timeouts = [t for t in log if "timed out after 60 s: approve" in t]
    assert len(timeouts) == 2


def test_a_collapse_alarm_never_auto_approves_on_timeout(tmp_path: Path) -> None:
    eng, path = run_with_timeout(tmp_path, FakeCampaign(n_blocks=4, collapse_at=2), "approve", max_refusals=3)
    with JournalReader(path) as r:
        decisions = r.decisions()
        log = [e.text for e in r.events()]
    collapse = [d for d in decisions if d.needs_approval_reason.startswith("length-scale collapse")]
    # nobody acknowledges the alarm: every block after it waits, times out and is vetoed, never approved,
    # and max_refusals (3) unanswered timeouts in a row end the run cleanly
    assert [d.status for d in collapse] == ["vetoed", "vetoed", "dropped"]
    assert sum("length-scale collapse" in t and "timed out after 60 s: veto" in t for t in log) == 3
    assert not eng.completed and "max_refusals 3" in eng.stop_reason
    assert eng.state == EngineState.STOPPED


@pytest.mark.parametrize("on_timeout", ["stop", "veto"])
def test_approval_timeout_stop_and_veto(tmp_path: Path, on_timeout: str) -> None:
    eng, path = run_with_timeout(tmp_path, FakeCampaign(n_blocks=2), on_timeout, "step")
    with JournalReader(path) as r:
        decisions = r.decisions()
    if on_timeout == "stop":
        assert not eng.completed and "approval timed out after 60 s" in eng.stop_reason
        assert [d.status for d in decisions] == ["dropped"]
    else:  # step mode: every block waits, every wait is vetoed, until max_refusals unanswered in a row
        assert not eng.completed and "max_refusals 5" in eng.stop_reason
        assert [d.status for d in decisions] == ["vetoed"] * 4 + ["dropped"]


def test_approval_timeout_pause_pauses_the_run(tmp_path: Path) -> None:
    j = new_journal(tmp_path, "p.sqlite", "step")
    wall = FakeWall()
    states: list[EngineState] = []

    def sleep(s: float) -> None:
        wall.t += 10.0
        states.append(eng.state)
        if eng.state == EngineState.PAUSED:
            send_command(j.path, cmd(CommandKind.ABORT))

    eng = Engine(
        j,
        FakeCampaign(n_blocks=2),
        make_driver(),
        "step",
        poll_s=0.01,
        sleep=sleep,
        watch_s=None,
        approval_timeout_s=30.0,
        on_timeout="pause",
        wall_clock=wall,
    )
    try:
        eng.run()
    finally:
        j.close()
    assert EngineState.PAUSED in states and states[0] == EngineState.AWAITING_APPROVAL
    assert eng.state == EngineState.STOPPED and eng.stop_reason == "aborted by tester"


def test_a_headless_record_counts_refusals_and_the_runs_ledger() -> None:
    from core.run.headless import MemoryRecord

    record = MemoryRecord()
    driver = make_driver()
    eng = Engine(
        record,
        FakeCampaign(n_blocks=3),
        driver,
        "auto",
        watch_s=None,
        map_display_n=None,
        interlock=RefusingInterlock([CENTRES[1]]),  # type: ignore[arg-type]
        evaluator=FakeEvaluator(),  # type: ignore[arg-type]
    )
    assert eng.run() == EngineState.STOPPED and eng.completed
    assert (record.refusals, record.approvals, record.blocks, record.indents) == (1, 0, 3, 12)
    assert [(d.block.center_x_um, d.block.center_y_um) for d in record.decisions] == [
        CENTRES[0],
        CENTRES[2],
        CENTRES[3],
    ]
    # every step the driver took is in the ledger: it adds up to the instrument clock
    assert record.ledger.total_s == pytest.approx(driver.clock_s(), rel=1e-12)
    assert record.trajectory and all(
        m == pytest.approx(10.0 / (1 + i + 2)) for i, (_, m) in enumerate(record.trajectory)
    )

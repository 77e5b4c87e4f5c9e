"""An in-memory run that behaves like a supervised engine, for console tests, snapshots and the benchmark.

It is not a planner: centres come from a cheap "farthest from what was tested, per second of cost"
rule on an analytic ternary hardness field, and the GP fields are made up from distances. What it
does copy faithfully is the engine's *contract*: states, pending decisions, approve / veto / adjust /
step / pause / stop / abort semantics, ledger categories and costs (through core.cost), and the
snapshots a journal reader would produce. Time advances only when ``advance()`` is called, so every
test and screenshot is deterministic.
"""

from __future__ import annotations

import math
import threading
from dataclasses import fields, replace
from typing import Any

import numpy as np

from core.cost import CostLedger, indent_steps
from core.emulator import TernaryField
from core.errors import InputError
from core.plan import Alternative, Block, Decision, PlannerSettings, local_grid
from core.profile import InstrumentProfile
from core.runview import (
    Command,
    CommandKind,
    DriftStatus,
    EngineState,
    GpStatus,
    LogEvent,
    MapFields,
    QueueItem,
    RunSnapshot,
    TestedCenter,
)

SIDE_UM = 1000.0


_TERNARY = TernaryField(side_um=SIDE_UM, noise="hetero")


def ternary_hardness(x_um: np.ndarray, y_um: np.ndarray) -> np.ndarray:
    """The emulator's ternary library, so the fake maps look like a real run's."""
    return _TERNARY.hardness_gpa(np.clip(x_um, 0, SIDE_UM), np.clip(y_um, 0, SIDE_UM))


def ternary_noise(x_um: np.ndarray, y_um: np.ndarray) -> np.ndarray:
    return _TERNARY.noise_sd_gpa(np.clip(x_um, 0, SIDE_UM), np.clip(y_um, 0, SIDE_UM))


VALID_ADJUST: dict[str, tuple[type, float | None, float | None]] = {
    "target_sem_gpa": (float, 1e-4, 10.0),
    "beta": (float, 0.0, 100.0),
    "fixed_hold_s": (float, 0.0, 600.0),
    "local_center_limit": (int, 0, 50),
    "edge_penalty": (float, 0.0, 1.0),
    "budget_s": (float, 0.0, None),
    "indent_budget": (int, 1, None),
    "sigma_target_gpa": (float, 0.0, None),
    "mape_target_pct": (float, 0.0, 100.0),
}


def check_adjust(payload: dict[str, object], settings: PlannerSettings) -> PlannerSettings:
    """Validate an adjust payload the way the engine does: unknown field or bad value → InputError."""
    names = {f.name for f in fields(PlannerSettings)}
    changes: dict[str, Any] = {}
    for key, value in payload.items():
        if key not in names or key == "avoid_centers_um":
            raise InputError("adjust", f"unknown setting {key!r}")
        if key == "hold_policy":
            if value not in ("fixed", "adaptive"):
                raise InputError("adjust.hold_policy", f"{value!r} is not one of fixed, adaptive")
            changes[key] = value
            continue
        if value is None and key in ("budget_s", "indent_budget", "sigma_target_gpa", "mape_target_pct"):
            changes[key] = None
            continue
        kind, lo, hi = VALID_ADJUST[key]
        if not isinstance(value, int | float) or isinstance(value, bool):
            raise InputError(f"adjust.{key}", f"{value!r} is not a number")
        if kind is int and float(value) != int(value):
            raise InputError(f"adjust.{key}", f"{value!r} is not a whole number")
        v = kind(value)
        if (lo is not None and v < lo) or (hi is not None and v > hi):
            raise InputError(f"adjust.{key}", f"{v} is outside [{lo}, {hi if hi is not None else '∞'}]")
        changes[key] = v
    return replace(settings, **changes)


class FakeRun:
    """A deterministic stand-in for a journal reader + engine pair (implements ReplaySource)."""

    def __init__(
        self,
        supervision: str = "supervised",
        policy: str = "cost-aware",
        seed: int = 0,
        profile: InstrumentProfile | None = None,
        collapse_at_block: int | None = None,
        display_n: int = 50,
        run_name: str = "fake-demo",
        owner: str = "operator",
        can_command: bool = True,
        reverse_x: bool = True,
        indents_per_tick: int = 5,
    ) -> None:
        self.supervision = supervision
        self.policy = policy
        self.rng = np.random.default_rng(seed)
        self.profile = profile or InstrumentProfile()
        self.collapse_at_block = collapse_at_block
        self.display_n = display_n
        self.run_name = run_name
        self.owner = owner
        self.can_command = can_command
        self.reverse_x = reverse_x
        self.indents_per_tick = indents_per_tick
        self._lock = threading.RLock()
        self.state = EngineState.RUNNING
        self.settings = PlannerSettings(fixed_hold_s=self.profile.default_hold_s)
        self.ledger = CostLedger()
        self.clock_s = 0.0
        self.wall_s = 0.0
        self.position_um = (SIDE_UM / 2, SIDE_UM / 2)
        self.program_open = False
        self.locals_in_row = 0
        self.block_id = 0
        self.current: Block | None = None
        self.current_index = 0
        self.pending: Decision | None = None
        self.last_decision: Decision | None = None
        self.tested: list[TestedCenter] = []
        self.log: list[LogEvent] = []
        self.vetoed: list[tuple[float, float]] = []
        self.collapse = False
        self.stop_after = False
        self.finished = False
        self.snapshot_id = 0
        self.drift_events: list[tuple[float, float]] = []
        self.last_drift: float | None = None
        self.commands: list[Command] = []
        self.history: list[RunSnapshot] = []  # one snapshot per finished block, for replay
        self._event("info", f"run {run_name} started: policy {policy}, supervision {supervision}")

    # ------------------------------------------------------------------ engine side
    def _event(self, level: str, text: str) -> None:
        secs = int(self.wall_s)
        wall = f"2025-01-01T{10 + secs // 3600:02d}:{secs // 60 % 60:02d}:{secs % 60:02d}Z"
        self.log.append(LogEvent(wall_utc=wall, t_s=self.clock_s, level=level, text=text))

    def _grid_g(self, x: float, y: float) -> int:
        sigma = float(ternary_noise(np.array(x), np.array(y)))
        return int(np.clip(round(sigma / self.settings.target_sem_gpa), 2, 5))

    def _sd_at(self, x: np.ndarray, y: np.ndarray, upto: int | None = None) -> np.ndarray:
        tested = self.tested if upto is None else self.tested[:upto]
        if not tested:
            return np.full(np.shape(x), 0.9)
        cx = np.array([t.x_um for t in tested])
        cy = np.array([t.y_um for t in tested])
        d = np.sqrt((np.asarray(x)[..., None] - cx) ** 2 + (np.asarray(y)[..., None] - cy) ** 2).min(axis=-1)
        return 0.05 + 0.85 * (1 - np.exp(-d / 180.0))

    def _make_block(self, x: float, y: float, kind: str) -> Block:
        g = self._grid_g(x, y)
        hold = self.settings.fixed_hold_s if self.settings.hold_policy == "fixed" else 5.0
        return Block(
            block_id=self.block_id,
            kind="global" if kind == "global" else "local",
            center_x_um=x,
            center_y_um=y,
            grid_g=g,
            pitch_um=5.0,
            hold_s=hold,
            indents=local_grid(x, y, g, 5.0, hold),
        )

    def _cost(self, block: Block) -> float:
        pos, total = self.position_um, 0.0
        for i in range(block.n_indents):
            total += sum(s.seconds for s in indent_steps(self.profile, block, i, pos, self.program_open))
            pos = (block.indents[i].x_um, block.indents[i].y_um)
        return total

    def _may_stay(self, x: float, y: float) -> bool:
        near = math.hypot(x - self.position_um[0], y - self.position_um[1]) <= 200.0
        return near and self.program_open and self.locals_in_row < self.settings.local_center_limit

    def _propose(self) -> Decision:
        lattice = np.linspace(50.0, SIDE_UM - 50.0, 19)
        xx, yy = np.meshgrid(lattice, lattice)
        xs, ys = xx.ravel(), yy.ravel()
        sd = self._sd_at(xs, ys)
        ranked: list[tuple[float, float, float, float, float]] = []  # score, σ, cost, x, y
        for x, y, s in zip(xs, ys, sd, strict=True):
            if any(math.hypot(x - vx, y - vy) < 1.0 for vx, vy in self.vetoed):
                continue
            kind = "local" if self._may_stay(float(x), float(y)) else "global"
            cost = self._cost(self._make_block(float(x), float(y), kind))
            ranked.append((float(s) / cost * 1000.0, float(s), cost, float(x), float(y)))
        ranked.sort(key=lambda r: (-r[0], r[3], r[4]))
        best = ranked[0]
        bx, by = best[3], best[4]
        kind = "local" if self._may_stay(bx, by) else "global"
        block = self._make_block(bx, by, kind)
        alts = []
        for r in ranked[1:4]:
            alts.append(
                Alternative(
                    center_x_um=r[3],
                    center_y_um=r[4],
                    kind="local" if self._may_stay(r[3], r[4]) else "global",
                    score=r[0],
                    acquisition=r[1],
                    cost_s=r[2],
                )
            )
        locals_ = [r for r in ranked if self._may_stay(r[3], r[4])]
        globals_ = [r for r in ranked if not self._may_stay(r[3], r[4])]
        stay = locals_[0][0] if locals_ else None
        jump = globals_[0][0] if globals_ else None
        phase = "seed" if self.block_id < 2 else "explore" if self.block_id < 6 else "exploit"
        return Decision(
            block=block,
            policy=self.policy,
            acquisition=best[1],
            score=best[0],
            predicted_cost_s=best[2],
            stay_score=stay,
            jump_score=jump,
            alternatives=tuple(alts),
            reason="highest σ per second of instrument time"
            if kind == "global"
            else "stay: local σ/cost wins",
            phase=phase,
            hold_mode=f"{self.settings.hold_policy} {block.hold_s:g} s",
            area_error_pct=None if self.last_drift is None else abs(self.last_drift) * 8.0,
        )

    def _needs_approval(self, decision: Decision) -> bool:
        if self.supervision == "step":
            return True
        if self.supervision == "supervised":
            return decision.is_global_jump or self.collapse
        return False

    def _start(self, decision: Decision) -> None:
        self.current = decision.block
        self.current_index = 0
        self.last_decision = decision
        self.pending = None
        self.block_id += 1
        self.locals_in_row = self.locals_in_row + 1 if decision.block.kind == "local" else 0
        self._event(
            "decision",
            f"block {decision.block.block_id}: {decision.block.kind} at "
            f"({decision.block.center_x_um:.0f}, {decision.block.center_y_um:.0f}) µm, "
            f"{decision.block.grid_g}×{decision.block.grid_g}, hold {decision.block.hold_s:g} s",
        )

    def _finish_block(self) -> None:
        block = self.current
        assert block is not None
        h = float(ternary_hardness(np.array(block.center_x_um), np.array(block.center_y_um)))
        self.tested.append(TestedCenter(block.center_x_um, block.center_y_um, block.block_id, round(h, 3)))
        self.snapshot_id += 1
        self.current = None
        self.wall_s += 1.0
        self._event("info", f"block {block.block_id} done: median {h:.2f} GPa; GP refit")
        if self.collapse_at_block is not None and block.block_id == self.collapse_at_block:
            self.collapse = True
            self._event("warn", "length-scale collapse: ℓx fell below its floor (12 µm < 20 µm)")
        self.history.append(self._snapshot_now())
        if self.stop_after:
            self.state = EngineState.STOPPED
            self.finished = True
            self._event("info", "stopped after the block, as asked")

    def advance(self, ticks: int = 1) -> None:
        """Run the engine forward: each tick runs ``indents_per_tick`` indents or makes one decision."""
        with self._lock:
            for _ in range(ticks):
                self._tick()

    def _tick(self) -> None:
        if self.finished or self.state in (EngineState.PAUSED, EngineState.AWAITING_APPROVAL):
            return
        if self.current is None:
            if self.state is EngineState.PAUSING:
                self.state = EngineState.PAUSED
                return
            decision = self._propose()
            if self._needs_approval(decision):
                self.pending = decision
                self.state = EngineState.AWAITING_APPROVAL
                why = (
                    "collapse alarm"
                    if self.collapse
                    else "global jump"
                    if decision.is_global_jump
                    else "step mode"
                )
                self._event(
                    "decision",
                    f"awaiting approval ({why}): block {decision.block.block_id} at "
                    f"({decision.block.center_x_um:.0f}, {decision.block.center_y_um:.0f}) µm",
                )
                return
            self._start(decision)
            return
        block = self.current
        for _ in range(self.indents_per_tick):
            i = self.current_index
            steps = indent_steps(self.profile, block, i, self.position_um, self.program_open)
            self.ledger.extend(steps)
            self.clock_s += sum(s.seconds for s in steps)
            spec = block.indents[i]
            self.position_um = (spec.x_um, spec.y_um)
            self.program_open = True
            self.current_index += 1
            if i == 0 and block.kind == "global":
                rate = float(self.rng.normal(0.0, 0.05))
                self.last_drift = rate
                if abs(rate) > 0.07:
                    self.drift_events.append((self.clock_s, rate))
                    self._event("warn", f"drift event: {rate:+.3f} nm/s")
            if self.current_index >= block.n_indents:
                self._finish_block()
                if self.state is EngineState.PAUSING:
                    self.state = EngineState.PAUSED
                return
        self.wall_s += 0.2

    # ------------------------------------------------------------------ commands
    def send(self, command: Command) -> None:
        with self._lock:
            if not self.can_command:
                raise PermissionError(
                    f"{command.author} does not own run {self.run_name} (owner {self.owner})"
                )
            if self.finished:
                raise InputError("command", f"run {self.run_name} has ended")
            self.commands.append(command)
            kind = command.kind
            self._event(
                "command",
                f"{command.author}: {kind.value}" + (f" {command.payload}" if command.payload else ""),
            )
            if kind is CommandKind.PAUSE:
                self.state = EngineState.PAUSING if self.current is not None else EngineState.PAUSED
            elif kind is CommandKind.RESUME:
                self.state = (
                    EngineState.AWAITING_APPROVAL if self.pending is not None else EngineState.RUNNING
                )
            elif kind in (CommandKind.APPROVE, CommandKind.STEP):  # the engine treats step as approve
                if self.pending is None:
                    raise InputError(kind.value, "nothing is waiting for approval")
                self.collapse = False
                self._start(self.pending)
                self.state = EngineState.RUNNING
            elif kind is CommandKind.VETO:
                if self.pending is None:
                    raise InputError("veto", "nothing is waiting for approval")
                self.vetoed.append((self.pending.block.center_x_um, self.pending.block.center_y_um))
                self.pending = self._propose()
                self._event(
                    "decision",
                    f"next best after veto: ({self.pending.block.center_x_um:.0f}, "
                    f"{self.pending.block.center_y_um:.0f}) µm",
                )
            elif kind is CommandKind.ADJUST:
                changes = dict(command.payload)
                supervision = changes.pop("supervision", None)
                if supervision is not None and supervision not in ("auto", "supervised", "step"):
                    raise InputError(
                        "adjust.supervision", f"{supervision!r} is not one of auto, supervised, step"
                    )
                if changes:
                    self.settings = check_adjust(changes, self.settings)
                if supervision is not None:
                    self.supervision = str(supervision)
                    if self.pending is not None and not self._needs_approval(self.pending):
                        self._start(self.pending)
                        self.state = EngineState.RUNNING
            elif kind is CommandKind.STOP_AFTER_BLOCK:
                self.stop_after = True
                if self.current is None:
                    self.state = EngineState.STOPPED
                    self.finished = True
                else:
                    self.state = EngineState.STOPPING
            elif kind is CommandKind.ABORT:
                self.state = EngineState.STOPPED
                self.finished = True
                self.current = None
                self.pending = None

    # ------------------------------------------------------------------ reader side
    def _queue(self) -> tuple[QueueItem, ...]:
        items: list[QueueItem] = []
        eta = 0.0
        pos, is_open = self.position_um, self.program_open
        blocks: list[tuple[Block, int]] = []
        if self.current is not None:
            blocks.append((self.current, self.current_index))
        if self.pending is not None:
            blocks.append((self.pending.block, 0))
        for block, start in blocks:
            for i in range(start, block.n_indents):
                eta += sum(s.seconds for s in indent_steps(self.profile, block, i, pos, is_open))
                spec = block.indents[i]
                pos, is_open = (spec.x_um, spec.y_um), True
                items.append(QueueItem(block.block_id, i, spec, block.grid_g, eta))
        return tuple(items)

    def _snapshot_now(self) -> RunSnapshot:
        lx = 160.0 - 4.0 * len(self.tested)
        return RunSnapshot(
            run_name=self.run_name,
            journal_path=f"runs/{self.run_name}/journal.sqlite",
            state=self.state,
            supervision=self.supervision,
            policy=self.policy,
            profile_name=self.profile.name,
            owner=self.owner,
            can_command=self.can_command,
            instrument_s=self.clock_s,
            wall_s=self.wall_s,
            n_indents=self.ledger.indents,
            n_blocks=len(self.tested),
            reconfigurations=self.ledger.reconfigurations,
            ledger=self.ledger.as_dict(),
            grid_baseline_s=286392.0,
            queue=self._queue(),
            current_block=self.current,
            pending=self.pending,
            last_decision=self.last_decision,
            drift=DriftStatus(
                last_rate_nm_s=self.last_drift,
                hold_mode=f"{self.settings.hold_policy} {self.settings.fixed_hold_s:g} s",
                area_error_pct=None if self.last_drift is None else round(abs(self.last_drift) * 8.0, 3),
                events=tuple(self.drift_events),
            ),
            gp=GpStatus(
                lengthscales_um=(12.0, 150.0)
                if self.collapse
                else ((round(lx, 1), round(lx * 1.2, 1)) if self.tested else ()),
                noise_lengthscales_um=(300.0, 300.0) if self.tested else (),
                collapse_alarm=self.collapse,
                collapse_reason="ℓx 12 µm < floor 20 µm" if self.collapse else "",
                refit_s=0.4 if self.tested else None,
                snapshot_id=self.snapshot_id if self.tested else None,
            ),
            mape_pct=round(25.0 / (1 + len(self.tested)), 3) if self.tested else None,
            max_found_gpa=max((t.median_gpa for t in self.tested), default=None),
            tested=tuple(self.tested),
            settings=self.settings,
            log=tuple(self.log[-200:]),
            stage_bounds_um=(0.0, SIDE_UM, 0.0, SIDE_UM),
            reverse_x=self.reverse_x,
            finished=self.finished,
        )

    def snapshot(self) -> RunSnapshot:
        with self._lock:
            return self._snapshot_now()

    def map_fields(self, snapshot_id: int) -> MapFields | None:
        with self._lock:
            if not self.tested:
                return None
            xs = np.linspace(0.0, SIDE_UM, self.display_n)
            xx, yy = np.meshgrid(xs, xs)
            truth = ternary_hardness(xx, yy)
            epi = self._sd_at(xx, yy, upto=snapshot_id)
            noise = ternary_noise(xx, yy)
            mean = truth * (1 - 0.5 * epi) + 4.5 * 0.5 * epi
            nxt = (
                None
                if self.pending is None
                else (self.pending.block.center_x_um, self.pending.block.center_y_um)
            )
            return MapFields(
                snapshot_id=snapshot_id,
                x_um=xs,
                y_um=xs.copy(),
                mean_gpa=mean,
                epistemic_sd_gpa=epi,
                noise_sd_gpa=noise,
                total_sd_gpa=np.sqrt(epi**2 + noise**2),
                next_candidate_um=nxt,
            )

    def n_blocks(self) -> int:
        return len(self.history)

    def snapshot_at(self, block_index: int) -> RunSnapshot:
        return self.history[block_index]


def run_fake(blocks: int, **kwargs: Any) -> FakeRun:
    """A fake run in auto mode advanced until ``blocks`` blocks finished (for replay tests and screenshots)."""
    run = FakeRun(supervision="auto", **kwargs)
    while len(run.tested) < blocks and not run.finished:
        run.advance()
    return run

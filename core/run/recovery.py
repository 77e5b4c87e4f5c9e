"""A resumed engine picks the run up where its record's history says the last one left it."""

from __future__ import annotations

from dataclasses import replace
from datetime import datetime
from typing import TYPE_CHECKING

from core.errors import InputError
from core.operator import OperatorAvailability, OperatorHours
from core.run.events import Resolved, RunHistory

if TYPE_CHECKING:
    from core.run.engine import Engine

AWAY_UNTIL_KEY = "away_until"  # the planner state's record of an operator's away-until (engine-level)


def restore_absence(engine: Engine, away_until: object) -> None:
    """An ``away-until`` the last engine took holds for the resumed one (the absence is not forgotten)."""
    if not isinstance(away_until, str):
        return

    base = engine.operator or OperatorAvailability(OperatorHours.parse("always"))
    engine.operator = replace(base, away_until=datetime.fromisoformat(away_until))
    engine._plan_for_operator()


def recover(engine: Engine, history: RunHistory) -> None:
    """Pick the run up where its record says the last engine left it."""
    observed = history.observed
    if engine.interlock is not None:
        engine.interlock.restore(observed)
    if history.plan is not None:
        engine.campaign.restore(history.plan[0], observed)
        restore_absence(engine, history.plan[0].get(AWAY_UNTIL_KEY))
    elif observed:
        raise InputError(engine.record.name, "journal has observed blocks but no planner state")
    ds = history.driver
    engine._recovery_s = history.recovery_s
    engine._decision_id = history.last_decision_id
    engine._snapshot_id = history.last_snapshot_id
    if ds is not None:
        # the tip state after a crash is unknown: the driver re-engages before it indents again
        engine._set_driver(ds.clock_s, ds.position_um, False, ds.physics_clock_s)
        engine._needs_recovery = ds.program_open
    pending = history.pending
    parts = [f"the last engine stopped while {history.last_state}", f"{len(observed)} blocks observed"]
    if history.open_block is not None:
        block, done_results = history.open_block
        done = len(done_results)
        engine._current = (block, done)
        engine._results = list(done_results)
        engine._next_block_id = block.block_id
        if done >= block.n_indents:
            parts.append(f"block {block.block_id} was finished but not yet folded into the model")
        else:
            parts.append(f"block {block.block_id} continues at indent {done} of {block.n_indents}")
        loader = engine._stretch_loader
        queued = engine.campaign.queued_stretch() if loader is not None else ()
        if loader is not None and queued:  # mid-stretch: handed out with its first; nothing planned again
            loader.load_stretch((block, *queued))
            parts.append(f"the stretch goes on: {len(queued)} array(s) after this one")
        if pending is not None:
            engine._emit(Resolved(0.0, pending[0], "dropped", "engine"))
    else:
        engine._next_block_id = max((b.block_id for b, _ in observed), default=-1) + 1
        if pending is not None:
            engine._pending = pending
            engine._next_block_id = pending[1].block.block_id
            parts.append(f"decision {pending[0]} for block {pending[1].block.block_id} still awaits approval")
    if history.queued_commands:
        parts.append(f"{history.queued_commands} commands sent before the stop are processed now")
    if ds is not None:
        parts.append(
            f"instrument restored to t={ds.clock_s:,.0f} s at ({ds.position_um[0]:.0f}, {ds.position_um[1]:.0f}) µm"
        )
    engine._log("warn", "resumed: " + "; ".join(parts), category="recovery")
    engine._say("resumed: " + "; ".join(parts))

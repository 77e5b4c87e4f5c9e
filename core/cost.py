"""Pricing blocks on the instrument clock: every step lands in a ledger by category.

The same functions price a plan before it runs (the planner's cost) and charge it while it runs
(the simulated driver), so predicted and executed costs cannot drift apart.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field

from core.plan import LEDGER_CATEGORIES, Block, IndentSpec, StepRecord, local_grid
from core.profile import InstrumentProfile


@dataclass
class CostLedger:
    """Seconds by category, plus counts the console shows."""

    seconds: dict[str, float] = field(default_factory=lambda: dict.fromkeys(LEDGER_CATEGORIES, 0.0))
    reconfigurations: int = 0
    indents: int = 0

    def add(self, step: StepRecord) -> None:
        self.seconds[step.category] = self.seconds.get(step.category, 0.0) + step.seconds
        if step.category == "reconfigure":
            self.reconfigurations += 1
        elif step.category == "indent":
            self.indents += 1

    def extend(self, steps: Iterable[StepRecord]) -> CostLedger:
        for s in steps:
            self.add(s)
        return self

    @property
    def total_s(self) -> float:
        return float(sum(self.seconds.values()))

    def as_dict(self) -> dict[str, float]:
        return {k: round(v, 6) for k, v in self.seconds.items()}


def _indent_steps(
    profile: InstrumentProfile, block_id: int, index: int, spec: IndentSpec
) -> Iterator[StepRecord]:
    yield StepRecord("indent", profile.indent_base_s, block_id, index)
    if spec.hold_s > 0:
        yield StepRecord("hold", spec.hold_s, block_id, index)


def _move_steps(
    profile: InstrumentProfile,
    frm: tuple[float, float],
    to: tuple[float, float],
    block_id: int,
    index: int,
    engaged: bool,
) -> Iterator[StepRecord]:
    dx, dy = to[0] - frm[0], to[1] - frm[1]
    if engaged and profile.needs_reconfiguration(dx, dy):
        # safety rule: lift, move, re-engage, settle drift before the next indent
        yield StepRecord("reconfigure", profile.reconfiguration_s, block_id, index)
    s = profile.move_s(dx, dy)
    if s > 0:
        yield StepRecord("move", s, block_id, index)


def open_program_steps(profile: InstrumentProfile, block_id: int, program_open: bool) -> Iterator[StepRecord]:
    """Overhead of starting a global block (closing the running program first)."""
    if profile.global_jump_s is not None:
        yield StepRecord("reconfigure", profile.global_jump_s, block_id, -1)
        return
    if program_open:
        yield StepRecord("comeback", profile.comeback_s, block_id, -1)
    yield StepRecord("setup", profile.setup_s + profile.lens_travel_s, block_id, -1)
    yield StepRecord("lift", profile.lift_s, block_id, -1)


def settle_steps(profile: InstrumentProfile, block_id: int) -> Iterator[StepRecord]:
    if profile.global_jump_s is not None:
        return
    yield StepRecord("engage", profile.engage_s, block_id, -1)
    yield StepRecord("drift", profile.drift_settle_s, block_id, -1)


def indent_steps(
    profile: InstrumentProfile,
    block: Block,
    index: int,
    frm: tuple[float, float],
    program_open: bool,
) -> list[StepRecord]:
    """Steps to reach and perform indent ``index`` of ``block`` from stage position ``frm``.

    For the first indent of a global block this includes opening the program; the move to the first
    indent happens lifted (no safety rule), every later move happens engaged.
    """
    spec = block.indents[index]
    to = (spec.x_um, spec.y_um)
    if block.channel == "fast":
        return fast_indent_steps(profile, block, index, frm, program_open)
    steps: list[StepRecord] = []
    if index == 0 and block.kind == "global":
        steps.extend(open_program_steps(profile, block.block_id, program_open))
        steps.extend(_move_steps(profile, frm, to, block.block_id, index, engaged=False))
        steps.extend(settle_steps(profile, block.block_id))
    else:
        steps.extend(_move_steps(profile, frm, to, block.block_id, index, engaged=True))
    steps.extend(_indent_steps(profile, block.block_id, index, spec))
    return steps


def fast_indent_steps(
    profile: InstrumentProfile,
    block: Block,
    index: int,
    frm: tuple[float, float],
    program_open: bool,
) -> list[StepRecord]:
    """Steps of indent ``index`` of a fast array (SPEC §9; ``core.fast_array`` prices a whole array the same
    way): the first opens the program (lifted move, surface find and drift settle where the fast mode needs
    them, inside the flat jump where the profile has one); each costs ``fast.indent_s`` with the step to it,
    plus ``fast.column_change_s`` where its x differs from the previous site's (a new column)."""
    fast = profile.fast
    if fast is None:
        raise ValueError(
            f"block {block.block_id} is a fast array but profile {profile.name} has no fast mode"
        )
    spec = block.indents[index]
    steps: list[StepRecord] = []
    if index == 0:
        steps.extend(open_program_steps(profile, block.block_id, program_open))
        s = profile.move_s(spec.x_um - frm[0], spec.y_um - frm[1])
        if s > 0:
            steps.append(StepRecord("move", s, block.block_id, index))
        if profile.global_jump_s is None:
            if fast.surface_find:
                steps.append(StepRecord("engage", profile.engage_s, block.block_id, -1))
            if fast.drift_settle:
                steps.append(StepRecord("drift", profile.drift_settle_s, block.block_id, -1))
    elif spec.x_um != block.indents[index - 1].x_um and fast.column_change_s > 0:
        steps.append(StepRecord("move", fast.column_change_s, block.block_id, index))
    steps.append(StepRecord("indent", fast.indent_s, block.block_id, index))
    return steps


def block_steps(
    profile: InstrumentProfile, block: Block, start_um: tuple[float, float], program_open: bool
) -> list[StepRecord]:
    """All steps of one block from the current stage position (no closing comeback)."""
    steps: list[StepRecord] = []
    pos = start_um
    for i, spec in enumerate(block.indents):
        steps.extend(indent_steps(profile, block, i, pos, program_open))
        pos = (spec.x_um, spec.y_um)
    return steps


def comeback_step(profile: InstrumentProfile, block_id: int = -1) -> StepRecord:
    return StepRecord("comeback", profile.comeback_s, block_id, -1)


def price_sequence(
    profile: InstrumentProfile,
    blocks: Sequence[Block],
    start_um: tuple[float, float] | None = None,
    program_open: bool = False,
    end_with_comeback: bool = True,
) -> CostLedger:
    """The ledger of running ``blocks`` in order from ``start_um`` and returning to the lens."""
    ledger = CostLedger()
    if not blocks:
        return ledger
    first = blocks[0].indents[0]
    pos = start_um if start_um is not None else (first.x_um, first.y_um)
    is_open = program_open
    for block in blocks:
        if block.kind == "local" and not is_open:
            raise ValueError(f"block {block.block_id} is local but no program is open")
        ledger.extend(block_steps(profile, block, pos, is_open))
        last = block.indents[-1]
        pos = (last.x_um, last.y_um)
        is_open = True
    if end_with_comeback and is_open:
        ledger.add(comeback_step(profile))
    return ledger


def block_costs_for(
    profile: InstrumentProfile, block: Block, start_um: tuple[float, float], program_open: bool
) -> float:
    """Seconds of one block from the current position, without the final comeback."""
    return float(sum(s.seconds for s in block_steps(profile, block, start_um, program_open)))


def price_block(
    profile: InstrumentProfile,
    block: Block,
    start_um: tuple[float, float] | None = None,
    program_open: bool = False,
) -> float:
    """Seconds of one block from the current position, excluding the final comeback (the planner's cost)."""
    first = block.indents[0]
    pos = start_um if start_um is not None else (first.x_um, first.y_um)
    return float(sum(s.seconds for s in block_steps(profile, block, pos, program_open)))


def grid_baseline_blocks(
    area_x_um: float,
    area_y_um: float,
    n_blocks: int,
    g: int,
    pitch_um: float,
    hold_s: float,
    origin_um: tuple[float, float] = (0.0, 0.0),
) -> list[Block]:
    """The paper's grid baseline: n×n blocks of g×g, centres evenly spaced inside the area, snake order."""

    blocks: list[Block] = []
    step_x = area_x_um / (n_blocks + 1)
    step_y = area_y_um / (n_blocks + 1)
    bid = 0
    for j in range(n_blocks):
        cols = range(n_blocks) if j % 2 == 0 else range(n_blocks - 1, -1, -1)
        for i in cols:
            cx = origin_um[0] + (i + 1) * step_x
            cy = origin_um[1] + (j + 1) * step_y
            blocks.append(
                Block(
                    block_id=bid,
                    kind="global",
                    center_x_um=cx,
                    center_y_um=cy,
                    grid_g=g,
                    pitch_um=pitch_um,
                    hold_s=hold_s,
                    indents=local_grid(cx, cy, g, pitch_um, hold_s),
                )
            )
            bid += 1
    return blocks

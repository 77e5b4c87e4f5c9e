"""A fast array (NanoBlitz-class, SPEC §9) and what it costs on the instrument clock.

An array is ``rows × cols`` load-controlled indents at one pitch, run as one program: it opens like a global
block (closing a running program, set-up under the lens, lift, the move to its first site lifted, surface find,
drift settle), then runs column by column, each indent costing the profile's ``fast.indent_s`` (the step to
the next site included) and each change of column ``fast.column_change_s`` more. Its hops are one pitch, so
the safety rule's reconfiguration never fires inside an array (its extent is bounded by ``fast.max_extent_um``,
at most the iMicro's 1000 µm threshold in the built-in profile). The steps use the cost ledger's categories
(``core.cost``), so a fast array's seconds add up with the CSM blocks' in one ledger.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from core.cost import open_program_steps
from core.errors import InputError
from core.plan import Block, IndentSpec, StepRecord
from core.profile import FastMode, InstrumentProfile


@dataclass(frozen=True)
class FastArray:
    """``rows × cols`` sites at ``pitch_um``, centred on (``center_x_um``, ``center_y_um``), in stage µm.

    Columns run along stage y, one column per x; the instrument snakes (down one column, up the next).
    """

    center_x_um: float
    center_y_um: float
    rows: int
    cols: int
    pitch_um: float

    @property
    def n_indents(self) -> int:
        return self.rows * self.cols

    @property
    def extent_um(self) -> tuple[float, float]:
        """(x, y) distance from the first to the last site of a row and of a column."""
        return ((self.cols - 1) * self.pitch_um, (self.rows - 1) * self.pitch_um)

    def sites_um(self) -> np.ndarray:
        """(rows·cols, 2) stage positions in the order the instrument indents them (snaking by column)."""
        ex, ey = self.extent_um
        xs = self.center_x_um - ex / 2.0 + self.pitch_um * np.arange(self.cols)
        ys = self.center_y_um - ey / 2.0 + self.pitch_um * np.arange(self.rows)
        out = np.empty((self.n_indents, 2))
        for j, x in enumerate(xs):
            col = ys if j % 2 == 0 else ys[::-1]
            out[j * self.rows : (j + 1) * self.rows, 0] = x
            out[j * self.rows : (j + 1) * self.rows, 1] = col
        return out

    @property
    def first_site_um(self) -> tuple[float, float]:
        ex, ey = self.extent_um
        return (self.center_x_um - ex / 2.0, self.center_y_um - ey / 2.0)


def fast_mode_of(profile: InstrumentProfile) -> FastMode:
    """The profile's fast mode, or one line naming the profile that has none."""
    if profile.fast is None:
        raise InputError(f"profile {profile.name}", "has no fast mode (no [fast] section)")
    return profile.fast


def check_fast_array(profile: InstrumentProfile, array: FastArray) -> FastArray:
    """The array as the instrument can run it, or an InputError naming the field that is not."""
    fast = fast_mode_of(profile)
    for name, value in (("rows", array.rows), ("cols", array.cols)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise InputError(f"fast_array.{name}", f"must be a whole number ≥ 1, got {value!r}")
    numbers: tuple[tuple[str, float], ...] = (
        ("center_x_um", array.center_x_um),
        ("center_y_um", array.center_y_um),
        ("pitch_um", array.pitch_um),
    )
    for name, number in numbers:
        if not math.isfinite(number):
            raise InputError(f"fast_array.{name}", f"must be finite, got {number!r}")
    if array.n_indents > 1 and array.pitch_um < fast.min_pitch_um:
        raise InputError(
            "fast_array.pitch_um",
            f"{array.pitch_um:g} µm is below the profile's fast.min_pitch_um {fast.min_pitch_um:g} µm",
        )
    ex, ey = array.extent_um
    if max(ex, ey) > fast.max_extent_um:
        raise InputError(
            "fast_array",
            f"extent {ex:g} × {ey:g} µm is beyond the profile's fast.max_extent_um {fast.max_extent_um:g} µm",
        )
    return array


@dataclass(frozen=True)
class FastArrayCost:
    """Seconds of one fast array from the current stage position, by what they pay for."""

    opening_s: float  # closing a running program, set-up under the lens, lift
    travel_s: float  # the lifted move to the first site
    surface_find_s: float
    drift_settle_s: float
    indents_s: float
    column_changes_s: float
    steps: tuple[StepRecord, ...]

    @property
    def total_s(self) -> float:
        return (
            self.opening_s
            + self.travel_s
            + self.surface_find_s
            + self.drift_settle_s
            + self.indents_s
            + self.column_changes_s
        )


def price_fast_array(
    profile: InstrumentProfile,
    array: FastArray,
    start_um: tuple[float, float],
    program_open: bool,
    block_id: int = -1,
) -> FastArrayCost:
    """Seconds of ``array`` from ``start_um`` (no closing comeback: the next block or the run's end pays it).

    The opening is a global block's (``core.cost.open_program_steps``); the fast mode's surface find and drift
    settle are the profile's engage and drift steps, both inside the flat penalty where the profile has one.
    """
    check_fast_array(profile, array)
    fast = fast_mode_of(profile)
    steps: list[StepRecord] = list(open_program_steps(profile, block_id, program_open))
    opening_s = sum(s.seconds for s in steps)
    first = array.first_site_um
    travel_s = profile.move_s(first[0] - start_um[0], first[1] - start_um[1])
    if travel_s > 0:
        steps.append(StepRecord("move", travel_s, block_id, 0))
    # a flat global-jump penalty (the real-film workflow) already holds the engage and the settle
    flat = profile.global_jump_s is not None
    surface_s = profile.engage_s if fast.surface_find and not flat else 0.0
    settle_s = profile.drift_settle_s if fast.drift_settle and not flat else 0.0
    if surface_s > 0:
        steps.append(StepRecord("engage", surface_s, block_id, -1))
    if settle_s > 0:
        steps.append(StepRecord("drift", settle_s, block_id, -1))
    indents_s = fast.indent_s * array.n_indents
    columns_s = fast.column_change_s * (array.cols - 1)
    steps.append(StepRecord("indent", indents_s, block_id, -1))
    if columns_s > 0:
        steps.append(StepRecord("move", columns_s, block_id, -1))
    return FastArrayCost(
        opening_s=opening_s,
        travel_s=travel_s,
        surface_find_s=surface_s,
        drift_settle_s=settle_s,
        indents_s=indents_s,
        column_changes_s=columns_s,
        steps=tuple(steps),
    )


def fast_block(block_id: int, array: FastArray, keep: np.ndarray | None = None) -> Block:
    """The array as a plan's block (channel "fast", a global block: it opens its own program), its sites in
    the instrument's order; ``keep`` (one flag per site) leaves out the sites a sample does not allow (off
    the sample, near an exclusion or an earlier indent): the interlock would refuse them."""
    sites = array.sites_um()
    if keep is not None:
        sites = sites[np.asarray(keep, dtype=bool)]
    if not len(sites):
        raise InputError("fast_array", "no site of the array is allowed on this sample")
    return Block(
        block_id=block_id,
        kind="global",
        center_x_um=float(array.center_x_um),
        center_y_um=float(array.center_y_um),
        grid_g=array.rows,
        pitch_um=float(array.pitch_um),
        hold_s=0.0,
        indents=tuple(IndentSpec(float(x), float(y), 0.0) for x, y in sites),
        channel="fast",
    )


def fast_block_cost_s(
    profile: InstrumentProfile, block: Block, start_um: tuple[float, float], program_open: bool
) -> float:
    """Seconds of a fast ``block`` from ``start_um``: what ``core.cost.block_steps`` charges it, in closed form
    (the planner prices many arrays per decision)."""
    fast = fast_mode_of(profile)
    steps = list(open_program_steps(profile, block.block_id, program_open))
    first = block.indents[0]
    seconds = sum(s.seconds for s in steps) + profile.move_s(
        first.x_um - start_um[0], first.y_um - start_um[1]
    )
    if profile.global_jump_s is None:
        seconds += profile.engage_s * fast.surface_find + profile.drift_settle_s * fast.drift_settle
    xs = np.array([s.x_um for s in block.indents])
    columns = int(np.count_nonzero(xs[1:] != xs[:-1]))
    return float(seconds + fast.indent_s * block.n_indents + fast.column_change_s * columns)

"""The block design part: what one block of indents looks like, and how blocks make up programs.

- ``ReplicateGrid`` (the paper): a g×g grid of indents at one centre, collapsed to one robust value; seed
  grids first, then σ/cost choices between staying in the engaged program and a global jump.
- ``ScatteredSingles`` (``aeni``): a block is several single indents spread over the area the program can
  reach, ordered for travel; each indent is its own centre. The oracle study finds single indents about
  1.7× more informative per indent than replicate grids, and one program serves many of them.

A design says what a block is; what a candidate is worth is the policy's acquisition
(``core.policies.acquisition``), which the planner of the design is given.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class ReplicateGrid:
    stay: bool = True  # may continue the engaged program with local blocks (no lift, engage or drift wait)
    adaptive_grid: bool = False  # g from the predicted noise (SPEC §6.4) instead of fixed_g
    n_seed_blocks: int = 2
    seed_g: int = 5
    fixed_g: int = 5
    local_hop_um: float = 1000.0  # the meta-grid: 500 µm between consecutive sub-grids (safe band always)
    exploratory_iterations: int = 0  # aeni-paper: the first programs after the seeds allow few local centres
    exploratory_local_limit: int = 1
    local_limit: int | None = None  # local centres per program; None: the operator's setting (default 5)
    joint_program: bool = False  # price a jump with the sub-grids its program will run (planned jointly)


@dataclass(frozen=True)
class ScatteredSingles:
    indents_per_block: int = 16  # the fewest singles per block (a refit after each block) ...
    max_indents_per_block: int = 48  # ... and the most, when a program is dear to open (see block_sizes)
    # the space-filling start: this many singles on a low-discrepancy sequence before the model places any
    space_filling_indents: int = 64
    min_spacing_um: float = 15.0  # no two indents closer than this (site texture is shared below it)
    # a block adds at most this fraction to the indents the model was fitted on: pricing by gain per second
    # sees the program's overhead but not what a refit learns, so early on big blocks run on a model fitted
    # to few points (48 singles at a slow hold after the 64-indent start delayed the ternary's first maps)
    max_block_fraction: float = 0.25
    # stretches (core.policies.stretch): when the next load will run unattended for longer than this, the
    # planner fills the absence with one stretch of arrays; None: never (blocks stay adaptive, as today)
    stretch_min_s: float | None = None
    # price a new program over its life: its fixed overhead is charged to a block in the share of the indents
    # it will serve that the block takes (programs so far served this many on average), not to the first
    # block alone; False: the first block pays all of it (as before)
    program_life: bool = False

    def spacing_um(self, r_excl_um: float) -> float:
        """How far apart any two singles stay: the design's own spacing or the sample's exclusion."""
        return max(self.min_spacing_um, r_excl_um)

    def block_sizes(self, available: int, fitted_on: int | None = None) -> tuple[int, ...]:
        """Block sizes the planner prices against each other (gain per second): from the fewest to the most
        in steps of the fewest, capped at the ``available`` picks and at ``max_block_fraction`` of the
        ``fitted_on`` indents (no cap when None)."""
        lo = max(1, min(self.indents_per_block, available))
        most = self.max_indents_per_block
        if fitted_on is not None:
            most = min(most, int(self.max_block_fraction * fitted_on))
        top = max(lo, min(most, available))
        return tuple(sorted({*range(lo, top + 1, max(1, self.indents_per_block)), top}))


BlockDesign = ReplicateGrid | ScatteredSingles

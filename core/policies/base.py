"""The policy interface and the shared candidate machinery (masks, path-dependent block costs).

A policy turns a ``PlanContext`` (what is known now) into a ``Decision`` (what to run next and why).
Policies are pure functions of the context: every random choice is seeded from (seed, block_id), so a
resumed run plans exactly what an uninterrupted one would.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol, runtime_checkable

import numpy as np

from core.cost import block_steps
from core.geometry import SafeBand, exclusion_mask
from core.operator import LoadWindow
from core.plan import Alternative, Block, BlockKind, Decision, PlannerSettings, local_grid
from core.profile import InstrumentProfile

if TYPE_CHECKING:
    from core.geometry import Calibration, CandidateLattice
    from core.model import Prediction
    from core.policies.fidelity import FidelityView, HeldOutView
    from core.policies.parts import PolicyParts
    from core.sample import Sample

DEFAULT_PITCH_UM = 5.0
N_ALTERNATIVES = 5


@dataclass(frozen=True)
class GPSummary:
    """The mean GP's kernel as fitted: enough to compute posterior covariances of the latent map."""

    kernel: str  # "matern52" or "rbf"
    lengthscales_uv: tuple[float, float]
    outputscale_gpa2: float
    site_var_gpa2: float = 0.0  # learned scatter between centres that more indents do not average away


@dataclass(frozen=True)
class ModulusView:
    """The modulus map as the planner may weigh it beside the hardness (``map_weights``, issue 27)."""

    prediction: Prediction  # on lattice.uv
    gp: GPSummary
    tested_xy_um: np.ndarray  # (k, 2) centres with a modulus
    tested_noise_var_gpa2: np.ndarray  # (k,) noise variance of each centre's value, per the modulus model
    weight_hardness: float
    weight_modulus: float


@dataclass(frozen=True)
class PlanContext:
    """Everything a policy may look at, frozen at the moment of the decision."""

    profile: InstrumentProfile
    calibration: Calibration
    lattice: CandidateLattice
    prediction: Prediction | None  # on lattice.uv, None before the first fit
    settings: PlannerSettings
    seed: int
    block_id: int  # id the proposed block will get
    blocks_done: int
    clock_s: float
    position_um: tuple[float, float]
    program_open: bool
    program_center_um: tuple[float, float] | None  # centre of the running program's global block
    program_hold_s: float | None  # hold programmed for the running program (changing it needs a new program)
    locals_in_program: int  # local blocks run since the last global block
    tested_xy_um: np.ndarray  # (k, 2) centres already tested
    indents_xy_um: np.ndarray  # (m, 2) every taken place (actual positions): the places kept free
    best_observed_gpa: float | None
    last_drift_rate_nm_s: float | None
    avoid_xy_um: tuple[tuple[float, float], ...] = ()
    # after a veto: the alternative the vetoed proposal listed first, which the next proposal must be
    prefer_xy_um: tuple[float, float] | None = None
    pitch_um: float = DEFAULT_PITCH_UM
    dz_safe_um: float = 5.0
    r_excl_um: float = 20.0
    extras: dict[str, object] = field(default_factory=dict)
    globals_done: int = 0  # CSM programs (global blocks) run so far, seeds included; fast arrays are not
    # this run's measured CSM indents, what the map learnt from: the design's own rules (its space-filling
    # start, a block's cap against the data the model was fitted on, a program's life) count these, never a
    # fast indent, a failed one or an earlier run's, which take places but teach the CSM map nothing
    learnt_xy_um: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    tested_noise_var_gpa2: np.ndarray | None = (
        None  # (k,) noise variance of each centre's median, per the model
    )
    gp: GPSummary | None = None  # the fitted kernel, for planners that need covariances (y-free)
    recent_drift_rates_nm_s: tuple[float, ...] = ()  # the last drift readings (up to 25), oldest first
    # the last measured depths at maximum load (nm, up to 25; NaN where the instrument reported none)
    recent_depths_nm: tuple[float, ...] = ()
    placement_mask: np.ndarray | None = (
        None  # (n²,) lattice centres the sample allows (edge band, exclusions)
    )
    sample: Sample | None = None  # for planners whose blocks are not on the lattice (the grid baseline)
    modulus: ModulusView | None = None  # the modulus map, when map_weights asks for it (else hardness only)
    # how long the next load runs before anyone comes again, and when it must not end (core.visits); None:
    # attended, as always before
    unattended: LoadWindow | None = None
    # the two-fidelity model's view (core.policies.fidelity) once fast data are in; None: the CSM-only GP
    fidelity: FidelityView | HeldOutView | None = None

    @property
    def fixed_hold_s(self) -> float:
        """The operator's fixed hold, or the profile's default where none was chosen."""
        hold = self.settings.fixed_hold_s
        return self.profile.default_hold_s if hold is None else hold

    def rng(self, salt: int = 0) -> np.random.Generator:
        return np.random.default_rng([self.seed, self.block_id, salt])


class Policy(Protocol):
    name: str
    parts: PolicyParts  # what the Campaign builds its model from (a policy that never looks: the defaults)

    def propose(self, ctx: PlanContext) -> Decision | None:
        """The next block, or None when the policy has nothing left to do (e.g. the grid is complete)."""
        ...


@runtime_checkable
class PlansStretches(Protocol):
    """A policy that can plan, before an absence, the arrays of one stretch the operator loads at once."""

    def propose_stretch(self, ctx: PlanContext) -> list[Decision] | None:
        """The stretch's arrays, or None when no stretch is due (the next block is planned adaptively)."""
        ...


# -- shared machinery ------------------------------------------------------------------------------


def make_block(ctx: PlanContext, x_um: float, y_um: float, g: int, hold_s: float, kind: BlockKind) -> Block:
    return Block(
        block_id=ctx.block_id,
        kind=kind,
        center_x_um=float(x_um),
        center_y_um=float(y_um),
        grid_g=g,
        pitch_um=ctx.pitch_um,
        hold_s=hold_s,
        indents=local_grid(float(x_um), float(y_um), g, ctx.pitch_um, hold_s),
    )


def grid_size_for_noise(
    noise_sd_gpa: np.ndarray, target_sem_gpa: float, g_min: int = 2, g_max: int = 5
) -> np.ndarray:
    """SPEC §6.4: n_req = (σ_noise/ε)², g = clip(round(√n_req), 2, 5)."""
    n_req = (np.asarray(noise_sd_gpa, dtype=float) / target_sem_gpa) ** 2
    return np.clip(np.rint(np.sqrt(n_req)), g_min, g_max).astype(int)


def _within_grid_s(profile: InstrumentProfile, g: int, pitch_um: float, hold_s: float) -> float:
    """Seconds for the g² indents and the moves between them (independent of where the grid is)."""
    blk = Block(0, "local", 0.0, 0.0, g, pitch_um, hold_s, local_grid(0.0, 0.0, g, pitch_um, hold_s))
    return float(
        sum(s.seconds for s in block_steps(profile, blk, (blk.indents[0].x_um, blk.indents[0].y_um), True))
    )


def block_costs_s(
    ctx: PlanContext,
    xy_um: np.ndarray,
    g: np.ndarray | int,
    hold_s: float,
    kind: BlockKind,
    from_um: tuple[float, float] | None = None,
) -> np.ndarray:
    """Path-dependent cost of a g×g block at every candidate centre, from the current stage position
    (or ``from_um``, to price a plan ahead).

    Vectorised version of core.cost.block_steps: the same profile numbers, checked equal in tests.
    """
    p = ctx.profile
    pos = ctx.position_um if from_um is None else from_um
    g_arr = np.broadcast_to(np.asarray(g, dtype=int), (len(xy_um),))
    half = (g_arr - 1) / 2.0 * ctx.pitch_um
    first_x = xy_um[:, 0] - half
    first_y = xy_um[:, 1] - half
    dx = first_x - pos[0]
    dy = first_y - pos[1]
    move = p.move.axis_s_array(dx) + p.move.axis_s_array(dy)
    move = np.where((dx == 0) & (dy == 0), 0.0, move)
    within = np.zeros(len(xy_um))
    for gv in np.unique(g_arr):
        within[g_arr == gv] = _within_grid_s(p, int(gv), ctx.pitch_um, hold_s)
    if kind == "global":
        overhead = p.global_overhead_s
        if p.global_jump_s is None and not ctx.program_open:
            overhead -= p.comeback_s  # nothing to come back from yet
        return overhead + move + within
    far = (np.abs(dx) >= p.reconfig_threshold_um) | (np.abs(dy) >= p.reconfig_threshold_um)
    return move + within + np.where(far, p.reconfiguration_s, 0.0)


def base_mask(ctx: PlanContext, g_max_halfwidth_um: float) -> np.ndarray:
    """Candidates that may be proposed at all: outside the exclusion zone and away from vetoed centres."""

    xy = ctx.lattice.xy_um
    mask = np.ones(len(xy), dtype=bool) if ctx.placement_mask is None else ctx.placement_mask.copy()
    if len(ctx.indents_xy_um):
        mask &= exclusion_mask(xy, ctx.indents_xy_um, ctx.r_excl_um, g_max_halfwidth_um)
    for ax, ay in ctx.avoid_xy_um:
        # a vetoed centre and its immediate neighbourhood (2 lattice pitches) are avoided for a while
        pitch = _lattice_pitch_um(ctx)
        mask &= np.hypot(xy[:, 0] - ax, xy[:, 1] - ay) > 2.0 * pitch
    return mask


def preferred_index(ctx: PlanContext, xy_um: np.ndarray, ok: np.ndarray) -> int | None:
    """After a veto: the candidate (among ``ok``) nearest the alternative the operator was offered next."""
    if ctx.prefer_xy_um is None or not ok.any():
        return None
    d = np.hypot(xy_um[:, 0] - ctx.prefer_xy_um[0], xy_um[:, 1] - ctx.prefer_xy_um[1])
    return int(np.argmin(np.where(ok, d, np.inf)))


def _lattice_pitch_um(ctx: PlanContext) -> float:
    xy = ctx.lattice.xy_um
    d = np.hypot(xy[1, 0] - xy[0, 0], xy[1, 1] - xy[0, 1])
    return float(d)


def local_mask(ctx: PlanContext, g_max_halfwidth_um: float, max_hop_um: float) -> np.ndarray:
    """Candidates reachable without lifting: the whole grid inside the running program's safe band, its
    centre at most ``max_hop_um`` from the current position, and no move that would trip the safety rule."""
    if not ctx.program_open or ctx.program_center_um is None:
        return np.zeros(len(ctx.lattice.xy_um), dtype=bool)
    return reachable_mask(ctx, ctx.program_center_um, ctx.position_um, g_max_halfwidth_um, max_hop_um)


def reachable_mask(
    ctx: PlanContext,
    centre_um: tuple[float, float],
    position_um: tuple[float, float],
    halfwidth_um: float,
    max_hop_um: float,
    idx: np.ndarray | None = None,
) -> np.ndarray:
    """``local_mask`` for any program centre and stage position (to plan a program before opening it);
    with ``idx``, only for those lattice candidates."""

    xy = ctx.lattice.xy_um if idx is None else ctx.lattice.xy_um[idx]
    band = SafeBand(ctx.calibration.plane, float(centre_um[0]), float(centre_um[1]), ctx.dz_safe_um)
    ok = band.contains(xy[:, 0], xy[:, 1], grid_halfwidth_um=halfwidth_um)
    dx = np.abs(xy[:, 0] - position_um[0])
    dy = np.abs(xy[:, 1] - position_um[1])
    ok &= np.hypot(dx, dy) <= max_hop_um
    ok &= np.maximum(dx, dy) + 2 * halfwidth_um < ctx.profile.reconfig_threshold_um
    return np.asarray(ok, dtype=bool)


def alternatives(
    ctx: PlanContext,
    order: np.ndarray,
    score: np.ndarray,
    acq: np.ndarray,
    cost: np.ndarray,
    kinds: np.ndarray,
    skip: int,
) -> tuple[Alternative, ...]:
    """The next-best candidates after the chosen one, spread out (not the chosen one's neighbours)."""
    xy = ctx.lattice.xy_um
    chosen = xy[order[0]] if len(order) else None
    pitch = _lattice_pitch_um(ctx)
    out: list[Alternative] = []
    taken: list[np.ndarray] = [] if chosen is None else [chosen]
    for idx in order[skip:]:
        p = xy[idx]
        if any(np.hypot(*(p - t)) < 3 * pitch for t in taken):
            continue
        taken.append(p)
        out.append(
            Alternative(
                center_x_um=float(p[0]),
                center_y_um=float(p[1]),
                kind=str(kinds[idx]),  # type: ignore[arg-type]
                score=float(score[idx]),
                acquisition=float(acq[idx]),
                cost_s=float(cost[idx]),
            )
        )
        if len(out) >= N_ALTERNATIVES:
            break
    return tuple(out)

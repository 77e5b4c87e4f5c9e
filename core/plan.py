"""Plans as data: the small immutable records that planner, driver, engine, journal and console share.

Everything here is a frozen dataclass of plain numbers and strings so that the journal can store it
and the console can show it without knowing who made it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Any, Literal

BlockKind = Literal["global", "local"]
# what became of a commanded indent: only a measured one carries numbers the model may learn from.
# ``unverified``: the instrument made it (its export says where the tip went) but the export was refused,
# so it is kept away from and priced, never learnt from.
IndentStatus = Literal["measured", "failed", "not_run", "unverified"]
INDENT_STATUSES: tuple[IndentStatus, ...] = ("measured", "failed", "not_run", "unverified")
# which kind of indent: a CSM indent (the map's own measurement) or a fast, load-controlled one of a
# NanoBlitz-class array (SPEC §9): a cheaper, biased reading of the same map that only the two-fidelity model
# learns from
Channel = Literal["csm", "fast"]
CHANNELS: tuple[Channel, ...] = ("csm", "fast")

# Ledger categories, in the order the console lists them.
LEDGER_CATEGORIES: tuple[str, ...] = (
    "setup",
    "lift",
    "move",
    "engage",
    "drift",
    "indent",
    "hold",
    "reconfigure",
    "comeback",
    "recovery",
)


@dataclass(frozen=True)
class IndentSpec:
    """One commanded indent in stage coordinates."""

    x_um: float
    y_um: float
    hold_s: float


@dataclass(frozen=True)
class Block:
    """One g×g local grid at one centre: what the instrument runs as a programmed array.

    A ``global`` block opens a new program (setup under the lens, lift, move, engage, drift settle);
    a ``local`` block continues the engaged program from the previous block's last indent (the
    meta-grid "stay"), paying only moves, indents and, where a hop is ≥ the safety threshold,
    a reconfiguration.
    """

    block_id: int
    kind: BlockKind
    center_x_um: float
    center_y_um: float
    grid_g: int
    pitch_um: float
    hold_s: float
    indents: tuple[IndentSpec, ...]
    # "fast": a fast array (core.fast_array): one program of load-controlled indents, priced per indent and
    # column change, no holds; ``grid_g`` is then its rows and ``pitch_um`` its pitch
    channel: Channel = "csm"

    @property
    def n_indents(self) -> int:
        return len(self.indents)


@dataclass(frozen=True)
class StepRecord:
    """One executed (or priced) instrument step: the unit of the cost ledger."""

    category: str
    seconds: float
    block_id: int = -1
    indent_index: int = -1


@dataclass(frozen=True)
class IndentResult:
    """What the instrument reports for one commanded indent.

    A ``failed`` indent (the instrument tried and reported no valid value) or a ``not_run`` one (it
    never happened) is journaled as such with NaN in place of every value it did not measure; the
    campaign never learns from it. ``note`` says why, in the instrument's words.
    """

    block_id: int
    indent_index: int
    commanded_x_um: float
    commanded_y_um: float
    actual_x_um: float
    actual_y_um: float
    hold_s: float
    hardness_gpa: float
    modulus_gpa: float
    drift_rate_nm_s: float
    t_s: float  # instrument clock when the indent finished
    status: IndentStatus = "measured"
    note: str = ""
    # displacement at maximum load (nm): the depth Eq. 7's drift error is relative to; None where the
    # instrument did not report it (the drift rules then assume the nominal depth)
    depth_at_max_load_nm: float | None = None
    channel: Channel = "csm"  # a fast indent is learnt only by the two-fidelity model, never as a CSM value

    def __post_init__(self) -> None:
        if self.status == "measured" and not math.isfinite(self.hardness_gpa):
            raise ValueError(
                f"block {self.block_id} indent {self.indent_index}: a measured indent needs a finite hardness "
                f"(got {self.hardness_gpa!r}); report it as failed"
            )

    @property
    def depth_nm(self) -> float:
        """The reported depth at maximum load, NaN when there is none."""
        return math.nan if self.depth_at_max_load_nm is None else self.depth_at_max_load_nm

    @property
    def measured(self) -> bool:
        return self.status == "measured"

    @classmethod
    def unmeasured(
        cls,
        block_id: int,
        indent_index: int,
        spec: IndentSpec,
        t_s: float,
        status: IndentStatus,
        note: str,
        channel: Channel = "csm",
    ) -> IndentResult:
        """A failed or not-run indent: where it was commanded, when, why; no values."""
        if status == "measured":
            raise ValueError("an unmeasured indent needs the status failed, not_run or unverified")
        nan = float("nan")
        return cls(
            block_id,
            indent_index,
            spec.x_um,
            spec.y_um,
            nan,
            nan,
            spec.hold_s,
            nan,
            nan,
            nan,
            t_s,
            status,
            note,
            channel=channel,
        )


@dataclass(frozen=True)
class Alternative:
    """A candidate the planner ranked but did not pick (shown to the operator)."""

    center_x_um: float
    center_y_um: float
    kind: BlockKind
    score: float
    acquisition: float
    cost_s: float


# the phases of a stretch's arrays (a decision's ``phase``): the first is a visit of the operator's, the
# others were loaded with it (core.visits counts them so; the engine hands a stretch's tickets out together)
STRETCH_PHASE = "stretch"
STRETCH_CONTINUES = "stretch-continues"


@dataclass(frozen=True)
class Decision:
    """A planner proposal with everything the operator and the journal need to judge it."""

    block: Block
    policy: str
    acquisition: float  # raw acquisition value at the proposed centre (σ for UE)
    score: float  # the ranking score (acquisition / cost for cost-aware policies)
    predicted_cost_s: float
    stay_score: float | None = None  # best local (no reconfiguration) score, where the policy has one
    jump_score: float | None = None  # best global score, including the jump penalty
    alternatives: tuple[Alternative, ...] = ()
    reason: str = ""
    # which planner phase produced it (seed, explore, exploit, grid ...), shown in the console
    phase: str = ""
    # hold-mode bookkeeping for the drift panel
    hold_mode: str = "fixed"
    area_error_pct: float | None = None

    @property
    def is_global_jump(self) -> bool:
        return self.block.kind == "global"


MAPS: tuple[str, ...] = ("hardness", "modulus")


@dataclass(frozen=True)
class MapWeights:
    """How much each map's relative error counts in the acquisition; a weight of 0 drops that map.

    Both maps by default (issue 37): on the ternary, aiming at both brought the hardness map to the grid's
    error no later than aiming at it alone (docs/benchmarks.md, "Both maps by default")."""

    hardness: float = 1.0
    modulus: float = 1.0

    def __post_init__(self) -> None:
        for name in MAPS:
            w = getattr(self, name)
            if isinstance(w, bool) or not isinstance(w, int | float) or not math.isfinite(w) or w < 0:
                raise ValueError(f"map_weights.{name} must be a finite number ≥ 0, got {w!r}")
        if self.hardness == 0 and self.modulus == 0:
            raise ValueError("map_weights: at least one map needs a weight > 0")

    @property
    def maps_modulus(self) -> bool:
        """The modulus map is planned for (and so learned after every block)."""
        return self.modulus > 0


@dataclass(frozen=True)
class PlannerSettings:
    """Operator-adjustable knobs (the console's adjust form edits these)."""

    target_sem_gpa: float = 0.05
    beta: float = 4.0
    hold_policy: Literal["fixed", "adaptive"] = "fixed"
    fixed_hold_s: float | None = None  # None: the instrument profile's default hold
    local_center_limit: int = 5
    edge_penalty: float = 0.5
    budget_s: float | None = None
    indent_budget: int | None = None
    sigma_target_gpa: float | None = None
    mape_target_pct: float | None = None
    stop_at: str | None = None  # local wall clock "HH:MM": the last block is one that ends before it
    stop_rel_sd_pct: float | None = None  # stop when the map's relative epistemic sd (p95) falls below
    avoid_centers_um: tuple[tuple[float, float], ...] = field(default_factory=tuple)
    map_weights: MapWeights = field(default_factory=MapWeights)


def local_grid(
    center_x_um: float, center_y_um: float, g: int, pitch_um: float, hold_s: float
) -> tuple[IndentSpec, ...]:
    """A g×g grid centred on (x, y), in boustrophedon order so consecutive indents are one pitch apart."""
    if g < 1:
        raise ValueError(f"grid size must be ≥ 1, got {g}")
    half = (g - 1) / 2.0
    out: list[IndentSpec] = []
    for row in range(g):
        cols = range(g) if row % 2 == 0 else range(g - 1, -1, -1)
        for col in cols:
            out.append(
                IndentSpec(
                    x_um=center_x_um + (col - half) * pitch_um,
                    y_um=center_y_um + (row - half) * pitch_um,
                    hold_s=hold_s,
                )
            )
    return tuple(out)


# -- plans in and out of JSON (the journal, the planner's saved state) ----------------------------------
def block_from_dict(d: dict[str, Any]) -> Block:
    return Block(
        block_id=int(d["block_id"]),
        kind=d["kind"],
        center_x_um=float(d["center_x_um"]),
        center_y_um=float(d["center_y_um"]),
        grid_g=int(d["grid_g"]),
        pitch_um=float(d["pitch_um"]),
        hold_s=float(d["hold_s"]),
        indents=tuple(
            IndentSpec(float(s["x_um"]), float(s["y_um"]), float(s["hold_s"])) for s in d["indents"]
        ),
        channel=d.get("channel", "csm"),
    )


def decision_from_dict(d: dict[str, Any]) -> Decision:
    kw = dict(d)
    kw["block"] = block_from_dict(d["block"])
    kw["alternatives"] = tuple(Alternative(**a) for a in d.get("alternatives", ()))
    known = {f.name for f in fields(Decision)}
    return Decision(**{k: v for k, v in kw.items() if k in known})

"""Plain data in and out of the journal: frozen records go in as JSON or columns, come back the same.

Planner settings go through ``core.settings`` (the one codec the run file uses too).
"""

from __future__ import annotations

import dataclasses
import enum
import io
import json
import math
import sqlite3
import statistics
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from core.plan import Block, Decision, IndentResult, StepRecord
from core.plan import block_from_dict as block_from_dict
from core.plan import decision_from_dict as decision_from_dict
from core.run.records import DriverState as DriverState
from core.run.records import StoredCommand as StoredCommand
from core.runview import MapFields


def _default(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, enum.Enum):
        return obj.value
    if isinstance(obj, Path):
        return str(obj)
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return dataclasses.asdict(obj)
    if isinstance(obj, set | frozenset):
        return sorted(obj)
    raise TypeError(f"cannot store {type(obj).__name__} in the journal")


def to_json(obj: Any) -> str:
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        obj = dataclasses.asdict(obj)
    return json.dumps(obj, default=_default, separators=(",", ":"))


def map_fields_to_bytes(fields: MapFields) -> bytes:
    buf = io.BytesIO()
    nxt = np.asarray(fields.next_candidate_um if fields.next_candidate_um is not None else [], dtype=float)
    arrays: dict[str, np.ndarray] = {
        "x_um": fields.x_um,
        "y_um": fields.y_um,
        "mean_gpa": fields.mean_gpa,
        "epistemic_sd_gpa": fields.epistemic_sd_gpa,
        "noise_sd_gpa": fields.noise_sd_gpa,
        "total_sd_gpa": fields.total_sd_gpa,
        "next_candidate_um": nxt,
    }
    if fields.modulus_mean_gpa is not None and fields.modulus_sd_gpa is not None:
        arrays |= {"modulus_mean_gpa": fields.modulus_mean_gpa, "modulus_sd_gpa": fields.modulus_sd_gpa}
    if fields.bias_gpa is not None:
        arrays["bias_gpa"] = fields.bias_gpa
    np.savez_compressed(buf, allow_pickle=False, **arrays)
    return buf.getvalue()


def map_fields_from_bytes(snapshot_id: int, blob: bytes) -> MapFields:
    with np.load(io.BytesIO(blob)) as z:
        nxt = z["next_candidate_um"]
        return MapFields(
            snapshot_id=snapshot_id,
            x_um=z["x_um"],
            y_um=z["y_um"],
            mean_gpa=z["mean_gpa"],
            epistemic_sd_gpa=z["epistemic_sd_gpa"],
            noise_sd_gpa=z["noise_sd_gpa"],
            total_sd_gpa=z["total_sd_gpa"],
            next_candidate_um=(float(nxt[0]), float(nxt[1])) if nxt.size == 2 else None,
            modulus_mean_gpa=z["modulus_mean_gpa"] if "modulus_mean_gpa" in z.files else None,
            modulus_sd_gpa=z["modulus_sd_gpa"] if "modulus_sd_gpa" in z.files else None,
            bias_gpa=z["bias_gpa"] if "bias_gpa" in z.files else None,
        )


def utc_now() -> str:
    """Wall-clock time as the journal stores it (ISO 8601, milliseconds, Z)."""
    return datetime.now(UTC).isoformat(timespec="milliseconds").replace("+00:00", "Z")


@dataclass(frozen=True)
class StoredDecision:
    decision_id: int
    decision: Decision
    status: str
    needs_approval_reason: str
    t_s: float


@dataclass(frozen=True)
class BlockRecord:
    """One planned block with what became of it: the unit the replay walks."""

    block: Block
    status: str  # planned | running | executed | observed | aborted
    decision: Decision | None
    results: tuple[IndentResult, ...]
    steps: tuple[StepRecord, ...]
    snapshot_id: int | None
    fit_summary: dict[str, Any]
    planned_t_s: float
    finished_t_s: float | None

    @property
    def median_gpa(self) -> float | None:
        values = [r.hardness_gpa for r in self.results if r.measured]
        return statistics.median(values) if values else None

    @property
    def seconds(self) -> float:
        return float(sum(s.seconds for s in self.steps))


def _value(x: Any) -> float:
    """A stored value; NULL (what a failed or not-run indent stores) comes back as NaN."""
    return math.nan if x is None else float(x)


def _stored(x: float) -> float | None:
    return None if math.isnan(x) else x


def result_from_row(r: Sequence[Any]) -> IndentResult:
    return IndentResult(
        block_id=int(r[0]),
        indent_index=int(r[1]),
        commanded_x_um=r[2],
        commanded_y_um=r[3],
        actual_x_um=_value(r[4]),
        actual_y_um=_value(r[5]),
        hold_s=r[6],
        hardness_gpa=_value(r[7]),
        modulus_gpa=_value(r[8]),
        drift_rate_nm_s=_value(r[9]),
        t_s=r[10],
        status=r[11],
        note=r[12],
        depth_at_max_load_nm=None if r[13] is None else float(r[13]),
        # a row of a journal before schema 6 (or its event log) has no channel: every indent was a CSM one
        channel="fast" if len(r) > 14 and r[14] == "fast" else "csm",
    )


def result_to_row(r: IndentResult) -> tuple[Any, ...]:
    """The INDENT_COLS values of one result: what was not measured is stored as NULL, never as a number."""
    return (
        r.block_id,
        r.indent_index,
        r.commanded_x_um,
        r.commanded_y_um,
        _stored(r.actual_x_um),
        _stored(r.actual_y_um),
        r.hold_s,
        _stored(r.hardness_gpa),
        _stored(r.modulus_gpa),
        _stored(r.drift_rate_nm_s),
        r.t_s,
        r.status,
        r.note,
        None
        if r.depth_at_max_load_nm is None or not math.isfinite(r.depth_at_max_load_nm)
        else r.depth_at_max_load_nm,
        r.channel,
    )


APPROVAL_CATEGORY = "approval"  # the log rows of ApprovalAsked events: the console counts down from them

INDENT_COLS = (
    "block_id, indent_index, commanded_x_um, commanded_y_um, actual_x_um, actual_y_um, hold_s, "
    "hardness_gpa, modulus_gpa, drift_rate_nm_s, t_s, status, note, depth_at_max_load_nm, channel"
)


def indent_cols(conn: sqlite3.Connection) -> str:
    """INDENT_COLS as this journal can answer them: one before schema 6 (read, not migrated) has no channel
    column, and every indent in it was a CSM one."""
    names = {r[1] for r in conn.execute("PRAGMA table_info(indents)")}
    return INDENT_COLS if "channel" in names else INDENT_COLS.replace(", channel", ", 'csm'")

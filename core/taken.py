"""Which places on the sample are taken: the one rule the planners and the safety interlock share.

Every indent the instrument made is taken, whatever came of it: a measured one, a failed one (the tip went
down, the value was invalid) and an unverified one (its export was refused but says where the tip went).
Only a site that was never indented (``not_run``) is free. Where the tip went is the measured position, else
(an instrument that reported none) where it was sent.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np
from numpy.typing import NDArray

from core.plan import IndentResult

TAKEN_STATUSES: frozenset[str] = frozenset({"measured", "failed", "unverified"})
FREE_STATUSES: frozenset[str] = frozenset({"not_run"})


def is_taken(status: str) -> bool:
    """True when an indent with this status left a mark; an unknown status is an error, never a guess."""
    if status in TAKEN_STATUSES:
        return True
    if status in FREE_STATUSES:
        return False
    raise ValueError(f"unknown indent status {status!r}")


def tip_xy_um(result: IndentResult) -> tuple[float, float]:
    """Where the tip went down: the reported position, else the commanded one."""
    if math.isfinite(result.actual_x_um) and math.isfinite(result.actual_y_um):
        return (result.actual_x_um, result.actual_y_um)
    return (result.commanded_x_um, result.commanded_y_um)


def taken_xy_um(results: Iterable[IndentResult]) -> NDArray[np.float64]:
    """The places (k, 2) that these results take, in their order."""
    spots = [tip_xy_um(r) for r in results if is_taken(r.status)]
    return np.asarray(spots, dtype=float).reshape(-1, 2)

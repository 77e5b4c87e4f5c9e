"""The paper's drift arithmetic (Eq. 7–9): how much a measured drift rate distorts the contact area."""

from __future__ import annotations

import numpy as np

AREA_ERROR_THRESHOLD_PCT = 2.0
# below this, a running median of drift readings is the meter's noise, not drift (the emulator's meter reads
# 0.002 nm/s + 10 %, clipped at 0): correcting it would add that noise and its one-sided bias to every indent
# of a quiet run. The bias left uncorrected under it is < 0.4 % of hardness.
DRIFT_READING_FLOOR_NM_S = 0.005
# what Eq. 7 assumes when the instrument does not say: the iMicro method's drift segment (the profile's
# [drift] segment_s) and the depth of a CSM test to the paper's 100 nm (an export's "Displacement At Max
# Load" replaces it per indent)
DRIFT_SEGMENT_S = 40.0
NOMINAL_DEPTH_NM = 100.0


def area_error_pct(
    drift_rate_nm_s: float,
    depth_nm: float = NOMINAL_DEPTH_NM,
    t_measure_s: float = DRIFT_SEGMENT_S,
) -> float:
    """|h_meas² − h_true²| / h_true² · 100 with h_true = h_meas − DR·t and h_meas the measured depth."""
    h_meas = depth_nm
    h_true = h_meas - abs(drift_rate_nm_s) * t_measure_s
    if h_true <= 0:
        return float("inf")
    return abs(h_meas**2 - h_true**2) / h_true**2 * 100.0


def smoothed_drift_rates_nm_s(rates_nm_s: np.ndarray, half_width: int = 2) -> np.ndarray:
    """A running median over consecutive indents' drift readings (the window shrinks at the ends).

    One reading is noisy (and, when the instrument is quiet, mostly its noise floor, which would bias every
    corrected indent upwards); drift changes over minutes, several indents. A median keeps the step of an
    event that starts mid-block sharp, where a mean would smear it over the indents before it.
    """
    r = np.asarray(rates_nm_s, dtype=float)
    n = r.size
    if n == 0 or half_width <= 0:
        return r.copy()
    return np.array([np.median(r[max(0, i - half_width) : i + half_width + 1]) for i in range(n)])


def drift_corrected_hardness_gpa(
    hardness_gpa: np.ndarray,
    drift_rate_nm_s: np.ndarray,
    hold_s: np.ndarray,
    full_hold_s: float,
    depth_nm: np.ndarray | float = NOMINAL_DEPTH_NM,
    t_measure_s: float = DRIFT_SEGMENT_S,
    floor_nm_s: float = DRIFT_READING_FLOOR_NM_S,
) -> np.ndarray:
    """Undo Eq. 7's area error on indents whose hold was too short for the instrument to correct the drift.

    H ∝ 1/A and A ∝ h², so H_true = H_meas·(1 + area error) with the drift rate measured at the indent (the
    campaign passes the running median of the block's readings). An 80 s hold is left alone (the
    instrument's post-hold segment corrected it), and so is a rate at the meter's noise floor. A fast indent
    hit by an event after its block was planned carries a bias far above the grid's noise; the readings show
    the event, so the correction pulls it back instead of leaving it to the robust centre value. Beyond
    DR·t ≥ depth the formula has no answer and the value is kept as measured. ``full_hold_s`` is the
    profile's longest hold (the one the instrument's own correction is complete after). ``depth_nm`` is
    each indent's measured depth at maximum load (NaN where the instrument did not report one: the
    nominal depth stands in) and ``t_measure_s`` the profile's drift segment.
    """
    h = np.asarray(hardness_gpa, dtype=float)
    rate = np.abs(np.asarray(drift_rate_nm_s, dtype=float))
    hold = np.asarray(hold_s, dtype=float)
    depth = np.broadcast_to(np.asarray(depth_nm, dtype=float), h.shape)
    depth = np.where(np.isfinite(depth) & (depth > 0), depth, NOMINAL_DEPTH_NM)
    h_true = depth - rate * t_measure_s
    ok = (hold < full_hold_s) & (h_true > 0) & (rate > floor_nm_s)
    factor = np.where(ok, (depth / np.where(ok, h_true, 1.0)) ** 2, 1.0)
    return h * factor


def typical_depth_nm(depths_nm: tuple[float, ...] | np.ndarray) -> float:
    """The depth the hold rule prices the next block's drift against: the median of recent measured
    depths at maximum load, or the nominal depth when the instrument reported none."""
    d = np.asarray(depths_nm, dtype=float)
    d = d[np.isfinite(d) & (d > 0)]
    return float(np.median(d)) if d.size else NOMINAL_DEPTH_NM

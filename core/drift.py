"""The paper's drift arithmetic (Eq. 7–9): how much a measured drift rate distorts the contact area."""

from __future__ import annotations

AREA_ERROR_THRESHOLD_PCT = 2.0


def area_error_pct(
    drift_rate_nm_s: float, nominal_depth_nm: float = 100.0, t_measure_s: float = 40.0
) -> float:
    """|h_meas² − h_true²| / h_true² · 100 with h_true = h_meas − DR·t and h_meas the nominal depth."""
    h_meas = nominal_depth_nm
    h_true = h_meas - abs(drift_rate_nm_s) * t_measure_s
    if h_true <= 0:
        return float("inf")
    return abs(h_meas**2 - h_true**2) / h_true**2 * 100.0

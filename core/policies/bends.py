"""Where the map bends: a weight on the integrated variance reduction for the error a stationary GP makes there.

A GP with one length-scale over the whole sample smooths a map whose slope changes fast (a kink where a
composition saturates, a phase boundary, a narrow hump): there the error of its mean is mostly bias, which its
posterior variance does not show, and an even design leaves it where it is. The bias of a smooth interpolant
with fill distance h grows with the local curvature times h², so the relative error it leaves at x scales with
κ(x) = ‖∇²μ(x)‖ / μ(x), the Frobenius norm of the fitted mean's Hessian relative to the map's value.

``bend_factor`` turns κ into a factor on the reference points' weights (already 1/μ², what MAPE counts):
``1 + strength · min(κ / mean κ, cap)``. On a map of constant curvature (a plane, a paraboloid) it is the same
everywhere and the design stays even; on a map that bends in one place the reduction of variance there counts
up to ``1 + strength · cap`` times more, so the greedy picks crowd there until the variance left is that much
lower. The cap keeps a single noisy wiggle of an early fit from drawing a whole block.
"""

from __future__ import annotations

import numpy as np

BEND_CAP = 4.0  # κ above this multiple of its mean over the area counts as this multiple


def relative_curvature(mean_grid: np.ndarray, pitch_uv: tuple[float, float]) -> np.ndarray:
    """‖∇²μ‖_F / |μ| on an (n, n) lattice of the fitted mean (rows along v, columns along u), per unit (u, v)²."""
    du, dv = float(pitch_uv[0]), float(pitch_uv[1])
    m = np.asarray(mean_grid, dtype=float)
    g_v, g_u = np.gradient(m, dv, du)
    g_uv, g_uu = np.gradient(g_u, dv, du)
    g_vv, g_vu = np.gradient(g_v, dv, du)
    hess = np.sqrt(g_uu**2 + g_vv**2 + g_uv**2 + g_vu**2)
    return np.asarray(hess / np.maximum(np.abs(m), 1e-6), dtype=float)


def bend_factor(kappa: np.ndarray, strength: float, cap: float = BEND_CAP) -> np.ndarray:
    """The weight factor ``1 + strength · min(κ / mean κ, cap)`` of each reference point (1 where κ is 0)."""
    k = np.asarray(kappa, dtype=float)
    scale = float(np.mean(k))
    if strength <= 0 or not np.isfinite(scale) or scale <= 0:
        return np.ones_like(k)
    return np.asarray(1.0 + strength * np.minimum(k / scale, cap), dtype=float)

"""Fitting: deterministic L-BFGS on a GP's raw hyperparameters, warm and cold starts, the refit schedule.

A warm refit is one short run from the previous fit's raw vector; a cold fit runs a few fixed starts and
keeps the best. Nothing here draws random numbers: given the journal's record and the data, a resumed run
makes the same fits (crash-exact resume).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch

from core.model.kernels import DTYPE, NOISE_VAR_FLOOR, OUTPUTSCALE_FLOOR, inv_softplus
from core.model.problem import Problem

COLD_LENGTHSCALES_UV = (0.15, 0.4)  # deterministic starts of a cold fit
# a warm-started refit follows its own optimum as data arrive and can stay in it after the data favour
# another (the grains: texture read as noise at a long length-scale); whenever the data have grown by this
# factor since the last cold fit, the refit also runs the cold starts and keeps the better likelihood
COLD_REFIT_GROWTH = 1.5
# ... and only by more than this (log marginal likelihood + prior): on smooth maps the cold starts land in
# the warm optimum and would win by rounding, replacing a settled model with an equivalent one (measured:
# 0.00–0.01 nats on the ternary, 19.6 nats on the grains once their texture is in the data)
COLD_WIN_NATS = 2.0
WARM_MIN_OUTPUTSCALE = 0.05  # standardised: a warm start never begins below this
WARM_MIN_LENGTHSCALE_EXCESS_UV = 0.005  # ... nor with a length-scale closer than this to its floor
WARM_MIN_NOISE_VAR = 1e-3  # ... nor with a learned noise variance (standardised) below this
COLD_NOISE_VAR = 0.1  # initial learned noise (standardised) of a cold homoskedastic fit
TOL_GRAD = 1e-4  # on −mll/n per raw parameter: warm and cold fits agree to < 0.3 % in length-scale
TOL_CHANGE = 1e-8  # absolute, on −mll/n and on the raw step


# the interpolated GP (large designs) keeps its hyperparameters and only conditions on the new data until
# the data have grown by this factor since its last optimisation: one more centre among thousands moves the
# optimum by far less than the fit's tolerance, and a warm L-BFGS run would cost most of a decision
SKI_REFIT_GROWTH = 1.1


def optimisation_due(n: int, fit_n: int) -> bool:
    return n >= SKI_REFIT_GROWTH * max(fit_n, 1)


def cold_search_due(n: int, cold_n: int) -> bool:
    """The refit schedule: a cold search whenever the data have grown by COLD_REFIT_GROWTH since the last."""
    return n >= COLD_REFIT_GROWTH * max(cold_n, 1)


def optimise(p: Problem, theta0: torch.Tensor, max_iter: int) -> tuple[torch.Tensor, int]:
    """Deterministic L-BFGS (strong Wolfe) on the raw vector; a failed or non-finite run keeps ``theta0``."""
    theta = theta0.detach().clone().requires_grad_(True)
    opt = torch.optim.LBFGS(
        [theta],
        lr=1.0,
        max_iter=max_iter,
        max_eval=int(max_iter * 1.5) + 1,
        tolerance_grad=TOL_GRAD,
        tolerance_change=TOL_CHANGE,
        history_size=10,
        line_search_fn="strong_wolfe",
    )

    def closure() -> torch.Tensor:
        opt.zero_grad()
        surrogate, value = p.loss(theta)
        surrogate.backward()
        return torch.tensor(value, dtype=DTYPE)

    try:
        opt.step(closure)
    except (RuntimeError, torch.linalg.LinAlgError):
        return theta0.detach().clone(), 0
    result = theta.detach()
    if not bool(torch.isfinite(result).all()):
        return theta0.detach().clone(), 0
    return result, int(opt.state[theta].get("n_iter", 0))


def cold_theta(lengthscale: float, floor_uv: float, learn_noise: bool) -> torch.Tensor:
    raw_ls = inv_softplus(max(lengthscale - floor_uv, 1e-3))
    values = [0.0, inv_softplus(1.0 - OUTPUTSCALE_FLOOR), raw_ls, raw_ls]
    if learn_noise:
        values.append(inv_softplus(COLD_NOISE_VAR - NOISE_VAR_FLOOR))
    return torch.tensor(values, dtype=DTYPE)


def raw_for(p: Problem, raw: Sequence[float]) -> list[float]:
    """A recorded raw vector sized to the problem: a learned noise added at its cold value where the record
    had none (a fit on spreads), dropped where the problem learns none."""
    size = 5 if p.learn_noise else 4
    values = list(raw[:size])
    if len(values) < size:
        values.append(inv_softplus(COLD_NOISE_VAR - NOISE_VAR_FLOOR))
    return values


def fit_problem(
    p: Problem, warm: Sequence[float] | None, max_iter: int, warm_max_iter: int
) -> tuple[torch.Tensor, int]:
    """Warm: one short L-BFGS run from the previous raw vector. Cold: a few deterministic starts, best kept."""
    if warm is not None:
        values = raw_for(p, warm)
        # an outputscale that went to ~0 on a few points has a vanishing gradient (softplus' tail): lift it,
        # or every later warm fit stays trapped in the "constant function" corner
        values[1] = max(values[1], inv_softplus(WARM_MIN_OUTPUTSCALE))
        values[2] = max(values[2], inv_softplus(WARM_MIN_LENGTHSCALE_EXCESS_UV))  # same at the floor
        values[3] = max(values[3], inv_softplus(WARM_MIN_LENGTHSCALE_EXCESS_UV))
        if p.learn_noise:
            values[4] = max(values[4], inv_softplus(WARM_MIN_NOISE_VAR))
        return optimise(p, torch.tensor(values, dtype=DTYPE), warm_max_iter)
    best: tuple[float, torch.Tensor] | None = None
    iterations = 0
    for lengthscale in COLD_LENGTHSCALES_UV:
        theta, it = optimise(p, cold_theta(lengthscale, p.floor_uv, p.learn_noise), max_iter)
        iterations += it
        value = p.objective(theta)
        if math.isfinite(value) and (best is None or value < best[0]):
            best = (value, theta)
    assert best is not None, "every start of the GP fit failed"
    return best[1], iterations

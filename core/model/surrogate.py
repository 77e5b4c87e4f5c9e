"""The heteroskedastic GP surrogate: hardness medians per tested centre, with a second GP for the noise.

The mean GP sees one robust value per executed local grid (the median of its g² indents) with a fixed
per-point noise eff·σ²(x)/n, where σ²(x) comes from the noise model (``core.model.noise``). Up to
``ski_above`` centres both GPs are exact (``core.model.exact``); above it, GPs interpolated on a 2-D
grid (KISS-GP, ``core.model.ski``) with the same noise, priors, refit schedule and guard. Decisions take 0.05 s at
100 centres and 0.2 s at 400 with the exact GP (benchmarks/decision_latency.py; benchmarks/scale.py beyond).
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import gpytorch
import numpy as np
import torch

from core.errors import InputError
from core.model.exact import ExactProblem, data_covariance, objective
from core.model.fitting import COLD_WIN_NATS, cold_search_due, fit_problem, optimisation_due
from core.model.guard import GUARDS, CollapseRule, GuardName, cold_search_confirms
from core.model.held_out import loo_residuals
from core.model.hyper import Hyperparameters, ModelKind, NoiseKind
from core.model.kernels import (
    DTYPE,
    MIN_NOISE_STD,
    KernelName,
    lengthscales_of,
    pair_sq_diffs,
    unpack,
)
from core.model.noise import MIN_SPREADS_FOR_GP, NoiseData, NoiseField, noise_data, noise_kind_for
from core.model.observations import Observations, pooled_var, spread_mask, standardise
from core.model.problem import Predictor, Problem
from core.model.ski import SKI_ABOVE, Grid, SkiConditioned, SkiProblem, grid_for

MAX_THREADS = 2  # torch intra-op threads; 1 is the default: on a busy 2-core machine a second thread
# mostly waits for a core (measured 3–5× slower decisions under load, no gain when idle)
REGRID_PASSES = 2  # refits on a grid that follows the length-scale (the interpolated GP)
PREDICT_CHUNK = 4096  # candidates per block of the predictive diagonal (fastest measured at n = 100–400)


@dataclass(frozen=True)
class Prediction:
    """The four fields of the paper's Figure 8, in GPa."""

    mean: np.ndarray
    epistemic_sd: np.ndarray  # sd of the latent hardness f
    noise_sd: np.ndarray  # per-indent noise sd σ(x) (what grid sizing uses)
    total_sd: np.ndarray  # sqrt(epistemic² + noise²)


@dataclass(frozen=True)
class FitReport:
    lengthscales_uv: tuple[float, float]
    noise_lengthscales_uv: tuple[float, float] | None
    outputscale: float  # prior variance of the latent field, GPa²
    mean_const: float  # GPa
    collapse: bool
    collapse_reason: str
    used_last_good: bool
    n_points: int
    iterations: int  # L-BFGS iterations, mean GP + noise GP
    seconds: float
    hyperparameters: Hyperparameters  # the hyperparameters in use: warm start, journal, resume

    @property
    def hyper(self) -> dict[str, Any]:
        """The journal's record of ``hyperparameters`` (JSON-able)."""
        return self.hyperparameters.to_json()

    @property
    def model(self) -> ModelKind:
        return self.hyperparameters.model


def _problem(model: ModelKind, grid: Grid, **fields: Any) -> Problem:
    return SkiProblem(**fields, grid=grid) if model == "ski" else ExactProblem(**fields)


class HeteroskedasticGP:
    """Mean GP on grid medians + noise GP on log within-grid variances, with a length-scale collapse guard."""

    def __init__(
        self,
        kernel: KernelName = "matern52",
        heteroskedastic: bool = True,
        lengthscale_floor_uv: float = 0.02,
        collapse_drop_ratio: float = 0.35,
        guard: GuardName = "keep-last-good",
        max_iter: int = 60,
        seed: int = 0,
        warm_max_iter: int | None = None,
        lengthscale_prior: bool = True,
        collapse_min_points: int = 8,
        threads: int = 1,
        nugget: bool = False,
        ski_above: int = SKI_ABOVE,
    ) -> None:
        if kernel not in ("matern52", "rbf"):
            raise InputError("surrogate.kernel", f"unknown kernel {kernel!r}; allowed: matern52, rbf")
        if guard not in GUARDS:
            raise InputError("surrogate.guard", f"unknown guard {guard!r}; allowed: {', '.join(GUARDS)}")
        if not 0.0 < lengthscale_floor_uv < 1.0:
            raise InputError(
                "surrogate.lengthscale_floor_uv", f"must be in (0, 1), got {lengthscale_floor_uv}"
            )
        if not 0.0 < collapse_drop_ratio < 1.0:
            raise InputError("surrogate.collapse_drop_ratio", f"must be in (0, 1), got {collapse_drop_ratio}")
        if max_iter < 1:
            raise InputError("surrogate.max_iter", f"must be >= 1, got {max_iter}")
        if ski_above < 1:
            raise InputError("surrogate.ski_above", f"must be >= 1, got {ski_above}")
        self.kernel: KernelName = kernel
        self.heteroskedastic = heteroskedastic
        self.floor_uv = float(lengthscale_floor_uv)
        self.collapse_drop_ratio = float(collapse_drop_ratio)
        self.guard: GuardName = guard
        self.max_iter = int(max_iter)
        self.warm_max_iter = int(warm_max_iter) if warm_max_iter is not None else max(10, self.max_iter // 3)
        self.seed = seed  # the fit draws no random numbers: kept for the record
        self.lengthscale_prior = bool(lengthscale_prior)
        self.collapse_min_points = int(collapse_min_points)
        self.collapse_rule = CollapseRule(self.floor_uv, self.collapse_drop_ratio, self.collapse_min_points)
        # learn a site-to-site variance on top of the within-grid noise: scatter between centres that the
        # spreads of tight grids cannot see (indent-scale heterogeneity) then needs no short length-scale
        self.nugget = bool(nugget)
        self.ski_above = int(ski_above)  # more centres than this: the inducing-point GP
        if not 1 <= threads <= MAX_THREADS:
            raise InputError("surrogate.threads", f"must be 1..{MAX_THREADS}, got {threads}")
        if torch.get_num_threads() != threads:
            torch.set_num_threads(threads)  # process-wide; the only torch user is this package
        self._hyper: Hyperparameters | None = None
        self._last_good: Hyperparameters | None = None
        self._mean: Predictor | None = None
        self._mean_problem: Problem | None = None
        self._noise = NoiseField(None)
        self._site_var_gpa2 = 0.0  # the learned site-to-site variance (nugget), GPa²
        self._y_loc = 0.0
        self._y_scale = 1.0

    # -- public -----------------------------------------------------------------------------------

    @property
    def hyper(self) -> dict[str, Any] | None:
        """The journal's record of the hyperparameters in use (JSON-able), or None before a fit."""
        return None if self._hyper is None else self._hyper.to_json()

    @property
    def hyperparameters(self) -> Hyperparameters | None:
        return self._hyper

    def model_for(self, n_points: int) -> ModelKind:
        """Which GP a data set of this size gets (deterministic in n: a resumed run chooses the same)."""
        return "ski" if n_points > self.ski_above else "exact"

    def fit(self, obs: Observations) -> FitReport:
        """Fit both GPs by (MAP) marginal likelihood, warm-started from the previous fit's hyperparameters."""
        t0 = time.perf_counter()
        if obs.n == 0:
            raise InputError("observations", "no tested centres to fit")
        prev = self._hyper
        compatible = prev is not None and prev.kernel == self.kernel
        model = self.model_for(obs.n)
        kind = noise_kind_for(obs, self.heteroskedastic)
        if (
            model == "ski"
            and compatible
            and prev is not None
            and prev.model == "ski"
            and prev.noise_kind == kind
            and not optimisation_due(obs.n, prev.fit_n)
            and not cold_search_due(obs.n, prev.cold_n)
        ):
            # between optimisations the interpolated GP conditions on the new data with the same
            # hyperparameters (deterministic in the record and the data: a resumed run does the same)
            hyper = replace(prev, n_points=obs.n)
            self._install(hyper, obs)
            return self._report(hyper, obs, False, "", False, 0, time.perf_counter() - t0)
        iterations = 0
        noise_raw: tuple[float, ...] | None = None
        if kind == "gp":
            warm_noise = prev.noise_raw if compatible and prev is not None else None
            pn = self._noise_problem(obs, model, warm_noise)[0]
            theta_n, it = fit_problem(pn, warm_noise, self.max_iter, self.warm_max_iter)
            theta_n, it = self._regrid(lambda raw: self._noise_problem(obs, model, raw)[0], pn, theta_n, it)
            iterations += it
            noise_raw = tuple(theta_n.tolist())
        warm_mean = prev.mean_raw if compatible and prev is not None else None
        pm = self._mean_problem_for(obs, model, kind, noise_raw, warm_mean)
        cold_n = prev.cold_n if compatible and prev is not None else 0
        cold_won = False
        theta_m, it = fit_problem(pm, warm_mean, self.max_iter, self.warm_max_iter)
        iterations += it
        if warm_mean is None:
            cold_n = obs.n
        elif cold_search_due(obs.n, cold_n):
            # deterministic in (obs, previous record): a resumed run makes the same choice
            theta_c, it = fit_problem(pm, None, self.max_iter, self.warm_max_iter)
            iterations += it
            warm_value, cold_value = pm.objective(theta_m), pm.objective(theta_c)
            if (warm_value - cold_value) * obs.n > COLD_WIN_NATS:
                theta_m = theta_c
                cold_won = True
            elif self.guard == "keep-last-good-unless-confirmed" and cold_search_confirms(
                pm, warm_mean, warm_value, cold_value, obs.n
            ):
                # the warm fit's slide is where the cold search lands too, and the data prefer it by more
                # than the margin to the kernel in use: the data's own choice (the grains' texture),
                # which keep-last-good would otherwise veto at every refit
                cold_won = True
            cold_n = obs.n
        theta_m, it = self._regrid(
            lambda raw: self._mean_problem_for(obs, model, kind, noise_raw, raw), pm, theta_m, 0
        )
        iterations += it
        hyper = Hyperparameters(
            kernel=self.kernel,
            lengthscale_floor_uv=self.floor_uv,
            mean_raw=tuple(theta_m.tolist()),
            noise_kind=kind,
            noise_raw=noise_raw,
            nugget=self.nugget,
            n_points=obs.n,
            cold_n=cold_n,
            model=model,
            fit_n=obs.n if model == "ski" else 0,
        )
        # a drop against the previous fit is a slide of the warm optimum; a cold start that wins on the
        # likelihood over 1.5× more data is the data's own choice, held only to the floor
        collapse, reason = self.collapse_rule.check(hyper, None if cold_won or not compatible else prev)
        used_last_good = False
        if collapse and self.guard != "off":
            if self._last_good is not None and self._last_good.kernel == self.kernel:
                hyper = hyper.with_kernel_of(self._last_good)
                used_last_good = True
                reason += "; kept the last good hyperparameters"
            else:
                reason += "; no earlier good fit to fall back to"
        self._install(hyper, obs)
        if not collapse:
            self._last_good = hyper
        return self._report(
            hyper, obs, collapse, reason, used_last_good, iterations, time.perf_counter() - t0
        )

    def condition(self, obs: Observations) -> FitReport | None:
        """Condition on ``obs`` with the hyperparameters in use, no optimisation, as the interpolated GP does
        between optimisations; None where that cannot be (no fit yet, another GP or noise model for this
        many points): then only ``fit`` will do. The record keeps its optimisation counters, so the next
        ``fit`` re-optimises as it would have here (a resumed run does the same)."""
        t0 = time.perf_counter()
        prev = self._hyper
        if (
            prev is None
            or obs.n == 0
            or prev.kernel != self.kernel
            or prev.model != self.model_for(obs.n)
            or prev.noise_kind != noise_kind_for(obs, self.heteroskedastic)
        ):
            return None
        hyper = replace(prev, n_points=obs.n)
        self._install(hyper, obs)
        return self._report(hyper, obs, False, "", False, 0, time.perf_counter() - t0)

    def set_hyper(self, hyper: dict[str, Any] | Hyperparameters, obs: Observations) -> None:
        """Condition on ``obs`` with the given hyperparameters (or their journal record), no optimisation:
        crash-resume."""
        record = hyper if isinstance(hyper, Hyperparameters) else Hyperparameters.from_json(hyper)
        if record.kernel != self.kernel or record.lengthscale_floor_uv != self.floor_uv:
            raise InputError(
                "surrogate.hyper",
                f"recorded for kernel {record.kernel} / floor {record.lengthscale_floor_uv}, "
                f"this model is {self.kernel} / {self.floor_uv}",
            )
        if record.nugget != self.nugget:
            raise InputError(
                "surrogate.hyper", f"recorded with nugget={record.nugget}, this model has {self.nugget}"
            )
        if obs.n == 0:
            raise InputError("observations", "no tested centres to condition on")
        if record.noise_kind == "gp" and int(np.sum(spread_mask(obs))) < MIN_SPREADS_FOR_GP:
            raise InputError(
                "surrogate.hyper", "has a noise GP but the observations have fewer than 3 spreads"
            )
        self._install(record, obs)
        self._last_good = record

    def predict(self, uv: np.ndarray) -> Prediction:
        """Mean, epistemic, noise and total sd at ``uv`` (m, 2): the predictive diagonal only, in chunks."""
        if self._mean is None:
            raise RuntimeError("HeteroskedasticGP.predict before fit() or set_hyper()")
        pts = np.array(uv, dtype=float)  # a private, writable copy for torch
        if pts.ndim != 2 or pts.shape[1] != 2:
            raise InputError("uv", f"expected shape (m, 2), got {pts.shape}")
        m = pts.shape[0]
        mean = torch.empty(m, dtype=DTYPE)
        var = torch.empty(m, dtype=DTYPE)
        noise_var = torch.empty(m, dtype=DTYPE)
        xs_all = torch.as_tensor(pts, dtype=DTYPE)
        with torch.no_grad():
            for start in range(0, m, PREDICT_CHUNK):
                xs = xs_all[start : start + PREDICT_CHUNK]
                mu, v = self._mean.mean_var(xs)
                mean[start : start + xs.shape[0]] = mu
                var[start : start + xs.shape[0]] = v
                noise_var[start : start + xs.shape[0]] = self._noise.var_at(xs)
        mean_gpa = mean.numpy() * self._y_scale + self._y_loc
        epi = np.sqrt(var.numpy()) * self._y_scale
        noise = np.sqrt(noise_var.numpy())
        return Prediction(
            mean=mean_gpa, epistemic_sd=epi, noise_sd=noise, total_sd=np.sqrt(epi**2 + noise**2)
        )

    def predict_noise_sd(self, uv: np.ndarray) -> np.ndarray:
        """The per-indent noise sd σ(x) (GPa) only: the noise model, without the mean GP's work."""
        if self._mean is None:
            raise RuntimeError("HeteroskedasticGP.predict_noise_sd before fit() or set_hyper()")
        xs = torch.as_tensor(np.array(uv, dtype=float).reshape(-1, 2), dtype=DTYPE)
        with torch.no_grad():
            return np.sqrt(self._noise.var_at(xs).numpy())

    def predict_mean(self, uv: np.ndarray) -> np.ndarray:
        """The posterior mean only (GPa): one kernel product, no variances (metrics on large lattices)."""
        if self._mean is None:
            raise RuntimeError("HeteroskedasticGP.predict_mean before fit() or set_hyper()")
        xs = torch.as_tensor(np.array(uv, dtype=float).reshape(-1, 2), dtype=DTYPE)
        parts = []
        with torch.no_grad():
            for start in range(0, len(xs), PREDICT_CHUNK):
                parts.append(self._mean.mean(xs[start : start + PREDICT_CHUNK]).numpy())
        mean = np.concatenate(parts) if parts else np.empty(0)
        return np.asarray(mean * self._y_scale + self._y_loc, dtype=float)

    def loo_residuals(self) -> tuple[np.ndarray, np.ndarray]:
        """Each centre's value less its prediction from the others (GPa), and that prediction's variance
        (GPa², noise included), hyperparameters held (``core.model.held_out``). The interpolated GP is read
        through its exact kernel at the centres (n × n: a few thousand centres at most)."""
        pm, hyper = self._mean_problem, self._hyper
        if pm is None or hyper is None:
            raise RuntimeError("HeteroskedasticGP.loo_residuals before fit() or set_hyper()")
        with torch.no_grad():
            u = unpack(torch.tensor(hyper.mean_raw, dtype=DTYPE), self.floor_uv, pm.learn_noise)
            k = data_covariance(pm, u, *pair_sq_diffs(pm.x))
            resid, var = loo_residuals(k, pm.y, torch.ones(pm.n, 1, dtype=DTYPE))
        return resid * self._y_scale, var * self._y_scale**2

    def latent_grid(self) -> tuple[Grid, np.ndarray, np.ndarray]:
        """The interpolated GP's posterior over its grid values in GPa: (grid, mean (m,), covariance (m, m)).

        The latent map at x is wₓᵀ g (the cubic weights sum to one), so a model built on this GP (the
        two-fidelity model's fast channel) can carry its whole posterior, not only its diagonal.
        """
        if not isinstance(self._mean, SkiConditioned):
            raise RuntimeError("HeteroskedasticGP.latent_grid needs a fitted interpolated (ski) GP")
        mean = (self._mean.grid_mean.numpy() + self._mean.constant) * self._y_scale + self._y_loc
        return self._mean.grid, mean, self._mean.grid_cov.numpy() * self._y_scale**2

    @property
    def model(self) -> ModelKind | None:
        """The GP in use ("exact" or "ski"), None before a fit."""
        return None if self._hyper is None else self._hyper.model

    @property
    def site_var_gpa2(self) -> float:
        return self._site_var_gpa2

    @property
    def site_sd_gpa(self) -> float:
        """Scatter between centres beyond their indents' noise (0 without a nugget): more indents per
        centre do not average it away, so grid sizing ignores it."""
        return math.sqrt(self._site_var_gpa2)

    @property
    def outputscale_gpa2(self) -> float | None:
        """Prior variance of the latent map in GPa² (None before a fit): planners that need covariances."""
        return None if self._mean is None else float(self._mean.outputscale * self._y_scale**2)

    def reference_latent(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Latent mean and variance (GPa, GPa²) by gpytorch's default predictive path: slow; tests and benchmarks."""
        model = self._exact_model("reference_latent")
        model.eval()
        xs = torch.as_tensor(np.asarray(uv, dtype=float), dtype=DTYPE)
        try:
            with torch.no_grad(), warnings.catch_warnings():
                warnings.simplefilter("ignore")
                post = model(xs)
                mean = post.mean.numpy() * self._y_scale + self._y_loc
                var = post.variance.numpy() * self._y_scale**2
        finally:
            model.train()
        return mean, var

    def reference_neg_mll(self) -> tuple[float, float]:
        """(this package's objective, gpytorch's −ExactMarginalLogLikelihood) at the hyperparameters in use."""
        model = self._exact_model("reference_neg_mll")
        assert isinstance(self._mean_problem, ExactProblem) and self._hyper is not None
        x, y = model.train_inputs[0], model.train_targets
        ours = objective(self._mean_problem, torch.tensor(self._hyper.mean_raw, dtype=DTYPE))
        model.train()
        mll = gpytorch.mlls.ExactMarginalLogLikelihood(model.likelihood, model)
        with torch.no_grad(), gpytorch.settings.max_cholesky_size(100_000):
            theirs = float(-mll(model(x), y))
        return ours, theirs

    # -- data and noise model ---------------------------------------------------------------------

    def _exact_model(self, what: str) -> Any:
        if self._mean is None or self._hyper is None:
            raise RuntimeError(f"HeteroskedasticGP.{what} before fit() or set_hyper()")
        model = getattr(self._mean, "model", None)
        if model is None:
            raise RuntimeError(
                f"HeteroskedasticGP.{what}: the exact GP's reference, not the {self.model} GP's"
            )
        return model

    def _grid(self, raw: Sequence[float] | None) -> Grid:
        """The interpolated GP's grid for a raw vector (None: before any fit)."""
        return grid_for(None if raw is None else lengthscales_of(raw, self.floor_uv))

    def _regrid(
        self, make: Callable[[Sequence[float]], Problem], p: Problem, theta: torch.Tensor, iterations: int
    ) -> tuple[torch.Tensor, int]:
        """An interpolated GP fitted on a grid too coarse (or needlessly fine) for the length-scale it found
        is fitted again, warm, on the grid for it; twice at most (deterministic: resume does the same)."""
        for _ in range(REGRID_PASSES):
            if not isinstance(p, SkiProblem) or self._grid(theta.tolist()) == p.grid:
                break
            p = make(theta.tolist())
            theta, it = fit_problem(p, theta.tolist(), self.max_iter, self.warm_max_iter)
            iterations += it
        return theta, iterations

    def _noise_problem(
        self, obs: Observations, model: ModelKind, raw: Sequence[float] | None
    ) -> tuple[Problem, NoiseData]:
        data = noise_data(obs)
        problem = _problem(
            model,
            self._grid(raw),
            kernel=self.kernel,
            floor_uv=self.floor_uv,
            with_prior=self.lengthscale_prior,
            x=data.x,
            y=data.target,
            noise_fixed=data.target_var,
            noise_scale=torch.ones_like(data.target),
        )
        return problem, data

    def _mean_problem_for(
        self,
        obs: Observations,
        model: ModelKind,
        kind: NoiseKind,
        noise_raw: tuple[float, ...] | None,
        mean_raw: Sequence[float] | None,
    ) -> Problem:
        """The mean GP's data; its fixed per-centre noise eff·σ²(x_i)/n_i comes from the noise model."""
        self._y_loc, self._y_scale = standardise(obs.median_gpa)
        y = torch.as_tensor((obs.median_gpa - self._y_loc) / self._y_scale, dtype=DTYPE)
        x = torch.as_tensor(obs.uv, dtype=DTYPE)
        assert obs.efficiency is not None
        scale = torch.as_tensor(obs.efficiency / obs.n_indents, dtype=DTYPE)
        fixed: torch.Tensor | None = None
        self._noise = NoiseField(None)
        if kind == "gp":
            assert noise_raw is not None
            pn, data = self._noise_problem(obs, model, noise_raw)
            gp = pn.condition(torch.tensor(noise_raw, dtype=DTYPE))
            self._noise = NoiseField(gp, data.loc, data.scale)
            with torch.no_grad():
                var_gpa2 = self._noise.var_at(x)
            fixed = scale * var_gpa2 / self._y_scale**2
        elif kind == "pooled":
            fixed = scale * pooled_var(obs) / self._y_scale**2
        if fixed is not None:
            fixed = fixed.clamp_min(MIN_NOISE_STD)
        return _problem(
            model,
            self._grid(mean_raw),
            kernel=self.kernel,
            floor_uv=self.floor_uv,
            with_prior=self.lengthscale_prior,
            x=x,
            y=y,
            noise_fixed=fixed,
            noise_scale=scale,
            nugget=self.nugget,
        )

    def _install(self, hyper: Hyperparameters, obs: Observations) -> None:
        """Condition on ``obs`` with ``hyper``: the one path shared by fit and set_hyper (resume is bit-identical)."""
        pm = self._mean_problem_for(obs, hyper.model, hyper.noise_kind, hyper.noise_raw, hyper.mean_raw)
        theta = torch.tensor(hyper.mean_raw, dtype=DTYPE)
        self._mean = pm.condition(theta)
        self._mean_problem = pm
        if hyper.noise_kind == "pooled":
            self._noise = replace(self._noise, constant_var_gpa2=pooled_var(obs))
        elif hyper.noise_kind == "learned":
            u = unpack(theta, self.floor_uv, True)
            assert u.noise_var is not None
            self._noise = replace(self._noise, constant_var_gpa2=float(u.noise_var) * self._y_scale**2)
        self._site_var_gpa2 = 0.0
        if pm.nugget and pm.noise_fixed is not None:
            u = unpack(theta, self.floor_uv, True)
            assert u.noise_var is not None
            self._site_var_gpa2 = float(u.noise_var) * self._y_scale**2
        self._hyper = hyper

    def _report(
        self,
        hyper: Hyperparameters,
        obs: Observations,
        collapse: bool,
        reason: str,
        used_last_good: bool,
        iterations: int,
        seconds: float,
    ) -> FitReport:
        assert self._mean is not None
        ls = hyper.lengthscales_uv
        return FitReport(
            lengthscales_uv=(float(ls[0]), float(ls[1])),
            noise_lengthscales_uv=self._noise.lengthscales_uv,
            outputscale=self._mean.outputscale * self._y_scale**2,
            mean_const=self._mean.constant * self._y_scale + self._y_loc,
            collapse=collapse,
            collapse_reason=reason,
            used_last_good=used_last_good,
            n_points=obs.n,
            iterations=iterations,
            seconds=seconds,
            hyperparameters=hyper,
        )

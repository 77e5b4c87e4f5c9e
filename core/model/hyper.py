"""The hyperparameters of a fit, typed, and their codec to and from the journal's JSON record.

The journal stores the record ``to_json`` writes (version 1, the same keys as journals written before the
model became a package, so those still resume); ``from_json`` reads it back or names what is wrong.
Raw values are in the optimiser's unconstrained space and standardised units: [constant, outputscale,
ℓu, ℓv(, learned noise variance)], mapped through softplus as gpytorch's ``GreaterThan`` does.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, Literal, get_args

from core.errors import InputError
from core.model.kernels import KernelName, lengthscales_of

HYPER_VERSION = 1
NoiseKind = Literal["gp", "pooled", "learned"]  # a noise GP on the spreads, their pooled variance, or learned
ModelKind = Literal["exact", "ski"]  # the exact GP, or the interpolated (KISS-GP) one for large designs
NOISE_KINDS: tuple[NoiseKind, ...] = get_args(NoiseKind)
MODEL_KINDS: tuple[ModelKind, ...] = get_args(ModelKind)
_FIELD = "surrogate.hyper"


@dataclass(frozen=True)
class Hyperparameters:
    """One fit's hyperparameters: everything needed to condition the same model again (crash-resume)."""

    kernel: KernelName
    lengthscale_floor_uv: float
    mean_raw: tuple[float, ...]
    noise_kind: NoiseKind
    noise_raw: tuple[float, ...] | None  # the noise GP's raw vector (noise_kind "gp" only)
    nugget: bool
    n_points: int
    cold_n: int = 0  # data size at the last cold search (the refit schedule's clock)
    restored_from_n_points: int | None = None  # the guard kept the kernel of the fit on this many points
    model: ModelKind = "exact"
    fit_n: int = 0  # data size at the last optimisation (the interpolated GP re-optimises on growth only)

    @property
    def lengthscales_uv(self) -> tuple[float, float]:
        return lengthscales_of(self.mean_raw, self.lengthscale_floor_uv)

    def with_kernel_of(self, good: Hyperparameters) -> Hyperparameters:
        """This record with the mean GP's kernel from ``good`` (the guard's fallback); the noise stays."""
        raw = tuple(good.mean_raw[:4]) + tuple(self.mean_raw[4:])
        return replace(self, mean_raw=raw, restored_from_n_points=good.n_points)

    def to_json(self) -> dict[str, Any]:
        noise: dict[str, Any] = {"kind": self.noise_kind}
        if self.noise_raw is not None:
            noise["raw"] = list(self.noise_raw)
        record: dict[str, Any] = {
            "version": HYPER_VERSION,
            "kernel": self.kernel,
            "lengthscale_floor_uv": self.lengthscale_floor_uv,
            "mean": {"raw": list(self.mean_raw)},
            "noise": noise,
            "nugget": self.nugget,
            "lengthscales_uv": list(self.lengthscales_uv),  # derived, for people reading the journal
            "n_points": self.n_points,
            "cold_n": self.cold_n,
        }
        if self.restored_from_n_points is not None:
            record["restored_from_n_points"] = self.restored_from_n_points
        if self.model != "exact":  # absent in records of the exact GP, as before the interpolated GP existed
            record["model"] = self.model
            record["fit_n"] = self.fit_n
        return record

    @classmethod
    def from_json(cls, record: object) -> Hyperparameters:
        if not isinstance(record, dict) or record.get("version") != HYPER_VERSION:
            raise InputError(_FIELD, f"not a version-{HYPER_VERSION} hyperparameter record")
        try:
            kernel = record["kernel"]
            floor = float(record["lengthscale_floor_uv"])
            mean_raw = _raw(record["mean"]["raw"], "mean.raw")
            noise = record["noise"]
            kind = noise["kind"]
            noise_raw = _raw(noise["raw"], "noise.raw") if "raw" in noise else None
            n_points = int(record.get("n_points", 0))
            cold_n = int(record.get("cold_n", 0))
            restored = record.get("restored_from_n_points")
            model = record.get("model", "exact")
            fit_n = int(record.get("fit_n", 0))
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(_FIELD, f"malformed hyperparameter record: {exc!r}") from None
        if kernel not in ("matern52", "rbf"):
            raise InputError(_FIELD, f"unknown kernel {kernel!r}")
        if kind not in NOISE_KINDS:
            raise InputError(_FIELD, f"unknown noise kind {kind!r}")
        if len(mean_raw) not in (4, 5):
            raise InputError(_FIELD, f"mean.raw has {len(mean_raw)} values, expected 4 or 5")
        if (kind == "gp") != (noise_raw is not None):
            raise InputError(_FIELD, "a noise GP record needs noise.raw, and only it")
        if model not in MODEL_KINDS:
            raise InputError(_FIELD, f"unknown model {model!r}")
        return cls(
            kernel=kernel,
            lengthscale_floor_uv=floor,
            mean_raw=mean_raw,
            noise_kind=kind,
            noise_raw=noise_raw,
            nugget=bool(record.get("nugget", False)),
            n_points=n_points,
            cold_n=cold_n,
            restored_from_n_points=None if restored is None else int(restored),
            model=model,
            fit_n=fit_n,
        )


def _raw(values: object, name: str) -> tuple[float, ...]:
    if not isinstance(values, list) or not all(isinstance(v, int | float) for v in values):
        raise InputError(_FIELD, f"{name} must be a list of numbers")
    raw = tuple(float(v) for v in values)
    if not all(math.isfinite(v) for v in raw):
        raise InputError(_FIELD, f"{name} has non-finite values")
    return raw

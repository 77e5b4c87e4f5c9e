"""Emulator scenarios: each is a built-in sample plus a truth field, a drift model and lateral scatter.

``aeni simulate``, ``aeni demo`` and ``aeni bench`` run on these. A scenario's truth can be laid onto any
sample (``Scenario.on_sample``), so the simulated instrument can stand in for a real sample file.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

from core.errors import InputError
from core.geometry import Calibration
from core.profile import InstrumentProfile, load_profile
from core.sample import Sample
from drivers.sim.drift import DRIFT_SCENARIOS, DriftModel
from drivers.sim.driver import SimulatedDriver
from drivers.sim.emulator import Emulator
from drivers.sim.evaluator import TruthEvaluator
from drivers.sim.failures import FailureModes
from drivers.sim.fields import (
    EdgeSpotField,
    PhaseBoundaryField,
    QuaternaryFilm,
    RotatedQuaternaryField,
    RoughField,
    SiteTexture,
    TernaryField,
)
from drivers.sim.laid import LaidTruth
from drivers.sim.truth import (
    Bounds,
    NoiseOverride,
    TruthField,
    check_noise_mode,
    check_seed,
)
from drivers.sim.truth_csv import CsvTruth

# the share of indents a scenario's simulated instrument fails by default (drivers.sim.failures) when a run
# names no rate: none, so `aeni simulate` repeats `aeni run` of the same seed indent for indent
SCENARIO_FAILURE_RATE: dict[str, float] = {}

# scenario samples: the whole square is usable (no edge band, no exclusions), as in the paper's studies
SCENARIO_EDGE_BAND_UM = 0.0


def builtin_sample(name: str, calibration: Calibration, profile: str, lattice_n: int) -> Sample:
    """The sample a scenario runs on: its calibrated rectangle, the SPEC's default safety distances."""
    return Sample(
        name=f"scenario:{name}",
        profile=profile,
        calibration=calibration,
        lattice_n=lattice_n,
        edge_band_um=SCENARIO_EDGE_BAND_UM,
        source=f"built-in scenario {name}",
    )


@dataclass(frozen=True)
class Scenario:
    """A built-in sample plus a truth field: everything the simulated instrument needs for a study.

    The campaign sees only ``sample``; ``truth``, ``drift`` and the rest stay in the simulated instrument.
    """

    name: str
    truth: TruthField
    drift: DriftModel
    sample: Sample
    lateral_sd_um: float
    description: str
    seed: int = 0
    site_texture: SiteTexture | None = None
    failures: FailureModes = field(
        default_factory=FailureModes
    )  # how often the simulated instrument fails, as a real one does

    @property
    def calibration(self) -> Calibration:
        return self.sample.calibration

    @property
    def profile_name(self) -> str:
        return self.sample.profile

    @property
    def lattice_n(self) -> int:
        return self.sample.lattice_n

    def make_emulator(self, profile: InstrumentProfile | None = None) -> Emulator:
        """The measurement physics; a full hold is the profile's longest (its drift segment corrects fully).

        A profile without holds (fast indents) corrects nothing: any hold is measured against the iMicro's.
        """
        profile = profile or load_profile(self.profile_name)
        longest = max(profile.allowed_holds_s)
        return Emulator(
            self.truth,
            self.drift,
            self.seed,
            lateral_sd_um=self.lateral_sd_um,
            t_measure_s=profile.drift_segment_s,
            full_correction_hold_s=longest if longest > 0 else max(InstrumentProfile.allowed_holds_s),
            site_texture=self.site_texture,
        )

    def on_sample(self, sample: Sample) -> Scenario:
        """This scenario's truth laid onto another sample's geometry (its unit square onto the sample's)."""
        if sample.calibration.corners == self.sample.calibration.corners:
            return replace(self, sample=sample)
        return replace(self, truth=LaidTruth(self.truth, sample.calibration), sample=sample)

    def make_driver(
        self,
        profile: InstrumentProfile,
        speed: float | None = None,
        start_um: tuple[float, float] | None = None,
    ) -> SimulatedDriver:
        """The simulated instrument for this scenario, starting over the sample's centre."""
        if start_um is None:
            x0, x1, y0, y1 = self.sample.calibration.bounds_um
            start_um = ((x0 + x1) / 2.0, (y0 + y1) / 2.0)
        return SimulatedDriver(
            self.make_emulator(profile), profile, speed=speed, start_um=start_um, failures=self.failures
        )

    def evaluator(self, n: int = 100) -> TruthEvaluator:
        """The map-error scorer for a campaign on this scenario (the truth never reaches the campaign)."""
        return TruthEvaluator.for_truth(self.truth, self.sample.calibration, n)


SCENARIOS: dict[str, str] = {
    "ternary": "the paper's ternary library, 1000 µm square, heteroskedastic noise (~1.5 % of max H), no drift",
    "ternary-good-drift": "ternary library with good drift: small events (~0.3 nm/s) that recover in minutes",
    "ternary-bad-drift": "ternary library with bad drift: large events (~1 nm/s) that decay over about an hour",
    "film": "Ta–Ti–Hf–Zr-like film, 5 × 3 mm at stage (10, 20) mm, noise up to 10 % of max H, good drift",
    "phase-boundary": "two smooth phases split by a sharp curved boundary (~2 GPa over ~10 µm)",
    "edge-spot": "ternary library plus a small hard spot (+2 GPa, ~60 µm radius) near the right edge",
    "rotated-quaternary": "four-component spread with gradient axes rotated 30° from the stage axes",
    "rough": "smooth trend plus seeded multi-scale correlated roughness (a real-looking map)",
    "collapse": (
        "ternary library with indent-scale heterogeneity (0.1 GPa over ~40 µm) that within-grid spreads"
        " cannot see: provokes length-scale collapse"
    ),
    "wafer-library": (
        "the ternary library spread over a 50 × 50 mm wafer, a 200 × 200 candidate lattice, fast indents"
        " (kla-nanoblitz profile, ~1 s, no hold): a design of thousands of centres"
    ),
    "csv": (
        "ground truth read from a CSV file (x_um, y_um, hardness_gpa[, noise_sd_gpa, modulus_gpa,"
        " modulus_noise_sd_gpa])"
    ),
}

# surface tilt (µm of z per µm of stage): gentle on the 1000 µm square, steeper on the film so that a 5 µm
# safe band is ~450 µm wide there
_TILT_SQUARE = (0.005, 0.007)
_TILT_FILM = (0.02, 0.01)
_Z_MID_UM = 1500.0
_WAFER_SIDE_UM = 50_000.0  # the large scenario: a 50 × 50 mm library (same total height change as the square)
# the collapse provocation's site texture: larger than the median of a 5×5 grid can average (≈ 0.03 GPa),
# shared by every indent of a 20 µm grid, independent between centres 100 µm apart
_COLLAPSE_SITE_SD_GPA = 0.1
_COLLAPSE_SITE_SCALE_UM = 40.0


def _calibration_for(bounds: Bounds, tilt: tuple[float, float]) -> Calibration:
    x_min, x_max, y_min, y_max = bounds
    a, b = tilt
    c = _Z_MID_UM - a * 0.5 * (x_min + x_max) - b * 0.5 * (y_min + y_max)
    return Calibration.rectangle(x_min, y_min, x_max - x_min, y_max - y_min, z_plane=(a, b, c))


def make_scenario(
    name: str,
    seed: int,
    noise: str | None = None,
    drift: str | None = None,
    truth_csv: str | None = None,
    lateral_sd_um: float | None = None,
    failure_rate: float | None = None,
) -> Scenario:
    """Build a named scenario; ``noise``, ``drift``, ``lateral_sd_um`` and ``failure_rate`` (the simulated
    instrument's failures, drivers.sim.failures) override its defaults."""
    if name not in SCENARIOS:
        raise InputError("scenario", f"unknown scenario {name!r} (known: {', '.join(SCENARIOS)})")
    seed = check_seed(seed)
    if noise is not None:
        check_noise_mode(noise)
    if drift is not None and drift not in DRIFT_SCENARIOS:
        raise InputError("drift", f"unknown drift scenario {drift!r} (known: {', '.join(DRIFT_SCENARIOS)})")
    if lateral_sd_um is not None and not (math.isfinite(lateral_sd_um) and lateral_sd_um >= 0):
        raise InputError("lateral_sd_um", f"must be a finite number ≥ 0, got {lateral_sd_um!r}")
    if name == "csv" and not truth_csv:
        raise InputError("truth_csv", "scenario 'csv' needs a truth CSV file")
    if name != "csv" and truth_csv:
        raise InputError("truth_csv", f"a truth CSV is only used by scenario 'csv', not {name!r}")

    profile, lattice_n, default_drift, lateral, tilt = "kla-imicro", 100, "none", 0.0, _TILT_SQUARE
    truth: TruthField
    site_texture: SiteTexture | None = None
    if name in ("ternary", "ternary-good-drift", "ternary-bad-drift", "collapse"):
        truth = TernaryField(1000.0, noise or "hetero")
        default_drift = {"ternary-good-drift": "good", "ternary-bad-drift": "bad"}.get(name, "none")
        if name == "collapse":
            site_texture = SiteTexture(_COLLAPSE_SITE_SD_GPA, _COLLAPSE_SITE_SCALE_UM, seed)
    elif name == "edge-spot":
        truth = EdgeSpotField(1000.0, noise or "hetero")
    elif name == "wafer-library":
        truth = TernaryField(_WAFER_SIDE_UM, noise or "hetero")
        profile, lattice_n = "kla-nanoblitz", 200
        tilt = (_TILT_SQUARE[0] * 1000.0 / _WAFER_SIDE_UM, _TILT_SQUARE[1] * 1000.0 / _WAFER_SIDE_UM)
    else:
        if name == "film":
            truth = QuaternaryFilm()
            profile, lattice_n, default_drift, lateral, tilt = "kla-imicro-film", 50, "good", 1.0, _TILT_FILM
        elif name == "phase-boundary":
            truth = PhaseBoundaryField()
        elif name == "rotated-quaternary":
            truth = RotatedQuaternaryField()
        elif name == "rough":
            truth = RoughField(seed=seed)
        else:
            assert truth_csv is not None
            truth = CsvTruth.from_file(truth_csv)
            x_min, x_max, y_min, y_max = truth.bounds_um
            span = max(x_max - x_min, y_max - y_min)
            lattice_n = 100 if span <= 2000.0 else 50
            tilt = (_TILT_SQUARE[0] * 1000.0 / span, _TILT_SQUARE[1] * 1000.0 / span)
        if noise is not None and noise != "hetero":
            truth = NoiseOverride(truth, noise)
    drift_name = drift or default_drift
    description = SCENARIOS[name]
    if noise is not None or drift is not None:
        description += f" [noise {noise or 'default'}, drift {drift_name}]"
    return Scenario(
        name=name,
        truth=truth,
        drift=DriftModel.scenario(drift_name, seed),
        sample=builtin_sample(name, _calibration_for(truth.bounds_um, tilt), profile, lattice_n),
        lateral_sd_um=lateral if lateral_sd_um is None else float(lateral_sd_um),
        description=description,
        seed=seed,
        site_texture=site_texture,
        failures=FailureModes.at_rate(
            SCENARIO_FAILURE_RATE.get(name, 0.0) if failure_rate is None else failure_rate, seed
        ),
    )

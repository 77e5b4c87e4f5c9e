"""Instrument profiles: every step time and the move-time model, loaded from TOML.

Numbers live in profiles, never in code, so a lab can calibrate its own stage.
"""

from __future__ import annotations

import csv
import math
import tomllib
from dataclasses import dataclass, fields, replace
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from core.drift import DRIFT_READING_FLOOR_NM_S, DRIFT_SEGMENT_S
from core.errors import InputError

BUILTIN_PROFILES = ("kla-imicro", "kla-imicro-film", "kla-nanoblitz")


@dataclass(frozen=True)
class MoveModel:
    """Seconds to move one stage axis by d µm: exponential below the breakpoint, linear beyond."""

    short_a: float = 4196.41
    short_b: float = 4.99e-7
    short_c: float = 4195.05
    long_slope: float = 1.53e-4
    long_intercept: float = 2.60
    breakpoint_um: float = 500.0

    def axis_s(self, d_um: float) -> float:
        d = abs(d_um)
        if d < self.breakpoint_um:
            return self.short_a * math.exp(self.short_b * d) - self.short_c
        return self.long_slope * d + self.long_intercept

    def axis_s_array(self, d_um: np.ndarray) -> np.ndarray:
        d = np.abs(np.asarray(d_um, dtype=float))
        short = self.short_a * np.exp(self.short_b * d) - self.short_c
        long = self.long_slope * d + self.long_intercept
        return np.where(d < self.breakpoint_um, short, long)


@dataclass(frozen=True)
class InViewSettings:
    """How this lab's InView takes an array and names its methods: the KLA file exchange's conventions.

    The array dialog imports ``x, y`` offsets in µm from the crosshair; its axes need not be the stage's.
    The default flips Y (InView counts array Y down the camera image, the stage counts it up); a lab checks
    its own with a 3-site test block (docs/kla.md) and sets the signs here.
    """

    methods: tuple[tuple[float, str], ...] = (
        (0.0, "AENI hold 0 s.nmt"),
        (5.0, "AENI hold 5 s.nmt"),
        (80.0, "AENI hold 80 s.nmt"),
    )
    array_x_sign: int = 1
    array_y_sign: int = -1
    array_swap_xy: bool = False
    position_tolerance_um: float = 3.0  # an export row must lie this close to its planned site
    stable_polls: int = 3  # an export counts as complete when size and mtime hold for this many polls
    poll_s: float = 1.0
    deadline_factor: float = 1.5  # deadline = estimate × factor + margin
    deadline_margin_s: float = 180.0

    def method_for(self, hold_s: float) -> str:
        for hold, name in self.methods:
            if math.isclose(hold, hold_s):
                return name
        raise InputError("inview.methods", f"no InView method for a {hold_s:g} s hold")


@dataclass(frozen=True)
class FastMode:
    """The instrument's fast-array option (NanoBlitz-class, SPEC §9): load-controlled indents in seconds.

    An array is ``rows × cols`` indents at a pitch, run column by column; it pays one program opening, one
    surface find and one drift settle (the profile's ``steps.engage_s`` and ``steps.drift_settle_s``, when
    ``surface_find`` and ``drift_settle`` say it needs them), then ``indent_s`` per indent (the step to the
    next site included) and ``column_change_s`` more at each change of column.
    """

    indent_s: float
    column_change_s: float
    max_extent_um: float  # the largest side of one array (first to last site)
    min_pitch_um: float  # the closest two sites of an array may be
    peak_load_mn: float
    surface_find: bool
    drift_settle: bool
    # the InView test method an array runs (the KLA driver's fast ticket names it); the default is the name
    # kla-imicro gives it, for journals and code written before the field
    method: str = "NanoBlitz 3D.nmt"


_FAST_NUMBERS = {"indent_s", "column_change_s", "max_extent_um", "min_pitch_um", "peak_load_mn"}
_FAST_FLAGS = {"surface_find", "drift_settle"}
_FAST_TEXTS = {"method"}


@dataclass(frozen=True)
class InstrumentProfile:
    name: str = "kla-imicro"
    description: str = ""
    lift_s: float = 30.0
    engage_s: float = 65.0
    drift_settle_s: float = 300.0
    comeback_s: float = 35.0
    setup_s: float = 20.0
    lens_travel_s: float = 20.0
    indent_base_s: float = 40.0
    default_hold_s: float = 80.0
    allowed_holds_s: tuple[float, ...] = (0.0, 5.0, 80.0)
    global_jump_s: float | None = None
    move: MoveModel = MoveModel()
    reconfig_threshold_um: float = 1000.0
    reconfig_lift_s: float = 25.0
    reconfig_engage_s: float = 65.0
    reconfig_drift_s: float = 300.0
    reverse_x: bool = True
    # steepest sample plane the stage can follow (µm of height per mm of travel): a sample file whose corner
    # heights imply more is refused (mis-read z, or a sample not lying flat)
    max_tilt_um_per_mm: float = 50.0
    # the stage's XY travel from its origin (µm): a position beyond it cannot be on this stage (a flag in mm that
    # is beyond it was typed in µm). Assumption to check against the stage's manual: the paper mounts a 100 mm
    # wafer on the iMicro (SPEC §IV's film), so the travel is at least that; 150 mm leaves room for the holder.
    stage_travel_um: float = 150_000.0
    # drift readings below this are the meter's noise, not drift: the correction leaves them alone
    drift_noise_floor_nm_s: float = DRIFT_READING_FLOOR_NM_S
    # the test method's drift segment (s): the time over which Eq. 7's drift displaces the measured depth
    drift_segment_s: float = DRIFT_SEGMENT_S
    inview: InViewSettings = InViewSettings()
    # the fast-array option (NanoBlitz-class): None when the instrument has none (a profile without [fast])
    fast: FastMode | None = None

    @property
    def reconfiguration_s(self) -> float:
        """The safety-rule penalty for one ≥ threshold hop (390 s on the iMicro)."""
        return self.reconfig_lift_s + self.reconfig_engage_s + self.reconfig_drift_s

    @property
    def global_overhead_s(self) -> float:
        """Fixed seconds a new program costs, excluding moves (what a global jump pays)."""
        if self.global_jump_s is not None:
            return self.global_jump_s
        return self.itemised_program_s

    @property
    def itemised_program_s(self) -> float:
        """A new program's fixed steps added up: comeback, setup, lens travel, lift, engage, drift settle."""
        return (
            self.comeback_s
            + self.setup_s
            + self.lens_travel_s
            + self.lift_s
            + self.engage_s
            + self.drift_settle_s
        )

    def move_s(self, dx_um: float, dy_um: float) -> float:
        """Seconds for a stage move between two indents: t(|dx|) + t(|dy|), 0 when not moving."""
        if dx_um == 0.0 and dy_um == 0.0:
            return 0.0
        return self.move.axis_s(dx_um) + self.move.axis_s(dy_um)

    def needs_reconfiguration(self, dx_um: float, dy_um: float) -> bool:
        t = self.reconfig_threshold_um
        return abs(dx_um) >= t or abs(dy_um) >= t

    @property
    def fast_hold_s(self) -> float:
        """The adaptive hold's fast choice: the shortest allowed hold that still reads the drift (> 0 s)."""
        return min((h for h in self.allowed_holds_s if h > 0), default=self.default_hold_s)

    def indent_s(self, hold_s: float) -> float:
        return self.indent_base_s + hold_s

    def check_stage_mm(self, value_mm: float, flag: str) -> float:
        """A stage coordinate given in mm (``aeni kla check --x-mm``): refused beyond the stage's travel."""
        if not math.isfinite(value_mm):
            raise InputError(flag, f"{value_mm!r} is not a stage position in mm")
        travel_mm = self.stage_travel_um / 1000.0
        if abs(value_mm) <= travel_mm:
            return value_mm
        hint = f"; it looks like µm: {value_mm / 1000.0:g} mm?" if abs(value_mm) / 1000.0 <= travel_mm else ""
        raise InputError(
            flag,
            f"{value_mm:g} mm is beyond the stage's {travel_mm:g} mm travel (profile {self.name}, "
            f"stage.travel_um){hint}",
        )

    def check_hold(self, hold_s: float, source: str = "hold_s") -> float:
        if not any(math.isclose(hold_s, h) for h in self.allowed_holds_s):
            allowed = ", ".join(f"{h:g}" for h in self.allowed_holds_s)
            raise InputError(source, f"hold {hold_s:g} s is not one of the profile's holds ({allowed})")
        return hold_s


_STEP_FIELDS = {
    "lift_s",
    "engage_s",
    "drift_settle_s",
    "comeback_s",
    "setup_s",
    "lens_travel_s",
    "indent_base_s",
    "default_hold_s",
    "allowed_holds_s",
    "global_jump_s",
}
_MOVE_FIELDS = {f.name for f in fields(MoveModel)}
_RECONF_MAP = {
    "threshold_um": "reconfig_threshold_um",
    "lift_s": "reconfig_lift_s",
    "engage_s": "reconfig_engage_s",
    "drift_s": "reconfig_drift_s",
}


def _number(source: str, key: str, value: Any, *, positive: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise InputError(source, f"field {key} must be a finite number, got {value!r}")
    if value < 0 or (positive and value == 0):
        raise InputError(source, f"field {key} must be {'> 0' if positive else '≥ 0'}, got {value!r}")
    return float(value)


def _apply(base: InstrumentProfile, data: dict[str, Any], source: str) -> InstrumentProfile:
    known = {
        "name",
        "description",
        "extends",
        "steps",
        "move",
        "reconfiguration",
        "display",
        "stage",
        "drift",
        "inview",
        "fast",
    }
    for key in data:
        if key not in known:
            raise InputError(
                source, f"unknown section or field {key!r} (allowed: {', '.join(sorted(known))})"
            )
    updates: dict[str, Any] = {}
    if "name" in data:
        if not isinstance(data["name"], str) or not data["name"].strip():
            raise InputError(source, "field name must be a non-empty string")
        updates["name"] = data["name"]
    if "description" in data:
        updates["description"] = str(data["description"])
    steps = data.get("steps", {})
    if not isinstance(steps, dict):
        raise InputError(source, "[steps] must be a table")
    for key, value in steps.items():
        if key not in _STEP_FIELDS:
            raise InputError(
                source, f"unknown field steps.{key} (allowed: {', '.join(sorted(_STEP_FIELDS))})"
            )
        if key == "allowed_holds_s":
            if not isinstance(value, list) or not value:
                raise InputError(source, "field steps.allowed_holds_s must be a non-empty list of seconds")
            updates[key] = tuple(sorted(_number(source, f"steps.{key}", v) for v in value))
        elif key == "global_jump_s":
            updates[key] = _number(source, f"steps.{key}", value, positive=True)
        else:
            updates[key] = _number(source, f"steps.{key}", value)
    move = data.get("move", {})
    if not isinstance(move, dict):
        raise InputError(source, "[move] must be a table")
    move_updates: dict[str, float] = {}
    for key, value in move.items():
        if key not in _MOVE_FIELDS:
            raise InputError(source, f"unknown field move.{key} (allowed: {', '.join(sorted(_MOVE_FIELDS))})")
        move_updates[key] = _number(source, f"move.{key}", value, positive=key == "breakpoint_um")
    if move_updates:
        updates["move"] = replace(base.move, **move_updates)
    reconf = data.get("reconfiguration", {})
    if not isinstance(reconf, dict):
        raise InputError(source, "[reconfiguration] must be a table")
    for key, value in reconf.items():
        if key not in _RECONF_MAP:
            raise InputError(
                source, f"unknown field reconfiguration.{key} (allowed: {', '.join(sorted(_RECONF_MAP))})"
            )
        updates[_RECONF_MAP[key]] = _number(
            source, f"reconfiguration.{key}", value, positive=key == "threshold_um"
        )
    display = data.get("display", {})
    if not isinstance(display, dict):
        raise InputError(source, "[display] must be a table")
    for key, value in display.items():
        if key != "reverse_x" or not isinstance(value, bool):
            raise InputError(source, f"field display.{key} is unknown or not true/false")
        updates["reverse_x"] = value
    stage = data.get("stage", {})
    if not isinstance(stage, dict):
        raise InputError(source, "[stage] must be a table")
    for key, value in stage.items():
        if key not in ("max_tilt_um_per_mm", "travel_um"):
            raise InputError(source, f"unknown field stage.{key} (allowed: max_tilt_um_per_mm, travel_um)")
        name = "stage_travel_um" if key == "travel_um" else str(key)
        updates[name] = _number(source, f"stage.{key}", value, positive=True)
    drift = data.get("drift", {})
    if not isinstance(drift, dict):
        raise InputError(source, "[drift] must be a table")
    drift_fields = {"noise_floor_nm_s": "drift_noise_floor_nm_s", "segment_s": "drift_segment_s"}
    for key, value in drift.items():
        if key not in drift_fields:
            raise InputError(source, f"unknown field drift.{key} (allowed: {', '.join(drift_fields)})")
        updates[drift_fields[key]] = _number(source, f"drift.{key}", value, positive=key == "segment_s")
    if "inview" in data:
        updates["inview"] = _inview(base.inview, data["inview"], source)
    if "fast" in data:
        updates["fast"] = _fast(base.fast, data["fast"], source)
    profile = replace(base, **updates)
    missing = [
        h for h in profile.allowed_holds_s if not any(math.isclose(h, m) for m, _ in profile.inview.methods)
    ]
    if missing:
        shown = ", ".join(f"{h:g}" for h in missing)
        raise InputError(source, f"inview.methods has no method for the allowed hold(s) {shown} s")
    if profile.default_hold_s not in profile.allowed_holds_s:
        raise InputError(
            source, f"steps.default_hold_s {profile.default_hold_s:g} is not in steps.allowed_holds_s"
        )
    return profile


_INVIEW_NUMBERS = {"position_tolerance_um", "poll_s", "deadline_factor", "deadline_margin_s"}


def _inview(base: InViewSettings, table: Any, source: str) -> InViewSettings:
    """The [inview] table: methods = { "80" = "file.nmt", ... }, axis signs, inbox checks."""
    if not isinstance(table, dict):
        raise InputError(source, "[inview] must be a table")
    allowed = {f.name for f in fields(InViewSettings)}
    updates: dict[str, Any] = {}
    for key, value in table.items():
        where = f"inview.{key}"
        if key not in allowed:
            raise InputError(source, f"unknown field {where} (allowed: {', '.join(sorted(allowed))})")
        if key == "methods":
            if not isinstance(value, dict) or not value:
                raise InputError(source, f'field {where} must be a table like {{ "80" = "method.nmt" }}')
            methods = []
            for hold, name in value.items():
                try:
                    hold_s = float(hold)
                except ValueError:
                    raise InputError(
                        source, f"field {where}: key {hold!r} is not a hold in seconds"
                    ) from None
                if not isinstance(name, str) or not name.strip():
                    raise InputError(source, f"field {where}.{hold} must be a method file name")
                methods.append((_number(source, f"{where}.{hold}", hold_s), name.strip()))
            updates[key] = tuple(sorted(methods))
        elif key in ("array_x_sign", "array_y_sign"):
            if value not in (1, -1) or isinstance(value, bool):
                raise InputError(source, f"field {where} must be 1 or -1, got {value!r}")
            updates[key] = int(value)
        elif key == "array_swap_xy":
            if not isinstance(value, bool):
                raise InputError(source, f"field {where} must be true or false, got {value!r}")
            updates[key] = value
        elif key == "stable_polls":
            if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= 100:
                raise InputError(source, f"field {where} must be a whole number from 1 to 100, got {value!r}")
            updates[key] = value
        else:
            assert key in _INVIEW_NUMBERS
            updates[key] = _number(source, where, value, positive=key != "deadline_margin_s")
    if updates.get("deadline_factor", base.deadline_factor) < 1:
        raise InputError(
            source, "field inview.deadline_factor must be ≥ 1 (the deadline is after the estimate)"
        )
    return replace(base, **updates)


def _fast(base: FastMode | None, table: Any, source: str) -> FastMode | None:
    """The [fast] table: every field required unless inherited; ``available = false`` removes an inherited one."""
    if not isinstance(table, dict):
        raise InputError(source, "[fast] must be a table")
    allowed = _FAST_NUMBERS | _FAST_FLAGS | _FAST_TEXTS | {"available"}
    for key in table:
        if key not in allowed:
            raise InputError(source, f"unknown field fast.{key} (allowed: {', '.join(sorted(allowed))})")
    available = table.get("available", True)
    if not isinstance(available, bool):
        raise InputError(source, f"field fast.available must be true or false, got {available!r}")
    if not available:
        if len(table) > 1:
            raise InputError(source, "field fast.available = false takes no other [fast] field")
        return None
    if base is None:
        missing = sorted((_FAST_NUMBERS | _FAST_FLAGS | _FAST_TEXTS) - set(table))
        if missing:
            raise InputError(source, f"[fast] needs field(s) {', '.join(f'fast.{m}' for m in missing)}")
    updates: dict[str, Any] = {}
    for key, value in table.items():
        if key in _FAST_FLAGS:
            if not isinstance(value, bool):
                raise InputError(source, f"field fast.{key} must be true or false, got {value!r}")
            updates[key] = value
        elif key in _FAST_TEXTS:
            if not isinstance(value, str) or not value.strip():
                raise InputError(source, f"field fast.{key} must be the InView method's name, got {value!r}")
            updates[key] = value.strip()
        elif key in _FAST_NUMBERS:
            updates[key] = _number(source, f"fast.{key}", value, positive=key != "column_change_s")
    fast = FastMode(**updates) if base is None else replace(base, **updates)
    if fast.min_pitch_um > fast.max_extent_um:
        raise InputError(
            source,
            f"field fast.min_pitch_um {fast.min_pitch_um:g} is larger than fast.max_extent_um "
            f"{fast.max_extent_um:g}",
        )
    return fast


def _read_toml(text: str, source: str) -> dict[str, Any]:
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(source, f"not valid TOML ({exc})") from None


def _builtin_text(name: str) -> str:
    return resources.files("core").joinpath("profiles", f"{name}.toml").read_text(encoding="utf-8")


def load_profile(name_or_path: str | Path | None = None) -> InstrumentProfile:
    """A built-in profile by name (``kla-imicro``, ``kla-imicro-film``, ``kla-nanoblitz``) or a TOML file."""
    key = str(name_or_path) if name_or_path is not None else "kla-imicro"
    if key in BUILTIN_PROFILES:
        data = _read_toml(_builtin_text(key), f"profile {key}")
        source = f"profile {key}"
    else:
        path = Path(key)
        if not path.is_file():
            raise InputError(key, f"no such profile file (built-in profiles: {', '.join(BUILTIN_PROFILES)})")
        try:
            text = path.read_text(encoding="utf-8-sig")
        except (OSError, UnicodeDecodeError) as exc:
            raise InputError(key, f"cannot read profile ({exc})") from None
        data = _read_toml(text, key)
        source = key
    base = InstrumentProfile()
    parent = data.get("extends")
    if parent is not None:
        if parent not in BUILTIN_PROFILES:
            raise InputError(
                source, f"extends {parent!r} is not a built-in profile ({', '.join(BUILTIN_PROFILES)})"
            )
        if parent != key:
            base = load_profile(parent)
    return _apply(base, data, source)


def profile_to_dict(profile: InstrumentProfile) -> dict[str, Any]:
    """Plain-data form for the journal and JSON output."""
    out: dict[str, Any] = {}
    for f in fields(profile):
        value = getattr(profile, f.name)
        if isinstance(value, MoveModel):
            value = {mf.name: getattr(value, mf.name) for mf in fields(MoveModel)}
        elif isinstance(value, InViewSettings):
            value = {vf.name: getattr(value, vf.name) for vf in fields(InViewSettings)}
            value["methods"] = [[h, m] for h, m in value["methods"]]
        elif isinstance(value, FastMode):
            value = {ff.name: getattr(value, ff.name) for ff in fields(FastMode)}
        elif isinstance(value, tuple):
            value = list(value)
        out[f.name] = value
    return out


def profile_from_dict(data: dict[str, Any]) -> InstrumentProfile:
    kwargs = dict(data)
    kwargs["move"] = MoveModel(**kwargs["move"])
    kwargs["allowed_holds_s"] = tuple(kwargs["allowed_holds_s"])
    if "inview" in kwargs:  # journals written before the KLA driver have none: the defaults apply
        inview = dict(kwargs["inview"])
        inview["methods"] = tuple((float(h), str(m)) for h, m in inview["methods"])
        kwargs["inview"] = InViewSettings(**inview)
    if kwargs.get("fast") is not None:  # absent in journals written before the fast mode: none
        kwargs["fast"] = FastMode(**kwargs["fast"])
    return InstrumentProfile(**kwargs)


@dataclass(frozen=True)
class MoveFit:
    model: MoveModel
    n_points: int
    rmse_s: float


def fit_move_model(csv_path: str | Path, base: MoveModel | None = None) -> MoveFit:
    """Fit the piecewise move-time model to a lab's measured ``distance_um, seconds`` pairs."""
    from scipy.optimize import curve_fit

    base = base or MoveModel()
    source = str(csv_path)
    try:
        with open(csv_path, newline="", encoding="utf-8") as fh:
            reader = csv.DictReader(fh)
            header = [h.strip() for h in (reader.fieldnames or [])]
            if "distance_um" not in header or "seconds" not in header:
                raise InputError(
                    source, f"needs columns distance_um, seconds; found {', '.join(header) or 'none'}"
                )
            rows: list[tuple[float, float]] = []
            for lineno, raw in enumerate(reader, start=2):
                row = {k.strip(): (v or "").strip() for k, v in raw.items() if k is not None}
                try:
                    dist, secs = float(row["distance_um"]), float(row["seconds"])
                except ValueError:
                    raise InputError(
                        source, f"line {lineno}: distance_um and seconds must be numbers"
                    ) from None
                if not (math.isfinite(dist) and math.isfinite(secs)) or dist < 0 or secs < 0:
                    raise InputError(source, f"line {lineno}: distance_um and seconds must be finite and ≥ 0")
                rows.append((dist, secs))
    except OSError as exc:
        raise InputError(source, f"cannot read ({exc.strerror})") from None
    except UnicodeDecodeError:
        raise InputError(source, "not a UTF-8 text CSV") from None
    if len(rows) < 4:
        raise InputError(source, f"needs at least 4 measured moves, found {len(rows)}")
    d = np.array([r[0] for r in rows])
    s = np.array([r[1] for r in rows])
    bp = base.breakpoint_um
    short, long_ = d < bp, d >= bp
    a, b, c = base.short_a, base.short_b, base.short_c
    if short.sum() >= 3:
        # a·exp(b·d) − c is nearly linear over the short range; fit slope and offset with a fixed and
        # recover (b, c), which keeps the fit well-conditioned.
        def f_short(x: np.ndarray, slope: float, offset: float) -> np.ndarray:
            return a * np.exp((slope / a) * x) - (a - offset)

        (slope, offset), _ = curve_fit(f_short, d[short], s[short], p0=(a * b, a - c))
        b, c = slope / a, a - offset
    slope_l, icpt_l = base.long_slope, base.long_intercept
    if long_.sum() >= 2:
        slope_l, icpt_l = (float(v) for v in np.polyfit(d[long_], s[long_], 1))
    model = MoveModel(float(a), float(b), float(c), float(slope_l), float(icpt_l), bp)
    resid = model.axis_s_array(d) - s
    return MoveFit(model=model, n_points=len(rows), rmse_s=float(np.sqrt(np.mean(resid**2))))

"""Physical plausibility: values no real sample or stage can have are refused, naming the likely unit slip.

A truth file written in MPa under ``hardness_gpa``, or a path in nm under ``x_um``, parses as numbers and
would run; these checks stop it before anything is computed, with one line that says what the value
would be in the unit that was probably meant. The hardness and modulus limits are physics (nothing is
harder or stiffer than diamond); the stage limit is generous on purpose (a sample file's own
``stage_rect_um`` says where a particular stage may go).
"""

from __future__ import annotations

import math

from core.errors import InputError

# Diamond, the hardest and stiffest material known: ~70–150 GPa hardness, ~1,050–1,220 GPa modulus.
MAX_HARDNESS_GPA = 150.0
MAX_MODULUS_GPA = 1_250.0
# No nanoindenter stage reaches further than ±200 mm from its origin (the iMicro's exports sit at 40–130 mm).
MAX_STAGE_UM = 200_000.0

_UNIT_GUESSES_GPA = (("MPa", 1e-3), ("kPa", 1e-6), ("Pa", 1e-9))
_UNIT_GUESSES_UM = (("nm", 1e-3), ("Å", 1e-4), ("pm", 1e-6), ("mm", 1e3), ("m", 1e6))


def _guess(value: float, lo: float, hi: float, guesses: tuple[tuple[str, float], ...], unit: str) -> str:
    for name, factor in guesses:
        if lo <= value * factor <= hi:
            return f"; it looks like {name} ({value:g} {name} = {value * factor:g} {unit})"
    return ""


def check_pressure_gpa(source: str, name: str, value: float, max_gpa: float) -> float:
    """A hardness or modulus in GPa: finite, > 0 and at most ``max_gpa``."""
    if not math.isfinite(value):
        raise InputError(source, f"{name} {value!r} is not a finite number")
    if value <= 0:
        raise InputError(source, f"{name} must be > 0 GPa, got {value:g}")
    if value > max_gpa:
        hint = _guess(value, 1e-3, max_gpa, _UNIT_GUESSES_GPA, "GPa")
        raise InputError(
            source, f"{name} {value:g} GPa is impossible (no material exceeds {max_gpa:g} GPa){hint}"
        )
    return value


def check_hardness_gpa(source: str, value: float, name: str = "hardness_gpa") -> float:
    return check_pressure_gpa(source, name, value, MAX_HARDNESS_GPA)


def check_modulus_gpa(source: str, value: float, name: str = "modulus_gpa") -> float:
    return check_pressure_gpa(source, name, value, MAX_MODULUS_GPA)


def check_noise_sd_gpa(source: str, value: float, hardness_gpa: float, name: str = "noise_sd_gpa") -> float:
    """A measurement noise sd in GPa: finite, ≥ 0 and below the hardness it scatters around."""
    if not math.isfinite(value) or value < 0:
        raise InputError(source, f"{name} must be a finite number ≥ 0 GPa, got {value!r}")
    if value >= hardness_gpa:
        hint = _guess(value, 0.0, hardness_gpa, _UNIT_GUESSES_GPA[:1], "GPa")
        raise InputError(
            source,
            f"{name} {value:g} GPa is not below the hardness {hardness_gpa:g} GPa it scatters around "
            f"(a sd that large measures nothing){hint}",
        )
    return value


def check_stage_um(
    source: str, name: str, value: float, lo_um: float, hi_um: float, what: str = "the reach of any stage"
) -> float:
    """A stage coordinate in µm within [lo_um, hi_um]; outside, say which unit would put it inside."""
    if not math.isfinite(value):
        raise InputError(source, f"{name} {value!r} is not a finite number")
    if not lo_um <= value <= hi_um:
        hint = _guess(value, lo_um, hi_um, _UNIT_GUESSES_UM, "µm") if value else ""
        raise InputError(source, f"{name} {value:g} µm is outside {what} ({lo_um:g} to {hi_um:g} µm){hint}")
    return value

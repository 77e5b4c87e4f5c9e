"""Small text formats shared by the panels (durations, positions, scores)."""

from __future__ import annotations

import math


def hms(seconds: float | None) -> str:
    """Seconds as h:mm:ss (hours grow past 24: instrument runs last days)."""
    if seconds is None or not math.isfinite(seconds):
        return "–"
    s = round(max(seconds, 0.0))
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}"


def short_duration(seconds: float | None) -> str:
    """Compact duration: 45 s, 12.5 min, 3.2 h."""
    if seconds is None or not math.isfinite(seconds):
        return "–"
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.1f} min"
    return f"{seconds / 3600:.1f} h"


def xy(x_um: float, y_um: float) -> str:
    return f"({x_um:.0f}, {y_um:.0f})"


def num(value: float | None, digits: int = 3) -> str:
    """Short number: 3 significant digits, scientific below 0.01 (acquisition / cost scores are tiny)."""
    if value is None or not math.isfinite(value):
        return "–"
    if value != 0 and abs(value) < 0.01:
        return f"{value:.{max(digits - 1, 0)}e}".replace("e-0", "e-")
    return f"{value:.{digits}g}"


def bar(fraction: float, width: int, full: str = "█", empty: str = "░") -> str:
    """A horizontal bar, ``fraction`` of ``width`` filled (eighth-block resolution)."""
    f = min(max(fraction, 0.0), 1.0) * width
    whole = int(f)
    eighths = " ▏▎▍▌▋▊▉"
    part = eighths[int((f - whole) * 8)] if whole < width and full == "█" else ""
    part = part.strip() if part.strip() else ""
    used = whole + (1 if part else 0)
    return full * whole + part + empty * max(width - used, 0)

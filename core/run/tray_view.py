"""A tray run as people read it: a line per sample (its progress to its goal, the current one, time left),
from what the journal keeps (the run spec's tray and the tray campaign's last state). ``aeni status`` and the
console's tray panel show these lines."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from core.sample.tray import Tray, tray_from_dict


@dataclass(frozen=True)
class SampleProgress:
    name: str
    role: str
    current: bool
    done: str  # why a library is left alone ("" while it runs)
    fraction: float | None  # progress to the goal, 0..1 (None: not known yet)
    text: str  # the progress in words
    left_s: float | None  # instrument seconds left to the goal, where the goal says (budget, indents)


def journal_tray(meta: Mapping[str, Any]) -> Tray | None:
    """The tray a journal's run indents (None: a single-sample run)."""
    spec = meta.get("run_spec") or {}
    data = spec.get("tray")
    return None if data is None else tray_from_dict(data)


def tray_progress(tray: Tray, state: Mapping[str, Any] | None) -> list[SampleProgress]:
    run: Mapping[str, Any] = (state or {}).get("tray_run") or {}
    on = run.get("on")
    out = []
    for s in tray.samples:
        if s.role == "reference" and s.reference is not None:
            checks = run.get("checks") or []
            last = checks[-1] if checks else None
            if last is None:
                text = "no tip check yet"
            else:
                dev = last[3]
                verdict = "passed" if last[4] else "FAILED"
                shown = "nothing measured" if dev is None or not math.isfinite(dev) else f"{dev:+.1f} %"
                text = (
                    f"{len(checks)} tip check(s), last {shown} ({verdict}, ±{s.reference.tolerance_pct:g} %)"
                )
            out.append(SampleProgress(s.name, s.role, on == s.name, "", None, text, None))
            continue
        assert s.goal is not None
        done = str((run.get("done") or {}).get(s.name, ""))
        own_s = float((run.get("own_s") or {}).get(s.name, 0.0))
        n = int((run.get("indents") or {}).get(s.name, 0))
        rel = (run.get("rel_sd_p95_pct") or {}).get(s.name)
        g = s.goal
        fraction: float | None
        left_s: float | None = None
        if g.kind == "indents":
            fraction = min(n / g.value, 1.0)
            text = f"{n} of {g.value:g} indents"
            if n:
                left_s = max(g.value - n, 0) * own_s / n
        elif g.kind == "budget_s":
            fraction = min(own_s / g.value, 1.0)
            text = f"{own_s / 3600:.1f} of {g.value / 3600:.1f} h"
            left_s = max(g.value - own_s, 0.0)
        else:
            fraction = None if rel is None else min(g.value / max(float(rel), 1e-9), 1.0)
            text = (
                "no map yet" if rel is None else f"relative sd {float(rel):.2f} %"
            ) + f", goal {g.value:g} %"
        if done:
            fraction, left_s = 1.0, 0.0
        out.append(SampleProgress(s.name, s.role, on == s.name, done, fraction, text, left_s))
    return out


def progress_line(p: SampleProgress) -> str:
    mark = "▶" if p.current else " "
    state = "at its goal" if p.done else ("reference" if p.role == "reference" else "running")
    left = "" if p.left_s is None or p.done else f", ~{p.left_s / 3600:.1f} h left"
    return f"{mark} {p.name}: {state}: {p.text}{left}"

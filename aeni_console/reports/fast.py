"""The fast channel in a run's report (issue 36): how many indents each channel made and how much instrument
time went to fast arrays, read from the journal's indents (each with its channel) and its step ledger."""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from core.plan import IndentResult


@dataclass(frozen=True)
class FastTally:
    """A run's indents by channel, and the instrument time of its fast arrays (each array's steps: opening,
    moves, surface find, drift settle and indents)."""

    csm_measured: int
    csm_unmeasured: int
    fast_measured: int
    fast_unmeasured: int  # failed (or never made): no value, never learnt from
    fast_arrays: int
    fast_array_s: float

    @property
    def fast_indents(self) -> int:
        return self.fast_measured + self.fast_unmeasured


def fast_tally(indents: Sequence[IndentResult], steps: Iterable[tuple[int, float]]) -> FastTally:
    """``steps``: (block_id, seconds) of every step the journal's ledger holds."""
    fast_blocks = {r.block_id for r in indents if r.channel == "fast"}
    return FastTally(
        csm_measured=sum(1 for r in indents if r.channel != "fast" and r.measured),
        csm_unmeasured=sum(1 for r in indents if r.channel != "fast" and not r.measured),
        fast_measured=sum(1 for r in indents if r.channel == "fast" and r.measured),
        fast_unmeasured=sum(1 for r in indents if r.channel == "fast" and not r.measured),
        fast_arrays=len(fast_blocks),
        fast_array_s=float(sum(s for b, s in steps if b in fast_blocks)),
    )


def fast_summary_lines(tally: FastTally, instrument_s: float, bias_gpa: np.ndarray | None) -> list[str]:
    """summary.md's lines on the fast channel (none for a CSM-only run)."""
    if not tally.fast_indents:
        return []
    share = f" ({100 * tally.fast_array_s / instrument_s:.0f} % of the run)" if instrument_s > 0 else ""
    lines = [
        f"- channels: {tally.csm_measured} CSM indents measured; {tally.fast_measured} fast (NanoBlitz-class) "
        f"indents measured in {tally.fast_arrays} fast array{'s' if tally.fast_arrays != 1 else ''}"
        + (f", {tally.fast_unmeasured} fast indents without a value" if tally.fast_unmeasured else ""),
        f"- time in fast arrays: {tally.fast_array_s:,.0f} s{share}",
    ]
    finite = None if bias_gpa is None else bias_gpa[np.isfinite(bias_gpa)]
    if finite is not None and finite.size:
        lines.append(
            f"- learnt fast-channel bias H_csm − H_fast: {finite.min():+.3f} to {finite.max():+.3f} GPa "
            f"(median {float(np.median(finite)):+.3f} GPa); the map is the two-fidelity one"
        )
    else:
        lines.append(
            "- learnt fast-channel bias: none yet (too few fast cells or CSM centres for the two-fidelity map)"
        )
    return lines

"""A small unattended soak in the suite (issue 23): headless KLA runs against the fake InView with faults, a
kill -9 and `aeni resume`, and the exchange folder taken away and brought back. Each run must end by its
budget, and the journal must agree with the fake InView's own ledger: nothing stalled, lost, duplicated or
changed. The full soak (50 runs) is `benchmarks/unattended_soak.py`."""

from __future__ import annotations

from dataclasses import replace

import pytest

from benchmarks.unattended_soak import plan_run, soak_one


@pytest.mark.slow
def test_a_short_soak_run_ends_with_nothing_stalled_lost_duplicated_or_changed() -> None:
    """One run with the faults that lost or miscounted indents before: killed while a refused (flipped-Y)
    export's block waits for a corrected one (the refused rows were lost before the refusal kept them), then
    no export after a confirmed start (the sites are held as taken), with the folder away for a second."""
    planned = replace(
        plan_run(0, 7), faults=["flipped-y@0", "missing-export@1"], kill_on="refused", kill_at_s=30.0,
        folder_away_at_s=1.0, folder_away_s=1.0,
    )  # fmt: skip
    out = soak_one(planned, 3500.0, 0.05, 10.0, 6.0, 120.0)
    detail = " | ".join(out.notes)
    assert out.killed and out.folder_removed, detail
    assert out.end_state.startswith("stopped") and "budget" in out.stop_reason, detail
    assert (out.stalled, out.lost, out.duplicated, out.changed) == (False, 0, 0, 0), detail
    assert out.blocks >= 2 and out.indents_unexported > 0, detail  # both faults met
    assert out.recorded_made == out.indents_made, detail  # every indent made is held as made

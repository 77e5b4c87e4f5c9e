"""Issue 36, kept: `aeni export` carries each indent's (and block's) channel and writes the fast channel's
learnt bias where the run has one; `aeni report` counts the channels, the time in fast arrays, and draws the
bias. One real run: `aeni run --fast on` on a profile whose fast mode is cheap enough that the planner's first
priced array wins (its own pricing decides, not a recipe), stopped by its budget just after that array."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from aeni_console.cli.main import main
from aeni_console.console.heatmap import field_keys_of
from aeni_console.console.journal_source import JournalSource
from aeni_console.reports.fast import fast_summary_lines, fast_tally
from core.journal import JournalReader
from core.plan import IndentResult

# the iMicro with a fast mode 10× cheaper than kla-imicro's and no set-up per array: an assumption for the
# test only (the shipped profile's fast mode is kla-imicro's [fast], with its sources)
CHEAP_FAST = """extends = "kla-imicro"
name = "cheap-fast"
[fast]
indent_s = 0.1
column_change_s = 0.1
max_extent_um = 1000.0
min_pitch_um = 5.0
peak_load_mn = 5.0
surface_find = false
drift_settle = false
"""


@pytest.fixture(scope="module")
def fast_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("fastrun")
    profile = d / "cheap-fast.toml"
    profile.write_text(CHEAP_FAST, encoding="utf-8")
    run_file = d / "run.toml"
    run_file.write_text(
        f'name = "fastrun"\n[campaign]\nprofile = "{profile}"\nlattice_n = 20\n[planner]\nbudget_s = 5400\n',
        encoding="utf-8",
    )
    journal = d / "fast.sqlite"
    assert main(["run", str(run_file), "--fast", "on", "--quiet", "--journal", str(journal)]) == 0
    return journal


def test_export_carries_the_channel_and_the_bias_map(fast_run: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    assert main(["export", str(fast_run), "--out", str(out)]) == 0
    with JournalReader(fast_run) as r:
        kept = r.results()
    ind = pd.read_csv(out / "indents.csv")
    assert len(ind) == len(kept) and set(ind["channel"]) == {"csm", "fast"}
    assert (ind["channel"] == "fast").sum() == sum(1 for k in kept if k.channel == "fast") > 20
    fast = ind[ind["channel"] == "fast"]
    assert (fast["hold_s"] == 0).all()  # a fast indent has no hold
    blocks = pd.read_csv(out / "blocks.csv")
    assert set(blocks.loc[blocks["block_id"].isin(fast["block_id"]), "channel"]) == {"fast"}
    assert set(blocks.loc[~blocks["block_id"].isin(fast["block_id"]), "channel"]) == {"csm"}
    bias = pd.read_csv(out / "fast_bias.csv")
    pred = pd.read_csv(out / "predictions.csv")
    assert list(bias.columns) == ["x_um", "y_um", "bias_gpa"]
    assert np.allclose(bias[["x_um", "y_um"]], pred[["x_um", "y_um"]])  # the same points as the maps
    assert np.isfinite(bias["bias_gpa"]).all() and bias["bias_gpa"].abs().max() < 10.0


def test_report_counts_the_channels_and_draws_the_bias(fast_run: Path, tmp_path: Path) -> None:
    out = tmp_path / "report"
    assert main(["report", str(fast_run), "--out", str(out)]) == 0
    assert (out / "bias.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    text = (out / "summary.md").read_text(encoding="utf-8")
    with JournalReader(fast_run) as r:
        kept = r.results()
        cols, rows = r.table("steps")
    n_fast = sum(1 for k in kept if k.channel == "fast" and k.measured)
    n_csm = sum(1 for k in kept if k.channel == "csm" and k.measured)
    fast_blocks = {k.block_id for k in kept if k.channel == "fast"}
    i_b, i_s = cols.index("block_id"), cols.index("seconds")
    fast_s = sum(float(x[i_s]) for x in rows if int(x[i_b]) in fast_blocks)
    assert (
        f"- channels: {n_csm} CSM indents measured; {n_fast} fast (NanoBlitz-class) indents measured" in text
    )
    assert f"- time in fast arrays: {fast_s:,.0f} s" in text and fast_s > 0
    assert "learnt fast-channel bias H_csm − H_fast:" in text and "bias.png" in text


def _indent(block_id: int, channel: str, measured: bool = True) -> IndentResult:
    h = 5.0 if measured else float("nan")
    return IndentResult(block_id, 0, 1.0, 1.0, 1.0, 1.0, 0.0, h, 100.0, 0.0, 0.0, channel=channel,  # type: ignore[arg-type]
                        status="measured" if measured else "failed")  # fmt: skip


def test_the_tally_by_channel_and_a_csm_only_run_says_nothing() -> None:
    indents = [_indent(0, "csm"), _indent(1, "fast"), _indent(1, "fast", measured=False), _indent(2, "csm")]
    tally = fast_tally(indents, [(0, 100.0), (1, 30.0), (1, 12.5), (2, 50.0), (-1, 5.0)])
    assert (tally.csm_measured, tally.fast_measured, tally.fast_unmeasured, tally.fast_arrays) == (2, 1, 1, 1)
    assert tally.fast_array_s == pytest.approx(42.5)
    lines = fast_summary_lines(tally, 197.5, None)
    assert "1 fast indents without a value" in lines[0] and "42 s (22 % of the run)" in lines[1]
    assert "none yet" in lines[2]
    csm_only = fast_tally([_indent(0, "csm")], [(0, 100.0)])
    assert csm_only.fast_indents == 0 and fast_summary_lines(csm_only, 100.0, None) == []


def test_the_console_reads_the_channel_and_the_bias_from_the_journal(fast_run: Path) -> None:
    """What `aeni console` reads (the same JournalSource): each indent's channel in the snapshot, and the bias
    beside the last map fields the engine stored, so `m` offers the bias view."""
    source = JournalSource(fast_run)
    try:
        snap = source.snapshot()
        with JournalReader(fast_run) as r:
            kept = r.results()
        assert [m.channel for m in snap.indents] == [k.channel for k in kept]
        assert snap.gp.snapshot_id is not None
        fields = source.map_fields(snap.gp.snapshot_id)
    finally:
        source.close()
    assert fields is not None and fields.bias_gpa is not None and np.isfinite(fields.bias_gpa).any()
    assert field_keys_of(fields)[-1] == "bias"

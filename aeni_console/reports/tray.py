"""A tray run's report: the single-sample report of each library (its indents, blocks, maps and instrument
time only), in a folder per sample, and a short summary of the tray (goals, indents, time, tip checks).

One report over the whole tray would draw every library's indents on one outline and score one library's map
against another's truth; each library is its own campaign (core.run.tray), so each gets its own report. Which
sample a block is on is the tray's geometry, as the interlock reads it (its first indent's commanded point).
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from aeni_console.files import check_out_folder, write_atomic
from aeni_console.reports.finalmaps import tray_final_maps
from aeni_console.reports.run import RunData, _pyplot, read_run, render_report, report_head
from core.campaign_config import campaign_config_to_dict
from core.errors import InputError
from core.journal import JournalReader
from core.run.spec import run_spec_from_meta
from core.run.tray import library_config
from core.run.tray_view import journal_tray
from core.sample.tray import Tray, TraySample
from core.tipcheck import TipCheck, judge


@dataclasses.dataclass(frozen=True)
class SampleTotals:
    """What the tray summary says of one sample."""

    name: str
    role: str
    goal: str  # the goal in words ("" for the reference)
    done: str  # why the library was left alone ("" while it had not reached its goal)
    measured: int
    unmeasured: int  # failed, unverified or not run: no value
    blocks: int
    instrument_s: float  # the steps of its blocks (its moves and sample changes included)


def _goal_text(entry: TraySample) -> str:
    g = entry.goal
    if g is None:
        return ""
    if g.kind == "rel_sd_pct":
        return f"relative sd ≤ {g.value:g} %"
    if g.kind == "budget_s":
        return f"{g.value / 3600:g} h of instrument time"
    return f"{g.value:g} indents"


def _block_samples(tray: Tray, blocks: list[Any]) -> dict[int, str]:
    """Each block's sample: the one holding its first indent's commanded point ("" for none)."""
    out = {}
    for block in blocks:
        first = block.indents[0] if block.indents else None
        entry = None if first is None else tray.sample_at(first.x_um, first.y_um)
        out[int(block.block_id)] = "" if entry is None else entry.name
    return out


def _library_data(
    run: RunData,
    entry: TraySample,
    on: dict[int, str],
    ledger: dict[str, dict[str, float]],
    snapshots: dict[str, list[tuple[int, float, Any, dict[str, Any]]]],
    done: str,
    base_config: Any,
    maps: Any,
) -> RunData:
    """The run's data restricted to one library: its blocks' indents, decisions, time and maps."""
    name = entry.name
    sample = entry.placed
    own = snapshots.get(name, [])
    uncertainty, fits = [], []
    recorded = None
    for _, t_s, mf, summ in own:
        if np.isfinite(mf.epistemic_sd_gpa).any():
            uncertainty.append(
                (t_s, float(np.nanmean(mf.epistemic_sd_gpa)), float(np.nanmean(mf.total_sd_gpa)))
            )
            scales = tuple(float(v) for v in summ.get("lengthscales_um") or ())
            fits.append((int(summ.get("_block_id", -1)), scales, bool(summ.get("collapse_alarm", False))))
        if summ.get("mape_pct") is not None:
            recorded = float(summ["mape_pct"])
    times = ledger.get(name, {})
    return dataclasses.replace(
        run,
        name=f"{run.name}/{name}",
        config=campaign_config_to_dict(library_config(base_config, entry)),
        outline_xy_um=np.array([[c.x_um, c.y_um] for c in sample.calibration.corners], dtype=float),
        exclusions=tuple(sample.exclusions),
        earlier_indents_um=[(float(x), float(y)) for x, y in sample.earlier_indents_um],
        indents=[r for r in run.indents if on.get(int(r.block_id)) == name],
        ledger_s=dict(times),
        instrument_s=float(sum(times.values())),
        grid_baseline_s=0.0,  # the run's grid baseline is the whole tray's, not this library's
        decisions=[d for d in run.decisions if on.get(int(d.decision.block.block_id)) == name],
        snapshots=[(sid, t_s) for sid, t_s, _, _ in own],
        final_map=own[-1][2] if own else None,
        uncertainty=uncertainty,
        fits=fits,
        stop_reason=done,
        recorded_mape_pct=recorded,
        final_maps=maps,
    )


def write_tray_report(path: str | Path, out_dir: str | Path) -> list[Path]:
    """A folder per library under ``out_dir`` with its single-sample report, and ``summary.md`` of the tray."""
    _pyplot()  # before reading anything: a missing matplotlib is said at once
    out = check_out_folder(out_dir)
    with JournalReader(path) as r:
        tray = journal_tray(r.meta)
        if tray is None:
            raise InputError(str(path), "not a tray run: `aeni report` writes its single-sample report")
        config = run_spec_from_meta(r.meta).campaign
        blocks = [b for b, _, _ in r.q.block_rows()]
        history = r.history()  # the resume's fold of the run's events
        latest = None if history is None else history.plan
        observed = [] if history is None else history.observed
        s_cols, s_rows = r.table("steps")
        g_cols, g_rows = r.table("gp_snapshots")
        on = _block_samples(tray, blocks)
        ledger: dict[str, dict[str, float]] = defaultdict(lambda: defaultdict(float))
        i_b, i_c, i_s = s_cols.index("block_id"), s_cols.index("category"), s_cols.index("seconds")
        for row in s_rows:
            ledger[on.get(int(row[i_b]), "")][str(row[i_c])] += float(row[i_s])
        snapshots: dict[str, list[tuple[int, float, Any, dict[str, Any]]]] = defaultdict(list)
        i_sid, i_bid, i_t = g_cols.index("snapshot_id"), g_cols.index("block_id"), g_cols.index("t_s")
        i_blob, i_sum = g_cols.index("fields_npz"), g_cols.index("summary_json")
        for row in g_rows:
            if row[i_blob] is None:
                continue
            summ = dict(json.loads(row[i_sum]), _block_id=int(row[i_bid]))
            name = on.get(int(row[i_bid]), "")
            snapshots[name].append((int(row[i_sid]), float(row[i_t]), r.map_fields(int(row[i_sid])), summ))
    run_state: dict[str, Any] = ((latest[0] if latest else {}) or {}).get("tray_run") or {}
    done_of = {str(k): str(v) for k, v in (run_state.get("done") or {}).items()}
    run = read_run(path)
    maps = tray_final_maps(path)
    written: list[Path] = []
    totals: list[SampleTotals] = []
    for entry in tray.samples:
        own = [x for x in run.indents if on.get(int(x.block_id)) == entry.name]
        n_meas = sum(1 for x in own if x.measured)
        totals.append(
            SampleTotals(
                name=entry.name,
                role=entry.role,
                goal=_goal_text(entry),
                done=done_of.get(entry.name, ""),
                measured=n_meas,
                unmeasured=len(own) - n_meas,
                blocks=sum(1 for b in on.values() if b == entry.name),
                instrument_s=float(sum(ledger.get(entry.name, {}).values())),
            )
        )
        if entry.role != "library":
            continue
        data = _library_data(
            run, entry, on, ledger, snapshots, done_of.get(entry.name, ""), config, maps.get(entry.name)
        )
        written += render_report(data, out / entry.name)
    checks: list[TipCheck] = []
    ref = tray.reference
    if ref is not None and ref.reference is not None:
        checks = [judge(b, res, ref.reference) for b, res in observed if on.get(int(b.block_id)) == ref.name]
    summary = out / "summary.md"
    write_atomic(summary, tray_summary_markdown(run, tray, totals, checks))
    return [*written, summary]


def tray_summary_markdown(
    run: RunData, tray: Tray, totals: list[SampleTotals], checks: list[TipCheck]
) -> str:
    lines = [
        *report_head("Tray report", run),
        f"- instrument time {run.instrument_s:,.0f} s ({run.instrument_s / 3600:.2f} h) over "
        f"{len(tray.samples)} samples",
        "",
        "| sample | role | goal | reached | indents measured | no value | blocks | instrument h | report |",
        "|---|---|---|---|---:|---:|---:|---:|---|",
    ]
    for t in totals:
        if t.role == "library":
            reached = f"yes: {t.done}" if t.done else "no"
            report = f"[{t.name}/summary.md]({t.name}/summary.md)"
        else:
            reached, report = "–", "–"
        lines.append(
            f"| {t.name} | {t.role} | {t.goal or '–'} | {reached} | {t.measured} | {t.unmeasured} | {t.blocks} "
            f"| {t.instrument_s / 3600:.2f} | {report} |"
        )
    ref = tray.reference
    if ref is not None and ref.reference is not None:
        m = ref.reference
        lines += [
            "",
            f"## Tip checks on {ref.name} ({m.material}: nominal H {m.hardness_gpa:g} GPa, "
            f"tolerance ±{m.tolerance_pct:g} %, every {m.check_every_h:g} h of instrument time)",
            "",
        ]
        if not checks:
            lines.append("No tip check yet.")
        else:
            lines += [
                "| block | at (h) | median H (GPa) | indents | deviation | verdict |",
                "|---:|---:|---:|---:|---:|---|",
            ]
            for c in checks:
                median = f"{c.median_gpa:.3f}" if math.isfinite(c.median_gpa) else "nothing measured"
                dev = f"{c.deviation_pct:+.1f} %" if math.isfinite(c.deviation_pct) else "–"
                at = f"{c.t_s / 3600:.2f}" if math.isfinite(c.t_s) else "–"
                verdict = "passed" if c.passed else "FAILED (tip worn or contaminated?)"
                lines.append(f"| {c.block_id} | {at} | {median} | {c.n_measured} | {dev} | {verdict} |")
    return "\n".join(lines) + "\n"

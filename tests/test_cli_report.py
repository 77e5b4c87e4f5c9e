"""`aeni report RUN`: a finished supervised demo run gives figures that show what happened, and a summary."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from aeni_console.cli.main import main

pytest.importorskip("matplotlib")

FIGURES = ("maps.png", "modulus.png", "time.png", "uncertainty.png", "drift.png", "decisions.png")


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A finished demo run (supervised) where the operator vetoes the first jump and approves the rest."""
    from aeni_console.testkit.scripted import run_supervised

    path = tmp_path_factory.mktemp("report") / "demo.sqlite"
    return run_supervised(
        path,
        {"name": "demo", "campaign.policy": "cost-aware", "planner.budget_s": 14_000},
        answers=("veto", "approve"),
    )


def _image(path: Path) -> np.ndarray:
    import matplotlib.image as mpimg

    return np.asarray(mpimg.imread(path))


def test_report_writes_figures_with_content(demo_run: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = demo_run.parent / "notebook"
    assert main(["report", str(demo_run), "--out", str(out)]) == 0
    assert "wrote 7 files" in capsys.readouterr().out
    for name in FIGURES:
        img = _image(out / name)
        h, w = img.shape[:2]
        assert w >= 600 and h >= 300, f"{name} is {w}×{h}"
        rgb = img[..., :3]
        assert rgb.std() > 0.05, f"{name} is blank"
        # more than a frame and some text: a figure with data has many distinct colours
        assert len(np.unique((rgb * 255).astype(np.uint8).reshape(-1, 3), axis=0)) > 40, name
    # the maps are drawn with the viridis map of the GP mean: its dark-purple end and its yellow end are there
    maps = _image(out / "maps.png")[..., :3]
    purple = (np.abs(maps - np.array([0.27, 0.0, 0.33])).sum(axis=-1) < 0.12).sum()
    yellow = (np.abs(maps - np.array([0.99, 0.91, 0.14])).sum(axis=-1) < 0.12).sum()
    assert purple > 200 and yellow > 200


def test_report_summary_names_what_happened(demo_run: Path) -> None:
    from aeni_console.reports.run import read_run, truth_mape_pct

    out = demo_run.parent / "summary-check"
    assert main(["report", str(demo_run), "--out", str(out)]) == 0
    text = (out / "summary.md").read_text(encoding="utf-8")
    data = read_run(demo_run)
    statuses = {d.status for d in data.decisions}
    assert {"vetoed", "approved"} <= statuses
    assert f"{len(data.indents)} indents" in text
    assert "vetoed" in text and "approved" in text
    mape = truth_mape_pct(data)
    assert mape is not None and f"MAPE {mape[0]:.2f} %" in text
    # the report's MAPE, on the stored map, agrees with the one the engine recorded on its own lattice
    assert data.recorded_mape_pct is not None
    assert mape[0] == pytest.approx(data.recorded_mape_pct, rel=0.25)
    for name in FIGURES:
        assert f"]({name})" in text
    # the modulus map: planned for beside the hardness (both maps, the default since issue 37), scored
    from aeni_console.reports.run import modulus_mape_pct

    e_mape = modulus_mape_pct(data)
    assert (
        e_mape is not None
        and 0 < e_mape[0] < 10
        and f"modulus map error against the simulated truth: MAPE {e_mape[0]:.2f} %" in text
    )
    assert "modulus map: planned for beside the hardness (map_weights); H/E 0.0" in text


def test_report_of_a_real_run_claims_no_truth(demo_run: Path) -> None:
    import dataclasses
    import math

    from aeni_console.reports.run import read_run, render_report, summary_markdown, truth_mape_pct

    data = read_run(demo_run)
    data.driver = "kla"
    assert truth_mape_pct(data) is None
    assert "not known (a real sample has no ground truth)" in summary_markdown(data, [], None)
    # an instrument that reported no value: counted, never a number
    nan = math.nan
    data.indents[0] = dataclasses.replace(
        data.indents[0], status="failed", hardness_gpa=nan, modulus_gpa=nan, note="surface not found"
    )
    text = summary_markdown(data, [], None)
    assert f"{len(data.indents) - 1} indents measured" in text and "1 failed and 0 not run" in text
    assert "nan" not in text.lower()
    written = render_report(data, demo_run.parent / "with-a-failed-indent")  # and the figures still draw
    assert len(written) == 7 and all(p.stat().st_size > 1_000 for p in written)


def test_report_refuses_a_file_as_out_folder(demo_run: Path, capsys: pytest.CaptureFixture[str]) -> None:
    blocker = demo_run.parent / "a-file"
    blocker.write_text("x", encoding="utf-8")
    assert main(["report", str(demo_run), "--out", str(blocker)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "a-file" in err and "is a file" in err


def test_report_of_a_running_run(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A run whose engine is still going (here: waiting for approval) gets a report too, said to be a snapshot."""
    import time

    from aeni_console.cli.run import start_engine_process
    from core.journal import JournalReader
    from core.runconfig import load_run_config
    from core.runview import EngineState

    rc = load_run_config(None, {"name": "live", "planner.budget_s": 200_000})
    journal = tmp_path / "live.sqlite"
    proc = start_engine_process(rc.campaign, journal, "supervised", speed=1e5)
    assert not isinstance(proc, int)
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            with JournalReader(journal) as r:
                if r.state()[0] == EngineState.AWAITING_APPROVAL:
                    break
            time.sleep(0.1)
        assert main(["report", str(journal)]) == 0
    finally:
        proc.terminate()
        proc.wait(timeout=60)
    out_dir = journal.with_name("live.report")
    text = (out_dir / "summary.md").read_text(encoding="utf-8")
    assert "awaiting-approval (the engine is still running; a snapshot)" in text
    for name in FIGURES:
        assert (out_dir / name).stat().st_size > 5_000


def test_report_draws_the_samples_exclusions_and_earlier_indents(tmp_path: Path) -> None:
    """On a sample file with a clamp, a particle and an earlier test: the map shows all three."""
    from aeni_console.cli.run import run_engine
    from aeni_console.reports.run import read_run, render_report
    from core.runconfig import load_run_config

    root = Path(__file__).resolve().parents[1]
    rc = load_run_config(
        None,
        {"sample.file": str(root / "docs/examples/NiTiCu-library-07.toml"), "planner.indent_budget": 25},
    )
    journal = tmp_path / "sample.sqlite"
    assert run_engine(journal, create=(rc.campaign, rc.options), quiet=True) == 0
    data = read_run(journal)
    assert len(data.exclusions) == 2 and len(data.earlier_indents_um) == 40
    with_them = render_report(data, tmp_path / "with")
    data.exclusions, data.earlier_indents_um = (), []
    without = render_report(data, tmp_path / "without")
    a, b = _image(with_them[0]), _image(without[0])
    assert a.shape == b.shape
    assert (np.abs(a - b).sum(axis=-1) > 0.1).sum() > 500  # the regions and the earlier indents are drawn


def _legend_labels(fig) -> list[str]:  # type: ignore[no-untyped-def]
    return [t for ax in fig.axes for t in ax.get_legend_handles_labels()[1]]


def test_report_figures_read_without_help(demo_run: Path) -> None:
    """Plain stage-µm ticks; failed, unverified and never-indented sites apart; every veto counted where it
    happened; one legend entry per meaning; the cause named where the total sd jumps."""
    import dataclasses

    import matplotlib.pyplot as plt

    from aeni_console.reports.run import _overlay, _stage_axes, _vetoes, read_run, uncertainty_jumps
    from core.plan import IndentResult, IndentSpec

    data = read_run(demo_run)
    # the instrument's other outcomes, at sites of the run (as an export reports them)
    spec = IndentSpec(data.indents[0].commanded_x_um, data.indents[0].commanded_y_um, 5.0)
    extra = [
        IndentResult.unmeasured(99, i, spec, 1.0, s, "test") for i, s in enumerate(("failed", "not_run"))
    ]
    data = dataclasses.replace(data, indents=[*data.indents, *extra])
    fig, ax = plt.subplots()
    _overlay(ax, data)
    _stage_axes(ax, data)
    fig.canvas.draw()
    labels = _legend_labels(fig)
    assert len(labels) == len(set(labels)), labels
    assert any(lb.startswith("failed") for lb in labels) and any(
        lb.startswith("never indented") for lb in labels
    )
    ticks = [t.get_text() for t in ax.get_xticklabels() if t.get_text()]
    assert 2 <= len(ticks) <= 6 and all(t.lstrip("−-").isdigit() for t in ticks), ticks
    # vetoes: one marker per place, counted; the legend says how many in all
    n_vetoed = sum(1 for d in data.decisions if d.status == "vetoed")
    assert n_vetoed >= 1
    fig2, ax2 = plt.subplots()
    assert _vetoes(ax2, data, "vetoed") == n_vetoed
    assert _legend_labels(fig2) == [f"vetoed ({n_vetoed})"]
    plt.close("all")
    # a jump of the total sd is explained: here a refit that moved the length-scales
    assert len(data.uncertainty) >= 2 and len(data.fits) == len(data.uncertainty)
    (t0, e0, s0), (t1, e1, _) = data.uncertainty[:2]
    bid, scales, _ = data.fits[1]
    jumped = dataclasses.replace(
        data,
        uncertainty=[(t0, e0, s0), (t1, e1, 3 * s0), *data.uncertainty[2:]],
        fits=[data.fits[0], (bid, tuple(3 * v for v in scales), False), *data.fits[2:]],
        warnings=[],
    )
    notes = dict(uncertainty_jumps(jumped))
    assert 1 in notes and "sd ×3.0" in notes[1] and "refit: ℓ" in notes[1]


def test_approvals_the_timeout_took_are_not_shown_as_the_operators(tmp_path: Path) -> None:
    """Issue 38: supervised, nobody at the keys, approval_timeout_s: every approval is the timeout's."""
    import matplotlib.pyplot as plt

    from aeni_console.cli.run import run_engine
    from aeni_console.reports.run import _decision_figure, decision_who, read_run, summary_markdown
    from core.runconfig import RunOptions, make_campaign_config

    cfg = make_campaign_config("alone", policy="cost-aware", lattice_n=30, settings={"indent_budget": 40})
    path = tmp_path / "alone.sqlite"
    opts = RunOptions(supervision="supervised", approval_timeout_s=0.2, on_timeout="approve")
    assert run_engine(path, create=(cfg, opts), quiet=True) == 0
    data = read_run(path)
    approved = [d for d in data.decisions if d.status == "approved"]
    assert approved and {decision_who(d, data.resolved_by) for d in approved} == {"approved-timeout"}
    text = summary_markdown(data, [], None)
    assert f"{len(approved)} approved by the timeout (approval_timeout_s)" in text, text
    assert "approved by the operator" not in text
    fig_path = _decision_figure(plt, data, tmp_path)
    assert fig_path.exists()
    plt.close("all")


def test_unverified_indents_are_counted_and_listed_and_their_two_kinds_told_apart(demo_run: Path) -> None:
    """Issue 38: a refused export and no export at all are two things; summary.md counts and lists both."""
    import dataclasses

    import matplotlib.pyplot as plt

    from aeni_console.reports.run import _overlay, read_run, summary_markdown
    from core.plan import IndentResult, IndentSpec

    data = read_run(demo_run)
    spec = IndentSpec(data.indents[0].commanded_x_um, data.indents[0].commanded_y_um, 5.0)
    refused = "export r-099-export.xlsx refused: the Y axis is flipped; made, not learnt from"
    no_export = (
        "no export by the deadline: the array was confirmed started, so the tip may have indented here"
    )
    extra = [
        IndentResult.unmeasured(99, 0, spec, 1.0, "unverified", refused),
        IndentResult.unmeasured(99, 1, spec, 1.0, "unverified", refused),
        IndentResult.unmeasured(99, 2, spec, 1.0, "unverified", no_export),
    ]
    data = dataclasses.replace(data, indents=[*data.indents, *extra])
    text = summary_markdown(data, [], None)
    assert (
        "0 failed, 3 unverified (2 made with their export refused, 1 started with no export at all) and 0 not run"
        in text
    ), text
    assert "## Unverified indents" in text
    rows = [ln for ln in text.splitlines() if ln.startswith("| 99 |")]
    assert [r.split(" | ")[2] for r in rows] == ["export refused", "export refused", "no export"], rows
    fig, ax = plt.subplots()
    _overlay(ax, data)
    labels = _legend_labels(fig)
    assert "unverified: made, its export refused (2)" in labels, labels
    assert "unverified: started, no export at all (1)" in labels, labels
    plt.close("all")

"""Sample files: the template, `aeni sample new | check`, every bad file refused in one line, and a run on
a real-looking sample (rotated 3°, skewed corners, two exclusions, 40 earlier indents) end to end."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest

from aeni_console.cli.main import main
from core.errors import InputError
from core.sample import SAMPLE_TEMPLATE, Sample, load_sample, parse_sample, sample_from_dict

EXAMPLE = Path(__file__).resolve().parents[1] / "docs" / "examples" / "NiTiCu-library-07.toml"


def template() -> dict:
    return tomllib.loads(SAMPLE_TEMPLATE)


def test_the_template_and_the_example_are_valid_and_round_trip() -> None:
    s = parse_sample(template(), "template")
    assert s.name == "NiTiCu-library-07" and s.lattice_n == 50 and len(s.exclusions) == 2
    assert (s.dz_safe_um, s.r_excl_um, s.edge_band_um) == (5.0, 20.0, 25.0)
    ex = load_sample(EXAMPLE)
    assert len(ex.earlier_indents_um) == 40
    # rotated 3°: the bottom edge BL→BR rises at 3°; the corners are skewed off a parallelogram
    bl, br = ex.calibration.bl, ex.calibration.br
    assert np.degrees(np.arctan2(br.y_um - bl.y_um, br.x_um - bl.x_um)) == pytest.approx(3.0, abs=0.01)
    assert ex.calibration.parallelogram_residual_um > 1.0
    again = sample_from_dict(ex.to_dict(), "journal")
    assert again == ex


def test_sample_new_writes_the_template_once(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    target = tmp_path / "s.toml"
    assert main(["sample", "new", str(target)]) == 0
    assert target.read_text(encoding="utf-8") == SAMPLE_TEMPLATE
    assert main(["sample", "new", str(target)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "already exists" in err and str(target) in err


def test_sample_check_prints_the_facts_and_draws_the_sample(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["sample", "check", str(EXAMPLE), "--width", "80", "--height", "24"]) == 0
    out = capsys.readouterr().out
    for fact in (
        "valid",
        "area 1.800 mm²",
        "parallelogram defect 2.0 µm",
        "plane tilt 2.23 µm/mm",
        "2 exclusion region(s), 40 earlier indent(s)",
        "grid baseline",
    ):
        assert fact in out, fact
    assert "stage x (µm), reversed: as the sample is seen" in out
    # x reversed (kla-imicro): the tick labels fall from left to right
    ticks = [line for line in out.splitlines() if "13,498" in line and "11,937" in line]
    assert ticks and ticks[0].index("13,498") < ticks[0].index("11,937")


def _with(data: dict, path: tuple[str, ...], value: object) -> dict:
    node = data
    for key in path[:-1]:
        node = node[key]
    if value is None:
        del node[path[-1]]
    else:
        node[path[-1]] = value
    return data


def _toml(data: dict) -> str:
    def val(v: object) -> str:
        if isinstance(v, dict):
            return "{ " + ", ".join(f"{k} = {val(x)}" for k, x in v.items()) + " }"
        if isinstance(v, list):
            return "[" + ", ".join(val(x) for x in v) + "]"
        if isinstance(v, str):
            return f'"{v}"'
        return repr(v)

    lines = [f"{k} = {val(v)}" for k, v in data.items() if not isinstance(v, dict | list) or k == "lattice_n"]
    for k, v in data.items():
        if isinstance(v, dict):
            lines.append(f"[{k}]")
            lines += [f"{kk} = {val(vv)}" for kk, vv in v.items()]
    for e in data.get("exclusions", []):
        lines.append("[[exclusions]]")
        lines += [f"{kk} = {val(vv)}" for kk, vv in e.items()]
    return "\n".join(lines) + "\n"


def _swap(data: dict, a: str, b: str) -> dict:
    c = data["corners"]
    c[a], c[b] = c[b], c[a]
    return data


def _mm(data: dict) -> dict:
    for c in data["corners"].values():
        c["x_um"] /= 1000.0
        c["y_um"] /= 1000.0
    return data


BAD = [
    ("missing corner", lambda d: _with(d, ("corners", "tr"), None), "field corners.tr is missing"),
    (
        "collinear",
        lambda d: _with(d, ("corners", "tr"), {"x_um": 12748.95, "y_um": 8039.25, "z_um": 250.0}),
        "collinear corners",
    ),
    (
        "self-crossing",
        lambda d: _swap(d, "tr", "br"),
        "not a convex quadrilateral",
    ),
    (
        "outside the stage",
        lambda d: _with(d, ("safety", "stage_rect_um"), [0.0, 0.0, 13000.0, 100000.0]),
        "field safety.stage_rect_um: corner(s) TR, BR lie outside",
    ),
    (
        "too much tilt",
        lambda d: _with(d, ("corners", "tl"), d["corners"]["tl"] | {"z_um": 400.0}),
        "imply a tilt of",
    ),
    (
        "exclusions cover all",
        lambda d: _with(d, ("exclusions",), [{"circle_um": [12700.0, 8650.0, 5000.0]}]),
        "field exclusions: the exclusion regions and the edge band cover the whole area",
    ),
    ("unknown profile", lambda d: _with(d, ("profile",), "kla-nano"), "field profile = 'kla-nano'"),
    ("corners in mm", _mm, "field corners: the corners span only"),
    (
        "r_excl in mm",
        lambda d: _with(d, ("safety", "r_excl_um"), 0.02),
        "field safety.r_excl_um = 0.02 looks like mm",
    ),
    (
        "exclusion in mm",
        lambda d: _with(d, ("exclusions",), [{"circle_um": [12.7, 8.65, 0.15]}]),
        "field exclusions[0].circle_um = [12.7, 8.65, 0.15] looks like mm",
    ),
    (
        "no such csv",
        lambda d: _with(d, ("earlier",), {"indents_csv": "nope.csv"}),
        "field earlier.indents_csv",
    ),
    ("unknown field", lambda d: _with(d, ("safety", "r_exc_um"), 3.0), "unknown field safety.r_exc_um"),
]


@pytest.mark.parametrize(("case", "edit", "message"), BAD, ids=[b[0] for b in BAD])
def test_bad_sample_files_give_one_line_naming_file_and_field(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], case: str, edit: object, message: str
) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(_toml(edit(template())), encoding="utf-8")  # type: ignore[operator]
    assert main(["sample", "check", str(path), "--no-plot"]) == 2
    out = capsys.readouterr()
    assert out.out == ""
    assert out.err.startswith(f"aeni: error: {path}: ") and out.err.count("\n") == 1, out.err
    assert message in out.err and "Traceback" not in out.err
    # the run refuses the same file the same way, before any journal exists
    journal = tmp_path / "run.sqlite"
    assert main(["run", "--sample", str(path), "--journal", str(journal), "--quiet"]) == 2
    assert message in capsys.readouterr().err and not journal.exists()


def test_placement_mask_keeps_sub_grids_off_edges_and_exclusions() -> None:
    s = parse_sample(template(), "t")
    xy = np.array(
        [[12700.0, 8650.0], [12700.0, 8805.0], [12700.0, 8830.0], [12720.0, 9230.0], [12900.0, 8400.0]]
    )
    assert s.allowed(xy, 10.0).tolist() == [False, False, True, False, True]


def test_a_scenario_laid_onto_a_sample_is_scored_on_the_sample() -> None:
    from drivers.sim.scenarios import LaidTruth, make_scenario

    s: Sample = load_sample(EXAMPLE)
    scen = make_scenario("ternary", 0).on_sample(s)
    assert isinstance(scen.truth, LaidTruth) and scen.sample is s
    # the ternary maximum (7 GPa at the field's bottom-left) lands at the sample's BL corner
    bl = s.calibration.bl
    assert float(scen.truth.hardness_gpa(bl.x_um + 1e-6, bl.y_um + 1e-6)) == pytest.approx(7.0, abs=0.05)
    ev = scen.evaluator(20)
    assert ev.xy_um.shape == (400, 2)
    assert s.calibration.contains_stage(ev.xy_um[:, 0], ev.xy_um[:, 1]).mean() > 0.95


def test_a_run_on_a_real_looking_sample_keeps_off_exclusions_and_earlier_indents(tmp_path: Path) -> None:
    """The issue's 'done when': rotated 3°, skewed corners, two exclusions, 40 earlier indents, --driver sim."""
    from core.journal import JournalReader

    journal = tmp_path / "real.sqlite"
    argv = ["run", "--sample", str(EXAMPLE), "--driver", "sim", "--journal", str(journal)]
    assert main([*argv, "--budget-s", "30000", "--lattice-n", "30", "--quiet"]) == 0
    sample = load_sample(EXAMPLE)
    with JournalReader(journal) as r:
        cols, rows = r.table("indents")
        snap = r.snapshot()
        _, events = r.table("events")
        meta_sample = r.meta["config"]["sample"]
    assert snap.finished and snap.n_blocks >= 5 and snap.mape_pct is not None
    assert not [e for e in events if "safety interlock refused" in str(e)]
    assert sample_from_dict(meta_sample, "journal") == sample  # the journal keeps the sample it ran on
    col = {name: i for i, name in enumerate(cols)}
    for kind in ("commanded", "actual"):
        xy = np.array([(row[col[f"{kind}_x_um"]], row[col[f"{kind}_y_um"]]) for row in rows])
        assert len(xy) == snap.n_indents > 100
        assert (sample.exclusion_clearance_um(xy[:, 0], xy[:, 1]) > 0).all()  # in no excluded place
        e = sample.earlier_xy_um
        d = np.hypot(xy[:, None, 0] - e[None, :, 0], xy[:, None, 1] - e[None, :, 1])
        assert d.min() >= sample.r_excl_um - 1e-9  # none within r_excl of an earlier indent
    cmd = np.array([(row[col["commanded_x_um"]], row[col["commanded_y_um"]]) for row in rows])
    assert (sample.calibration.edge_distance_um(cmd[:, 0], cmd[:, 1]) >= sample.edge_band_um - 1e-9).all()


def test_sample_errors_are_input_errors_naming_the_source() -> None:
    with pytest.raises(InputError, match=r"^t: field name is missing"):
        parse_sample({k: v for k, v in template().items() if k != "name"}, "t")


def test_the_readme_documents_the_example_sample_file() -> None:
    """The README shows the worked sample file abridged: every setting it shows is the file's own."""
    readme = (EXAMPLE.parents[2] / "README.md").read_text(encoding="utf-8")
    block = readme.split("```toml\n", 1)[1].split("```", 1)[0]
    assert 'name = "NiTiCu-library-07"' in block and str(EXAMPLE.name) in readme

    def settings(text: str) -> list[str]:
        lines = (ln.split("#", 1)[0].strip() for ln in text.splitlines())
        return [" ".join(ln.split()) for ln in lines if "=" in ln]

    shown, kept = settings(block), set(settings(EXAMPLE.read_text(encoding="utf-8")))
    assert len(shown) >= 10 and [ln for ln in shown if ln not in kept] == []


def test_resuming_a_journal_from_before_samples_says_why_it_cannot(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from core.journal import Journal
    from core.profile import load_profile

    path = tmp_path / "old.sqlite"
    old = {"name": "old", "policy": "cost-aware", "scenario": "ternary", "seed": 0, "settings": {}}
    Journal.create(path, old, load_profile("kla-imicro"), {}, name="old").close()
    assert main(["resume", str(path), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"aeni: error: {path}: written before runs had a sample") and err.count("\n") == 1


def test_allowed_is_the_one_placement_rule_for_planners_the_check_and_the_map() -> None:
    """Sample.allowed also keeps r_excl from the indents the sample came with, and the campaign's lattice mask
    (planners, final maps) and `aeni sample check` are that function, not copies of it."""
    from dataclasses import replace as dc_replace

    from aeni_console.cli.sample import allowed_lattice
    from core.campaign import Campaign
    from core.campaign_config import CampaignConfig
    from core.policies.base import DEFAULT_PITCH_UM

    s = parse_sample(template(), "t")
    xy = np.array([[12700.0, 8830.0], [12700.0, 8845.0], [12700.0, 8900.0]])
    assert s.allowed(xy).tolist() == [True, True, True]
    used = dc_replace(s, earlier_indents_um=((12700.0, 8830.0),))
    assert used.allowed(xy).tolist() == [False, False, True]  # r_excl 20 µm around the earlier indent
    assert used.allowed(xy, 10.0).tolist() == [False, False, True]
    lattice_xy, ok = allowed_lattice(used)
    np.testing.assert_array_equal(ok, used.allowed(lattice_xy, 2 * DEFAULT_PITCH_UM))
    c = Campaign(CampaignConfig(policy="cost-aware", seed=0), used)
    np.testing.assert_array_equal(c.placement_mask, used.allowed(c.lattice.xy_um, 2 * DEFAULT_PITCH_UM))
    assert not c.placement_mask.all() and c.placement_mask.any()

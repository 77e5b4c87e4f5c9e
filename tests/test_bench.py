"""``aeni bench``: the quick bench end to end (relations between policies, never absolute times), the
aggregation rules, the report files, and bad input."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from aeni_console.bench.harness import BenchConfig, RunRecord, summarise
from aeni_console.bench.statistics import _paired_speedups, _quartiles
from aeni_console.cli.main import main


@pytest.fixture(scope="module")
def quick(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, object]]:
    """The quick bench on the hardness, as the paper's relations are stated: aiming at both maps runs every
    `aeni` seed on to the modulus target, about 6× this fixture's CPU (352 s against 60 s); scoring both maps is
    tested at a small size below (the both-maps table and trajectories) and measured by the benchmarks."""
    out = tmp_path_factory.mktemp("bench")
    argv = ["bench", "--quick", "--quiet", "--out", str(out), "--map-weights", "hardness=1,modulus=0"]
    assert main(argv) == 0
    return out, json.loads((out / "results.json").read_text(encoding="utf-8"))


def _summary(data: dict[str, object], policy: str) -> dict[str, object]:
    summaries = data["summaries"]
    assert isinstance(summaries, list)
    return next(s for s in summaries if s["policy"] == policy and s["scenario"] == "ternary")


def _median_hit(data: dict[str, object], policy: str) -> float:
    q = _summary(data, policy)["t_hit_s"]
    return math.inf if q is None or q[1] is None else float(q[1])  # type: ignore[index]


def test_quick_bench_runs_every_policy_on_the_same_seeds(quick: tuple[Path, dict[str, object]]) -> None:
    _, data = quick
    runs = data["runs"]
    assert isinstance(runs, list)
    cfg = BenchConfig.make(quick=True)
    expected = {(p, s) for sc in cfg.scenarios for p in sc.policies for s in range(cfg.seeds)}
    assert {(r["policy"], r["seed"]) for r in runs} == expected
    grid = {r["seed"]: r for r in runs if r["policy"] == "grid"}
    for r in runs:
        g = grid[r["seed"]]
        # same target and budget for every policy on a seed: the grid's final MAPE and its time
        assert r["target_mape_pct"] == pytest.approx(g["final_mape_pct"])
        if r["policy"] != "grid":
            assert r["budget_s"] == pytest.approx(g["instrument_s"])
            assert r["instrument_s"] <= g["instrument_s"] * 1.02 + 1.0
        assert sum(r["ledger"].values()) == pytest.approx(r["instrument_s"], rel=1e-9)
        if r["t_hit_s"] is not None:
            # results.json rounds the trajectory (1 s, 1e-4 %)
            hit = next(t for t, m in r["trajectory"] if m <= r["target_mape_pct"] + 1e-4)
            assert r["t_hit_s"] == pytest.approx(hit, abs=1.0)


def test_quick_bench_relations(quick: tuple[Path, dict[str, object]]) -> None:
    _, data = quick
    grid = _median_hit(data, "grid")
    assert grid == pytest.approx(286_600, rel=0.01)  # the grid reaches its own final MAPE at its end
    for policy in ("uncertainty", "cost-aware", "aeni-paper", "aeni"):
        s = _summary(data, policy)
        assert s["hit_rate"] == 1.0, policy
        assert _median_hit(data, policy) < grid, policy
    # cost-awareness, the paper's workflow and scattered singles pay: each reaches the grid's final MAPE sooner
    assert _median_hit(data, "cost-aware") < grid / 1.5
    assert _median_hit(data, "aeni-paper") < _median_hit(data, "uncertainty")
    assert _median_hit(data, "aeni") < _median_hit(data, "aeni-paper")
    assert _summary(data, "aeni")["speedup_grid"][1] > 4.0  # type: ignore[index]
    # the grid never finds the corner maximum; the adaptive policies get closer to it
    grid_max = _summary(data, "grid")["max_found_gpa"][1]  # type: ignore[index]
    assert _summary(data, "uncertainty")["max_found_gpa"][1] > grid_max + 0.5  # type: ignore[index]


def test_quick_bench_writes_the_report(quick: tuple[Path, dict[str, object]]) -> None:
    out, _ = quick
    md = (out / "RESULTS.md").read_text(encoding="utf-8")
    assert "| policy | reached | time to grid's final MAPE | speed-up vs grid | vs uncertainty |" in md
    for policy in ("grid", "uncertainty", "cost-aware", "aeni-paper", "aeni"):
        assert f"| `{policy}` |" in md
    assert "## Targets" in md and "≥ 10×" in md and "## Every policy on every field" in md
    # every campaign ran through the engine and its interlock: the product's planners are never refused
    lines = md.splitlines()
    heads = [
        i
        for i, line in enumerate(lines)
        if line.endswith(
            "| interlock refusals | approvals | failed indents | fast indents | time in fast arrays |"
        )
    ]
    assert heads
    failed = 0
    for i in heads:
        rows = []
        for line in lines[i + 2 :]:
            if not line.startswith("|"):
                break
            rows.append(line)
        cells = [[c.strip() for c in line.strip("|").split("|")] for line in rows]
        assert rows and all(c[-5:-3] == ["0", "0"] for c in cells)
        failed += sum(int(c[-3]) for c in cells)
        # the fast column, for every policy: the quick bench's policies plan CSM indents only
        assert all(c[-2:] == ["0", "0 s"] for c in cells)
    # the simulated instrument fails like a real one by default (1.5 % of indents): the quick bench meets it
    assert failed > 0
    assert "1.5 % of indents come back invalid" in md
    for name in ("curves_ternary.png", "maps_ternary.png", "costs.png"):
        png = out / "figures" / name
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert f"figures/{name}" in md
    assert not (out / "rough_truth.csv").exists()  # working files stay out of the report folder


# -- aggregation rules ----------------------------------------------------------------------------------


def _rec(policy: str, seed: int, hit: float | None, final: float = 0.5) -> RunRecord:
    return RunRecord(
        scenario="s",
        policy=policy,
        seed=seed,
        target_mape_pct=0.5,
        t_hit_s=hit,
        final_mape_pct=final,
        max_found_gpa=5.0,
        true_max_gpa=6.0,
        instrument_s=hit or 1000.0,
        budget_s=1000.0,
        indents=100,
        blocks=10,
        reconfigurations=0,
        ledger={"indent": 100.0},
        stop_reason="",
        wall_s=1.0,
        trajectory=[(hit or 1000.0, final)],
        max_found=[(10.0, 5.0)],
    )


def test_quartiles_keep_misses_as_infinite() -> None:
    assert _quartiles([1.0, 2.0, 3.0]) == (1.5, 2.0, 2.5)
    assert _quartiles([1.0, 2.0, 3.0, math.inf]) == (1.75, 2.5, math.inf)
    assert math.isinf(_quartiles([1.0, math.inf, math.inf])[1])  # type: ignore[index]
    assert _quartiles([]) is None


def test_speedups_are_paired_by_seed_and_misses_count_as_infinitely_slow() -> None:
    ref = {0: _rec("grid", 0, 1000.0), 1: _rec("grid", 1, 1000.0), 2: _rec("grid", 2, None)}
    pol = {0: _rec("p", 0, 250.0), 1: _rec("p", 1, None), 2: _rec("p", 2, 400.0)}
    assert sorted(_paired_speedups(pol, ref)) == [0.0, 4.0, math.inf]
    both_miss = {2: _rec("p", 2, None)}
    assert _paired_speedups(both_miss, ref) == []
    rows = summarise([*ref.values(), *pol.values()])
    p = next(r for r in rows if r.policy == "p")
    assert p.hit_rate == pytest.approx(2 / 3)
    assert p.speedup_grid is not None and p.speedup_grid[1] == pytest.approx(4.0)


def test_scenario_subset_keeps_the_bench_order_of_the_given_keys() -> None:
    full = BenchConfig.make(quick=False, only="film, collapse,film")
    assert [s.key for s in full.scenarios] == ["film", "collapse"]
    assert full.seeds == 10 and full.lattice_n == 50
    # the collapse provocation runs on past its target: divergence shows only after it
    assert full.scenarios[1].margin is not None and full.scenarios[1].margin > full.margin
    assert {"grid", "aeni-paper", "aeni"} <= set(full.scenarios[1].policies)


def test_policy_subset_holds_on_extra_fields_and_runs_the_ablations_it_names() -> None:
    """``--policies`` filters every scenario, also one added with ``--scenarios`` (rough-csv ran all eight
    policies before), and an ablation it names runs beside them instead of being dropped in silence."""
    config = BenchConfig.make(
        quick=False, only="rough-csv,good-drift", policies="aeni,aeni+strict-guard,uncertainty"
    )
    by_key = {s.key: s.policies for s in config.scenarios}
    assert sorted(by_key["rough-csv"]) == ["aeni", "aeni+strict-guard", "grid", "uncertainty"]
    # the drift provocation runs no uncertainty: a named policy runs only where its scenario runs it
    assert sorted(by_key["good-drift"]) == ["aeni", "aeni+strict-guard", "grid"]


# -- bad input ------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--seeds", "0"], "--seeds"),
        (["--jobs", "two"], "--jobs"),
        (["--out", "{file}"], "folder"),
        (["--scenarios", "ternary,nope"], "nope"),
        (["--lattice", "5"], "--lattice"),
    ],
)
def test_bench_bad_input_is_one_line_exit_2_and_nothing_written(
    args: list[str], needle: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    afile = tmp_path / "taken.txt"
    afile.write_text("x", encoding="utf-8")
    args = [a.format(file=afile) for a in args]
    if "--out" not in args:
        args += ["--out", str(tmp_path / "out")]
    try:
        code = main(["bench", "--quick", *args])
    except SystemExit as exc:
        code = int(exc.code or 0)
    captured = capsys.readouterr()
    assert code == 2 and captured.out == ""
    err = captured.err.strip()
    assert "\n" not in err and needle in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["taken.txt"]


def test_the_full_report_renders_every_section_from_synthetic_runs(tmp_path: Path) -> None:
    """A full bench takes half an hour: every table, target and reason must render before it is started.
    Synthetic runs (no campaigns) cover every scenario and policy of the full configuration, some seeds
    missing the target, so each code path of the report is taken."""
    from dataclasses import replace

    from aeni_console.reports.bench import results_markdown, targets, write_report

    config = BenchConfig.make(quick=False, seeds=3)
    records = []
    for sc in config.scenarios:
        for p_i, policy in enumerate(sc.policies):
            for seed in range(config.seeds):
                hit = None if (p_i + seed) % 4 == 3 else 280_000.0 / (1 + p_i + 0.1 * seed)
                base = _rec(policy, seed, hit if policy != "grid" else 280_000.0, final=0.5 + 0.01 * p_i)
                records.append(
                    replace(
                        base,
                        scenario=sc.key,
                        trajectory=[(1000.0, 3.0), (base.instrument_s, base.final_mape_pct or 0.5)],
                        ledger={"indent": base.instrument_s * 0.6, "drift": base.instrument_s * 0.4},
                    )
                )
    md = results_markdown(records, config, 60.0, {})
    for sc in config.scenarios:
        for policy in sc.policies:
            assert f"| `{policy}` |" in md
    names = [t["target"] for t in targets(summarise(records), records, config)]
    assert any("collapse" in n for n in names) and any("real-film" in n for n in names)
    robust = [sc.key for sc in config.scenarios if sc.group == "robustness"]
    assert len(robust) >= 8 and all(any(k in n for n in names) for k in robust)
    assert "### Where the policies lose" in md
    # the oracle's limit is read from benchmarks/results/oracle_bound.json, not typed in
    oracle = json.loads((Path(__file__).parents[1] / "benchmarks/results/oracle_bound.json").read_text())
    assert f"takes {oracle['best']['median']['indents']} indents" in md
    write_report(records, config, tmp_path, 60.0)
    assert json.loads((tmp_path / "results.json").read_text(encoding="utf-8"))["runs"]
    assert "## Speed-up by error level" in md and "| ternary | `meta-grid` | `uncertainty` |" in md
    assert "| outliers |" in md and "### At 2× the grid's final MAPE" in md


def test_why_text_gives_each_missed_fields_even_design_limit_from_its_own_json(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A robustness field (or the film) where ``aeni`` misses its target gets that field's even-design limit,
    read from benchmarks/results/oracle_bound_<field>.json: here small files in a tmp folder."""
    from dataclasses import replace

    from aeni_console.reports import bench as report

    def oracle(field: str, best: int | None, rows: list[tuple[int, bool]]) -> None:
        table = [
            {
                "centres": n,
                "g": 1,
                "estimator": "median",
                "indents": n,
                "reaches_target": ok,
                "max_speedup": 2e5 / n,
            }
            for n, ok in rows
        ]
        pick = next((r for r in table if r["indents"] == best), None)
        data = {"field": field, "seeds": 3, "grid_time_s": 9e6, "grid_final_mape_pct": 1.2345, "rows": table}
        data |= {"best": {"median": pick, "huber": None}, "wall_s": 1.0}
        (tmp_path / f"oracle_bound_{field}.json").write_text(json.dumps(data), encoding="utf-8")

    oracle("grains", 1444, [(1024, False), (1444, True)])
    oracle("stripe", None, [(196, False), (2500, False)])
    oracle("rotated-quaternary", 400, [(196, False), (400, True)])  # the bench calls this field "rotated"
    oracle("step", 196, [(196, True)])  # aeni meets its target there: no line
    oracle("film", 196, [(196, True), (400, True)])  # the smallest design tried reaches it: no limit found
    monkeypatch.setattr(report, "ORACLE_DIR", tmp_path)
    records = []
    misses = (("grains", 100_000.0), ("stripe", None), ("rotated", 90_000.0), ("film", 80_000.0))
    for key, aeni_hit in (*misses, ("step", 10_000.0)):
        aeni = replace(_rec("aeni", 0, aeni_hit, final=0.53), scenario=key, indents=1563)
        if aeni_hit is None:
            aeni = replace(aeni, stop_reason="policy aeni has nothing left to propose")
        records += [replace(_rec("grid", 0, 280_000.0), scenario=key), aeni]
    text = report.why_text(summarise(records), records)
    lines = {ln.split("**")[1]: ln for ln in text.splitlines() if ln.startswith("- **`aeni` on")}
    assert set(lines) == {f"`aeni` on {key}:" for key, _ in misses}
    assert lines["`aeni` on grains:"].endswith(
        "The cheapest even design of single indents that reaches the grid's MAPE on this field (1.234 % in"
        " `benchmarks/oracle_bound.py --field grains`, 3 seeds) takes 1,444 indents: at most 138.5× faster"
        " than the grid."
    )
    assert (
        "No even design of single indents up to 2,500 indents reaches the grid's MAPE"
        in lines["`aeni` on stripe:"]
    )
    # a seed that missed says how far from its target it ended, and what ended it
    assert (
        "never reached the grid's MAPE on seed 0 (ended at 0.530 % against 0.500 % after 1,563 indents:"
        " policy aeni has nothing left to propose)." in lines["`aeni` on stripe:"]
    )
    assert (
        "--field rotated-quaternary" in lines["`aeni` on rotated:"]
        and "takes 400 indents" in lines["`aeni` on rotated:"]
    )
    assert lines["`aeni` on film:"].endswith(
        "Even the smallest even design tried, 196 single indents, reaches the grid's MAPE on this field (1.234 %"
        " in `benchmarks/oracle_bound.py --field film`, 3 seeds): the limit lies above 1020.4×."
    )
    # no ternary file in the folder: no ternary line; a field without a file gets no sentence
    assert "The even-design limit" not in text
    assert report._oracle("ternary") is None and report._field_limit("phase-noise") == ""
    assert report._field_limit("collapse") == ""  # a provocation, not a field the oracle speaks for


def test_render_from_results_json_gives_the_same_report(
    quick: tuple[Path, dict[str, object]], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out, _ = quick
    again = tmp_path / "again"
    (again / "figures").mkdir(parents=True)
    (again / "figures" / "maps_ternary.png").write_bytes((out / "figures" / "maps_ternary.png").read_bytes())
    assert main(["bench", "--render-from", str(out / "results.json"), "--out", str(again)]) == 0
    assert "rendered" in capsys.readouterr().out
    old = (out / "RESULTS.md").read_text(encoding="utf-8").splitlines()
    new = (again / "RESULTS.md").read_text(encoding="utf-8").splitlines()
    assert "Rendered again from the run's `results.json`" in new[6]
    # the tables come from the stored runs; the map drawn by the run is kept
    assert new[:6] + new[8:] == old
    # not bench output: one line, exit 2
    bad = tmp_path / "bad.json"
    bad.write_text('{"runs": []}', encoding="utf-8")
    assert main(["bench", "--render-from", str(bad), "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "bad.json" in err and "not the output of aeni bench" in err
    assert not (tmp_path / "x").exists()


def test_render_from_several_results_merges_them_and_later_runs_replace_earlier_ones(
    quick: tuple[Path, dict[str, object]], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A sweep run in pieces renders as one: the union of the runs, a later part's run replacing the same
    (scenario, policy, seed) of an earlier one, map figures carried over; parts whose grid baselines differ
    were not run on the same emulator and are refused."""
    out, data = quick
    runs = data["runs"]
    assert isinstance(runs, list)
    part_a = dict(data, runs=[r for r in runs if r["policy"] in ("grid", "uncertainty")])
    changed = [dict(r, final_mape_pct=0.123) if r["policy"] == "uncertainty" else r for r in runs]
    part_b = dict(data, runs=[r for r in changed if r["policy"] in ("grid", "uncertainty", "aeni")])
    (tmp_path / "a" / "figures").mkdir(parents=True)
    (tmp_path / "b").mkdir()
    (tmp_path / "a" / "results.json").write_text(json.dumps(part_a), encoding="utf-8")
    (tmp_path / "b" / "results.json").write_text(json.dumps(part_b), encoding="utf-8")
    (tmp_path / "a" / "figures" / "maps_ternary.png").write_bytes(
        (out / "figures" / "maps_ternary.png").read_bytes()
    )
    merged = tmp_path / "merged"
    sources = f"{tmp_path / 'a' / 'results.json'},{tmp_path / 'b' / 'results.json'}"
    assert main(["bench", "--render-from", sources, "--out", str(merged)]) == 0
    assert "from 2 runs" in capsys.readouterr().out
    got = json.loads((merged / "results.json").read_text(encoding="utf-8"))["runs"]
    keys = sorted((r["policy"], r["seed"]) for r in got)
    want = sorted((r["policy"], r["seed"]) for r in runs if r["policy"] in ("grid", "uncertainty", "aeni"))
    assert keys == want  # the union, each run once
    assert {r["final_mape_pct"] for r in got if r["policy"] == "uncertainty"} == {0.123}  # b replaced a
    md = (merged / "RESULTS.md").read_text(encoding="utf-8")
    assert "Generated by 2 runs of `aeni bench`" in md and "maps_ternary.png" in md
    assert (merged / "figures" / "maps_ternary.png").is_file()
    # grid baselines that disagree: one line, exit 2, nothing written
    other = dict(data, runs=[dict(r, final_mape_pct=9.9) if r["policy"] == "grid" else r for r in runs])
    (tmp_path / "c.json").write_text(json.dumps(other), encoding="utf-8")
    refused = tmp_path / "refused"
    bad = f"{tmp_path / 'a' / 'results.json'},{tmp_path / 'c.json'}"
    assert main(["bench", "--render-from", bad, "--out", str(refused)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "grid baseline" in err and "not the same emulator" in err
    assert not refused.exists()


def test_no_worse_mape_is_asked_at_the_time_the_faster_policy_stopped() -> None:
    from dataclasses import replace

    from aeni_console.bench.harness import mape_at_equal_time, speedup_by_level

    fast = replace(_rec("fast", 0, 100.0, final=0.5), trajectory=[(60.0, 0.8), (100.0, 0.5)])
    slow = replace(
        _rec("slow", 0, 400.0, final=0.3), instrument_s=500.0, trajectory=[(50.0, 0.9), (400.0, 0.45)]
    )
    # at 100 s the slow policy's map is still at 0.9 %, even though it ends better
    assert mape_at_equal_time([fast, slow], "s", "fast", "slow") == (0.5, 0.9)
    assert mape_at_equal_time([fast], "s", "fast", "slow") is None
    # target 0.5: 4× at 1× the target; at 2× (1.0 %) both are there from their first point
    assert speedup_by_level([fast, slow], "s", "fast", "slow", 1.0) == (4.0, 4.0, 4.0)
    assert speedup_by_level([fast, slow], "s", "fast", "slow", 2.0) == (50 / 60, 50 / 60, 50 / 60)


# -- the robustness fields ------------------------------------------------------------------------------


def test_robustness_fields_have_the_character_they_are_named_for() -> None:
    import numpy as np

    from drivers.sim.robust_fields import ROBUST_FIELDS, robust_scenario

    x = np.linspace(0.0, 1000.0, 401)
    gx, gy = np.meshgrid(x, x)
    fields = {k: robust_scenario(k, 0) for k in ROBUST_FIELDS}
    h = {k: s.truth.hardness_gpa(gx, gy) for k, s in fields.items()}
    for k, v in h.items():
        assert np.isfinite(v).all() and v.min() > 1.0, k
    # grains: a handful of phase levels, changing every few tens of µm along a line
    row = h["grains"][200]
    assert 8 <= np.count_nonzero(np.abs(np.diff(row)) > 0.5) <= 50  # neighbours may share a phase
    # step: +1.5 GPa across a line, within a few µm
    jumps = np.abs(np.diff(h["step"], axis=1))
    assert jumps.max() > 1.0 and np.count_nonzero(jumps > 0.5) <= 2 * len(x)
    # stripe: flat within 2 % outside a narrow band that is ~1 GPa harder
    assert np.mean(h["stripe"] > 6.3) < 0.06 and h["stripe"].max() > 6.9
    # phase-noise: the noise is tied to the hard phase
    s = fields["phase-noise"].truth
    hard = h["phase-noise"] > 5.8
    rel = s.noise_sd_gpa(gx, gy) / h["phase-noise"]
    assert rel[hard].mean() > 5 * rel[~hard & (h["phase-noise"] < 5.0)].mean()
    # outliers: pores over 5 % of the surface read 50 % low; the truth (and MAPE) is the film without them
    pores = fields["outliers"].site_texture
    assert pores is not None
    rng = np.random.default_rng(1)
    px, py = rng.uniform(0, 1000, 40_000), rng.uniform(0, 1000, 40_000)
    off = pores.offset_gpa(px, py)
    assert 0.04 < np.mean(off < 0) < 0.06
    truth = fields["outliers"].truth.hardness_gpa(px, py)
    assert np.allclose(off[off < 0], -0.5 * truth[off < 0])


def test_an_indent_on_a_pore_reads_half_and_the_scenario_keeps_the_ternary_stage() -> None:
    from drivers.sim.robust_fields import robust_scenario
    from drivers.sim.scenarios import make_scenario

    s = robust_scenario("outliers", 3)
    base = make_scenario("ternary", 3)
    assert s.calibration == base.calibration and s.profile_name == base.profile_name and s.drift == base.drift
    pores = s.site_texture
    assert pores is not None
    centre = pores._tree.data[0]  # a known pore centre
    emu = s.make_emulator()
    m = emu.measure(float(centre[0]), float(centre[1]), 80.0, 0.0, 0, 0)
    true = float(s.truth.hardness_gpa(centre[0], centre[1]))
    assert m.hardness_gpa == pytest.approx(0.5 * true, rel=0.1)


def test_bench_runs_on_a_dask_cluster_like_it_runs_locally() -> None:
    """``--dask ADDRESS``: the same sweep through joblib's Dask backend gives the same records (a tiny sweep
    on an in-process LocalCluster: a few blocks of the grid, seconds)."""
    from dataclasses import replace

    distributed = pytest.importorskip("distributed")
    from aeni_console.bench.runner import BenchRun, _parallel

    sc = BenchConfig.make(quick=True).scenarios[0]
    specs = [BenchRun(sc, "grid", seed, lattice_n=10, max_blocks=3) for seed in (0, 1)]
    local = _parallel(specs, 1, None)
    with distributed.LocalCluster(
        n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None
    ) as cl:
        remote = _parallel(specs, 1, None, dask_address=cl.scheduler_address)
    assert [replace(r, wall_s=0.0) for r in remote] == [replace(r, wall_s=0.0) for r in local]
    assert [r.seed for r in remote] == [0, 1] and all(r.blocks == 3 for r in remote)


def test_dask_address_that_answers_nothing_is_a_one_line_error(capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("distributed")
    from aeni_console.bench.runner import _dask_client
    from core.errors import InputError

    with pytest.raises(InputError, match="--dask"):
        _dask_client("tcp://127.0.0.1:9")


def test_flat_map_error_is_the_best_constant_maps_and_flags_a_grid_that_resolves_nothing() -> None:
    """The best constant map's MAPE (weighted median of the truth) is what a map that resolves nothing
    scores; a robustness target on a field where the grid's own map is no better is flagged as such."""
    from dataclasses import replace

    import numpy as np

    from aeni_console.reports.bench import flat_map_errors, resolution_table, targets
    from drivers.sim.evaluator import TruthEvaluator
    from drivers.sim.robust_fields import GrainField

    two = TruthEvaluator(GrainField(), np.zeros((4, 2)), np.array([4.0, 4.0, 4.0, 8.0]))
    assert two.flat_mape_pct() == pytest.approx(
        100 * 0.25 * 0.5
    )  # c = 4: only the 8 GPa cell is off, by 50 %
    candidates = np.linspace(3.0, 9.0, 601)
    brute = min(float(np.mean(np.abs(c - two.truth_gpa) / two.truth_gpa)) * 100 for c in candidates)
    assert two.flat_mape_pct() == pytest.approx(brute)

    config = BenchConfig.make(quick=False, seeds=2, only="grains,step")
    flat = flat_map_errors(config)
    assert 5.0 < flat["grains"] < 20.0 and 5.0 < flat["step"] < 20.0
    records = [
        replace(_rec(p, s, 1000.0 if p == "grid" else 100.0, final=f), scenario=sc)
        for sc, f in (("grains", flat["grains"] * 1.01), ("step", 0.2 * flat["step"]))
        for p in ("grid", "aeni")
        for s in range(2)
    ]
    summaries = summarise(records)
    table = "\n".join(resolution_table(summaries, config, flat))
    assert "| grains |" in table and "(**nothing**)" in table.split("| grains |")[1].split("\n")[0]
    assert "(**nothing**)" not in table.split("| step |")[1].split("\n")[0]
    notes = {t["target"]: t["note"] for t in targets(summaries, records, config, flat)}
    assert "no better than a constant" in notes["`aeni` vs `grid`, grains"]
    assert "no better than a constant" not in notes["`aeni` vs `grid`, step"]


def test_merged_full_runs_keep_the_full_scenarios() -> None:
    """Merging full runs keeps the full bench's scenarios (titles, maps), never the quick bench's namesakes."""
    from dataclasses import replace

    from aeni_console.bench.harness import FULL_SCENARIOS, merge_results

    config = BenchConfig.make(quick=False, seeds=1, only="ternary,step")
    a = [replace(_rec(p, 0, 100.0), scenario="ternary") for p in ("grid", "uncertainty")]
    b = [replace(_rec(p, 0, 100.0), scenario=s) for s in ("ternary", "step") for p in ("grid", "aeni")]
    records, merged, wall = merge_results([(a, config, 1.0), (b, config, 2.0)])
    full = {s.key: s for s in FULL_SCENARIOS}
    assert [s.title for s in merged.scenarios] == [full["ternary"].title, full["step"].title]
    assert merged.scenarios[0].policies == config.scenarios[0].policies and wall == 3.0
    assert len(records) == 5


def test_the_bench_scores_both_maps_and_a_hardness_only_run_writes_what_it_wrote() -> None:
    """Both maps (the default since issue 37): every run scores the modulus map too, the grid's final modulus
    MAPE is the others' second target, and the report gains the both-maps table; a hardness-only run
    (``--map-weights hardness=1,modulus=0``) keeps results.json as it was."""
    from dataclasses import replace

    from aeni_console.bench.harness import BenchRun, records_to_json, run_one
    from aeni_console.reports.bench import two_maps_table

    config = BenchConfig.make(quick=True)
    sc = config.scenarios[0]
    both = {"hardness": 1.0, "modulus": 1.0}
    grid = run_one(BenchRun(sc, "grid", 0, lattice_n=10, max_blocks=4, map_weights=both))
    assert (
        grid.final_mape_modulus_pct is not None
        and grid.target_mape_modulus_pct == grid.final_mape_modulus_pct
    )
    assert grid.t_hit_modulus_s is not None and grid.trajectory_modulus[-1][1] == grid.final_mape_modulus_pct
    spec = BenchRun(
        sc,
        "aeni",
        0,
        lattice_n=10,
        max_blocks=6,
        budget_s=grid.instrument_s,
        target_mape_pct=grid.final_mape_pct,
        map_weights=both,
        target_mape_modulus_pct=grid.final_mape_modulus_pct,
    )
    aeni = run_one(spec)
    assert len(aeni.trajectory_modulus) == len(aeni.trajectory) > 0
    assert aeni.target_mape_modulus_pct == grid.final_mape_modulus_pct
    table = "\n".join(two_maps_table([grid, aeni]))
    assert "## Both maps: hardness and modulus" in table and "| ternary | aeni |" in table
    assert "speed-up to both, median (worst seed)" in table
    data = records_to_json([grid, aeni], config, 1.0)
    assert all("trajectory_modulus" in r for r in data["runs"])
    # hardness only (modulus=0): no modulus is scored, and nothing of it is written
    hardness_only = {"hardness": 1.0, "modulus": 0.0}
    plain = run_one(replace(spec, map_weights=hardness_only, target_mape_modulus_pct=None))
    assert plain.trajectory_modulus == [] and plain.final_mape_modulus_pct is None
    run = records_to_json([plain], config, 1.0)["runs"][0]
    assert not any("modulus" in k for k in run) and two_maps_table([plain]) == []

"""The bench report: RESULTS.md, results.json and the PNG figures (drawn by ``aeni_console.reports.bench_figures``).

Everything here reads the bench's records; nothing reruns a campaign. matplotlib is imported only when a
figure is drawn, so ``aeni`` works without it (the Markdown and JSON are written either way).
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from aeni_console.bench.harness import (
    EXTRA_SCENARIOS,
    FULL_SCENARIOS,
    LEVEL_FACTORS,
    LEVEL_PAIRS,
    LOOSE_FACTOR,
    BenchConfig,
    PolicySummary,
    RunRecord,
    flat_mape_pct,
    records_to_json,
    speedup_by_level,
    summarise,
    worst_rise,
)
from aeni_console.files import write_atomic
from aeni_console.reports.bench_figures import (
    LEDGER_COLORS,
    figure_costs,
    figure_curves,
    figure_maps,
    matplotlib_pyplot,
    policy_color,
    policy_order,
)

DIVERGED_RISE = 1.5  # a run whose MAPE rises above 1.5× its best so far has diverged

# -- numbers ---------------------------------------------------------------------------------------------


def _fmt_time(q: tuple[float, float, float] | None) -> str:
    if q is None:
        return "—"
    lo, med, hi = q
    if math.isinf(med):
        return "not reached"

    def k(v: float) -> str:
        return "∞" if math.isinf(v) else f"{v / 1000:,.0f}k" if v >= 10_000 else f"{v / 1000:,.1f}k"

    return f"{k(med)} s [{k(lo)}–{k(hi)}]"


def _fmt_ratio(q: tuple[float, float, float] | None) -> str:
    if q is None:
        return "—"
    lo, med, hi = q

    def f(v: float) -> str:
        return "∞" if math.isinf(v) else f"{v:.2f}"

    return f"{f(med)}× [{f(lo)}–{f(hi)}]"


def _fmt_num(q: tuple[float, float, float] | None, digits: int = 2, unit: str = "") -> str:
    if q is None:
        return "—"
    return f"{q[1]:.{digits}f}{unit}"


def _fmt_fast_s(q: tuple[float, float, float] | None, total: tuple[float, float, float] | None) -> str:
    """Instrument time in fast arrays (median) and its share of the run's (median)."""
    if q is None:
        return "—"
    if q[1] == 0 or total is None or total[1] <= 0:
        return f"{q[1]:,.0f} s"
    return f"{q[1]:,.0f} s ({100 * q[1] / total[1]:.0f} %)"


def _med(q: tuple[float, float, float] | None) -> float | None:
    return None if q is None else q[1]


def scenario_table(rows: Sequence[PolicySummary]) -> str:
    head = (
        "| policy | reached | time to grid's final MAPE | speed-up vs grid | vs uncertainty | vs its reference "
        f"| speed-up at {LOOSE_FACTOR:g}× that MAPE | final MAPE | max found (true) | reconfig. | indents "
        "| interlock refusals | approvals | failed indents | fast indents | time in fast arrays |"
    )
    lines = [head, "|" + "---|" * 16]
    for r in rows:
        ref = ""
        for name, q in r.speedup_ref.items():
            ref = f"{_fmt_ratio(q)} ({name})"
        mx = "—" if r.max_found_gpa is None else f"{r.max_found_gpa[1]:.2f} ({r.true_max_gpa:.2f}) GPa"
        lines.append(
            f"| `{r.policy}` | {_seeds(r)} | {_fmt_time(r.t_hit_s)} "
            f"| {_fmt_ratio(r.speedup_grid)} | {_fmt_ratio(r.speedup_uncertainty)} | {ref or '—'} "
            f"| {_fmt_ratio(r.speedup_grid_loose)} | {_fmt_num(r.final_mape_pct, 3, ' %')} | {mx} "
            f"| {_fmt_num(r.reconfigurations, 0)} | {_fmt_num(r.indents, 0)} "
            f"| {r.interlock_refusals} | {r.approvals} | {r.failed_indents} "
            f"| {_fmt_num(r.fast_indents, 0)} | {_fmt_fast_s(r.fast_array_s, r.instrument_s)} |"
        )
    return "\n".join(lines)


def _get(summaries: Sequence[PolicySummary], scenario: str, policy: str) -> PolicySummary | None:
    return next((s for s in summaries if s.scenario == scenario and s.policy == policy), None)


TERNARY_GOAL, LOOSE2_GOAL, UNC_GOAL, SUITE_GOAL, FILM_GOAL = 10.0, 25.0, 4.0, 5.0, 4.0


def _sw(s: PolicySummary | None, factor: str = "1") -> tuple[float, float] | None:
    return None if s is None else s.suite_vs_grid.get(factor)


def targets(
    summaries: Sequence[PolicySummary],
    records: Sequence[RunRecord] = (),
    config: BenchConfig | None = None,
    flat: dict[str, float] | None = None,
) -> list[dict[str, Any]]:
    """Issue 13's targets for ``aeni``, each with the measured median (and worst seed) and whether it is met.
    ``flat``: each field's best constant map error (see ``resolution_table``), to flag a target the grid's
    own map makes meaningless."""
    out: list[dict[str, Any]] = []

    def add(name: str, goal: str, measured: float | None, ok: bool | None, note: str = "") -> None:
        out.append({"target": name, "goal": goal, "measured": measured, "met": ok, "note": note})

    t = _get(summaries, "ternary", "aeni")
    if t is not None:
        one, two = _sw(t, "1"), _sw(t, "2")
        if one is not None:
            add(
                "`aeni` vs `grid`, ternary, at the grid's final MAPE",
                f"≥ {TERNARY_GOAL:g}×",
                one[0],
                one[0] >= TERNARY_GOAL,
                f"worst seed {_x(one[1])}; reached on {_seeds(t)} seeds",
            )
        if two is not None:
            add(
                "`aeni` vs `grid`, ternary, at 2× that MAPE",
                f"≥ {LOOSE2_GOAL:g}×",
                two[0],
                two[0] >= LOOSE2_GOAL,
                f"worst seed {_x(two[1])}",
            )
        u = _med(t.speedup_uncertainty)
        if u is not None:
            lo = t.speedup_uncertainty[0] if t.speedup_uncertainty else None
            add(
                "`aeni` vs `uncertainty`, ternary",
                f"≥ {UNC_GOAL:g}×",
                u,
                u >= UNC_GOAL,
                f"lower quartile {_x(lo)}",
            )
    robust = [sc.key for sc in (config.scenarios if config is not None else ()) if sc.group == "robustness"]
    for sc in robust:
        a = _get(summaries, sc, "aeni")
        sw = _sw(a)
        if a is None or sw is None:
            continue
        note = f"worst seed {_x(sw[1])}; reached on {_seeds(a)} seeds"
        share = _resolved(summaries, sc, flat)
        if share is not None and share < RESOLVED_FLOOR:
            note += (
                f"; the grid's map is no better than a constant one here ({100 * share:.0f} % of the flat map's"
                " error removed): reaching its MAPE shows how soon a map settles on the mean, not mapping"
            )
        add(
            f"`aeni` vs `grid`, {sc}",
            f"≥ {SUITE_GOAL:g}× median, worst seed ≥ 1×",
            sw[0],
            sw[0] >= SUITE_GOAL and sw[1] >= 1.0,
            note,
        )
    f = _get(summaries, "film", "aeni")
    sw = _sw(f)
    if f is not None and sw is not None:
        add(
            "`aeni` on the real-film scenario: every seed, vs `grid`",
            f"all seeds, ≥ {FILM_GOAL:g}×",
            sw[0],
            f.hit_rate == 1.0 and sw[0] >= FILM_GOAL,
            f"reached on {_seeds(f)} seeds; worst seed {_x(sw[1])}",
        )
    c = _get(summaries, "collapse", "aeni")
    if c is not None:
        rise = c.worst_rise[2] if c.worst_rise else None
        runs = [r for r in records if r.scenario == "collapse" and r.policy == "aeni"]
        diverged = sum(1 for r in runs if (w := worst_rise(r.trajectory)) is not None and w > DIVERGED_RISE)
        ok = c.hit_rate == 1.0 and diverged == 0
        add(
            "`aeni` under collapse provocation: no failure on any seed",
            f"all seeds reach the target, none diverges (MAPE above {DIVERGED_RISE:g} times its best)",
            100.0 * c.hit_rate,  # share of seeds that reached the target
            ok,
            f"reached on {_seeds(c)} seeds; diverged on {diverged}; upper-quartile rise {_x(rise)}",
        )
    return out


RESOLVED_FLOOR = 0.1  # a grid map that removes less than this share of the flat map's error resolves nothing


def _resolved(summaries: Sequence[PolicySummary], key: str, flat: dict[str, float] | None) -> float | None:
    """The share of the best constant map's error that the grid's final map removes (median over seeds)."""
    g = _get(summaries, key, "grid")
    if flat is None or key not in flat or g is None or g.final_mape_pct is None or flat[key] <= 0:
        return None
    return 1.0 - g.final_mape_pct[1] / flat[key]


def flat_map_errors(config: BenchConfig) -> dict[str, float]:
    """Each scenario's best constant map error, from the simulated truth (``drivers.sim``)."""

    out = {}
    for sc in config.scenarios:
        v = flat_mape_pct(sc)
        if v is not None:
            out[sc.key] = v
    return out


def resolution_table(
    summaries: Sequence[PolicySummary], config: BenchConfig, flat: dict[str, float]
) -> list[str]:
    """How much of each field the grid resolves: its final MAPE against the best constant map's. Where the
    grid removes little of that error, its MAPE is a weak target: a map that has barely started, or one that
    smooths the field's feature away, gets there as well."""
    rows = []
    for sc in config.scenarios:
        share = _resolved(summaries, sc.key, flat)
        g = _get(summaries, sc.key, "grid")
        if share is None or g is None or g.final_mape_pct is None:
            continue
        rows.append(
            f"| {sc.key} | {flat[sc.key]:.3f} % | {g.final_mape_pct[1]:.3f} % | {100 * share:.0f} %"
            + (" (**nothing**)" if share < RESOLVED_FLOOR else "")
            + " |"
        )
    if not rows:
        return []
    return [
        "### How much of each field the grid resolves",
        "",
        "The best constant map (the truth's weighted median: a map that resolves nothing) against the grid's"
        " final map (median over seeds). The share of the constant map's error that the grid removes says how"
        " demanding its MAPE is as a target: where it is small, a model that has only settled on the mean, or"
        " one that smooths the field's one feature away, reaches it too.",
        "",
        "| field | best constant map | grid's final map | error removed by the grid |",
        "|---|---|---|---|",
        *rows,
        "",
    ]


def _x(v: float | None) -> str:
    if v is None:
        return "—"
    return "∞" if math.isinf(v) else f"{v:.2f}×"


def suite_tables(summaries: Sequence[PolicySummary], config: BenchConfig) -> list[str]:
    """Policies × fields against the grid at 1×, 1.5× and 2× its final MAPE: median (worst seed)."""
    scens = [sc for sc in config.scenarios if any(s.scenario == sc.key for s in summaries)]
    pols = policy_order([s.policy for s in summaries if s.policy != "grid"])
    out = [
        "## Every policy on every field",
        "",
        "Grid time / policy time to reach f × the grid's final MAPE, paired by seed: median (worst seed in"
        " brackets; 0 = that seed never reached it within the grid's time, — = not run on that field).",
        "",
    ]
    for f in ("1", "1.5", "2"):
        out += [
            f"### At {f}× the grid's final MAPE",
            "",
            "| field | " + " | ".join(f"`{p}`" for p in pols) + " |",
            "|---|" + "---|" * len(pols),
        ]
        for sc in scens:
            cells = []
            for p in pols:
                sw = _sw(_get(summaries, sc.key, p), f)
                cells.append("—" if sw is None else f"{_x(sw[0])} ({_x(sw[1])})")
            out.append(f"| {sc.key} | " + " | ".join(cells) + " |")
        out.append("")
    return out


ORACLE_DIR = Path(__file__).resolve().parents[2] / "benchmarks" / "results"


def _oracle(field: str = "ternary") -> dict[str, Any] | None:
    """benchmarks/results/oracle_bound.json (ternary) or oracle_bound_<field>.json: evenly spread designs on
    that field, written by benchmarks/oracle_bound.py (read, not typed in). None when there is none."""
    path = ORACLE_DIR / ("oracle_bound.json" if field == "ternary" else f"oracle_bound_{field}.json")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        best = data["best"]["median"]
        tried = [int(r["indents"]) for r in data["rows"] if r["estimator"] == "median"]
        return {
            "target_pct": float(data["grid_final_mape_pct"]),
            "singles": None if best is None else int(best["indents"]),
            "bound_x": None if best is None else float(best["max_speedup"]),
            "largest": max(tried),
            "smallest": min(tried),
            "seeds": int(data["seeds"]),
        }
    except (OSError, ValueError, KeyError, TypeError):
        return None


def _field_of(key: str) -> str | None:
    """The emulator scenario or robustness field behind a bench scenario key, for the film and the robustness
    suite (whose targets an even design may not reach at all); None for the others."""
    sc = next((s for s in (*FULL_SCENARIOS, *EXTRA_SCENARIOS) if s.key == key), None)
    if sc is None or not (sc.group == "robustness" or sc.key == "film"):
        return None
    return sc.scenario


def _field_limit(key: str) -> str:
    """The even-design limit on a film or robustness field, from its oracle_bound_<field>.json ("" if none)."""
    field = _field_of(key)
    oracle = None if field is None or field == "ternary" else _oracle(field)
    if oracle is None:
        return ""
    if oracle["singles"] is None:
        return (
            f" No even design of single indents up to {oracle['largest']:,} indents reaches the grid's MAPE"
            f" on this field ({oracle['target_pct']:.3f} % in `benchmarks/oracle_bound.py --field {field}`,"
            f" {oracle['seeds']} seeds)."
        )
    if oracle["singles"] <= oracle["smallest"]:
        return (
            f" Even the smallest even design tried, {oracle['singles']:,} single indents, reaches the grid's MAPE"
            f" on this field ({oracle['target_pct']:.3f} % in `benchmarks/oracle_bound.py --field {field}`,"
            f" {oracle['seeds']} seeds): the limit lies above {oracle['bound_x']:.1f}×."
        )
    return (
        f" The cheapest even design of single indents that reaches the grid's MAPE on this field"
        f" ({oracle['target_pct']:.3f} % in `benchmarks/oracle_bound.py --field {field}`, {oracle['seeds']} seeds)"
        f" takes {oracle['singles']:,} indents: at most {oracle['bound_x']:.1f}× faster than the grid."
    )


def _miss_text(r: RunRecord) -> str:
    """How far a seed that never reached its target ended from it, and what ended it."""
    final = f"ended at {r.final_mape_pct:.3f} %" if r.final_mape_pct is not None else "ended unscored"
    target = f" against {r.target_mape_pct:.3f} %" if r.target_mape_pct is not None else ""
    return f"seed {r.seed} ({final}{target} after {r.indents:,} indents: {r.stop_reason})"


def why_text(summaries: Sequence[PolicySummary], records: Sequence[RunRecord] = ()) -> str:
    """Where each policy loses, with this run's own figures, and the oracle's limit read from its JSON."""
    out = ["### Where the policies lose", ""]
    t = _get(summaries, "ternary", "aeni")
    oracle = _oracle()
    if oracle is not None and oracle["singles"] is not None:
        text = (
            f"- **The even-design limit.** `benchmarks/oracle_bound.py` ({oracle['seeds']} seeds) spreads single"
            f" indents evenly with no travel, drift or overhead: the cheapest such design that reaches the grid's"
            f" final MAPE ({oracle['target_pct']:.3f} %) takes {oracle['singles']} indents, at most"
            f" {oracle['bound_x']:.1f}× faster than the grid."
        )
        if t is not None and t.indents is not None and _sw(t) is not None:
            text += (
                f" `aeni` reaches it {_x(_sw(t)[0])} faster (median), with a median of {t.indents[1]:.0f} indents"  # type: ignore[index]
                " when its run ends (the target plus the run-on)."
            )
        out.append(text)
    for sc in dict.fromkeys(s.scenario for s in summaries):
        a = _get(summaries, sc, "aeni")
        sw = _sw(a)
        if a is None or sw is None:
            continue
        worst = [r for r in records if r.scenario == sc and r.policy == "aeni"]
        miss = [r for r in worst if r.t_hit_s is None]
        if sw[0] < SUITE_GOAL or sw[1] < 1.0 or miss:
            out.append(
                f"- **`aeni` on {sc}:** median {_x(sw[0])}, worst seed {_x(sw[1])}"
                + (f"; never reached the grid's MAPE on {'; '.join(map(_miss_text, miss))}" if miss else "")
                + "."
                + _field_limit(sc)
            )
    for pol in policy_order([s.policy for s in summaries]):
        if pol in ("grid", "aeni"):
            continue
        losses = [
            s.scenario for s in summaries if s.policy == pol and (sw := _sw(s)) is not None and sw[0] < 1.0
        ]
        if losses:
            out.append(f"- `{pol}` is slower than the grid (median) on: {', '.join(losses)}.")
    return "\n".join(out)


def two_maps_table(records: Sequence[RunRecord]) -> list[str]:
    """With map_weights (issue 27): each policy's time to both grids' final MAPEs, hardness and modulus, and
    the speed-up over the grid per map and to both (paired per seed: the grid's time to both its final MAPEs
    over the policy's; medians over seeds, worst seed); nothing for a hardness-only bench."""
    if not any(r.trajectory_modulus for r in records):
        return []
    grid_t = {(r.scenario, r.seed): r for r in records if r.policy == "grid"}
    lines = [
        "## Both maps: hardness and modulus (map_weights)",
        "",
        "| scenario | policy | final MAPE H % | final MAPE E % | t(H) s | t(E) s | t(both) s | speed-up H "
        "| speed-up E | speed-up to both, median (worst seed) |",
        "|" + "---|" * 10,
    ]
    groups: dict[tuple[str, str], list[RunRecord]] = {}
    for r in records:
        groups.setdefault((r.scenario, r.policy), []).append(r)

    def med(vals: Sequence[float | None]) -> float | None:
        ok = [v if v is not None else math.inf for v in vals]
        return float(np.median(ok)) if ok else None

    def fmt(v: float | None, spec: str) -> str:
        return "—" if v is None or not math.isfinite(v) else format(v, spec)

    def ratio(grid: float | None, run: float | None) -> float:
        return grid / run if grid and run else 0.0  # a miss counts as never (0×)

    for (scenario, policy), runs in sorted(groups.items(), key=lambda kv: (kv[0][0], kv[0][1] != "grid")):
        sp_h, sp_e, sp_both, worst = [], [], [], (math.inf, -1)
        for r in runs:
            g = grid_t.get((scenario, r.seed))
            if g is None:
                continue
            sp_h.append(ratio(g.t_hit_s, r.t_hit_s))
            sp_e.append(ratio(g.t_hit_modulus_s, r.t_hit_modulus_s))
            sp_both.append(ratio(g.t_hit_both_s, r.t_hit_both_s))
            worst = min(worst, (sp_both[-1], r.seed))
        both = f"{fmt(float(np.median(sp_both)) if sp_both else None, '.1f')}×"
        lines.append(
            f"| {scenario} | {policy} | {fmt(med([r.final_mape_pct for r in runs]), '.3f')} "
            f"| {fmt(med([r.final_mape_modulus_pct for r in runs]), '.3f')} "
            f"| {fmt(med([r.t_hit_s for r in runs]), ',.0f')} | {fmt(med([r.t_hit_modulus_s for r in runs]), ',.0f')} "
            f"| {fmt(med([r.t_hit_both_s for r in runs]), ',.0f')} "
            f"| {fmt(float(np.median(sp_h)) if sp_h else None, '.1f')}× | {fmt(float(np.median(sp_e)) if sp_e else None, '.1f')}× "
            f"| {both} ({fmt(worst[0], '.1f')}×, seed {worst[1]}) |"
        )
    return [
        *lines,
        "",
        "t(·): instrument time to the grid's final MAPE of that map (a miss counts as never); t(both): the later "
        "of the two. Speed-ups are paired per seed with the grid's own times.",
        "",
    ]


def calendar_table(records: Sequence[RunRecord], config: BenchConfig) -> list[str]:
    """With a simulated operator (``--operator-hours``): the wall clock and the visits to the grid's final MAPE."""
    cal = config.calendar
    if cal is None or not any(r.wall_clock_h is not None for r in records):
        return []
    a = cal.availability
    lines = [
        "## The calendar",
        "",
        f"A simulated operator ({a.hours.text}, answers within {a.response_s / 60:g} min, comes by every"
        f" {a.visit_every_s / 60:g} min) loads every block from a start at"
        f" {cal.start.strftime('%a %H:%M')}; the grid is loaded once. Wall clock (h) and operator visits from the"
        " start to the grid's final MAPE (hardness; with both maps scored, also to both grids' final MAPEs):"
        " median, worst seed in brackets (a run that never reached it: ∞).",
        "",
        "| field | policy | wall clock h | visits | instrument h | to both maps: wall clock h | visits | seeds |",
        "|---|---|---|---|---|---|---|---|",
    ]
    groups: dict[tuple[str, str], list[RunRecord]] = {}
    for r in records:
        groups.setdefault((r.scenario, r.policy), []).append(r)
    for (scen, policy), runs in groups.items():
        wall = [r.wall_clock_h if r.wall_clock_h is not None else math.inf for r in runs]
        visits = [float(r.operator_visits) if r.operator_visits is not None else math.inf for r in runs]
        inst = [r.t_hit_s / 3600.0 if r.t_hit_s is not None else math.inf for r in runs]
        both = any(r.trajectory_modulus for r in runs)
        wall_b = [r.wall_clock_both_h if r.wall_clock_both_h is not None else math.inf for r in runs]
        visits_b = [
            float(r.operator_visits_both) if r.operator_visits_both is not None else math.inf for r in runs
        ]

        def cell(v: list[float], digits: int = 1) -> str:
            med, worst = float(np.median(v)), max(v)
            return f"{med:.{digits}f} ({worst:.{digits}f})".replace("inf", "∞")

        lines.append(
            f"| {scen} | `{policy}` | {cell(wall)} | {cell(visits, 0)} | {cell(inst)} "
            f"| {cell(wall_b) if both else '—'} | {cell(visits_b, 0) if both else '—'} | {len(runs)} |"
        )
    return [*lines, ""]


def level_table(records: Sequence[RunRecord]) -> list[str]:
    """Each idea against its reference at the grid's final MAPE and at looser multiples of it."""
    rows = []
    for scen, pol, ref in LEVEL_PAIRS:
        cells = [speedup_by_level(records, scen, pol, ref, f) for f in LEVEL_FACTORS]
        if any(c is not None for c in cells):
            rows.append(f"| {scen} | `{pol}` | `{ref}` | " + " | ".join(_fmt_ratio(c) for c in cells) + " |")
    if not rows:
        return []
    return [
        "## Speed-up by error level",
        "",
        "The paper's figures were read off MAPE curves at error levels it does not state. Reference time /"
        " policy time to reach f × the grid's final MAPE, paired by seed (median [inter-quartile range]).",
        "",
        "| scenario | policy | against | "
        + " | ".join(f"{f:g}× the grid's MAPE" for f in LEVEL_FACTORS)
        + " |",
        "|---|---|---|" + "---|" * len(LEVEL_FACTORS),
        *rows,
        "",
    ]


def _seeds(s: PolicySummary) -> str:
    return f"{round(s.hit_rate * s.n_seeds)}/{s.n_seeds}"


def _fmt_target(v: float | None, goal: str) -> str:
    if v is None:
        return "—"
    if math.isinf(v):
        return "∞"
    return f"{v:.2f}" + ("×" if "×" in goal else " %")


def results_markdown(
    records: Sequence[RunRecord],
    config: BenchConfig,
    wall_s: float,
    figures: dict[str, list[str]],
    figures_note: str = "",
    from_json: bool = False,
    parts: int = 1,
) -> str:
    summaries = summarise(records)
    order = {p: i for i, p in enumerate(policy_order([r.policy for r in records]))}
    lines = [
        "# AE-NI policy benchmark",
        "",
        (
            f"Generated by `aeni bench{' --quick' if config.quick else ''} --seeds {config.seeds} --jobs {config.jobs}`"
            f" in {wall_s / 60:.1f} min of wall time ({len(records)} campaigns)."
            if parts == 1
            else f"Generated by {parts} runs of `aeni bench` (a sweep run in pieces, up to {config.seeds} seeds,"
            f" `--jobs {config.jobs}`), merged by `aeni bench --render-from`: {wall_s / 60:.1f} min of wall time"
            f" in all ({len(records)} campaigns)."
        )
        + " Medians over seeds, with the inter-quartile range in brackets.",
        "",
        "Size of this run (field: seeds × policies): " + _size(records, config) + ".",
        *(
            [
                "",
                "_Rendered again from the run's `results.json` (`aeni bench --render-from`): the figures at"
                " looser error levels come from its stored, thinned trajectories._",
            ]
            if from_json and parts == 1
            else []
        ),
        "",
        "## Protocol",
        "",
        "- Every scenario and seed runs the `grid` baseline (9×9 blocks of 5×5 at 80 s) in full first. Its final",
        "  MAPE is the seed's **target** and its instrument time the **budget** of every other policy on that",
        "  scenario and seed (same emulated sample, same noise draws and drift events).",
        f"- The other policies run until they reach the target and then on for {100 * config.margin:.0f} % of"
        f" that time, or until the budget, a cap of {config.max_blocks} blocks or {config.max_centres:,} tested"
        " centres ends them (a run of single indents that has not reached the target by then counts as a miss,"
        " even if it might have reached it later within the grid's time). MAPE is the GP mean"
        " against the truth on the 100×100 lattice, after every refit.",
        *[
            f"- `{sc.key}` runs on for {100 * sc.margin:.0f} % instead: a collapse shows after the target, not before."
            for sc in config.scenarios
            if sc.margin is not None
        ],
        "- **Speed-up** = reference time / policy time to reach the target, paired by seed; a run that never"
        " reaches it counts as infinitely slow (a speed-up of 0, or ∞ when only the reference misses).",
        f"- The looser target ({LOOSE_FACTOR:g}× the grid's final MAPE) shows the comparison where the noise floor"
        " does not decide it.",
        f"- Candidate lattice {config.lattice_n}×{config.lattice_n} (the product's default on the 1000 µm square"
        " is 100×100); the decisions use the same cost model, GP and rules as `aeni simulate`.",
        "- Every campaign runs through the engine an operator runs, in `auto` supervision: each block passes the"
        " interlock; a refused one is vetoed and the planner asked again (the **interlock refusals** column, totals"
        " over the seeds); **approvals** counts blocks that waited for one.",
        (
            f"- The simulated instrument fails like a real one: {100 * config.failure_rate:g} % of indents come back"
            f" invalid and {25 * config.failure_rate:g} % of blocks each find no surface or stop half way (the"
            " **failed indents** column, totals over the seeds). A failed indent is priced and kept away from,"
            " never learnt from."
            if config.failure_rate
            else "- The simulated instrument never fails (`--failure-rate 0`)."
        ),
        "",
    ]
    flat = flat_map_errors(config)
    tgts = targets(summaries, records, config, flat)
    if tgts:
        lines += [
            "## Targets",
            "",
            "| target | goal | measured (median) | met | note |",
            "|---|---|---|---|---|",
        ]
        for t in tgts:
            met = "—" if t["met"] is None else ("yes" if t["met"] else "**no**")
            lines.append(
                f"| {t['target']} | {t['goal']} | {_fmt_target(t['measured'], t['goal'])} | {met} | {t['note']} |"
            )
        lines += ["", why_text(summaries, records), ""]
        lines += resolution_table(summaries, config, flat)
    lines += suite_tables(summaries, config)
    lines += calendar_table(records, config)
    lines += level_table(records)
    lines += two_maps_table(records)
    for group, title in (
        ("paper", "The paper's comparisons"),
        ("provocation", "Provocations: drift and length-scale collapse"),
        ("robustness", "Robustness: fields nothing was tuned on"),
        ("scale", "Large designs: thousands of centres"),
    ):
        scens = [s for s in config.scenarios if s.group == group]
        if not scens:
            continue
        lines += [f"## {title}", ""]
        for sc in scens:
            rows = sorted(
                (s for s in summaries if s.scenario == sc.key), key=lambda s: order.get(s.policy, 99)
            )
            if not rows:
                continue
            grid = _get(summaries, sc.key, "grid")
            tgt = _quartiles_of(
                [r.target_mape_pct for r in records if r.scenario == sc.key and r.policy == "grid"]
            )
            lines += [
                f"### {sc.title}",
                "",
                f"Scenario `{sc.scenario}`; grid baseline {(_med(grid.instrument_s) or 0) / 3600:.1f} h, final MAPE"
                f" {tgt:.3f} % (median target)."
                if grid is not None and tgt is not None
                else f"Scenario `{sc.scenario}`.",
                "",
                scenario_table(rows),
                "",
            ]
            for fig in figures.get(sc.key, []):
                lines.append(f"![{sc.key}](figures/{fig})")
            lines.append("")
    if figures.get("_all"):
        lines += ["## Cost breakdown", ""] + [f"![costs](figures/{f})" for f in figures["_all"]] + [""]
    if figures_note:
        lines += [figures_note, ""]
    lines += [
        "## Columns",
        "",
        "- *reached*: seeds whose run reached the grid's final MAPE within the budget.",
        "- *vs its reference*: each idea against the policy it extends (adaptive grid and meta-grid against fixed",
        "  5×5 grids = `uncertainty`; adaptive hold against fixed 80 s = `cost-aware`; `aeni-paper` against",
        "  `uncertainty`; `aeni` against `aeni-paper`; the unguarded ablation against the guarded one).",
        "- *max found*: highest true hardness among indented points (true maximum of the field in brackets).",
        "- *fast indents*, *time in fast arrays*: median per seed of the fast (NanoBlitz-class) indents made, and",
        "  of the instrument time from each fast array's start to its end (opening, surface find and drift settle",
        "  included; in brackets its share of the run's median time); 0 for a policy that plans CSM indents only",
        "  (docs/two-fidelity.md).",
        "- *reconfig.*: reconfigurations in the ledger: safety-rule hops ≥ 1000 µm while engaged and, on the film",
        "  profile, every global jump (priced there as one 520 s reconfiguration).",
        "",
    ]
    return "\n".join(lines)


def _size(records: Sequence[RunRecord], config: BenchConfig) -> str:
    parts = []
    for sc in config.scenarios:
        runs = [r for r in records if r.scenario == sc.key]
        if runs:
            seeds = len({r.seed for r in runs})
            pols = policy_order(sorted({r.policy for r in runs}))
            parts.append(f"{sc.key} {seeds} × {len(pols)} ({', '.join(pols)})")
    return "; ".join(parts)


def _quartiles_of(values: Sequence[float | None]) -> float | None:
    vals = [v for v in values if v is not None]
    return float(np.median(vals)) if vals else None


# -- writing ---------------------------------------------------------------------------------------------


def write_report(
    records: Sequence[RunRecord],
    config: BenchConfig,
    out_dir: Path,
    wall_s: float,
    keep_existing_maps: bool = False,
    parts: int = 1,
) -> list[Path]:
    """RESULTS.md, results.json and (with matplotlib) figures/*.png in ``out_dir``; the paths written.

    ``keep_existing_maps``: records read back from results.json carry no maps; the map figures already in
    ``out_dir`` (drawn by the run itself) stay and are referenced.
    """

    out_dir.mkdir(parents=True, exist_ok=True)
    # the measurements first: a figure or a table that fails to render must not take the numbers with it
    write_atomic(
        out_dir / "results.json", json.dumps(records_to_json(records, config, wall_s), separators=(",", ":"))
    )
    written: list[Path] = []
    figures: dict[str, list[str]] = {}
    note = ""
    try:
        matplotlib_pyplot()
    except ImportError:
        note = "_Figures skipped: matplotlib is not installed (`pip install -e '.[report]'`)._"
    else:
        fig_dir = out_dir / "figures"
        fig_dir.mkdir(exist_ok=True)
        for sc in config.scenarios:
            if not any(r.scenario == sc.key for r in records):
                continue
            name = f"curves_{sc.key}.png"
            figure_curves(records, sc.key, sc.title, fig_dir / name)
            figures.setdefault(sc.key, []).append(name)
            written.append(fig_dir / name)
            name = f"maps_{sc.key}.png"
            if figure_maps(records, sc.key, sc.title, fig_dir / name):
                figures[sc.key].append(name)
                written.append(fig_dir / name)
            elif keep_existing_maps and (fig_dir / name).is_file():
                figures[sc.key].append(name)
        figure_costs(records, config, fig_dir / "costs.png")
        figures["_all"] = ["costs.png"]
        written.append(fig_dir / "costs.png")
    md = results_markdown(records, config, wall_s, figures, note, from_json=keep_existing_maps, parts=parts)
    write_atomic(out_dir / "RESULTS.md", md)
    for p in (out_dir / "RESULTS.md", out_dir / "results.json"):
        p.chmod(0o644)
    return [out_dir / "RESULTS.md", out_dir / "results.json", *written]


__all__ = ["LEDGER_COLORS", "policy_color", "policy_order", "results_markdown", "targets", "write_report"]

"""Policies on real (short) emulator campaigns: placement and cost invariants, the paper's rules, decisions."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, replace

import numpy as np
import pytest

from core.campaign import Campaign
from core.campaign_config import CampaignConfig
from core.cost import block_costs_for, block_steps
from core.errors import InputError
from core.plan import Block, Decision, IndentResult, PlannerSettings, StepRecord
from core.policies.base import PlanContext, grid_size_for_noise
from core.policies.blocks import ReplicateGrid, ScatteredSingles
from core.policies.hold import HoldRule, robust_rate
from core.policies.parts import PolicyParts
from core.policies.planner import BayesPlanner
from core.policies.registry import POLICY_DESCRIPTIONS, RECOMMENDED, make_policy, policy_names, policy_parts
from core.profile import load_profile
from core.run.headless import run_auto
from drivers.sim.scenarios import make_scenario

# the adaptive hold's two choices come from the instrument profile (5 s and 80 s on the iMicro)
FAST_HOLD_S = load_profile("kla-imicro").fast_hold_s
SLOW_HOLD_S = load_profile("kla-imicro").default_hold_s
_TERNARY = make_scenario("ternary", 0).sample
PLUS = "aeni-paper+huber+bias-hold+drift-corr"  # the paper's workflow with this product's noise and hold


@dataclass
class Run:
    campaign: Campaign
    decisions: list[Decision]
    steps: list[list[StepRecord]]  # per block
    results: list[list[IndentResult]]
    positions_before: list[tuple[float, float]]
    open_before: list[bool]


def _run(
    policy: str,
    scenario: str = "ternary",
    budget_s: float = 30_000.0,
    seed: int = 1,
    lattice_n: int = 30,
    **settings: object,
) -> Run:
    sc = make_scenario(scenario, seed)
    c = Campaign(
        CampaignConfig(
            policy=policy,
            seed=seed,
            lattice_n=lattice_n,
            settings=PlannerSettings(budget_s=budget_s, **settings),  # type: ignore[arg-type]
        ),
        sc.sample,
    )
    driver = sc.make_driver(c.profile)
    run = Run(c, [], [], [], [], [])
    block_id = 0
    while (
        d := c.propose(driver.clock_s(), driver.position_um(), driver.program_open(), block_id)
    ) is not None:
        run.positions_before.append(driver.position_um())
        run.open_before.append(driver.program_open())
        events = list(driver.execute_block(d.block))
        results = [e for e in events if isinstance(e, IndentResult)]
        run.steps.append([e for e in events if isinstance(e, StepRecord)])
        run.results.append(results)
        run.decisions.append(d)
        c.observe_block(d.block, results)
        block_id += 1
    return run


_RUNS: dict[tuple[str, str], Run] = {}


def _cached(policy: str, scenario: str = "ternary") -> Run:
    key = (policy, scenario)
    if key not in _RUNS:
        _RUNS[key] = _run(policy, scenario, budget_s=40_000.0 if scenario == "film" else 30_000.0)
    return _RUNS[key]


PLANNERS = ("cost-aware", "meta-grid", "adaptive-hold", "aeni-paper", "aeni", PLUS)


# -- registry -------------------------------------------------------------------------------------------


def test_every_registered_policy_builds_and_unknown_names_fail() -> None:
    names = policy_names()
    assert set(names) == set(POLICY_DESCRIPTIONS)
    # one recommendation, first; the paper's policies stay as named references; nothing else is top-level
    assert names[0] == RECOMMENDED == "aeni"
    assert set(names) == {
        "aeni",
        "grid",
        "uncertainty",
        "cost-aware",
        "adaptive-grid",
        "meta-grid",
        "adaptive-hold",
        "aeni-paper",
    }
    for name in names:
        assert make_policy(name).name == name
    with pytest.raises(InputError, match="unknown policy 'nope'"):
        make_policy("nope")
    with pytest.raises(InputError, match="unknown modifier 'turbo'"):
        make_policy("aeni-paper+turbo")
    with pytest.raises(InputError, match="scattered singles"):
        make_policy("aeni-paper+fast")  # fast arrays are priced beside scattered singles only (issue 36)
    with pytest.raises(InputError, match="replicate grids"):
        make_policy("aeni+tight")  # aeni places singles: a grid setting does not apply
    assert CampaignConfig().policy == "aeni"  # the default everywhere starts here


def test_each_ablation_changes_one_setting_of_one_part() -> None:
    """The ablations measure one idea each only if the policies differ in exactly those settings."""
    paper = policy_parts("aeni-paper")
    plus = policy_parts(PLUS)
    assert replace(policy_parts("adaptive-hold"), noise=replace(paper.noise, drift_correction=True)) == (
        policy_parts("adaptive-hold+drift-corr")
    )
    assert plus == replace(
        paper,
        noise=replace(paper.noise, centre_estimator="huber", drift_correction=True),
        hold=replace(paper.hold, bias_aware=True),
    )
    assert policy_parts(f"{PLUS}+nugget") == replace(plus, surrogate=replace(plus.surrogate, nugget=True))
    assert not paper.noise.drift_correction and not policy_parts("cost-aware").noise.drift_correction
    aeni = policy_parts("aeni")
    assert policy_parts("aeni+gaussian") == replace(aeni, noise=replace(aeni.noise, outliers="none"))


# -- placement and cost invariants ----------------------------------------------------------------------


@pytest.mark.parametrize("policy", [*PLANNERS, "uncertainty"])
def test_indents_stay_in_the_calibrated_area_and_clear_of_earlier_ones(policy: str) -> None:
    run = _cached(policy)
    cal = run.campaign.calibration
    xy = np.array([(r.commanded_x_um, r.commanded_y_um) for rs in run.results for r in rs])
    assert len(xy) >= 20
    assert cal.contains_stage(xy[:, 0], xy[:, 1]).all()
    # exclusion zone: a new grid's indents are ≥ 20 µm from every indent of earlier blocks
    earlier: list[tuple[float, float]] = []
    for rs in run.results:
        pts = np.array([(r.commanded_x_um, r.commanded_y_um) for r in rs])
        if earlier:
            prev = np.array(earlier)
            d = np.hypot(pts[:, None, 0] - prev[None, :, 0], pts[:, None, 1] - prev[None, :, 1])
            assert d.min() >= 20.0 - 1e-6
        earlier.extend(map(tuple, pts))


@pytest.mark.parametrize("policy", [*PLANNERS, "uncertainty"])
def test_the_planner_priced_exactly_what_ran(policy: str) -> None:
    """Every executed step, reconfigurations included, is what the cost model prices for the block (the
    safety rule itself is tested once, in test_cost)."""
    run = _cached(policy)
    p = run.campaign.profile
    for d, steps, pos, was_open in zip(
        run.decisions, run.steps, run.positions_before, run.open_before, strict=True
    ):
        assert steps == list(block_steps(p, d.block, pos, was_open))
        assert d.predicted_cost_s == pytest.approx(sum(s.seconds for s in steps), rel=1e-9)
        assert d.predicted_cost_s == pytest.approx(block_costs_for(p, d.block, pos, was_open), rel=1e-9)


@pytest.mark.parametrize(
    ("policy", "scenario"),
    [("cost-aware", "ternary"), ("meta-grid", "ternary"), ("aeni-paper", "film"), (PLUS, "film")],
)
def test_local_blocks_stay_in_the_safe_band_and_meta_grid_hops_stay_within_500_um(
    policy: str, scenario: str
) -> None:
    run = _cached(policy, scenario)
    cal = run.campaign.calibration
    centre = None
    locals_seen = 0
    hop_limit = 1000.0 if policy == "cost-aware" else 500.0
    prev_last: tuple[float, float] | None = None
    for d in run.decisions:
        b = d.block
        if b.kind == "global":
            centre = (b.center_x_um, b.center_y_um)
        else:
            locals_seen += 1
            assert centre is not None
            band = cal.safe_band(*centre, 5.0)
            xs = np.array([s.x_um for s in b.indents])
            ys = np.array([s.y_um for s in b.indents])
            assert band.contains(xs, ys).all()
            assert prev_last is not None
            assert np.hypot(b.center_x_um - prev_last[0], b.center_y_um - prev_last[1]) <= hop_limit + 1e-6
        prev_last = (b.indents[-1].x_um, b.indents[-1].y_um)
    # the film's 520 s jump is cheap against its 5×5 grids at 10 % noise: programs there are short
    assert locals_seen >= (1 if scenario == "film" else 2), (
        f"{policy} rarely stayed in a program on {scenario}"
    )


# -- the paper's rules ----------------------------------------------------------------------------------


def test_grid_size_rule_clips_to_2_5_and_follows_the_target_sem() -> None:
    sd = np.array([0.0, 0.05, 0.1, 0.15, 0.2, 1.0])
    assert grid_size_for_noise(sd, 0.05).tolist() == [2, 2, 2, 3, 4, 5]
    assert grid_size_for_noise(sd, 0.02).tolist() == [2, 2, 5, 5, 5, 5]


def test_adaptive_grid_sizes_respond_to_the_target_sem_in_a_campaign() -> None:
    loose = _run("meta-grid", budget_s=20_000.0, target_sem_gpa=0.05)
    tight = _run("meta-grid", budget_s=20_000.0, target_sem_gpa=0.015)
    g_loose = [d.block.grid_g for d in loose.decisions[2:]]
    g_tight = [d.block.grid_g for d in tight.decisions[2:]]
    assert g_loose and g_tight
    assert all(2 <= g <= 5 for g in g_loose + g_tight)
    assert np.mean(g_tight) >= np.mean(g_loose) + 1.0, (g_loose, g_tight)


def _context_after(policy: str, blocks: int = 4) -> tuple[Campaign, PlanContext]:
    """A campaign after a few blocks and the context for its next decision (to probe one rule at a time)."""
    c, ctx, _ = _context_and_history(policy, blocks)
    return c, ctx


def _context_and_history(
    policy: str, blocks: int
) -> tuple[Campaign, PlanContext, list[tuple[Block, list[IndentResult]]]]:
    sc = make_scenario("ternary", 2)
    c = Campaign(
        CampaignConfig(policy=policy, seed=2, lattice_n=30, settings=PlannerSettings(budget_s=1e6)), sc.sample
    )
    driver = sc.make_driver(c.profile)
    history = []
    for block_id in range(blocks):
        d = c.propose(driver.clock_s(), driver.position_um(), driver.program_open(), block_id)
        assert d is not None
        results = [e for e in driver.execute_block(d.block) if isinstance(e, IndentResult)]
        c.observe_block(d.block, results)
        history.append((d.block, results))
    ctx = c.context(driver.clock_s(), driver.position_um(), driver.program_open(), blocks)
    return c, ctx, history


def test_adaptive_hold_is_fast_in_quiet_drift_and_slow_in_a_bad_event() -> None:
    c, ctx = _context_after("adaptive-hold")
    quiet = c.policy.propose(replace(ctx, last_drift_rate_nm_s=0.005, program_open=False))
    bad = c.policy.propose(replace(ctx, last_drift_rate_nm_s=1.0, program_open=False))
    assert quiet is not None and bad is not None
    assert quiet.block.hold_s == FAST_HOLD_S and "fast" in quiet.hold_mode
    assert quiet.area_error_pct is not None and quiet.area_error_pct < 2.0
    assert bad.block.hold_s == SLOW_HOLD_S and bad.area_error_pct is not None and bad.area_error_pct > 2.0
    assert all(s.hold_s == bad.block.hold_s for s in bad.block.indents)


@pytest.mark.parametrize(("g", "switches"), [(2, False), (3, True)])
def test_slow_program_switches_to_fast_only_when_g2_times_75_s_pays_the_reconfiguration(
    g: int, switches: bool
) -> None:
    planner = BayesPlanner(
        "probe",
        PolicyParts(blocks=ReplicateGrid(fixed_g=g, local_hop_um=500.0), hold=HoldRule(adaptive=True)),
    )
    c, ctx = _context_after("adaptive-hold", blocks=3)
    assert ctx.program_open
    probe = replace(ctx, program_hold_s=SLOW_HOLD_S, last_drift_rate_nm_s=0.005, locals_in_program=0)
    d = planner.propose(probe)
    assert d is not None
    # g²·(80 − 5) = 300 s < 390 s: staying slow is allowed; 675 s ≥ 390 s: the program must end
    assert c.profile.reconfiguration_s == pytest.approx(390.0)
    if switches:
        assert d.block.kind == "global" and d.block.hold_s == FAST_HOLD_S
        assert d.stay_score is None and "saves" in d.reason
    else:
        assert d.stay_score is not None


def test_drift_rising_ends_a_fast_program() -> None:
    c, ctx = _context_after("adaptive-hold", blocks=3)
    probe = replace(ctx, program_hold_s=FAST_HOLD_S, last_drift_rate_nm_s=1.0, locals_in_program=0)
    d = c.policy.propose(probe)
    assert d is not None and d.block.kind == "global" and d.block.hold_s == SLOW_HOLD_S
    assert "drift rose" in d.reason


def test_aeni_phases_seeds_then_exploration_then_up_to_five_locals() -> None:
    run = _cached("aeni-paper")
    d = run.decisions
    assert [x.phase for x in d[:2]] == ["seed", "seed"]
    assert all(
        x.block.grid_g == 5 and x.block.hold_s == SLOW_HOLD_S and x.block.kind == "global" for x in d[:2]
    )
    programs: list[list[Decision]] = []
    for x in d:
        if x.block.kind == "global":
            programs.append([x])
        else:
            programs[-1].append(x)
    assert len(programs) >= 7
    # the seed programs and the next four allow at most one local centre each
    assert all(len(p) - 1 <= 1 for p in programs[:6]), "exploratory programs allow one local centre"
    assert all(p[0].phase == "explore" for p in programs[2:6])
    assert all(len(p) - 1 <= 5 for p in programs)
    assert any(len(p) - 1 >= 2 for p in programs[6:]), "after exploration a program runs several sub-grids"


# -- what every decision carries ------------------------------------------------------------------------


@pytest.mark.parametrize("policy", PLANNERS)
def test_decisions_carry_scores_costs_and_alternatives(policy: str) -> None:
    run = _cached(policy)
    model_decisions = [d for d in run.decisions if d.phase != "seed"]
    assert model_decisions
    stays = 0
    for d in model_decisions:
        assert d.jump_score is not None and np.isfinite(d.jump_score)
        assert d.predicted_cost_s > 0 and np.isfinite(d.score)
        assert 1 <= len(d.alternatives) <= 5
        assert all(a.cost_s > 0 and a.kind in ("global", "local") for a in d.alternatives)
        assert all(
            (a.center_x_um, a.center_y_um) != (d.block.center_x_um, d.block.center_y_um)
            for a in d.alternatives
        )
        if d.block.kind == "local":
            stays += 1
            assert d.stay_score is not None and d.stay_score >= d.jump_score
        elif d.stay_score is not None:
            assert d.jump_score > d.stay_score
        assert d.reason
    assert stays >= 1


def test_uncertainty_ignores_cost_and_always_opens_a_new_program() -> None:
    run = _cached("uncertainty")
    assert all(d.block.kind == "global" and d.block.grid_g == 5 for d in run.decisions)
    assert all(d.stay_score is None for d in run.decisions)
    pred = run.campaign.prediction
    assert pred is not None
    # the last decision went to (near) the highest-σ candidate that was allowed
    last = run.decisions[-1]
    assert last.acquisition > 0.0 and "highest σ" in last.reason


# -- aeni-plus ------------------------------------------------------------------------------------------


def test_variance_model_reproduces_the_surrogates_epistemic_sd() -> None:
    from core.policies.variance import PosteriorCov, reference_lattice

    c, ctx = _context_after(f"{PLUS}+ivr", blocks=6)
    assert ctx.gp is not None and ctx.tested_noise_var_gpa2 is not None and ctx.prediction is not None
    u, v = c.calibration.to_uv(ctx.tested_xy_um[:, 0], ctx.tested_xy_um[:, 1])
    ref = reference_lattice(4)
    model = PosteriorCov.build(
        ctx.gp, np.column_stack([u, v]), ctx.tested_noise_var_gpa2, ctx.lattice.uv, ref, np.ones(len(ref))
    )
    ours = np.sqrt(model.var_c)
    theirs = ctx.prediction.epistemic_sd
    assert np.allclose(ours, theirs, rtol=0.03, atol=1e-3 * float(theirs.max()))
    # conditioning on a planned grid lowers the variance there and never raises it anywhere
    j = int(np.argmax(model.var_c))
    after = model.condition_on(j, 0.001)
    assert after.var_c[j] < 0.5 * model.var_c[j]
    assert np.all(after.var_c <= model.var_c + 1e-12)


def test_aeni_ivr_prices_jumps_with_their_programs_and_holds_fast_when_drift_is_quiet() -> None:
    run = _cached(f"{PLUS}+ivr")
    later = [d for d in run.decisions if d.phase == "exploit"]
    assert later
    # the seeds hold 80 s (drift unknown); without drift the bias of a 5 s hold is far below the aim
    assert all(d.block.hold_s == SLOW_HOLD_S for d in run.decisions if d.phase == "seed")
    assert any("bias-aware: fast" in d.hold_mode for d in later)
    assert all(d.block.hold_s == FAST_HOLD_S for d in later if "bias-aware: fast" in d.hold_mode)
    # the operator sees that the fast indents' hardness will be drift-corrected before the model uses it
    assert all(d.hold_mode.endswith("; drift-corrected") for d in later if "bias-aware: fast" in d.hold_mode)
    assert any("planned sub-grids" in d.reason for d in later if d.block.kind == "global")


def test_aeni_nugget_uses_huber_values_and_learns_the_site_scatter() -> None:
    run = _cached(f"{PLUS}+nugget")
    c = run.campaign
    assert c.noise.centre_estimator == "huber" and c.surrogate.nugget
    assert not Campaign(CampaignConfig(policy=PLUS), _TERNARY).surrogate.nugget
    assert all(rec.efficiency is not None and rec.efficiency < 1.2 for rec in c.centres)
    obs = c.observations()
    assert np.allclose(obs.efficiency, [rec.efficiency for rec in c.centres])
    # the ternary field has no site texture: the learned scatter stays small against the indent noise
    assert c.surrogate.site_sd_gpa < 0.05


@pytest.mark.parametrize("policy", [PLUS, f"{PLUS}+nugget", "aeni"])
def test_aeni_plus_resumes_to_the_same_decision(policy: str) -> None:
    c, ctx, history = _context_and_history(policy, blocks=5)
    first = c.policy.propose(ctx)
    assert first is not None and first.phase != "seed"
    fresh = Campaign(c.config)
    fresh.restore(c.export_state(), history)  # the journal's view: blocks, results, saved state
    second = fresh.policy.propose(fresh.context(ctx.clock_s, ctx.position_um, ctx.program_open, ctx.block_id))
    assert second is not None
    assert (second.block.center_x_um, second.block.center_y_um, second.block.grid_g) == (
        first.block.center_x_um,
        first.block.center_y_um,
        first.block.grid_g,
    )
    assert second.jump_score == pytest.approx(first.jump_score, rel=1e-6)


def test_parts_are_frozen_data() -> None:
    parts = policy_parts("aeni")
    with pytest.raises(dataclasses.FrozenInstanceError):
        parts.hold = HoldRule()  # type: ignore[misc]
    with pytest.raises(dataclasses.FrozenInstanceError):
        parts.noise.drift_correction = False  # type: ignore[misc]


def test_aeni_nugget_learns_the_collapse_fields_site_scatter() -> None:
    """On the collapse provocation the scatter between centres is real (0.1 GPa of site texture): the nugget
    finds it, so the length-scales need not shrink to explain it."""
    run = _cached(f"{PLUS}+nugget", "collapse")
    c = run.campaign
    assert 0.04 < c.surrogate.site_sd_gpa < 0.2
    report = c.fit_report()
    assert report is not None and min(report.lengthscales_uv) > 0.05


def test_tight_and_unguarded_differ_only_in_the_guard() -> None:
    tight, loose = (
        Campaign(CampaignConfig(policy="aeni-paper+tight"), _TERNARY),
        Campaign(CampaignConfig(policy="aeni-paper+tight+unguarded"), _TERNARY),
    )
    assert tight.surrogate.guard == "keep-last-good" and tight.surrogate.lengthscale_prior
    assert tight.surrogate.floor_uv >= 0.005
    assert loose.surrogate.guard == "off" and not loose.surrogate.lengthscale_prior
    assert loose.surrogate.floor_uv < 0.25 * tight.surrogate.floor_uv
    assert replace(loose.policy.parts, guard=tight.policy.parts.guard) == tight.policy.parts


def test_aeni_guard_yields_to_a_confirmed_drop_and_strict_guard_does_not() -> None:
    aeni, strict = (
        Campaign(CampaignConfig(policy="aeni"), _TERNARY),
        Campaign(CampaignConfig(policy="aeni+strict-guard"), _TERNARY),
    )
    assert aeni.surrogate.guard == "keep-last-good-unless-confirmed"
    assert strict.surrogate.guard == "keep-last-good"
    assert aeni.surrogate.floor_uv == strict.surrogate.floor_uv and strict.surrogate.lengthscale_prior
    assert replace(strict.policy.parts, guard=aeni.policy.parts.guard) == aeni.policy.parts


def test_bias_aware_drift_estimate_ignores_the_reading_noise_but_not_an_event() -> None:
    rng = np.random.default_rng(0)
    quiet = tuple(np.maximum(0.002 * rng.standard_normal(25), 0.0).tolist())  # no drift, noisy readings
    assert robust_rate(quiet, 100.0, 40.0) < 0.0015
    # an event shows in the very next reading: the paper's 2 % rule fires on it at once
    event = (*quiet, 0.3)
    assert robust_rate(event, 100.0, 40.0) == pytest.approx(0.3)
    # one low reading after a high window is not trusted ...
    after = (*([0.2] * 11), 0.0)
    assert robust_rate(after, 100.0, 40.0) == pytest.approx(0.2)
    # ... but an event decaying over a slow block (16 indents of 120 s, tau 600 s) is: the newest readings
    # are under the 2 % rule (0.025 nm/s) while the window's median, half a window behind, is not
    decay = tuple((0.3 * np.exp(-np.arange(16) * 120.0 / 600.0)).tolist())
    assert float(np.median(decay[-12:])) > 0.025
    assert robust_rate(decay, 100.0, 40.0) == pytest.approx(decay[-2])
    assert robust_rate(decay, 100.0, 40.0) < 0.025


# -- aeni: scattered singles ----------------------------------------------------------------------------


def test_aeni_runs_blocks_of_scattered_singles_each_its_own_centre() -> None:
    run = _cached("aeni")
    c = run.campaign
    blocks = [d.block for d in run.decisions]
    assert all(b.grid_g == 1 and b.n_indents >= 2 for b in blocks)
    assert len(c.centres) == sum(len(r) for r in run.results)  # one centre per indent
    assert all(rec.n_indents == 1 and np.isnan(rec.spread_var_gpa2) for rec in c.centres)
    for d, steps in zip(run.decisions, run.steps, strict=True):
        pts = np.array([(i.x_um, i.y_um) for i in d.block.indents])
        gaps = np.hypot(pts[:, None, 0] - pts[None, :, 0], pts[:, None, 1] - pts[None, :, 1])
        np.fill_diagonal(gaps, np.inf)
        assert gaps.min() >= 15.0  # spread out, never sharing a site
        assert not any(s.category == "reconfigure" for s in steps)  # no hop trips the safety rule
        assert all(i.hold_s == d.block.hold_s for i in d.block.indents)
    # a space-filling start, then the model places the indents; programs serve several blocks
    phases = [d.phase for d in run.decisions]
    assert phases[0] == "explore" and "exploit" in phases
    assert sum(b.kind == "local" for b in blocks) >= 1
    # the first block holds 80 s (drift unknown); with no drift later ones go fast
    assert blocks[0].hold_s == SLOW_HOLD_S and any(b.hold_s == FAST_HOLD_S for b in blocks)


def test_aeni_on_the_products_lattice_indents_only_its_spaced_sites() -> None:
    """At 100×100 on 1,000 µm (9.9 µm apart) singles go to the sub-lattice whose sites are all 20 µm apart, so
    no pick jams the lattice for later ones (CandidateLattice.spaced_sites)."""
    from scipy.spatial import cKDTree

    from core.geometry import DISTANCE_TOL_UM

    run = _run("aeni", lattice_n=100, budget_s=6_000.0)
    c = run.campaign
    xy = np.array([(i.x_um, i.y_um) for d in run.decisions for i in d.block.indents])
    assert len(xy) >= 64 and any(d.phase == "exploit" for d in run.decisions)
    sites = c.lattice.xy_um[c.lattice.spaced_sites(20.0)]
    assert len(sites) == 2000
    d_site, _ = cKDTree(sites).query(xy)
    assert d_site.max() < 1e-6  # every indent on a spaced site
    d_pair = cKDTree(xy).query(xy, k=2)[0][:, 1]
    assert d_pair.min() >= 20.0 - DISTANCE_TOL_UM


def test_aeni_goes_off_the_spaced_sites_only_when_none_is_left() -> None:
    """Earlier work on a sample may block every spaced site and leave room between them: the run goes on
    there instead of stopping with places left."""
    from dataclasses import replace

    sc = make_scenario("ternary", 0)
    c = Campaign(CampaignConfig(policy="aeni", seed=0, lattice_n=100), sc.sample)
    ctx = c.context(0.0, (0.0, 0.0), False, 0)
    spaced = c.lattice.spaced_sites(20.0)
    on = c.policy.propose(ctx)
    assert on is not None
    idx = [c.lattice.nearest_index(i.x_um, i.y_um) for i in on.block.indents]
    assert spaced[idx].all()
    off = c.policy.propose(replace(ctx, placement_mask=~spaced))
    assert off is not None
    idx = [c.lattice.nearest_index(i.x_um, i.y_um) for i in off.block.indents]
    assert not spaced[idx].any()


def test_travel_order_visits_points_on_a_line_in_order() -> None:
    from core.policies.singles import travel_order

    _, ctx = _context_after("aeni", blocks=1)
    xs = np.array([700.0, 100.0, 400.0, 300.0, 600.0, 200.0, 500.0])
    pts = np.column_stack([xs, np.full(len(xs), 500.0)])
    order = travel_order(pts, (0.0, 500.0), ctx)
    assert list(xs[order]) == sorted(xs)


def test_aeni_treats_indents_on_pores_as_outliers() -> None:
    """5 % of the surface reads 50 % low: the Student-t rule inflates those values' noise so they barely pull
    the map, and leaves the film's real values trusted."""
    from drivers.sim.robust_fields import robust_scenario

    scen = robust_scenario("outliers", 2)
    c = Campaign(
        CampaignConfig(policy="aeni", seed=2, lattice_n=30, settings=PlannerSettings(budget_s=20_000.0)),
        scen.sample,
    )
    run_auto(c, scen.make_driver(c.profile))
    truth = scen.truth.hardness_gpa(
        np.array([r.x_um for r in c.centres]), np.array([r.y_um for r in c.centres])
    )
    on_pore = np.array([r.value_gpa for r in c.centres]) < 0.7 * truth
    inflation = np.array(c.noise_inflation)
    assert on_pore.sum() >= 3
    assert np.all(inflation[on_pore] > 4.0)  # at least a doubled sd, most far more
    assert np.mean(inflation[~on_pore] == 1.0) > 0.95
    gaussian = Campaign(replace(c.config, policy="aeni+gaussian"), scen.sample)
    run_auto(gaussian, scen.make_driver(gaussian.profile))
    assert all(v == 1.0 for v in gaussian.noise_inflation)
    evaluator = scen.evaluator()
    mine, theirs = evaluator.score(c).mape_pct, evaluator.score(gaussian).mape_pct
    assert mine is not None and theirs is not None and mine < theirs


def test_aeni_block_size_follows_what_opening_a_program_costs() -> None:
    """Block sizes 16–48 are priced against each other by gain per second: a program that is dear to open
    serves the most singles, one that costs nothing extra the fewest (a refit sooner)."""
    c, ctx = _context_after("aeni", blocks=5)
    assert len(ctx.learnt_xy_um) >= 64  # past the space-filling start: the model places the indents
    sizes = ScatteredSingles().block_sizes(100)
    assert sizes == (16, 32, 48) and ScatteredSingles().block_sizes(20) == (16, 20)
    # a block adds at most a quarter to the indents the model was fitted on
    assert ScatteredSingles().block_sizes(100, 64) == (16,)
    assert ScatteredSingles().block_sizes(100, 150) == (16, 32, 37)
    assert ScatteredSingles().block_sizes(100, 1000) == (16, 32, 48)
    cheap = c.policy.propose(
        replace(ctx, program_open=False, profile=replace(ctx.profile, global_jump_s=1.0))
    )
    dear = c.policy.propose(
        replace(ctx, program_open=False, profile=replace(ctx.profile, global_jump_s=50_000.0))
    )
    assert cheap is not None and dear is not None
    assert cheap.block.kind == dear.block.kind == "global"
    most = ScatteredSingles().block_sizes(10_000, len(ctx.learnt_xy_um))[-1]
    assert most > 16  # the context leaves room for a bigger block
    assert cheap.block.n_indents == 16 and dear.block.n_indents == most
    # the same posterior picks both: the dear block begins with the cheap one's singles
    first = [(i.x_um, i.y_um) for i in cheap.block.indents]
    assert set(first) <= {(i.x_um, i.y_um) for i in dear.block.indents}


def test_aeni_space_filling_jump_opens_where_the_stay_would_not_reach() -> None:
    """In the space-filling start a new program is anchored farthest from the earlier indents and from the
    stay's picks, so the start spreads over programs (anchored on the earlier indents alone, it opened beside
    the engaged program's area, and the ternary reached twice the grid's MAPE later)."""
    c, ctx = _context_after("aeni", blocks=2)
    assert ctx.program_open and len(ctx.learnt_xy_um) < ScatteredSingles().space_filling_indents
    stay = c.policy.propose(replace(ctx, profile=replace(ctx.profile, global_jump_s=1e7)))
    jump = c.policy.propose(replace(ctx, program_hold_s=1e5))  # the stay is on offer, but dear
    closed = c.policy.propose(replace(ctx, program_open=False))  # no stay: plain maximin
    assert stay is not None and jump is not None and closed is not None
    assert (stay.block.kind, jump.block.kind, closed.block.kind) == ("local", "global", "global")
    assert jump.phase == closed.phase == "explore"
    picks = np.array([(i.x_um, i.y_um) for i in stay.block.indents])
    earlier = np.asarray(ctx.learnt_xy_um)

    def gap(block: Block, points: np.ndarray) -> float:
        return float(np.min(np.hypot(points[:, 0] - block.center_x_um, points[:, 1] - block.center_y_um)))

    both = np.vstack([earlier, picks])
    assert gap(closed.block, earlier) >= gap(jump.block, earlier)  # maximin on the earlier indents alone
    assert gap(jump.block, both) > gap(closed.block, both)  # but the jump keeps away from the stay too


def _taken_elsewhere(ctx: PlanContext, n_side: int = 25) -> PlanContext:
    """The context with n_side² more taken places packed in one corner (4 µm apart): indents that teach the
    CSM map nothing, as a fast array's, failed ones or an earlier run's on the same sample."""
    x0, y0 = ctx.lattice.xy_um.min(axis=0)
    g = np.arange(n_side) * 4.0
    corner = np.column_stack([x0 + np.repeat(g, n_side), y0 + np.tile(g, n_side)])
    return replace(ctx, indents_xy_um=np.vstack([ctx.indents_xy_um, corner]))


def test_aeni_design_rules_count_what_the_map_learnt_not_every_taken_place() -> None:
    """A fast array, failed indents or an earlier run's indents take places (kept free by the exclusion) but
    teach the CSM map nothing: they must neither end the space-filling start, nor lift a block's cap against
    the data the model was fitted on, nor lengthen a program's life (an array of 150 fast indents once let
    the film's next CSM blocks grow to 53 singles on a model of 64, and made new programs look cheap)."""
    c, start = _context_after("aeni", blocks=2)
    assert len(start.learnt_xy_um) < ScatteredSingles().space_filling_indents
    crowded = _taken_elsewhere(start)
    assert len(crowded.indents_xy_um) > 600
    both = [c.policy.propose(replace(x, program_open=False)) for x in (start, crowded)]
    assert all(d is not None and d.phase == "explore" for d in both)

    c, later = _context_after("aeni", blocks=5)
    dear = replace(later.profile, global_jump_s=50_000.0)  # the biggest block the cap allows wins
    plain, packed = (
        c.policy.propose(replace(x, program_open=False, profile=dear))
        for x in (later, _taken_elsewhere(later))
    )
    assert plain is not None and packed is not None
    cap = ScatteredSingles().block_sizes(10_000, len(later.learnt_xy_um))[-1]
    assert plain.block.n_indents == packed.block.n_indents == cap

    from core.policies.scattered import program_life_indents

    assert program_life_indents(_taken_elsewhere(later)) == program_life_indents(later)
    assert program_life_indents(later) == len(later.learnt_xy_um) / later.globals_done


def test_aeni_jump_is_scored_on_the_posterior_before_the_stays_picks() -> None:
    """The stay and the jump are alternatives: picking the stay's singles must not change where the jump goes
    (it once did: both were picked from one posterior, which the stay's picks had already conditioned)."""
    c, ctx = _context_after("aeni", blocks=5)
    cheap = replace(ctx.profile, global_jump_s=1.0)  # a jump that costs nothing wins either way
    closed = c.policy.propose(replace(ctx, program_open=False, profile=cheap))
    open_ = c.policy.propose(replace(ctx, program_open=True, profile=cheap))
    assert closed is not None and open_ is not None
    assert open_.stay_score is not None and closed.stay_score is None  # a stay was on offer only when open
    assert closed.block.kind == open_.block.kind == "global"
    assert [(i.x_um, i.y_um) for i in open_.block.indents] == [(i.x_um, i.y_um) for i in closed.block.indents]


def test_bias_aware_hold_is_fast_when_the_drift_bias_is_negligible_however_small_the_aim() -> None:
    """On a nearly flat film the model can aim at 0.01 %: a bias of a few hundredths of a percent from the drift
    readings' own noise must not send a program to the 80 s hold."""
    _, ctx = _context_after("aeni", blocks=5)
    probe = replace(ctx, recent_drift_rates_nm_s=(0.001,) * 12, last_drift_rate_nm_s=0.001)
    rule = HoldRule(adaptive=True, bias_aware=True)
    hold, err, mode = rule.choose(probe, 0.0001)
    assert err is not None and err < rule.bias_floor_pct
    assert hold == FAST_HOLD_S and "bias-aware: fast" in mode
    # a real event is not negligible: slow
    event = replace(ctx, recent_drift_rates_nm_s=(0.001,) * 11 + (0.05,), last_drift_rate_nm_s=0.05)
    hold, err, _ = rule.choose(event, 0.0001)
    assert err is not None and err > rule.bias_floor_pct and hold == SLOW_HOLD_S

"""The heteroskedastic GP on the emulator's ternary field: accuracy, noise ranking, collapse guard, resume."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.stats import spearmanr

from core.errors import InputError
from core.model import FitReport, HeteroskedasticGP, Observations
from drivers.sim.emulator import TernaryField

SIDE_UM = 1000.0
PITCH_UV = 5.0 / SIDE_UM  # 5 µm indent pitch inside a local grid
FIELD = TernaryField(side_um=SIDE_UM)


def _lattice(n: int) -> np.ndarray:
    c = (np.arange(n) + 0.5) / n
    u, v = np.meshgrid(c, c)
    return np.column_stack([u.ravel(), v.ravel()])


def _indent_grids(
    centres_uv: np.ndarray, g: int, rng: np.random.Generator, noise_scale: float = 1.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every centre's g×g grid measured on the emulator: (uv per indent, hardness, centre id)."""
    offsets = (np.arange(g) - (g - 1) / 2) * PITCH_UV
    du, dv = (a.ravel() for a in np.meshgrid(offsets, offsets))
    uv = np.concatenate([np.column_stack([u + du, v + dv]) for u, v in centres_uv])
    ids = np.repeat(np.arange(len(centres_uv)), g * g)
    x_um, y_um = uv[:, 0] * SIDE_UM, uv[:, 1] * SIDE_UM
    sd = FIELD.noise_sd_gpa(x_um, y_um) * noise_scale
    hardness = FIELD.hardness_gpa(x_um, y_um) + sd * rng.standard_normal(len(uv))
    return uv, hardness, ids


def _obs(centres_uv: np.ndarray, g: int = 5, seed: int = 0) -> Observations:
    uv, h, ids = _indent_grids(centres_uv, g, np.random.default_rng(seed))
    return Observations.from_indents(uv, h, ids)


def _concat(a: Observations, b: Observations) -> Observations:
    return Observations(
        uv=np.vstack([a.uv, b.uv]),
        median_gpa=np.concatenate([a.median_gpa, b.median_gpa]),
        spread_var_gpa2=np.concatenate([a.spread_var_gpa2, b.spread_var_gpa2]),
        n_indents=np.concatenate([a.n_indents, b.n_indents]),
    )


def _truth(uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    x_um, y_um = uv[:, 0] * SIDE_UM, uv[:, 1] * SIDE_UM
    return FIELD.hardness_gpa(x_um, y_um), FIELD.noise_sd_gpa(x_um, y_um)


def _inline_truth(uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a, b = uv[:, 0], uv[:, 1]
    c = np.maximum(1 - a - b, 0.01)
    s = a + b + c
    a, b, c = a / s, b / s, c / s
    h = 3 * a + 5 * b + 7 * c - 4 * a * b - 3 * b * c - 2 * c * a - 6 * c**2 * (1 - c)
    return h, 0.005 + 0.1 * a + 0.05 * b + 0.025 * c


@pytest.fixture(scope="module")
def obs100() -> Observations:
    return _obs(_lattice(10), g=5, seed=0)


@pytest.fixture(scope="module")
def fitted(obs100: Observations) -> tuple[HeteroskedasticGP, FitReport]:
    gp = HeteroskedasticGP()
    return gp, gp.fit(obs100)


# -- data --------------------------------------------------------------------------------------------


def test_emulator_matches_the_spec_formula() -> None:
    uv = _lattice(37)
    h, sd = _truth(uv)
    h_ref, sd_ref = _inline_truth(uv)
    np.testing.assert_allclose(h, h_ref, rtol=1e-12)
    np.testing.assert_allclose(sd, sd_ref, rtol=1e-12)


def test_from_indents_groups_by_centre_in_first_seen_order() -> None:
    uv = np.array([[0.5, 0.5], [0.2, 0.2], [0.52, 0.5], [0.5, 0.52], [0.22, 0.2], [0.9, 0.9]])
    h = np.array([4.0, 6.0, 5.0, 9.0, 8.0, 3.0])
    ids = np.array([7, 2, 7, 7, 2, 4])
    obs = Observations.from_indents(uv, h, ids)
    np.testing.assert_allclose(obs.uv, [[1.52 / 3, 1.52 / 3], [0.21, 0.2], [0.9, 0.9]], rtol=1e-12)
    np.testing.assert_array_equal(obs.median_gpa, [5.0, 7.0, 3.0])
    np.testing.assert_allclose(
        obs.spread_var_gpa2[:2], [7.0, 2.0]
    )  # var([4,5,9], ddof=1) = 7, var([6,8]) = 2
    assert np.isnan(obs.spread_var_gpa2[2])
    np.testing.assert_array_equal(obs.n_indents, [3, 2, 1])


def test_observations_reject_bad_input() -> None:
    good = {
        "uv": np.zeros((2, 2)),
        "median_gpa": np.ones(2),
        "spread_var_gpa2": np.ones(2),
        "n_indents": [4, 4],
    }
    with pytest.raises(InputError, match=r"observations\.uv"):
        Observations(**{**good, "uv": np.zeros((2, 3))})
    with pytest.raises(InputError, match="median_gpa"):
        Observations(**{**good, "median_gpa": np.array([1.0, np.nan])})
    with pytest.raises(InputError, match="n_indents"):
        Observations(**{**good, "n_indents": [4, 0]})
    with pytest.raises(InputError, match="spread_var_gpa2"):
        Observations(**{**good, "spread_var_gpa2": np.array([1.0, -1.0])})
    with pytest.raises(InputError, match="no tested centres"):
        HeteroskedasticGP().fit(
            Observations(np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.zeros(0, dtype=int))
        )
    with pytest.raises(InputError, match="kernel"):
        HeteroskedasticGP(kernel="periodic")  # type: ignore[arg-type]
    with pytest.raises(InputError, match="threads"):
        HeteroskedasticGP(threads=3)
    with pytest.raises(RuntimeError, match="before fit"):
        HeteroskedasticGP().predict(np.zeros((3, 2)))


# -- accuracy and the noise field ----------------------------------------------------------------------


def test_recovers_the_ternary_field(fitted: tuple[HeteroskedasticGP, FitReport]) -> None:
    gp, report = fitted
    uv = _lattice(100)
    pred = gp.predict(uv)
    h, _ = _truth(uv)
    mape = float(np.mean(np.abs(pred.mean - h) / h) * 100)
    assert mape < 2.0, mape
    assert not report.collapse and report.collapse_reason == ""
    assert report.n_points == 100 and report.noise_lengthscales_uv is not None
    assert min(report.lengthscales_uv) > 0.1  # a smooth field: nowhere near the 0.02 floor
    np.testing.assert_allclose(pred.total_sd, np.sqrt(pred.epistemic_sd**2 + pred.noise_sd**2), rtol=1e-12)
    # epistemic sd is small at a tested centre and larger between centres and near the corners
    at_centre = gp.predict(np.array([[0.45, 0.45]])).epistemic_sd[0]
    corner = gp.predict(np.array([[0.0, 1.0]])).epistemic_sd[0]
    assert corner > 2 * at_centre


def test_mean_only_path_and_outputscale_agree_with_predict(
    fitted: tuple[HeteroskedasticGP, FitReport],
) -> None:
    gp, report = fitted
    uv = _lattice(30)
    np.testing.assert_allclose(gp.predict_mean(uv), gp.predict(uv).mean, rtol=0, atol=1e-12)
    assert gp.outputscale_gpa2 == pytest.approx(report.outputscale, rel=1e-12)


def test_noise_gp_ranks_noisy_against_quiet(fitted: tuple[HeteroskedasticGP, FitReport]) -> None:
    gp, _ = fitted
    uv = _lattice(50)
    pred = gp.predict(uv)
    _, sd_true = _truth(uv)
    rho = spearmanr(pred.noise_sd, sd_true).statistic
    assert rho > 0.6, rho
    # A-rich corner (u=1, v=0): σ ≈ 0.10 GPa; C-rich corner (0, 0): σ ≈ 0.035 GPa. Plain spreads near the
    # C corner also carry the field's steep trend across the 20 µm grid (sd ≈ 0.09), so only the order holds.
    loud, quiet = gp.predict(np.array([[0.95, 0.05], [0.05, 0.05]])).noise_sd
    assert loud > quiet
    assert 0.07 < loud < 0.14


def test_detrended_spreads_recover_the_noise_field() -> None:
    uv, h, ids = _indent_grids(_lattice(10), 5, np.random.default_rng(0))
    obs = Observations.from_indents(uv, h, ids, detrend=True)
    np.testing.assert_array_equal(obs.spread_dof, 22.0)
    gp = HeteroskedasticGP()
    gp.fit(obs)
    lattice = _lattice(50)
    pred = gp.predict(lattice)
    _, sd_true = _truth(lattice)
    assert spearmanr(pred.noise_sd, sd_true).statistic > 0.9
    assert float(np.median(np.abs(pred.noise_sd / sd_true - 1))) < 0.1
    loud, quiet = gp.predict(np.array([[0.95, 0.05], [0.05, 0.05]])).noise_sd
    assert loud > 2 * quiet
    assert 0.025 < quiet < 0.05  # truth 0.035


def test_detrend_removes_a_plane_exactly() -> None:
    offsets = np.array([-5.0, 0.0, 5.0]) / 1000
    du, dv = (a.ravel() for a in np.meshgrid(offsets, offsets))
    uv = np.column_stack([0.3 + du, 0.6 + dv])
    h = 4.0 + 30.0 * du - 12.0 * dv  # a steep plane, no noise
    plain = Observations.from_indents(uv, h, np.zeros(9))
    flat = Observations.from_indents(uv, h, np.zeros(9), detrend=True)
    assert plain.spread_var_gpa2[0] > 1e-3
    assert flat.spread_var_gpa2[0] == pytest.approx(0.0, abs=1e-20)
    assert flat.spread_dof is not None and flat.spread_dof[0] == 6.0
    assert flat.median_gpa[0] == plain.median_gpa[0] == pytest.approx(4.0)


def test_homoskedastic_option_learns_one_noise_level() -> None:
    centres = _lattice(6)
    uv, h, ids = _indent_grids(centres, 5, np.random.default_rng(3))
    x_um, y_um = uv[:, 0] * SIDE_UM, uv[:, 1] * SIDE_UM
    h = FIELD.hardness_gpa(x_um, y_um) + 0.05 * np.random.default_rng(4).standard_normal(len(h))
    obs = Observations.from_indents(uv, h, ids)
    gp = HeteroskedasticGP(heteroskedastic=False)
    report = gp.fit(obs)
    pred = gp.predict(_lattice(20))
    assert report.noise_lengthscales_uv is None
    assert np.ptp(pred.noise_sd) == 0.0  # one constant noise
    assert 0.01 < pred.noise_sd[0] < 0.25  # learned from the scatter of medians: loosely 0.05 GPa


def test_few_spreads_fall_back_to_the_pooled_variance() -> None:
    obs = _obs(np.array([[0.2, 0.3], [0.7, 0.6]]), g=3, seed=5)
    gp = HeteroskedasticGP()
    report = gp.fit(obs)
    pooled = float(np.mean(obs.spread_var_gpa2))  # equal degrees of freedom: the plain mean
    pred = gp.predict(_lattice(4))
    np.testing.assert_allclose(pred.noise_sd, np.sqrt(pooled), rtol=1e-12)
    assert report.hyper["noise"]["kind"] == "pooled"
    # single indents (no spread at all): the noise is learned, the fit still works
    single = _obs(_lattice(4), g=1, seed=6)
    assert np.all(np.isnan(single.spread_var_gpa2))
    gp1 = HeteroskedasticGP()
    assert gp1.fit(single).hyper["noise"]["kind"] == "learned"
    assert np.all(np.isfinite(gp1.predict(_lattice(5)).mean))


# -- the fast paths equal gpytorch's own ---------------------------------------------------------------


@pytest.mark.parametrize(("kernel", "hetero"), [("matern52", True), ("rbf", True), ("matern52", False)])
def test_cholesky_diagonal_equals_gpytorch(kernel: str, hetero: bool) -> None:
    rng = np.random.default_rng(11)
    obs = _obs(rng.uniform(0.02, 0.98, size=(40, 2)), g=3, seed=12)
    gp = HeteroskedasticGP(kernel=kernel, heteroskedastic=hetero)  # type: ignore[arg-type]
    gp.fit(obs)
    uv = np.vstack([rng.uniform(0, 1, size=(200, 2)), obs.uv[:5]])  # including training centres
    pred = gp.predict(uv)
    ref_mean, ref_var = gp.reference_latent(uv)
    np.testing.assert_allclose(pred.epistemic_sd**2, ref_var, rtol=0, atol=1e-6)
    np.testing.assert_allclose(pred.mean, ref_mean, rtol=0, atol=1e-6)
    ours, theirs = gp.reference_neg_mll()  # the optimised objective is gpytorch's exact MLL (+ prior)
    assert ours == pytest.approx(theirs, abs=1e-9)


# -- determinism, warm start and resume ----------------------------------------------------------------


def test_set_hyper_reproduces_the_fitted_model_bit_for_bit(
    fitted: tuple[HeteroskedasticGP, FitReport], obs100: Observations
) -> None:
    gp, report = fitted
    record = json.loads(json.dumps(report.hyper))  # through the journal
    resumed = HeteroskedasticGP()
    resumed.set_hyper(record, obs100)
    uv = _lattice(100)
    a, b = gp.predict(uv), resumed.predict(uv)
    for field in ("mean", "epistemic_sd", "noise_sd", "total_sd"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    # and the next (warm) fit continues identically in both
    more = _concat(obs100, _obs(np.array([[0.33, 0.71], [0.81, 0.12]]), seed=9))
    original = HeteroskedasticGP()
    original.set_hyper(record, obs100)
    assert original.fit(more).hyper == resumed.fit(more).hyper


def test_fit_is_deterministic_and_warm_start_is_cheaper(obs100: Observations) -> None:
    first, second = HeteroskedasticGP(), HeteroskedasticGP()
    cold_a, cold_b = first.fit(obs100), second.fit(obs100)
    assert cold_a.hyper == cold_b.hyper
    more = _concat(obs100, _obs(np.array([[0.52, 0.47]]), seed=21))
    warm = first.fit(more)
    cold = HeteroskedasticGP().fit(more)
    assert warm.iterations < cold.iterations
    np.testing.assert_allclose(warm.lengthscales_uv, cold.lengthscales_uv, rtol=0.05)


def test_warm_start_escapes_an_early_constant_fit(obs100: Observations) -> None:
    # on three centres both GPs are near-constant (outputscale ~ 0, a flat corner of the likelihood);
    # warm-starting from there must still find what a cold fit on the full data finds
    gp = HeteroskedasticGP()
    gp.fit(_obs(np.array([[0.2, 0.2], [0.8, 0.3], [0.4, 0.9]]), seed=3))
    warm = gp.fit(obs100)
    cold = HeteroskedasticGP().fit(obs100)
    assert warm.noise_lengthscales_uv is not None and cold.noise_lengthscales_uv is not None
    np.testing.assert_allclose(warm.lengthscales_uv, cold.lengthscales_uv, rtol=0.05)
    np.testing.assert_allclose(warm.noise_lengthscales_uv, cold.noise_lengthscales_uv, rtol=0.05)
    np.testing.assert_allclose(warm.outputscale, cold.outputscale, rtol=0.05)


def test_set_hyper_rejects_foreign_records(obs100: Observations) -> None:
    with pytest.raises(InputError, match="hyperparameter record"):
        HeteroskedasticGP().set_hyper({"version": 99}, obs100)
    record = HeteroskedasticGP().fit(_obs(_lattice(3))).hyper
    with pytest.raises(InputError, match="kernel"):
        HeteroskedasticGP(kernel="rbf").set_hyper(record, obs100)


# -- the length-scale collapse guard ---------------------------------------------------------------------


def _contradictory_cluster(k: int = 8) -> Observations:
    """Tight centres 12 µm apart whose precise medians (tiny spreads) flip between 4 and 6.5 GPa."""
    uv = np.array([[0.45 + 0.012 * (i % 4), 0.45 + 0.012 * (i // 4)] for i in range(k)])
    med = np.array([6.5 if (i % 2) == (i // 4) % 2 else 4.0 for i in range(k)])
    return Observations(uv, med, np.full(k, 0.02**2), np.full(k, 25))


@pytest.fixture(scope="module")
def healthy() -> Observations:
    return _obs(_lattice(6), seed=1)


def test_no_collapse_alarm_while_healthy(healthy: Observations) -> None:
    gp = HeteroskedasticGP()
    reports = [gp.fit(healthy)]
    for i in range(3):  # more centres, sensible data: no alarm on any refit
        extra = _obs(np.random.default_rng(40 + i).uniform(0.05, 0.95, size=(4, 2)), seed=50 + i)
        healthy = _concat(healthy, extra)
        reports.append(gp.fit(healthy))
    assert not any(r.collapse for r in reports)
    assert not any(r.used_last_good for r in reports)


def test_collapse_fires_and_keeps_the_last_good_hyperparameters(healthy: Observations) -> None:
    gp = HeteroskedasticGP()
    good = gp.fit(healthy)
    bad = gp.fit(_concat(healthy, _contradictory_cluster()))
    assert bad.collapse and bad.used_last_good
    assert "floor" in bad.collapse_reason and "dropped" in bad.collapse_reason
    assert "kept the last good" in bad.collapse_reason
    assert bad.lengthscales_uv == good.lengthscales_uv
    assert bad.hyper["mean"]["raw"] == good.hyper["mean"]["raw"]
    assert gp.hyper == bad.hyper
    # predictions use the restored length-scales: smooth, not spiking through the cluster
    pred = gp.predict(np.array([[0.45, 0.45], [0.462, 0.45]]))
    assert abs(pred.mean[0] - pred.mean[1]) < 1.0


def test_collapse_with_the_guard_off_reports_but_keeps_the_new_fit(healthy: Observations) -> None:
    gp = HeteroskedasticGP(guard="off")
    good = gp.fit(healthy)
    bad = gp.fit(_concat(healthy, _contradictory_cluster()))
    assert bad.collapse and not bad.used_last_good
    assert max(bad.lengthscales_uv) < 0.35 * min(good.lengthscales_uv)
    assert "kept" not in bad.collapse_reason


def test_sudden_drop_alone_raises_the_alarm(healthy: Observations) -> None:
    # a floor far below the fitted values: only the drop rule can fire
    gp = HeteroskedasticGP(lengthscale_floor_uv=0.001, collapse_drop_ratio=0.9, guard="off")
    first = gp.fit(healthy)
    forced = dict(first.hyper)
    raw = list(forced["mean"]["raw"])
    raw[2] += 2.0  # pretend the previous fit had much longer length-scales
    raw[3] += 2.0
    forced["mean"] = {"raw": raw}
    forced["lengthscales_uv"] = [float(np.log1p(np.exp(r)) + 0.001) for r in raw[2:4]]
    assert min(forced["lengthscales_uv"]) > 1.5
    gp.set_hyper(forced, healthy)
    report = gp.fit(healthy)
    assert report.collapse
    assert "dropped" in report.collapse_reason and "floor" not in report.collapse_reason


# -- site-to-site scatter (the nugget) -------------------------------------------------------------------


def _site_scattered(site_sd: float, seed: int = 3) -> Observations:
    """3×3 grids whose indents share one offset per centre: scatter that no within-grid spread shows."""
    rng = np.random.default_rng(seed)
    centres = rng.uniform(0.03, 0.97, size=(80, 2))
    uv, h, ids = _indent_grids(centres, 3, rng)
    h = h + rng.normal(0.0, site_sd, len(centres))[ids]
    return Observations.from_indents(uv, h, ids)


def test_nugget_learns_site_scatter_that_the_spreads_cannot_see() -> None:
    obs = _site_scattered(0.15)
    plain, nug = HeteroskedasticGP(), HeteroskedasticGP(nugget=True)
    rep_plain, rep_nug = plain.fit(obs), nug.fit(obs)
    assert plain.site_sd_gpa == 0.0
    assert nug.site_sd_gpa == pytest.approx(0.15, rel=0.35)
    uv = _lattice(50)
    truth, _ = _truth(uv)

    def mape(gp: HeteroskedasticGP) -> float:
        return float(np.mean(np.abs(gp.predict_mean(uv) - truth) / truth))

    # without it the GP chases the scatter with shorter length-scales and maps it as if it were hardness
    assert mape(nug) < 0.8 * mape(plain)
    assert min(rep_nug.lengthscales_uv) > min(rep_plain.lengthscales_uv)
    # its likelihood is still gpytorch's (fixed noise + the learned term)
    ours, theirs = nug.reference_neg_mll()
    assert ours == pytest.approx(theirs, abs=1e-9)
    # it resumes bit for bit, and a record never loads into a model of the other kind
    record = json.loads(json.dumps(rep_nug.hyper))
    resumed = HeteroskedasticGP(nugget=True)
    resumed.set_hyper(record, obs)
    np.testing.assert_array_equal(resumed.predict(uv).mean, nug.predict(uv).mean)
    assert resumed.site_sd_gpa == nug.site_sd_gpa
    with pytest.raises(InputError, match="nugget"):
        HeteroskedasticGP().set_hyper(record, obs)


def test_nugget_stays_small_without_site_scatter(obs100: Observations) -> None:
    gp = HeteroskedasticGP(nugget=True)
    gp.fit(obs100)
    truth, _ = _truth(_lattice(30))
    assert gp.site_sd_gpa < 0.01  # against per-indent noise of up to 0.1 GPa
    assert float(np.mean(np.abs(gp.predict_mean(_lattice(30)) - truth) / truth)) < 0.01


def test_observations_carry_the_estimators_efficiency() -> None:
    base = _obs(_lattice(3), g=3)
    assert np.all(base.efficiency == pytest.approx(np.pi / 2))
    huber = Observations(
        base.uv, base.median_gpa, base.spread_var_gpa2, base.n_indents, efficiency=np.full(9, 1.08)
    )
    gp_m, gp_h = HeteroskedasticGP(), HeteroskedasticGP()
    gp_m.fit(base)
    gp_h.fit(huber)
    # a more efficient centre value is a more certain one
    assert np.all(gp_h.predict(base.uv).epistemic_sd < gp_m.predict(base.uv).epistemic_sd)
    with pytest.raises(InputError, match="efficiency"):
        Observations(
            base.uv, base.median_gpa, base.spread_var_gpa2, base.n_indents, efficiency=np.full(9, 0.5)
        )


# -- cold restarts of a warm-started refit ---------------------------------------------------------------


def _texture(n: int, seed: int, period: float = 0.2, amplitude_gpa: float = 0.8) -> Observations:
    """Single indents on a texture of period 0.2 of the side, 1 % noise: 40 points read it as noise."""
    rng = np.random.default_rng(seed)
    uv = rng.uniform(0.0, 1.0, size=(n, 2))
    h = 5.0 + amplitude_gpa * _egg_box(uv, period)
    h = h + 0.05 * rng.standard_normal(n)
    return Observations(uv, h, np.full(n, np.nan), np.ones(n))


def _egg_box(uv: np.ndarray, period: float) -> np.ndarray:
    return np.sin(2 * np.pi * uv[:, 0] / period) * np.sin(2 * np.pi * uv[:, 1] / period)


def test_a_refit_on_grown_data_escapes_the_warm_optimum_and_resumes_the_same() -> None:
    """A warm start follows the optimum it fitted on few points (texture read as noise at a long length-scale);
    once the data have grown 1.5× since the last cold fit, the cold starts run too and the better likelihood
    wins, a short length-scale that is the data's own choice, not a collapse. The schedule is part of the
    record, so a resumed run makes the same choice."""
    few, many = _texture(40, 0), _texture(400, 0)
    gp = HeteroskedasticGP(lengthscale_floor_uv=0.01)
    first = gp.fit(few)
    assert min(first.lengthscales_uv) > 0.1 and first.hyper["cold_n"] == 40
    # the same refit with the cold starts not yet due: the warm optimum holds
    stuck = HeteroskedasticGP(lengthscale_floor_uv=0.01)
    stuck.set_hyper({**first.hyper, "cold_n": 10_000}, few)
    warm_only = stuck.fit(many)
    assert min(warm_only.lengthscales_uv) > 0.1
    resumed = HeteroskedasticGP(lengthscale_floor_uv=0.01)
    resumed.set_hyper(first.hyper, few)
    grown = gp.fit(many)
    assert max(grown.lengthscales_uv) < 0.05 and grown.hyper["cold_n"] == 400
    assert not grown.collapse and not grown.used_last_good
    assert resumed.fit(many).hyper == grown.hyper
    grid = _lattice(40)
    truth = 5.0 + 0.8 * np.sin(2 * np.pi * grid[:, 0] / 0.2) * np.sin(2 * np.pi * grid[:, 1] / 0.2)
    error = np.mean(np.abs(gp.predict_mean(grid) - truth))
    assert error < 0.5 * np.mean(np.abs(stuck.predict_mean(grid) - truth))


def test_a_drop_the_cold_search_confirms_passes_the_confirming_guard_only() -> None:
    """Here the warm refit itself slides from the few points' long scale (0.35) to the texture's (0.1): a
    drop keep-last-good vetoes. When the cold starts are due and land there too, beating the kept kernel by
    more than 2 nats, ``aeni``'s guard takes the drop as the data's; with the cold starts not due it keeps
    the last good kernel like the strict guard (the grains: 35 of 41 refits vetoed before)."""
    few, many = (
        _texture(30, 0, period=0.4, amplitude_gpa=0.3),
        _texture(300, 0, period=0.4, amplitude_gpa=0.3),
    )
    fits = {}
    for guard in ("keep-last-good", "keep-last-good-unless-confirmed"):
        for cold_due in (True, False):
            first = HeteroskedasticGP(lengthscale_floor_uv=0.01, guard=guard).fit(few)
            assert max(first.lengthscales_uv) > 0.3
            gp = HeteroskedasticGP(lengthscale_floor_uv=0.01, guard=guard)
            gp.set_hyper({**first.hyper, "cold_n": 30 if cold_due else 10_000}, few)
            fits[guard, cold_due] = (gp, gp.fit(many), first)
    _, confirmed, _ = fits["keep-last-good-unless-confirmed", True]
    assert max(confirmed.lengthscales_uv) < 0.15 and not confirmed.collapse and not confirmed.used_last_good
    for key in (
        ("keep-last-good", True),
        ("keep-last-good", False),
        ("keep-last-good-unless-confirmed", False),
    ):
        _, report, first = fits[key]
        assert report.collapse and report.used_last_good, key
        assert report.lengthscales_uv == pytest.approx(first.lengthscales_uv)
    grid = _lattice(40)
    truth = 5.0 + 0.3 * _egg_box(grid, 0.4)
    errors = {key: np.mean(np.abs(gp.predict_mean(grid) - truth)) for key, (gp, _, _) in fits.items()}
    assert errors["keep-last-good-unless-confirmed", True] < 0.5 * errors["keep-last-good", True]

"""A new array's re-optimisation runs beside the next block (core/model/deferred.py): the decision after the
array is made on the model conditioned with the hyperparameters it had, and the next fit installs the
re-optimisation, which is the synchronous fit's, bit for bit (a run's plans do not depend on the machine)."""

from __future__ import annotations

import copy
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from core.fast_array import FastArray, fast_block
from core.model.deferred import Deferred
from core.model.observations import Observations
from core.model.two_fidelity import TwoFidelityGP, fast_link_observations, fast_observations
from core.plan import Block, IndentSpec
from drivers.sim.scenarios import make_scenario
from tests.test_fast_plan import _after_one_array, _measured
from tests.test_two_fidelity import delta_truth, fast_truth, lattice, rho_truth

N_CSM = 40
MAX_ITER, WARM_MAX_ITER = 20, 8  # short optimisations: the tests compare two paths to one fit, not optima
ROOT = Path(__file__).resolve().parents[1]


def modulus(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return 120.0 + 30.0 * np.cos(4.0 * u) * np.sin(3.0 * v)


def csm_values(rng: np.random.Generator, uv: np.ndarray) -> Observations:
    h = rho_truth(uv[:, 0], uv[:, 1]) * fast_truth(uv[:, 0], uv[:, 1]) + delta_truth(uv[:, 0], uv[:, 1])
    vals = h[:, None] + 0.05 * rng.standard_normal((len(uv), 9))
    return Observations(
        uv=uv,
        median_gpa=np.median(vals, axis=1),
        spread_var_gpa2=np.var(vals, axis=1, ddof=1),
        n_indents=np.full(len(uv), 9),
    )


@pytest.fixture(scope="module")
def landed() -> dict[str, object]:
    """A model fitted on a first array (u < 0.6) and 40 CSM centres; the second array's data beside it."""
    rng = np.random.default_rng(37)
    uf = lattice(60)
    hf = fast_truth(uf[:, 0], uf[:, 1]) + 0.15 * rng.standard_normal(len(uf))
    ef = modulus(uf[:, 0], uf[:, 1]) + 3.0 * rng.standard_normal(len(uf))
    first = uf[:, 0] < 0.6
    csm = csm_values(rng, rng.random((N_CSM, 2)))
    more = csm_values(rng, rng.random((3, 2)))
    csm_more = Observations(
        uv=np.vstack([csm.uv, more.uv]),
        median_gpa=np.concatenate([csm.median_gpa, more.median_gpa]),
        spread_var_gpa2=np.concatenate([csm.spread_var_gpa2, more.spread_var_gpa2]),
        n_indents=np.concatenate([csm.n_indents, more.n_indents]),
    )
    model = TwoFidelityGP(max_iter=MAX_ITER, warm_max_iter=WARM_MAX_ITER)
    model.fit(
        csm, fast_observations(uf[first], hf[first]), fast_link_observations(uf[first], hf[first], ef[first])
    )
    return {
        "model": model,
        "csm": csm,
        "csm_more": csm_more,
        "fast": fast_observations(uf, hf),
        "fast_first": fast_observations(uf[first], hf[first]),
        "link_first": fast_link_observations(uf[first], hf[first], ef[first]),
        "link": fast_link_observations(uf, hf, ef),
    }


def test_the_decision_after_an_array_conditions_and_the_next_fit_is_the_synchronous_one(
    landed: dict[str, object],
) -> None:
    base = landed["model"]
    assert isinstance(base, TwoFidelityGP)
    csm, csm_more, fast, link = (landed[k] for k in ("csm", "csm_more", "fast", "link"))
    assert isinstance(csm, Observations) and isinstance(csm_more, Observations)
    assert isinstance(fast, Observations) and isinstance(link, Observations)
    deferred, synchronous = copy.deepcopy(base), copy.deepcopy(base)
    grid = lattice(20)
    new_side = grid[:, 0] > 0.7
    sd_before = base.predict(grid).epistemic_sd

    report = deferred.fit(csm, fast, link, defer=True)
    # the decision's model: the new cells learnt with the hyperparameters of before, no optimiser step
    assert report.iterations == 0 and deferred.reoptimising
    assert deferred.theta == base.theta
    now = deferred.predict(grid)
    sd_now = now.epistemic_sd
    assert np.median(sd_now[new_side]) < 0.8 * np.median(sd_before[new_side])
    # the journal's record meanwhile is that conditioned model, counters included: a resumed run
    # re-optimises at its next fit, as this one would have
    record = json.loads(json.dumps(deferred.hyper))
    assert record["cokriging"]["fast_n"] == base.hyper["cokriging"]["fast_n"]  # type: ignore[index]

    # a deep copy (the tests copy campaigns) owns its re-optimisation: not started, its own copy of the
    # work (run at its next fit); started, the finished result, copied
    unstarted = copy.deepcopy(deferred)
    deferred.start_reoptimisation()  # the decision is made: the thread runs beside the next block
    started = copy.deepcopy(deferred)
    assert synchronous.fit(csm, fast, link).iterations > 0
    for model in (deferred, synchronous, unstarted, started):
        model.fit(csm_more, fast, link, defer=True)
        assert not model.reoptimising
    assert len({id(m.fast_gp) for m in (deferred, unstarted, started)}) == 3
    for model in (deferred, unstarted, started):
        assert model.theta == synchronous.theta
        np.testing.assert_array_equal(model.predict(grid).mean, synchronous.predict(grid).mean)
        np.testing.assert_array_equal(
            model.predict(grid).epistemic_sd, synchronous.predict(grid).epistemic_sd
        )

    # a run resumed from that record (a crash before the next block's refit) prepares the same
    # re-optimisation again, and its next fit is the uninterrupted run's, bit for bit
    restored = TwoFidelityGP(max_iter=MAX_ITER, warm_max_iter=WARM_MAX_ITER)
    restored.set_hyper(record, csm, fast, link)
    np.testing.assert_array_equal(restored.predict(grid).mean, now.mean)
    assert restored.reoptimising
    restored.fit(csm_more, fast, link, defer=True)
    assert not restored.reoptimising and restored.theta == deferred.theta
    np.testing.assert_array_equal(restored.predict(grid).mean, deferred.predict(grid).mean)


def test_a_csm_block_never_defers(landed: dict[str, object]) -> None:
    """No new fast data: the refit is the usual one (conditioned or re-optimised now), never a thread."""
    model = copy.deepcopy(landed["model"])
    csm_more, fast_first, link_first = (landed[k] for k in ("csm_more", "fast_first", "link_first"))
    assert isinstance(model, TwoFidelityGP) and isinstance(csm_more, Observations)
    assert isinstance(fast_first, Observations) and isinstance(link_first, Observations)
    model.fit(csm_more, fast_first, link_first, defer=True)
    assert not model.reoptimising and model.mode == "two-fidelity"


def test_the_thread_returns_its_value_and_raises_its_error_in_the_caller() -> None:
    threads = Deferred(torch.get_num_threads, 1)
    assert threads.result() == 1

    def fail() -> int:
        raise ValueError("the optimiser's own error")

    with pytest.raises(ValueError, match="optimiser's own error"):
        Deferred(fail, 1).result()


def test_an_interpreter_that_exits_mid_fit_waits_and_exits_cleanly() -> None:
    """A run that ends while a re-optimisation runs: the process exits 0 (a daemon thread in torch at
    interpreter teardown aborts it with SIGABRT, exit 134)."""
    script = (
        "import torch\n"
        "from core.model.deferred import Deferred\n"
        "def work():\n"
        "    a = torch.randn(300, 300, dtype=torch.float64)\n"
        "    for _ in range(400):\n"
        "        a = torch.linalg.cholesky(a @ a.T + 300 * torch.eye(300, dtype=torch.float64)) / 20\n"
        "    return 1\n"
        "Deferred(work, 1).start()\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", script], cwd=ROOT, capture_output=True, text=True, timeout=120, check=False
    )
    assert done.returncode == 0, done.stderr[-500:]


def test_a_campaign_plans_after_a_second_array_on_the_conditioned_model() -> None:
    """The run's path: the second array is learnt at once with the hyperparameters of before, the
    proposal starts the re-optimisation, and the refit after the next block installs it."""
    campaign = copy.deepcopy(_after_one_array(1.0, faithful=True))
    assert campaign.fast is not None and campaign.fast.active
    model = campaign.fast.model
    theta = model.theta
    truth = make_scenario("ternary", 0).truth
    fb = fast_block(2, FastArray(200.0, 800.0, 8, 8, 40.0))
    sites = np.array([(s.x_um, s.y_um) for s in fb.indents])
    rng = np.random.default_rng(2)
    read = truth.hardness_gpa(sites[:, 0], sites[:, 1]) - 1.0 + rng.normal(0, 0.06, len(sites))
    campaign.observe_block(fb, _measured(2, sites, read, "fast"))
    assert model.reoptimising and model.theta == theta and campaign.fast.n == 121 + 64
    decision = campaign.propose(20_000.0, (200.0, 800.0), False, 3)
    assert decision is not None
    xy = np.array([[700.0, 250.0]])
    block = Block(3, "global", 700.0, 250.0, 1, 5.0, 80.0, (IndentSpec(700.0, 250.0, 80.0),))
    campaign.observe_block(block, _measured(3, xy, truth.hardness_gpa(xy[:, 0], xy[:, 1])))
    assert not model.reoptimising and model.theta != theta

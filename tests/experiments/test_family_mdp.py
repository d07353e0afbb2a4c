"""Finite MDPs through the generic loop: exact diagnostics, the bounds, DAgger vs Batch."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pyarrow as pa
import pytest

from loopid.algorithms.collect import policy_samples
from loopid.algorithms.loop import run_learning
from loopid.algorithms.loop_program import make_loop_program
from loopid.algorithms.schedules import policy_fractions
from loopid.control.value_iteration import occupancy
from loopid.experiments.families.mdp import MDP_SCENARIOS, mdp_figure, mdp_setup, run_mdp
from loopid.experiments.families.mdp.agent import (
    DIAGNOSTICS,
    MDPModel,
    counts_model,
    mdp_agent,
    mdp_diagnostics,
    mdp_plant,
)
from loopid.experiments.results import trace_table
from loopid.learners.base import Learner

pytestmark = pytest.mark.slow  # each scenario compiles one cell (~5-15 s)


@functools.cache
def _runs(scenario: str):
    return {m: run_mdp(m, scenario) for m in ("dagger", "batch")}


def _extra(trace, name):
    return np.asarray(trace.rows.extra[name])


@pytest.mark.parametrize("scenario", ["mdp-random", "mdp-trap", "mdp-trap-hinge"])
def test_bound_holds_on_every_row(scenario):
    for method, trace in _runs(scenario).items():
        j_best, bound = _extra(trace, "j_best"), _extra(trace, "bound")
        assert j_best.shape == (8, 30)
        assert np.all(j_best <= bound + 1e-9), method
        assert np.all(_extra(trace, "j_best") <= _extra(trace, "j_mixture") + 1e-12)
        # test_cost is the exact J of the iteration's policy
        np.testing.assert_allclose(trace.rows.test_cost, _extra(trace, "j_policy"), atol=1e-12)
        for name in DIAGNOSTICS:
            assert not np.isnan(_extra(trace, name)).any(), (method, name)
    # DAgger's bound (Lemma 4.1 from n = 2) only needs c_ν^{π*}: finite and shrinking
    dagger = _extra(_runs(scenario)["dagger"], "bound")
    assert np.isfinite(dagger).all() and np.all(dagger[:, -1] < dagger[:, 1])


def test_realisable_random_mdp_both_become_optimal():
    for method, trace in _runs("mdp-random").items():
        gap = _extra(trace, "j_policy") - _extra(trace, "j_optimal")
        assert gap[:, 0].mean() > 0.1, method  # the initial model is far from optimal
        assert np.mean(gap[:, -5:] < 1e-9) >= 0.8, method  # then nearly always optimal
        assert gap[:, -1].mean() < 0.02, method
        assert np.all(_extra(trace, "eps_mdl_l1") == 0.0)  # realisable: no modelling error
        l1 = _extra(trace, "eps_prd_l1")
        assert np.all(l1[:, -1] < 0.5 * l1[:, 1])


def test_trap_dagger_beats_batch_with_the_same_nu():
    runs = _runs("mdp-trap")
    j_star = _extra(runs["dagger"], "j_optimal")[0, 0]
    final = {m: _extra(t, "j_policy")[:, -1] for m, t in runs.items()}
    assert final["dagger"].mean() < final["batch"].mean() - 3.0
    assert np.all(final["dagger"] < j_star + 1e-9)
    # Batch's policy goes where ν rarely looks: c_ν^π̂ is huge, c_ν^{π*} is not
    assert np.median(_extra(runs["batch"], "c_nu_policy")[:, -1]) > 100
    assert _extra(runs["batch"], "c_nu")[0, 0] < 2


def test_classifier_is_agnostic_and_dagger_still_wins():
    runs = _runs("mdp-trap-hinge")
    for trace in runs.values():
        mdl = _extra(trace, "eps_mdl_l1")
        assert np.all(mdl > 0.05)  # the deterministic class cannot model the slip
        assert np.all(_extra(trace, "eps_prd_l1") >= mdl - 1e-12)  # nothing beats the best
    final = {m: _extra(t, "j_policy")[:, -1] for m, t in runs.items()}
    assert final["dagger"].mean() < final["batch"].mean() - 3.0


def test_a_learner_that_is_not_no_regret_gives_a_larger_bound_not_a_violation():
    s = MDP_SCENARIOS["mdp-trap"]
    setup = mdp_setup(s)
    good = counts_model(setup.mdp.n_states, setup.mdp.n_actions, alpha=s.alpha)
    frozen = Learner(good.learner.init, lambda state, X, Y, mask=None: state, good.learner.weights)
    broken = MDPModel(frozen, *good[1:4], "frozen")
    agent = mdp_agent(setup.mdp, broken)
    diag = mdp_diagnostics(setup.mdp, setup.nu_dist, broken)
    loop = setup.loop._replace(agent=agent)
    cell = make_loop_program(loop, 10, diagnostics=diag)
    trace = run_learning(loop, policy_fractions("dagger", 10), range(4), program=cell)
    bound, j_best = _extra(trace, "bound"), _extra(trace, "j_best")
    assert np.all(j_best <= bound + 1e-9)
    good_bound = _extra(_runs("mdp-trap")["dagger"], "bound")[:4, :10]
    assert np.all(bound[:, 2:] > good_bound[:, 2:])
    assert np.all(_extra(trace, "eps_prd_l1")[:, -1] > 0.5)  # the frozen model never improves


def test_geometric_draws_follow_the_discounted_distribution():
    setup = mdp_setup(MDP_SCENARIOS["mdp-random"])
    mdp, plant = setup.mdp, setup.plant
    S, A = mdp.n_states, mdp.n_actions
    K = jnp.full((S, A), 1.0 / A)
    tr = jax.jit(lambda k: policy_samples(plant, K, k, 20000, mode="geometric", gamma=0.9))(
        jax.random.key(0)
    )
    freq = np.zeros((S, A))
    np.add.at(freq, (np.asarray(tr.s), np.asarray(tr.a)), 1.0 / 20000)
    D = np.asarray(occupancy(mdp.P, mdp.mu, mdp.gamma, K))
    assert 0.5 * np.abs(freq - D).sum() < 0.03
    nu = setup.nu(jax.random.key(1), 20000)
    freq = np.zeros((S, A))
    np.add.at(freq, (np.asarray(nu.s), np.asarray(nu.a)), 1.0 / 20000)
    assert 0.5 * np.abs(freq - setup.nu_dist).sum() < 0.03
    traj = policy_samples(plant, K, jax.random.key(2), 64, mode="trajectory")
    assert traj.s.shape == (64,) and bool(traj.mask.all())


def test_results_table_and_figure(tmp_path):
    tables = [trace_table(name, m, t) for name in ("mdp-trap",) for m, t in _runs(name).items()]
    table = pa.concat_tables(tables)
    for name in ("j_policy", "j_best", "j_optimal", "bound", "c_nu_policy"):
        assert table.schema.field(name).type == pa.float64()
    path = mdp_figure(table, tmp_path / "mdp.png")
    assert path.stat().st_size > 10_000
    with pytest.raises(ValueError, match="MDP diagnostics"):
        mdp_figure(table.drop(["bound"]), tmp_path / "x.png")


def test_bad_arguments():
    with pytest.raises(ValueError, match="unknown MDP method"):
        run_mdp("pg", "mdp-trap")
    with pytest.raises(ValueError, match="unknown MDP scenario"):
        run_mdp("dagger", "mdp-nope")
    with pytest.raises(ValueError, match="horizon"):
        mdp_plant(mdp_setup(MDP_SCENARIOS["mdp-trap"]).mdp, 0)

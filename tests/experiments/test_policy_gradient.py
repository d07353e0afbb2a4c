"""The model-free policy-gradient baseline (issue 5 "Must show" 5; SPEC §2).

The unit tests check the method's parts on problems whose answer is known: the footnote's linear
system recovers the gradient of a quadratic exactly, the conservative step never moves to a point
its own estimate says is worse, and the budget never spends more than m transitions.

The issue also asks that it lowers its cost on hover over 20 iterations of 500 samples. It does
not (strict xfail; measured diagnosis in :mod:`loopid.algorithms.policy_gradient`, "Limits", and
``examples/pg_gradient_quality.py``): the estimated direction does carry descent information
(best ``J_400`` ratio 0.76 along it, 0.97 against it), but the steps that help are ~25x shorter
than the first trust radius, and the one-draw 125-step acceptance test lets longer ones through
(median over seeds ~3-10x π_1's cost after 20 iterations; no longer the 1e8 cap).
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from loopid.algorithms.policy_gradient import PGState, budget, fd_gradient, make_pg_step
from loopid.experiments.results import trace_table
from loopid.experiments.runner import _agent, run, setup
from loopid.experiments.scenarios import scenario

SCENARIO = scenario("hover", iterations=20, samples=500, seeds=2, test_trajectories=50)


def test_fd_gradient_is_exact_on_a_quadratic():
    """Antithetic differences of a quadratic are exactly ⟨∇c, δ⟩: with P ≥ d probes the linear
    system returns the autodiff gradient, with P < d its projection on the probed directions."""
    rng = np.random.default_rng(0)
    d = 6
    A = rng.normal(size=(d, d))
    H = A @ A.T + np.eye(d)
    b = rng.normal(size=d)

    def c(x):
        return 0.5 * x @ H @ x + b @ x + 3.0

    theta = jnp.asarray(rng.normal(size=d))
    exact = jax.grad(c)(theta)
    for P in (d, 2 * d):
        delta = jnp.asarray(rng.normal(size=(P, d)))
        half = jax.vmap(lambda dl: (c(theta + dl) - c(theta - dl)) / 2.0)(delta)
        np.testing.assert_allclose(fd_gradient(delta, half), exact, rtol=1e-9, atol=1e-9)
    delta = jnp.asarray(rng.normal(size=(2, d)))
    half = jax.vmap(lambda dl: (c(theta + dl) - c(theta - dl)) / 2.0)(delta)
    D = np.asarray(delta)
    projection = D.T @ np.linalg.solve(D @ D.T, D @ np.asarray(exact))
    np.testing.assert_allclose(fd_gradient(delta, half), projection, rtol=1e-9, atol=1e-9)


def test_budget_never_exceeds_m():
    for m in (4, 7, 100, 101, 500, 999):
        for horizon in (1, 25, 125, 400, 600):
            H, P, C = budget(m, horizon, 400)
            assert 1 <= H <= min(horizon, 400) and P >= 1 and C >= 1
            assert (2 * P + 2 * C) * H <= m
    assert budget(500, 400, 400) == (125, 1, 1)
    assert budget(100, 400, 400) == (25, 1, 1)
    with pytest.raises(ValueError, match="samples >= 4"):
        budget(3, 400, 400)


@pytest.mark.slow
def test_conservative_step_never_accepts_a_worse_estimate():
    """Over many iterations and seeds, a step is taken only when the candidate's mean log cost
    on the reference noise is below the reference's; otherwise θ stays put and ρ halves."""
    s = SCENARIO
    st = setup(s)
    agent = _agent(s, st)
    K1, _ = agent.policy(agent.init())
    one = make_pg_step(
        st.plant, K1, samples=s.samples, horizon=s.pg_horizon, sigma=s.pg_sigma,
        nu_state_var=s.nu_state_var, cost_cap=s.cost_cap,
    )  # fmt: skip
    step = jax.jit(jax.vmap(one))
    S = 8
    state = PGState(jnp.zeros((S, 4, 21)), jnp.full(S, s.pg_sigma * 2.0))
    keys = jax.random.split(jax.random.key(0), S)
    accepted_any = False
    for it in range(6):
        new, info = step(state, jax.vmap(lambda k, i=it: jax.random.fold_in(k, i))(keys))
        acc = np.asarray(info.accepted)
        assert np.all(np.asarray(info.log_cand)[acc] < np.asarray(info.log_ref)[acc])
        moved = np.any(np.asarray(new.theta != state.theta), axis=(1, 2))
        np.testing.assert_array_equal(moved, acc)
        np.testing.assert_allclose(
            np.asarray(new.radius), np.where(acc, 2.0, 0.5) * np.asarray(state.radius)
        )
        accepted_any |= bool(acc.any())
        state = new
    assert accepted_any  # the test exercised both branches
    assert np.all(np.isfinite(np.asarray(state.theta)))


@pytest.fixture(scope="module")
def trace():
    return run("pg", SCENARIO)


@pytest.mark.slow
def test_pg_trace_is_well_formed(trace):
    rows = trace.rows
    assert rows.test_cost.shape == (SCENARIO.seeds, SCENARIO.iterations)
    trace_table(SCENARIO.name, "pg", trace)  # no NaN
    assert np.all(rows.test_cost <= SCENARIO.cost_cap)
    assert np.all((rows.diverged >= 0) & (rows.diverged <= SCENARIO.test_trajectories))
    # each iteration spends at most the m transitions of the other methods, all on the policy
    H, P, C = budget(SCENARIO.samples, SCENARIO.pg_horizon, 400)
    assert np.all(rows.valid_samples[:, 1:] == (2 * P + 2 * C) * H)
    assert np.all(rows.policy_samples[:, 1:] == (2 * P + 2 * C) * H)
    assert (2 * P + 2 * C) * H <= SCENARIO.samples
    # it starts from the model-based methods' π_1, which barely acts (SPEC §4.4: ~2.6e6)
    assert np.all((rows.test_cost[:, 0] > 1e6) & (rows.test_cost[:, 0] < 1e7))


@pytest.mark.slow
@pytest.mark.xfail(
    strict=True,
    reason="PG does not lower its hover cost in 20 iterations of 500 samples (module docstring)",
)
def test_pg_lowers_its_cost(trace):
    c = trace.rows.test_cost
    assert np.median(c[:, -1]) < np.median(c[:, 0]), np.median(c, axis=0)

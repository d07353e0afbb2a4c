"""Drawing the training data (SPEC §1, §4.4; issue 5 "Must show" 2b–2d).

- ``geometric_steps`` draws the geometric law truncated to the horizon, ``P(L = k) ∝ γ^k``;
- ``plant.rollout`` cuts a training trajectory that leaves the safe region and restarts from the
  start state; cut rows are masked and zero-filled;
- ``policy_samples`` always returns exactly ``count`` rows, in both modes, whatever the mask.
"""

from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

from loopid.algorithms.collect import geometric_steps, policy_samples
from loopid.algorithms.plant import make_plant
from loopid.systems.helicopter.expert import expert_gains
from loopid.systems.helicopter.plant import helicopter_plant
from loopid.systems.helicopter.tasks import make_task
from loopid.systems.linear import linear_dynamics, linear_task


def truncated_geometric_pmf(gamma: float, horizon: int) -> np.ndarray:
    p = gamma ** np.arange(horizon)
    return p / p.sum()


def chi_square_pvalue(samples: np.ndarray, pmf: np.ndarray) -> float:
    """Pearson's test of integer samples against ``pmf`` on {0..len(pmf)−1}; bins with fewer
    than 5 expected counts are pooled into their neighbour."""
    counts = np.bincount(samples, minlength=pmf.size).astype(float)
    assert counts.size == pmf.size, "a sample lies outside the support"
    expected = samples.size * pmf
    obs, exp, o, e = [], [], 0.0, 0.0
    for c, x in zip(counts, expected, strict=True):
        o, e = o + c, e + x
        if e >= 5:
            obs.append(o)
            exp.append(e)
            o, e = 0.0, 0.0
    obs[-1] += o
    exp[-1] += e
    return float(stats.chisquare(obs, exp).pvalue)


@pytest.mark.parametrize(
    ("gamma", "horizon"),
    [(0.9, 400), (0.9, 10), (0.99, 100), (0.999, 5), (0.5, 3)],
)
def test_geometric_steps_law(gamma, horizon):
    n = 100_000
    L = np.asarray(geometric_steps(jax.random.key(7), n, gamma, horizon))
    assert L.shape == (n,) and L.dtype == np.int32
    assert L.min() >= 0 and L.max() <= horizon - 1
    pmf = truncated_geometric_pmf(gamma, horizon)
    assert chi_square_pvalue(L, pmf) > 1e-4
    k = np.arange(horizon)
    mean, sd = pmf @ k, np.sqrt(pmf @ k**2 - (pmf @ k) ** 2)
    assert abs(L.mean() - mean) < 5 * sd / np.sqrt(n)


def test_geometric_steps_rejects_bad_gamma():
    for gamma in (0.0, 1.0, 1.5, -0.1):
        with pytest.raises(ValueError, match="gamma"):
            geometric_steps(jax.random.key(0), 3, gamma, 10)


# ------------------------------------------------------------------ a small stable linear plant
LIN_H = 30


@pytest.fixture(scope="module")
def lin_plant():
    A = np.array([[0.9, 0.1], [0.0, 0.8]])
    B = np.array([[0.0], [1.0]])
    task = linear_task(np.eye(2), np.eye(1), np.ones(2), LIN_H, noise_std=0.1)
    return make_plant(task, linear_dynamics(A, B), stop_norm=100.0)


def test_geometric_mode_keeps_the_stopping_step(lin_plant):
    """Geometric sampling on a never-cut rollout: the kept step index has the truncated law."""
    gamma, count = 0.9, 4000
    K = jnp.zeros((LIN_H, 1, 3))
    tr = jax.jit(lambda k: policy_samples(lin_plant, K, k, count, mode="geometric", gamma=gamma))(
        jax.random.key(3)
    )
    assert tr.t.shape == (count,) and bool(tr.mask.all())
    t = np.asarray(tr.t)
    assert chi_square_pvalue(t, truncated_geometric_pmf(gamma, LIN_H)) > 1e-4
    # each draw is its own rollout: its state at step t is a real state of that run
    assert np.all(np.isfinite(np.asarray(tr.dx_next)))


# ------------------------------------------------------------------ the helicopter's stop rule
@pytest.fixture(scope="module")
def heli():
    task = make_task("hover")  # the hover panel's plant (stop_norm 5, cost cap 1e8)
    st = SimpleNamespace(
        plant=helicopter_plant(task, delay_mode="latency"), K_expert=expert_gains(task)
    )
    rollout = jax.jit(st.plant.rollout)
    return st, rollout


def _check_rollout_invariants(plant, tr, stop_norm=5.0):
    H = plant.horizon
    x0 = np.asarray(plant.task.x0)
    mask = np.asarray(tr.mask)
    t = np.asarray(tr.t)
    x, dx, du, dxn = (np.asarray(a) for a in (tr.x, tr.dx, tr.du, tr.dx_next))
    for a in (x, dx, du, dxn):
        assert a.shape[0] == H and np.all(np.isfinite(a))
    # the run starts at μ
    assert t[0] == 0 and np.allclose(x[0], x0)
    for i in range(H - 1):
        if not mask[i] or t[i] == H - 1:
            # a cut (or the end of the task): the next step restarts from the start state
            assert t[i + 1] == 0, i
            assert np.allclose(x[i + 1], x0), i
        else:
            # a valid step continues where it left off
            assert t[i + 1] == t[i] + 1, i
            if mask[i + 1]:
                np.testing.assert_allclose(dx[i + 1], dxn[i], rtol=1e-12, atol=1e-12)
    # every valid step lies in the safe region (constant error coordinate excluded)
    size = np.linalg.norm(np.concatenate([dx[:, :-1], du], axis=1), axis=1)
    assert np.all(size[mask] <= stop_norm)
    # masked rows are zero-filled
    for a in (x, dx, du, dxn):
        assert np.all(a[~mask] == 0.0)
    return mask, t


def test_stop_rule_cuts_unstable_policy(heli):
    st, rollout = heli
    K = -st.K_expert  # positive feedback: leaves the safe region within a few steps
    tr = rollout(K, jax.random.key(0))
    mask, t = _check_rollout_invariants(st.plant, tr)
    cuts = int((~mask).sum())
    assert cuts >= 5, cuts  # several cuts and restarts over the horizon
    assert mask.sum() >= 10  # and valid steps between them
    # the cut happens at the first unsafe step: valid steps stay short (a few steps per run)
    assert t.max() < 50


def test_stable_policy_is_never_cut(heli):
    st, rollout = heli
    tr = rollout(st.K_expert, jax.random.key(1))
    mask, t = _check_rollout_invariants(st.plant, tr)
    assert mask.all()
    np.testing.assert_array_equal(t, np.arange(st.plant.horizon))


def test_masked_rows_zero_filled_when_state_blows_up():
    """A system whose state becomes non-finite: the rows are masked and zero-filled, no NaN."""
    A = np.array([[1e200]])
    B = np.array([[1.0]])
    task = linear_task(np.eye(1), np.eye(1), np.ones(1), 5, noise_std=0.0)
    plant = make_plant(task, linear_dynamics(A, B), stop_norm=1e300)
    tr = jax.jit(plant.rollout)(jnp.zeros((5, 1, 2)), jax.random.key(0))
    mask = np.asarray(tr.mask)
    assert not mask.all()
    for a in (tr.x, tr.dx, tr.du, tr.dx_next):
        a = np.asarray(a)
        assert np.all(np.isfinite(a)) and np.all(a[~mask] == 0.0)


# ------------------------------------------------------------------ fixed shapes
COUNTS = (7, 450)
MODES = ("trajectory", "geometric")


@pytest.fixture(scope="module")
def drawn(heli):
    """policy_samples of three policies for every (mode, count), vmapped over the policies: a
    never-cut policy (the expert), an unstable one (cut every few steps) and a hopeless one (a
    feedforward of 10 leaves the safe region at once)."""
    st, _ = heli
    hopeless = st.K_expert.at[:, :, -1].set(10.0)
    policies = jnp.stack([st.K_expert, -st.K_expert, hopeless])
    out = {}
    for mode in MODES:
        for count in COUNTS:
            draw = jax.jit(
                jax.vmap(lambda K, k, c=count, m=mode: policy_samples(st.plant, K, k, c, mode=m))
            )
            batch = draw(policies, jax.random.split(jax.random.key(count), 3))
            out[mode, count] = [
                jax.tree_util.tree_map(lambda a, i=i: a[i], batch) for i in range(3)
            ]
    return out


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("count", COUNTS)
def test_policy_samples_fixed_shapes(heli, drawn, mode, count):
    """Exactly ``count`` rows whatever the mask, masked rows zero-filled."""
    good, unstable, none = drawn[(mode, count)]
    n = heli[0].plant.n_state
    for tr in (good, unstable, none):
        assert tr.x.shape == (count, 21) and tr.dx.shape == (count, n)
        assert tr.du.shape == (count, 4) and tr.dx_next.shape == (count, n)
        assert tr.t.shape == (count,) and tr.mask.shape == (count,)
        for a in (tr.x, tr.dx, tr.du, tr.dx_next):
            a = np.asarray(a)
            assert np.all(np.isfinite(a)) and np.all(a[~np.asarray(tr.mask)] == 0.0)
    assert bool(good.mask.all())  # the expert is never cut: every draw is usable
    assert not bool(none.mask.any())  # nothing usable, still count rows
    valid = int(unstable.mask.sum())
    if mode == "trajectory":
        # drawn among the valid steps (most of them are), without replacement
        assert valid == count
        key = np.concatenate([np.asarray(unstable.dx_next), np.asarray(unstable.t)[:, None]], 1)
        assert len(np.unique(key, axis=0)) == count
    elif count >= 100:
        # a geometric draw keeps its step even when that step was cut
        assert 0 < valid < count


def test_trajectory_mode_draws_uniformly_over_the_horizon(heli, drawn):
    """SPEC §1: the policy half is drawn uniformly from the whole rollouts, not their first steps
    (which would give a mean step of about 50 here)."""
    H = heli[0].plant.horizon
    t = np.asarray(drawn[("trajectory", 450)][0].t)  # 450 of the expert's 800 steps (2 runs)
    assert len(np.unique(t)) > 300  # both runs, spread over the horizon
    sd = np.sqrt((H**2 - 1) / 12 / t.size)  # (finite-population correction ignored: wider)
    assert abs(t.mean() - (H - 1) / 2) < 4 * sd, t.mean()
    assert t.max() > 0.9 * H and t.min() < 0.1 * H

"""The ν samplers as a loop program holds them (loopid.algorithms.exploration,
loop_program._sampler_branches): ν_e and ν_en are one drawing function at two action-noise
levels, so the switch that picks a method's ν has two branches for three samplers, and each
sampler drawn through its branch gives the very draws it gives alone, bit for bit."""

import jax
import numpy as np
import pytest

from loopid.algorithms.contracts import SharedSampler
from loopid.algorithms.exploration import NU_KINDS, make_nu, make_nus
from loopid.algorithms.loop_program import _sampler_branches
from loopid.systems.helicopter.expert import expert_gains
from loopid.systems.helicopter.plant import helicopter_plant
from loopid.systems.helicopter.tasks import make_task

SAMPLES = 30


@pytest.fixture(scope="module")
def hover():
    task = make_task("hover")
    return helicopter_plant(task), expert_gains(task)


def test_nu_e_and_nu_en_share_one_draw_at_their_own_noise(hover):
    plant, K = hover
    nus = make_nus(plant, K, expert_action_var=0.0004)
    t, e, en = nus
    assert not isinstance(t, SharedSampler)
    assert isinstance(e, SharedSampler) and e.draw is en.draw
    assert (e.param, en.param) == (0.0, 0.02)
    branches, branch, param = _sampler_branches(nus, SAMPLES)
    assert len(branches) == 2 and np.asarray(branch).tolist() == [0, 1, 1]
    np.testing.assert_array_equal(np.asarray(param), [0.0, 0.0, 0.02])
    for kind in NU_KINDS:  # one kind alone is the same sampler as in the list, at its parameter
        one, listed = make_nu(kind, plant, K, expert_action_var=0.0004), nus[NU_KINDS.index(kind)]
        assert type(one) is type(listed)
        assert getattr(one, "param", None) == getattr(listed, "param", None)


def test_each_sampler_drawn_through_its_branch_gives_its_own_draws(hover):
    plant, K = hover
    nus = make_nus(plant, K)
    branches, branch, param = _sampler_branches(nus, SAMPLES)
    keys = jax.random.split(jax.random.key(5), 3)
    draws = []
    for k, sampler in enumerate(nus):
        alone = jax.jit(jax.vmap(lambda key, f=sampler: f(key, SAMPLES)))(keys)
        branch_fn = branches[int(branch[k])]
        through = jax.jit(lambda keys, q, f=branch_fn: f(keys, q))(keys, param[k])
        for a, b in zip(jax.tree.leaves(alone), jax.tree.leaves(through), strict=True):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b), err_msg=NU_KINDS[k])
        draws.append(alone)
    # the expert's action noise is live in ν_en and absent in ν_e: different pairs, same shapes
    assert not np.array_equal(np.asarray(draws[1].du), np.asarray(draws[2].du))
    assert np.asarray(draws[1].du).shape == np.asarray(draws[2].du).shape == (3, SAMPLES, 4)


def test_a_negative_variance_is_refused_by_name_by_the_sampler_that_uses_it(hover):
    plant, K = hover
    with pytest.raises(ValueError, match="expert_action_var must be >= 0, got -1"):
        make_nus(plant, K, expert_action_var=-1.0)
    with pytest.raises(ValueError, match="state_var=-1"):
        make_nu("t", plant, K, state_var=-1.0)
    make_nu("e", plant, K, state_var=-1.0, expert_action_var=-1.0)  # uses neither

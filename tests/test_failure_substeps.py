"""A step whose Newton solve fails is taken again in substeps (NewtonConfig.failure_substeps)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from dano.errors import DanoError
from dano.sim import NewtonConfig, State, make_data, rollout
from dano.sim.dynamics import step_with_info
from dano.sim.implicit import DEFAULT_FAILURE_SUBSTEPS
from dano.sim.scenes import load_scene

#: one Newton iteration: a step into contact cannot converge in it, one in free flight does
ONE_ITERATION = dict(max_iterations=1, reverse_mode=False)


@pytest.fixture(scope="module")
def drops():
    """The bunny drop at its own dt and at a quarter of it, and two states: falling into the
    ground at 1 m/s, spinning (the solve needs more than one iteration), and in free flight."""
    setup = load_scene("bunny-drop")
    quarter = load_scene("bunny-drop", dt=setup.scene.dt / DEFAULT_FAILURE_SUBSTEPS)
    q = np.asarray(setup.state0.qpos, float)
    settled = rollout(setup.scene, State(jnp.asarray(q), jnp.zeros(6)), params=setup.params, steps=300)
    touching = settled.qpos[-1].copy()
    flying = touching.copy()
    flying[2] += 0.5
    v = np.array([0.3, 0.0, -1.0, 2.0, -1.0, 0.5])
    return setup, quarter, [(touching, v), (flying, v)]


def _step(scene, params, state, **newton):
    data = make_data(scene, jnp.asarray(state[0]), jnp.asarray(state[1]))
    d, info = jax.jit(step_with_info, static_argnums=3)(scene, params, data, NewtonConfig(**newton))
    return d, info


def test_a_failed_step_is_taken_again_as_substeps_of_a_quarter(drops):
    """Where the solve fails (here: it may take one iteration only), the step is the same as
    four steps of dt / 4 from the same start, each with its one iteration; where it does not
    fail, the one step; under vmap each member as on its own."""
    setup, quarter, (touching, flying) = drops
    d, info = _step(setup.scene, setup.params, touching, **ONE_ITERATION)
    assert int(info.substeps) == DEFAULT_FAILURE_SUBSTEPS
    data = make_data(quarter.scene, jnp.asarray(touching[0]), jnp.asarray(touching[1]))
    one = jax.jit(step_with_info, static_argnums=3)
    for _ in range(DEFAULT_FAILURE_SUBSTEPS):
        data, _ = one(quarter.scene, quarter.params, data, NewtonConfig(max_iterations=1, reverse_mode=False,
                                                                        failure_substeps=1))
    np.testing.assert_allclose(d.qpos, data.qpos, rtol=0, atol=1e-12)
    np.testing.assert_allclose(d.qvel, data.qvel, rtol=0, atol=1e-10)
    np.testing.assert_allclose(float(d.time), setup.scene.dt, rtol=1e-12)
    assert float(info.newton_iterations) == 1 + DEFAULT_FAILURE_SUBSTEPS  # every trip's iterations
    off, info_off = _step(setup.scene, setup.params, touching, failure_substeps=1, **ONE_ITERATION)
    assert int(info_off.substeps) == 1 and not np.allclose(off.qvel, d.qvel, atol=1e-6)

    d_fly, info_fly = _step(setup.scene, setup.params, flying, **ONE_ITERATION)
    assert int(info_fly.substeps) == 1
    plain, _ = _step(setup.scene, setup.params, flying, failure_substeps=1, **ONE_ITERATION)
    np.testing.assert_array_equal(d_fly.qvel, plain.qvel)

    both = [jnp.asarray(np.stack(x)) for x in zip(touching, flying)]
    batched = jax.jit(jax.vmap(lambda q, v: step_with_info(setup.scene, setup.params, make_data(setup.scene, q, v),
                                                           NewtonConfig(**ONE_ITERATION))))
    db, ib = batched(*both)
    np.testing.assert_array_equal(np.asarray(ib.substeps), [DEFAULT_FAILURE_SUBSTEPS, 1])
    np.testing.assert_allclose(db.qvel[0], d.qvel, rtol=0, atol=1e-10)
    np.testing.assert_allclose(db.qvel[1], d_fly.qvel, rtol=0, atol=1e-10)


def test_failure_substeps_defaults_and_refusals():
    """None: on (4) for forward-only steps, off for reverse-mode ones; an explicit count with
    reverse mode, or below 1, is refused by name."""
    from dano.sim.dynamics import failure_substeps
    assert failure_substeps(NewtonConfig()) == 1
    assert failure_substeps(NewtonConfig(reverse_mode=False)) == DEFAULT_FAILURE_SUBSTEPS
    assert failure_substeps(NewtonConfig(reverse_mode=False, failure_substeps=1)) == 1
    with pytest.raises(DanoError, match="failure_substeps=4 needs reverse_mode=False"):
        NewtonConfig(failure_substeps=4)
    with pytest.raises(DanoError, match="failure_substeps must be an integer >= 1"):
        NewtonConfig(failure_substeps=0, reverse_mode=False)

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


def test_a_run_whose_steps_fail_without_diverging_is_simulated_again_in_substeps():
    """Analytic physics: an unactuated drop cannot gain energy. Drop 762 of the energy check's
    seed 1 (random pose, spin and paper-range parameters) has steps whose solve fails without
    the run diverging; kept as they are (single steps), its energy rises (measured: to 26x
    its start). rollout counts the failed steps, simulates the run again with each failed step
    taken in substeps, warns, and the energy no longer rises."""
    import jax.tree_util as jtu

    from dano.errors import DanoWarning
    from dano.experiments.energy import random_drops
    from dano.sim.energy import mechanical_energy
    setup = load_scene("bunny-drop")
    sc = setup.scene
    qpos0, qvel0, cparams = random_drops(sc, 1000, seed=1)
    params = setup.params.replace(contact=jtu.tree_map(lambda x: x[762], cparams))
    state = State(np.asarray(qpos0[762]), np.asarray(qvel0[762]))
    single = rollout(sc, state, params=params, steps=300, newton=NewtonConfig(failure_substeps=1))
    assert single.metadata["failure_substeps"] == 1 and single.metadata["failed_steps"] > 0
    energy = mechanical_energy(sc, single.qpos, single.qvel)
    assert energy.max() > 1.5 * energy[0]
    with pytest.warns(DanoWarning, match="steps whose Newton solve failed"):
        again = rollout(sc, state, params=params, steps=300)
    assert again.metadata["failure_substeps"] == DEFAULT_FAILURE_SUBSTEPS
    assert again.metadata["failed_steps"] >= 1  # (the steps it took in substeps)
    energy = mechanical_energy(sc, again.qpos, again.qvel)
    assert energy.max() <= 1.01 * energy[0]
    # the same run up to its first failed step (step 66, measured; the loop's traced step length rounds differently)
    np.testing.assert_allclose(again.qpos[:66], single.qpos[:66], rtol=0, atol=1e-9)
    assert not np.allclose(again.qpos[68], single.qpos[68], rtol=0, atol=1e-3)


def test_an_identification_whose_steps_fail_near_its_answer_is_done_again_in_substeps():
    """The energy check's drop 762 (seed 1) observed at 100 Hz as the substeps simulate it
    (the energy kept), its sliding friction identified with single steps (the default) from
    the truth without a scan: there two steps fail without diverging (the energy rises 26x),
    and a local solve from there would move to 0.513 where none fails. identify sees the
    failed steps at its initial guess, identifies with the substeps, says so, and lands on
    the truth. With its scan and the default verification, the fit starts at 0.643 and ends
    near 0.53, where no step fails, but the profiles' points inside the interval fail steps
    whose substeps move the cost far beyond the interval's threshold: identified again with
    the substeps, the truth too. (Without that verification the fit ends at 0.547: a limit
    of the switch, docs/simulation.md.)"""
    import jax.tree_util as jtu

    from dano.experiments.energy import random_drops
    from dano.sysid import FitParameter, Observation, SysIdProblem, identify
    setup = load_scene("bunny-drop")
    sc = setup.scene
    qpos0, qvel0, cparams = random_drops(sc, 1000, seed=1)
    params = setup.params.replace(contact=jtu.tree_map(lambda x: x[762], cparams))
    truth = float(np.asarray(params.contact.sliding_friction).ravel()[0])
    state = State(np.asarray(qpos0[762]), np.asarray(qvel0[762]))
    observed = rollout(sc, state, params=params, steps=120, newton=NewtonConfig(reverse_mode=False))
    assert observed.metadata["failed_steps"] >= 1  # (taken in substeps)
    obs = Observation(time=observed.time, poses={sc.dano_names[0]: observed.qpos}, qvel0=observed.qvel[0])
    problem = SysIdProblem(sc, [obs], [FitParameter("sliding_friction", truth, 0.0, 1.0)], base_params=params)
    assert problem.failure_substeps == 1 and problem.failed_steps(np.r_[truth]).sum() >= 1
    for options, where in ((dict(scan=0, profile_points=0), "trajectories at the initial guess with single steps"),
                           ({}, "points of the verification's profiles inside the interval")):
        result = identify(problem, **options)
        assert result.failure_substeps == 4
        assert any(where in n and "taken again in 4 substeps" in n for n in result.notes), result.notes
        assert abs(result.estimates[0] - truth) < 1e-6 and result.rms_residual < 1e-8

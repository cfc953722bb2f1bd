"""Differentiability: forward-mode AD through rollouts agrees with central finite
differences (float64) on a contact window without onsets; no NaN anywhere."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from dano.asset import build
from dano.fields import BoxField
from dano.sim import DanoObject, SimParams, State, compose, rollout_arrays


@pytest.fixture(scope="module")
def sliding_box():
    asset = build(BoxField((0.1, 0.08, 0.05), edge_width=0.002), mass=1.0, num_samples=2000, mesh_resolution=0,
                  name="box")
    z = -asset.points[:, 2].min() - 0.002  # already in contact: no onset in the window
    scene = compose([DanoObject("box", asset, (0, 0, z))], dt=0.005)
    q0 = jnp.asarray([0, 0, z, 1, 0, 0, 0.0])
    v0 = jnp.asarray([1.5, 0.3, 0, 0, 0, 0.4])
    return scene, q0, v0


def alpha_of(scene):
    return float(scene.assets[0].alpha)


STEPS = 40  # every rollout of the sliding box: its compiled scan is shared by the tests


def outputs(scene, q0, v0, theta, steps=STEPS):
    mu, alpha, vx = theta
    base = scene.default_params()
    params = SimParams(dataclasses.replace(base.contact, sliding_friction=jnp.full((1,), mu)), alpha[None])
    # a known external push (4 N along x) makes the motion depend on the mass scale α
    push = jnp.zeros((steps, 6)).at[:, 0].set(4.0)
    qpos, qvel, psi = rollout_arrays(scene, State(q0, v0.at[0].set(vx)), None, params, steps, push)
    return jnp.concatenate([qpos[-1, :3], qvel[-1, :3], qvel[-1, 3:], psi[-1]])


def test_ad_matches_finite_differences(sliding_box):
    scene, q0, v0 = sliding_box
    theta = jnp.asarray([0.4, alpha_of(scene), 1.5])  # the box's own mass scale (1 kg)
    f = lambda th: outputs(scene, q0, v0, th)  # noqa: E731
    y = f(theta)
    assert np.all(np.isfinite(np.asarray(y)))
    J_ad = np.asarray(jax.jacfwd(f)(theta))
    J_fd = np.zeros_like(J_ad)
    for k in range(3):
        e = 1e-6 * max(1.0, abs(float(theta[k])))
        J_fd[:, k] = (np.asarray(f(theta.at[k].add(e))) - np.asarray(f(theta.at[k].add(-e)))) / (2 * e)
    scale = np.maximum(np.abs(J_ad), 1e-3 * np.abs(J_ad).max(axis=0, keepdims=True))
    rel = np.abs(J_ad - J_fd) / scale
    assert rel.max() < 1e-4, (rel.max(), np.unravel_index(rel.argmax(), rel.shape))
    # friction slows the box down; a heavier box is pushed less far; a faster start ends further
    assert J_ad[0, 0] < 0 and J_ad[0, 1] < 0 and J_ad[0, 2] > 0


def test_no_nan_at_rest_at_onset_and_without_contact(sliding_box):
    scene, q0, v0 = sliding_box
    params = scene.default_params()
    cases = {
        "at rest": (q0, jnp.zeros(6)),
        "onset": (q0.at[2].add(0.004), jnp.asarray([0.5, 0, -0.3, 0, 0, 0.0])),
        "free flight": (q0.at[2].add(1.0), jnp.zeros(6)),
    }

    for name, (q, v) in cases.items():
        def f(theta):
            p = SimParams(dataclasses.replace(params.contact, sliding_friction=theta[:1], impact_spring=theta[1:2]),
                          theta[2:3])
            qpos, qvel, psi = rollout_arrays(scene, State(q, v * theta[3]), None, p, STEPS)
            return jnp.concatenate([qpos.ravel(), qvel.ravel(), psi.ravel()])

        theta = jnp.asarray([0.3, 3e4, alpha_of(scene), 1.0])
        val, jac = f(theta), jax.jacfwd(f)(theta)
        assert np.all(np.isfinite(np.asarray(val))), name
        assert np.all(np.isfinite(np.asarray(jac))), name


def test_gradient_with_respect_to_controls_matches_finite_differences():
    """d(pusher position)/d(PD target) through the actuators of the sphere-pusher scene."""
    from dano.experiments.sysid_examples import pusher_scene

    scene, z = pusher_scene()
    q0 = np.array(scene.qpos0)
    q0[:3] = [-1.0, 0.0, 0.3]
    q0[3:10] = [0, 0, z, 1, 0, 0, 0]
    params = scene.default_params()

    def final_pusher(offset):
        targets = jnp.tile(jnp.asarray([-0.8, 0.0, 0.3]), (60, 1)).at[:, 0].add(offset[0])
        qpos, _, _ = rollout_arrays(scene, State(jnp.asarray(q0), jnp.zeros(scene.nv)), targets, params, 60)
        return qpos[-1, :3]

    x = jnp.asarray([0.05])
    ad = np.asarray(jax.jacfwd(final_pusher)(x))[:, 0]
    e = 1e-6
    fd = (np.asarray(final_pusher(x + e)) - np.asarray(final_pusher(x - e))) / (2 * e)
    assert ad[0] > 0.5  # the sphere follows its target
    np.testing.assert_allclose(ad, fd, rtol=1e-4, atol=1e-8)


def test_vmapped_rollouts_match_single_ones(sliding_box):
    """Batched simulation (jax.vmap over initial states) gives the same trajectories."""
    scene, q0, v0 = sliding_box
    params = scene.default_params()
    vs = jnp.stack([v0, v0 * 0.5, v0.at[1].set(-0.4)])
    batched = jax.vmap(lambda v: rollout_arrays(scene, State(q0, v), None, params, STEPS)[0])(vs)
    for k in range(3):
        single = rollout_arrays(scene, State(q0, vs[k]), None, params, STEPS)[0]
        np.testing.assert_allclose(np.asarray(batched[k]), np.asarray(single), rtol=1e-10, atol=1e-12)


def test_a_jointless_wall_body_leaves_reverse_mode_working(sliding_box):
    """A scene's wall or table as a body without joints is welded to the world: MuJoCo never
    collides it with the floor, so MuJoCo's constraint solver has no rows. A new user's scene
    with such a wall ran MJX's solver all the same (a ``while_loop``), and ``jax.grad``
    through the step failed with JAX's while-loop error. The step now leaves the solver out:
    the same motion, into the wall too, and reverse mode agrees with forward mode."""
    import mujoco

    _, q0, v0 = sliding_box
    spec = mujoco.MjSpec()
    spec.worldbody.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[2, 2, 0.1])
    wall = spec.worldbody.add_body(name="wall", pos=[0.2, 0, 0.05])
    wall.add_geom(name="wall", type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.02, 0.3, 0.05])
    box = sliding_box[0].assets[0]
    scene = compose([DanoObject("box", box, q0[:3])], base=spec, dt=0.005)
    assert not scene.has_constraints and [p.kind for p in scene.pairs] == ["plane", "box"]
    solver = dataclasses.replace(scene, has_constraints=True)  # what the step ran before
    params = scene.default_params()
    steps = 60  # 0.3 s at 1.5 m/s: the box reaches the wall
    qpos, _, _ = rollout_arrays(scene, State(q0, v0), None, params, steps)
    qpos_solver, _, _ = rollout_arrays(solver, State(q0, v0), None, params, steps)
    half_length = 0.1  # the box's half extent along x
    assert float(qpos[:, 0].max()) > 0.2 - 0.02 - half_length - 0.002  # it reached the wall's face
    assert float(qpos[-1, 0]) < float(qpos[:, 0].max()) - 0.005  # and the wall pushed it back
    np.testing.assert_allclose(qpos, qpos_solver, atol=1e-9)

    def final_x(mu):
        p = params.replace(contact=params.contact.replace(sliding_friction=jnp.full(2, mu)))
        return rollout_arrays(scene, State(q0, v0), None, p, 20)[0][-1, 0]

    assert float(jax.grad(final_x)(0.3)) == pytest.approx(float(jax.jacfwd(final_x)(0.3)), rel=1e-9)

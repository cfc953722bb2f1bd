"""float32, the float type a library user gets by default: JAX's 64-bit mode off (a fresh
process that never calls ``dano.enable_float64()``), or ``scene.astype(jnp.float32)`` with
it on (batched and GPU work, docs/simulation.md). The built-in bunny drop and a slide, with
both contact models, stay float32 and finite, come to rest where float64 does, never gain
energy, and slide the Coulomb distance v²/(2μg).

conftest.py turns 64-bit mode on for the whole test process; "x64-off" turns it off here
with ``jax.enable_x64(False)`` around everything from composing the scene to the rollout
(the switch is part of JAX's trace and compilation cache keys, so nothing compiled in
float64 is reused). The float64 reference is the golden drop (tests/make_golden_contact.py),
which tests/test_sim_physics.py checks against the float64 simulation itself.
"""

import contextlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from dano.sim import State, rollout
from dano.sim.scenes import load_scene, resting_height

from .make_golden_contact import GOLDEN, STEPS
from .test_sim_physics import G, energy

V0, MU = 2.5, 0.2  # the slide: 2.5 m/s along x, the paper's default friction, no drag (Coulomb)


@pytest.fixture(scope="module", params=[("x64-off", "centroid"), ("x64-off", "per_sample"),
                                        ("astype", "centroid"), ("astype", "per_sample")],
                ids=lambda p: "-".join(p))
def runs(request):
    """(how, contact model, float32 scene, drop trajectory, slide trajectory). The slide runs
    on the drop's scene (upright at its resting height, thrown along x) and as many steps,
    so that both share one compilation."""
    how, model = request.param
    with jax.enable_x64(False) if how == "x64-off" else contextlib.nullcontext():
        setup = load_scene("bunny-drop", contact_model=model)
        scene = setup.scene if how == "x64-off" else setup.scene.astype(jnp.float32)
        drop_params = scene.default_params(sliding_friction=0.1)  # setup.params, in the scene's dtype
        np.testing.assert_allclose(drop_params.contact.sliding_friction, setup.params.contact.sliding_friction)
        drop = rollout(scene, setup.state0, None, drop_params, STEPS)
        z = resting_height(scene.assets[0])
        start = State(jnp.asarray([0, 0, z, 1, 0, 0, 0.0]), jnp.asarray([V0, 0, 0, 0, 0, 0.0]))
        slide = rollout(scene, start, None, scene.default_params(sliding_friction=MU, sliding_drag=0.0), STEPS)
    return how, model, scene, drop, slide


def test_state_stays_float32_and_finite(runs):
    _, _, scene, drop, slide = runs
    assert scene.dtype == jnp.float32
    for traj in (drop, slide):
        for a in (traj.qpos, traj.qvel, traj.psi):
            assert a.dtype == np.float32 and np.all(np.isfinite(a))
        floats = [x.dtype for x in jax.tree_util.tree_leaves(traj.final_data)
                  if hasattr(x, "dtype") and jnp.issubdtype(x.dtype, jnp.floating)]
        assert floats and set(floats) == {jnp.dtype(jnp.float32)}, set(floats)  # nothing promoted to float64


def test_drop_comes_to_rest_where_float64_does(runs):
    """At rest after 5 s: the height within 10 µm of float64 (this machine: 6e-8 m apart, the
    resting pose within 4e-5 m), at rest, ψ = m·g/k, and no energy gained at any step beyond
    float32 round-off (1e-6 of the start's energy; float64: 1e-9, tests/test_sim_physics.py)."""
    _, model, scene, drop, _ = runs
    reference = np.load(GOLDEN)[f"{model}_qpos"][-1]  # float64, step STEPS
    assert abs(drop.qpos[-1, 2] - reference[2]) < 1e-5, (drop.qpos[-1, :3], reference[:3])
    assert np.abs(drop.qpos[-1, :2] - reference[:2]).max() < 1e-3  # after a 3 m tumble
    assert np.linalg.norm(drop.qvel[-1, :3]) < 1e-3 and np.linalg.norm(drop.qvel[-1, 3:]) < 1e-3
    assert drop.psi[-1, 0] == pytest.approx(scene.assets[0].mass * G / 3e4, rel=1e-3)
    E = energy(scene, drop)
    assert np.max(E - E[0]) <= 1e-6 * E[0]
    assert E[-1] < 0.7 * E[0]


def test_slide_stops_at_the_coulomb_distance(runs):
    _, _, _, _, slide = runs
    expected = V0**2 / (2 * MU * G)  # 1.59 m, after 1.27 s of the 5 s
    assert abs(slide.qpos[-1, 0] / expected - 1) < 0.03, (slide.qpos[-1, 0], expected)
    assert np.linalg.norm(slide.qvel[-1, :3]) < 1e-2
    assert abs(slide.qpos[-1, 1]) < 1e-3 * expected  # straight along x

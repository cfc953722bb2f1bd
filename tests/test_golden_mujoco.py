"""Golden check (issue 7): with no DANO contacts, dano's step is MuJoCo's own step.

The Menagerie Panda (real model files, ../shared/data/menagerie) with two free bodies
thrown past it, 100 steps of dano's ``step`` against MuJoCo C ``mj_step`` with the matching
integrator (explicit Euler; dano solves the implicit contact equation instead of
EULERDAMP, so the arm's joint damping is what Euler with EULERDAMP treats implicitly:
both use (M + h·D)). Actuation is disabled: with the Panda's stiff position actuators
explicit Euler at h = 2 ms amplifies round-off about 1.2x per step (MJX's own step
differs from C by 3e-7 after 100 steps there); the actuated case is checked at h = 0.5 ms.
"""

import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from dano.sim import compose, make_data, scan_steps

STEPS = 100


def panda_with_two_free_bodies(shared, dt, actuated):
    spec = mujoco.MjSpec.from_file(str(shared / "menagerie" / "franka_emika_panda" / "panda_nohand.xml"))
    spec.option.timestep = dt
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_EULER
    spec.option.tolerance = 1e-14
    # no contacts at all (none happen on this path; the joint limits stay)
    spec.option.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
    if not actuated:
        spec.option.disableflags |= mujoco.mjtDisableBit.mjDSBL_ACTUATION
    for k, (pos, typ, size) in enumerate([((0.6, 0.2, 0.5), mujoco.mjtGeom.mjGEOM_BOX, [0.04, 0.03, 0.02]),
                                          ((0.5, -0.3, 0.6), mujoco.mjtGeom.mjGEOM_SPHERE, [0.05, 0, 0])]):
        body = spec.worldbody.add_body(name=f"free{k}", pos=list(pos))
        body.add_freejoint()
        body.add_geom(type=typ, size=size, mass=0.3)
    return spec


@pytest.mark.slow
@pytest.mark.parametrize("dt, actuated", [(0.002, False), (0.0005, True)])
def test_step_equals_mujoco_c_on_the_panda(shared, dt, actuated):
    spec = panda_with_two_free_bodies(shared, dt, actuated)
    m = spec.copy().compile()
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, 0)
    ctrl = d.ctrl + 0.05  # targets off the start: the arm moves
    qvel = np.zeros(m.nv)
    for name, twist in (("free0", [0.3, -0.2, 1.5, 1.0, -2.0, 0.5]), ("free1", [-0.4, 0.1, 1.0, 3.0, 0.2, -1.0])):
        adr = m.jnt_dofadr[m.body_jntadr[m.body(name).id]]
        qvel[adr:adr + 6] = twist
    qpos0 = d.qpos.copy()
    d.qvel[:], d.ctrl[:] = qvel, ctrl
    reference = []
    for _ in range(STEPS):
        mujoco.mj_step(m, d)
        reference.append(np.r_[d.qpos, d.qvel])
    reference = np.array(reference)

    scene = compose([], spec, dt=dt)
    data = make_data(scene, qpos0, qvel, ctrl=ctrl)
    _, qpos, qvel_t, _, _ = scan_steps(scene, scene.default_params(), data, jnp.tile(jnp.asarray(ctrl), (STEPS, 1)),
                                       jnp.zeros((STEPS, scene.nv)))
    ours = np.concatenate([np.asarray(qpos[1:]), np.asarray(qvel_t[1:])], axis=1)
    assert np.abs(reference[-1, :7] - qpos0[:7]).max() > 1e-3  # the arm did move
    assert np.abs(ours - reference).max() < 1e-10

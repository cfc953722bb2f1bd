"""Contact physics of the simulation core v2 (issue 7, "Must show"): energy, rest on the
true surface, per-sample torsion, a non-convex object against MuJoCo C."""

import dataclasses
import functools

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from dano.asset import build
from dano.bench import bench_energy
from dano.fields import BoxField, mesh_field
from dano.sim import DanoObject, State, compose, rollout

G = 9.81
MODELS = ("centroid", "per_sample")


def test_random_drops_never_gain_energy():
    # 30 of the benchmark's random bunny drops across the paper's Table I ranges
    r = bench_energy(drops=30, batch=30, seed=0)
    assert (r["nonfinite"], r["diverged"], r["energy_rises"]) == (0, 0, 0), r
    assert r["max_energy_ratio"] <= 1.01


@pytest.fixture(scope="module")
def cube():
    h = 0.1048 / 2
    return build(BoxField((h, h, h)), mass=0.37, num_samples=5000, mesh_resolution=0, name="cube")


@pytest.mark.parametrize("model", MODELS)
def test_flat_face_rests_on_its_true_surface(cube, model):
    h = 0.1048 / 2
    scene = compose([DanoObject("cube", cube, (0, 0, h + 0.002))], dt=0.01, contact_model=model)
    traj = rollout(scene, State(jnp.asarray([0, 0, h + 0.002, 1, 0, 0, 0.0]), jnp.zeros(6)), None,
                   scene.default_params(), 300)
    last = slice(-50, None)
    assert traj.qpos[-1, 2] == pytest.approx(h, abs=2e-4)
    k = float(scene.default_params().contact.impact_spring[0])
    assert traj.psi[-1, 0] * k == pytest.approx(cube.mass * G, rel=1e-3)  # the normal force at rest is m·g
    assert np.ptp(traj.qpos[last, 2]) < 1e-5  # no rocking
    assert np.abs(traj.qvel[last]).max() < 1e-4


def test_per_sample_torsion_emerges_from_sliding_friction():
    # a flat 20 x 20 x 5 cm box spinning about z on the ground, torsional friction 0: the
    # uniform square patch (side s) under Coulomb friction mu decelerates it at
    # mu·m·g·c·s / I_z with c = (sqrt(2) + ln(1 + sqrt(2)))/6 = 0.3826 (the mean distance
    # from a square's centre in side lengths) and I_z = m·s²/6: 6·c·mu·g/s
    s, mu, w0 = 0.2, 0.3, 10.0
    box = build(BoxField((s / 2, s / 2, 0.025)), mass=1.0, num_samples=4000, mesh_resolution=0, name="plate")
    expected = (np.sqrt(2) + np.log(1 + np.sqrt(2))) * mu * G / s  # 6·c·mu·g/s
    rates = {}
    for model in MODELS:
        scene = compose([DanoObject("plate", box, (0, 0, 0.025))], dt=0.002, contact_model=model)
        params = scene.default_params(sliding_friction=mu, sliding_drag=0.0, torsional_friction=0.0,
                                      torsional_drag=0.0, rolling_friction=0.0, rolling_drag=0.0)
        # settle on the ground first, then spin
        settle = rollout(scene, State(jnp.asarray([0, 0, 0.0255, 1, 0, 0, 0.0]), jnp.zeros(6)), None, params, 200)
        q0 = settle.qpos[-1]
        # as many steps as the settling (one compilation); it stops after about 150
        traj = rollout(scene, State(jnp.asarray(q0), jnp.asarray([0, 0, 0, 0, 0, w0])), None, params, 200)
        w = traj.qvel[:, 5]
        fast = (w < 0.9 * w0) & (w > 0.4 * w0)  # well above the smoothed-friction speed scale
        rates[model] = -np.polyfit(traj.time[fast], w[fast], 1)[0] if fast.sum() > 5 else 0.0
    assert rates["per_sample"] == pytest.approx(expected, rel=0.05), (rates, expected)
    assert rates["centroid"] < 0.05 * expected  # one wrench at the centroid has no lever arm


# a U-shaped block (12 x 6 x 8 cm, legs 2 cm thick, opening down) as an extruded mesh
U_OUTLINE = np.array([(-.06, 0), (-.04, 0), (-.04, .06), (.04, .06), (.04, 0), (.06, 0), (.06, .06), (.06, .08),
                      (-.06, .08), (-.06, .06)])
U_TRIANGLES = np.array([(0, 1, 2), (0, 2, 9), (9, 2, 8), (2, 3, 7), (2, 7, 8), (3, 6, 7), (4, 5, 6), (4, 6, 3)])
U_BOXES = [((0.12, 0.06, 0.02), (0, 0, 0.07)), ((0.02, 0.06, 0.06), (-0.05, 0, 0.03)),
           ((0.02, 0.06, 0.06), (0.05, 0, 0.03))]  # its exact convex decomposition


def u_block_mesh() -> trimesh.Trimesh:
    mesh = trimesh.creation.extrude_triangulation(U_OUTLINE, U_TRIANGLES, 0.06)
    mesh.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
    mesh.apply_translation([0, 0.03, 0])
    trimesh.repair.fix_normals(mesh)
    assert mesh.is_watertight
    return mesh


@pytest.fixture(scope="module")
def u_block():
    mesh = u_block_mesh()
    asset = build(mesh_field(mesh), mass=0.3, num_samples=3000, mesh_resolution=0, name="u")
    com = np.asarray(asset.center_of_mass)
    tilt = Rotation.from_euler("y", 15, degrees=True)
    z = -tilt.apply(mesh.vertices - com)[:, 2].min() + 0.01  # lowest point 1 cm up, tilted 15°
    pos, quat = np.array([0.0, 0.0, z]), tilt.as_quat(scalar_first=True)

    # MuJoCo C with the three boxes, same mass, same start, no slip (friction 1)
    spec = mujoco.MjSpec()
    spec.option.timestep = 0.002
    spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 1])
    body = spec.worldbody.add_body(name="u")
    body.add_freejoint()
    volume = sum(np.prod(e) for e, _ in U_BOXES)
    for extent, centre in U_BOXES:
        body.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=list(np.array(extent) / 2),
                      pos=list(np.array(centre) - com), density=0.3 / volume, friction=[1.0, 0.005, 0.0001])
    m = spec.compile()
    d = mujoco.MjData(m)
    d.qpos[:3], d.qpos[3:7] = pos, quat
    for _ in range(1500):
        mujoco.mj_step(m, d)
    assert np.abs(d.qvel).max() < 1e-6
    return asset, pos, quat, d.xipos[1].copy(), d.xquat[1].copy()


@pytest.mark.parametrize("model", MODELS)
def test_non_convex_block_rests_where_mujoco_c_puts_its_convex_decomposition(u_block, model):
    asset, pos, quat, c_com, c_quat = u_block
    scene = compose([DanoObject("u", asset, tuple(pos), tuple(quat))], dt=0.005, contact_model=model)
    traj = rollout(scene, State(jnp.asarray(np.r_[pos, quat]), jnp.zeros(6)), None,
                   scene.default_params(sliding_friction=1.0), 600)
    q = traj.qpos[-1]
    assert np.abs(traj.qvel[-1]).max() < 1e-4
    angle = (Rotation.from_quat(q[3:7], scalar_first=True).inv() * Rotation.from_quat(c_quat, scalar_first=True))
    assert np.degrees(angle.magnitude()) < 1.0
    assert np.linalg.norm(q[:3] - c_com) < 1e-3


def test_per_sample_block_search_gives_the_all_samples_wrench():
    # the benchmark's bunny (bunny-drop) resting on the ground: the samples the two-level
    # block search keeps give the wrench and its Jacobian of all samples, with the search
    # holding them all and overflowing (too few blocks or samples: the full fallback); the
    # closed-form Jacobian is forward-mode AD's
    from dano._mjx import mjx
    from dano.contact.base import sample_rates
    from dano.contact.per_sample import REACH_MARGIN, PerSample, _AllSamples, depth_rates
    from dano.sim.dynamics import _group_params, contact_geometry, make_data, model_with_params
    from dano.sim.scenes import load_scene

    setup = load_scene("bunny-drop", contact_model="per_sample")
    scene, params = setup.scene, setup.params
    rest = rollout(scene, setup.state0, None, params, 500)  # at rest: the golden drop's 500 steps (its compilation)

    @jax.jit  # one compilation (run op by op, MJX's kinematics compile hundreds of small ones)
    def pair_geometry(qpos, qvel):
        m = model_with_params(scene, params)
        d = mjx.fwd_position(m, make_data(scene, qpos, qvel))
        geos, _ = contact_geometry(scene, params, m, d)
        return jax.tree_util.tree_map(lambda x: x[0], geos[0])

    g = pair_geometry(rest.qpos[-1], rest.qvel[-1])
    p = jax.tree_util.tree_map(lambda x: x[0], _group_params(params, scene.groups[0], 1))
    reach = int(np.sum(np.asarray(g.depth) > -REACH_MARGIN))
    assert 30 < reach <= PerSample().capacity[0]  # (51 samples within reach; 30 in contact)
    full = _AllSamples(g, (g.depth > -REACH_MARGIN) & (g.weight > 0), jnp.asarray(0.01))

    @functools.partial(jax.jit, static_argnums=0)
    def by_ad(model, st, u):
        return model.wrench(p, st, u), jax.jacfwd(lambda x: model.wrench(p, st, x))(u)

    closed_form = jax.jit(lambda model, st, u: model.wrench_and_jacobian(p, st, u), static_argnums=0)
    us = (jnp.zeros(6), jnp.asarray([0.2, -0.1, -0.3, 0.5, 1.0, -2.0]))
    # the wrench of all samples, the reference (it uses none of the search's counts: one program)
    reference = [by_ad(PerSample(), full, u) for u in us]
    # (a face's room of 96, evaluated in the Newton iteration in two chunks of 48: chunk_size)
    for model, overflows in ((PerSample(), False), (PerSample(blocks_searched=4), True),
                             (PerSample(max_active=16), True), (PerSample(max_active=96), False),
                             (PerSample(max_active=96, blocks_searched=4), True)):
        st = jax.jit(lambda g: model.prepare(g, 0.01))(g)  # noqa: B023  (called at once)
        assert bool(st.overflow) == overflows
        assert int(np.sum(np.asarray(st.active.weight) > 0)) == min(reach, model.capacity[0]) or overflows
        # reverse_mode=False: the Newton iteration's per-pair choice (the fallback a while loop)
        loop = dataclasses.replace(st, reverse_mode=False)
        for u, (expected, expected_jac) in zip(us, reference):
            for W, K in (by_ad(model, st, u), closed_form(model, st, u), by_ad(model, loop, u),
                         closed_form(model, loop, u)):
                np.testing.assert_allclose(W, expected, rtol=1e-12, atol=1e-12)
                np.testing.assert_allclose(K, expected_jac, rtol=1e-10, atol=1e-9)
            if not overflows:  # the kept samples alone
                np.testing.assert_allclose(by_ad(model, st.active, u)[0], expected, rtol=1e-12, atol=1e-12)

    # under vmap, a pair that overflows beside one out of reach (lifted by 1 m: depth far
    # below): each gets its own wrench, by the branch and by the per-pair loop
    model, u = PerSample(max_active=16), us[1]
    lifted = dataclasses.replace(g, depth=g.depth - 100.0)
    pair = jax.tree_util.tree_map(lambda a, b: jnp.stack([a, b]), g, lifted)
    st = jax.jit(jax.vmap(lambda g: model.prepare(g, 0.01)))(pair)
    assert np.asarray(st.overflow).tolist() == [True, False]
    for st_ in (st, dataclasses.replace(st, reverse_mode=False)):
        W, K = jax.jit(jax.vmap(lambda s: model.wrench_and_jacobian(p, s, u)))(st_)  # noqa: B023
        np.testing.assert_allclose(W[0], reference[1][0], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(K[0], reference[1][1], rtol=1e-10, atol=1e-9)
        assert not np.any(np.asarray(W[1])) and not np.any(np.asarray(K[1]))

    # the look-ahead: ż_i = c_i·u (the plane's affine shortcut), and a bunny moving down at
    # 1 m/s reaches h·1 m/s / r = 0.41 radii further; moving up, no further than at rest
    u = jnp.asarray([0.3, -0.2, -1.0, 0.4, -0.7, 0.2])
    np.testing.assert_allclose(depth_rates(g, u), u @ sample_rates(g), rtol=1e-12, atol=1e-12)
    gathered = jax.jit(lambda g, u: PerSample().prepare(g, 0.01, u).active.weight)

    def count(u):
        return int(np.sum(np.asarray(gathered(g, u)) > 0))

    assert count(jnp.asarray([0, 0, -1.0, 0, 0, 0])) > reach
    assert count(jnp.asarray([0, 0, 1.0, 0, 0, 0])) == reach


@pytest.mark.parametrize("bad", [dict(max_active=0), dict(blocks_searched=0), dict(blocks_searched=2.5),
                                 dict(max_active=True)])
def test_per_sample_rejects_counts_out_of_range(bad):
    from dano.contact.per_sample import PerSample
    from dano.errors import DanoError

    with pytest.raises(DanoError, match=f"PerSample.{next(iter(bad))} must be a positive integer"):
        PerSample(**bad)


def test_a_flat_face_is_gathered_at_once_and_the_slide_is_the_same():
    # a box's largest face holds more samples than the default room of 64: compose sizes the
    # per-sample pair for it (PerSample.sized_for), so that the slide gathers its samples once
    # per step instead of taking the all-samples fallback in every one; the motion is the same
    from dano.contact.per_sample import DEFAULT_MAX_ACTIVE, PerSample
    from dano.contact.samples import FACE_BAND, face_sample_count
    from dano.sim import rollout_arrays
    from dano.sim.scene import contact_samples
    from dano.sim.scenes import initial_state

    box = build(BoxField((0.05, 0.03, 0.015)), mass=0.3, num_samples=1500, seed=0, mesh_resolution=0, name="box")
    points, _, _, radius, _ = contact_samples(DanoObject("box", box))
    face = face_sample_count(points, radius)
    # the hull's largest facets lie on the box's faces: the count is the bottom (or top) face's
    # samples, those within the band of it, about its share of the surface (0.006 of 0.0216 m²)
    by_axis = [int(np.sum(sign * points[:, k] > np.max(sign * points[:, k]) - FACE_BAND * radius))
               for k in range(3) for sign in (1, -1)]
    assert face == max(by_axis) == max(by_axis[4:])  # a z face, the 10 x 6 cm one
    assert 0.8 < face / (len(points) * 0.006 / 0.0216) < 1.25
    ball = """<mujoco><worldbody><geom name="floor" type="plane" size="2 2 0.1"/>
      <geom name="ball" type="sphere" size="0.05" pos="1 1 0.05"/></worldbody></mujoco>"""
    sized = compose([DanoObject("box", box, (0, 0, 0.015))], ball, dt=0.01, contact_model="per_sample")
    room = sized.info.pairs[0].model.capacity[0]
    assert room >= face > 2 * room / 3 and room > DEFAULT_MAX_ACTIVE  # the size that holds the face (room_for)
    tables = ball.replace("</worldbody>", """<geom name="table" type="box" size="0.3 0.2 0.02" pos="-1 1 0.02"/>
      <geom name="pad" type="box" size="0.01 0.02 0.005" pos="1 -1 0.005"/></worldbody>""")
    models = {p.name: p.model for p in compose([DanoObject("box", box)], tables, contact_model="per_sample").info.pairs}
    assert models["box/floor"] == models["box/table"] == sized.info.pairs[0].model  # a table's face holds the box's
    # a sphere, or a pad smaller than the box's face, touches a patch of it: the default room
    assert models["box/ball"] == models["box/pad"] == PerSample()
    assert compose([DanoObject("box", box)], contact_model=PerSample(max_active=16)).info.pairs[0].model.max_active == 16
    fallback = compose([DanoObject("box", box, (0, 0, 0.015))], ball, dt=0.01,
                       contact_model=PerSample(max_active=DEFAULT_MAX_ACTIVE))

    def slide(scene):
        state = initial_state(scene, {"box": ((0, 0, 0.015), (1, 0, 0, 0))}, {"box": ((1.0, 0.2, 0), (0, 0, 2.0))})
        return np.asarray(rollout_arrays(scene, state, None, scene.default_params(sliding_friction=0.3), 40)[0])

    qpos = slide(sized)
    assert np.linalg.norm(qpos[-1, :2] - qpos[0, :2]) > 0.1  # it slid (at most 0.18 m at this friction)
    np.testing.assert_allclose(qpos, slide(fallback), rtol=0, atol=1e-10)


def test_per_sample_reverse_mode_matches_central_differences_through_its_fallback():
    # a sliding bunny with room for 8 samples only: every step takes the all-samples fallback
    # (a loop of 8-sample chunks inside the branch per force evaluation); jax.grad (reverse
    # mode through the implicit step's tangent) equals central differences
    from dano.contact.per_sample import PerSample
    from dano.sim import NewtonConfig, State, rollout_arrays
    from dano.sim.scenes import load_scene

    setup = load_scene("bunny-slide", contact_model=PerSample(max_active=8))

    def x_end(mu):
        params = setup.params.replace(contact=setup.params.contact.replace(sliding_friction=mu))
        return rollout_arrays(setup.scene, setup.state0, None, params, 20)[0][-1, 0]

    reverse = jax.grad(x_end)(0.2)
    central = (x_end(0.2 + 1e-6) - x_end(0.2 - 1e-6)) / 2e-6
    assert float(reverse) < -0.1  # more friction, a shorter slide
    np.testing.assert_allclose(reverse, central, rtol=1e-6)

    # forward mode only (NewtonConfig.reverse_mode=False: the fallback a while loop), vmapped
    # beside the same bunny 1 m up (in the air for the 20 steps, no sample within reach):
    # the slide's value and derivative as above, the flight's x0 + v·t with dx/dμ = 0
    def x_end_forward(mu, z):
        params = setup.params.replace(contact=setup.params.contact.replace(sliding_friction=mu))
        start = State(setup.state0.qpos.at[2].add(z), setup.state0.qvel)
        return rollout_arrays(setup.scene, start, None, params, 20, newton=NewtonConfig(reverse_mode=False))[0][-1, 0]

    x, dx = jax.jit(jax.vmap(lambda z: jax.jvp(lambda m: x_end_forward(m, z), (0.2,), (1.0,))))(jnp.asarray([0.0, 1.0]))
    np.testing.assert_allclose(x[0], x_end(0.2), rtol=1e-12)
    np.testing.assert_allclose(dx[0], reverse, rtol=1e-9)
    np.testing.assert_allclose(x[1], setup.state0.qpos[0] + 2.5 * 20 * setup.scene.dt, rtol=1e-12)
    assert float(dx[1]) == 0.0


def test_per_sample_look_ahead_rates_are_the_sample_rates_for_every_pair_kind():
    # ż_i = c_i·u: the plane's affine shortcut and the general form (per-sample depth
    # gradients: the sphere geom and DANO-DANO pairs) against the (6, S) rate columns
    from dano._mjx import mjx
    from dano.contact.base import sample_rates
    from dano.contact.per_sample import depth_rates
    from dano.sim.dynamics import contact_geometry, make_data, model_with_params
    from dano.sim.scenes import load_scene

    setup = load_scene("two-bunnies-sphere", contact_model="per_sample")
    scene, params = setup.scene, setup.params

    @jax.jit
    def geometries(qpos, qvel):
        m = model_with_params(scene, params)
        return contact_geometry(scene, params, m, mjx.fwd_position(m, make_data(scene, qpos, qvel)))[0]

    u = jnp.asarray([0.3, -0.2, -1.0, 0.4, -0.7, 0.2])
    kinds = set()
    for group, batch in zip(scene.groups, geometries(setup.state0.qpos, setup.state0.qvel)):
        g = jax.tree_util.tree_map(lambda x: x[0], batch)  # noqa: B023
        kinds.add(group.kind)
        rates = np.asarray(depth_rates(g, u))
        np.testing.assert_allclose(rates, np.asarray(u @ sample_rates(g)), rtol=0, atol=1e-12 * np.abs(rates).max())
    assert kinds == {"plane", "sphere", "dano"}

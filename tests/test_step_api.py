"""The public step and its pytrees (issue 7, "What to build" 1 and 6)."""

import dataclasses
import importlib
import re
import subprocess
import sys
from pathlib import Path
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import dano
from dano.asset import build
from dano.contact import ContactParams
from dano.fields import BoxField
from dano.sim import DanoObject, Scene, SimParams, compose, make_data, rollout, rollout_arrays, step
from dano.sim.dynamics import overlaps
from dano.sim.rollout import _scan_steps_compiled

SRC = Path(dano.__file__).parent
rollout_module = importlib.import_module("dano.sim.rollout")  # (dano.sim.rollout is also the function)

# A hinge arm whose actuator has activation dynamics (a first-order filter) beside a box
# DANO resting on the ground: act, time and ctrl must carry through step and chunks.
ARM = """
<mujoco>
  <option timestep="0.005"/>
  <worldbody>
    <geom name="ground" type="plane" size="0 0 1"/>
    <body name="arm" pos="0 1 0.5">
      <joint name="hinge" type="hinge" axis="0 1 0" damping="0.1"/>
      <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.02" mass="0.5" contype="0" conaffinity="0"/>
    </body>
  </worldbody>
  <actuator>
    <general joint="hinge" dyntype="filter" dynprm="0.05" gainprm="2"/>
  </actuator>
</mujoco>
"""


@pytest.fixture(scope="module")
def box_scene(tmp_path_factory):
    path = tmp_path_factory.mktemp("arm") / "arm.xml"
    path.write_text(ARM)
    h = 0.05
    asset = build(BoxField((h, h, h)), mass=0.3, num_samples=1000, mesh_resolution=0, name="box")
    scene = compose([DanoObject("box", asset, (0, 0, h))], path, dt=0.005)
    assert scene.pair_names == ("box/ground",)
    qpos = np.array(scene.qpos0)
    qpos[scene.qpos_adr[0]:scene.qpos_adr[0] + 7] = [0, 0, h + 0.01, 1, 0, 0, 0]
    qvel = np.zeros(scene.nv)
    qvel[scene.dof_adr[0]] = 0.5
    return scene, qpos, qvel


def with_theta(params, theta):
    """params with sliding friction theta[0] (every pair) and mass scale theta[1]."""
    return params.replace(contact=params.contact.replace(sliding_friction=jnp.full_like(
        params.contact.sliding_friction, theta[0])), alpha=theta[1:])


def final_state(scene, data, params, theta, steps, overlaps=True):
    """[qpos, qvel] after ``steps`` steps of a rollout with :func:`with_theta`'s parameters."""
    qp, qv, _ = rollout_arrays(scene, data, None, with_theta(params, theta), steps, overlaps=overlaps)
    return jnp.concatenate([qp[-1], qv[-1]])


def test_step_is_pure_and_keeps_the_callers_inputs(box_scene):
    scene, qpos, qvel = box_scene
    params = scene.default_params()
    data = make_data(scene, qpos, qvel)
    # ctrl 1 and a force of 0.01, made from the data's own fields (on their device, as the other
    # tests' data: the jitted step below is then the one they compile)
    data = data.replace(ctrl=data.ctrl + 1.0, qfrc_applied=data.qfrc_applied + 0.01)
    jstep = jax.jit(step)
    a, b = jstep(scene, params, data), jstep(scene, params, data)
    assert np.array_equal(np.asarray(a.qpos), np.asarray(b.qpos))
    np.testing.assert_array_equal(np.asarray(data.qpos), qpos)  # the input is untouched
    np.testing.assert_array_equal(np.asarray(a.qfrc_applied), 0.01)  # the caller's force stays
    assert float(a.time) == pytest.approx(scene.dt)
    assert float(a.act[0]) > 0  # the actuator's activation moved towards ctrl
    assert jax.tree_util.tree_structure(a) == jax.tree_util.tree_structure(data)


def test_a_jitted_step_loop_compiles_once(box_scene):
    """make_data's Data is committed to its device, as a jitted step's output is: a user's own
    `jax.jit(step)` loop (the README's) compiles once, not again on its second call (1.5 s on
    the bunny)."""
    scene, qpos, qvel = box_scene
    params = scene.default_params()
    jstep = jax.jit(step)
    data = make_data(scene, qpos, qvel)
    for _ in range(3):
        data = jstep(scene, params, data)
    assert jstep._cache_size() == 1


def test_rollout_in_chunks_continues_act_time_and_ctrl(box_scene, monkeypatch):
    scene, qpos, qvel = box_scene
    params = scene.default_params()
    data = make_data(scene, qpos, qvel, ctrl=[1.0])
    # (chunks of unequal length; 30 steps, as the other rollouts of this file: one compilation)
    whole = rollout(scene, data, None, params, 30)
    first = rollout(scene, data, None, params, 20)
    second = rollout(scene, first.final_data, None, params, 10)
    np.testing.assert_allclose(second.qpos[-1], whole.qpos[-1], atol=1e-12)
    np.testing.assert_allclose(np.asarray(second.final_data.act), np.asarray(whole.final_data.act), atol=1e-14)
    assert float(second.final_data.time) == pytest.approx(30 * scene.dt)
    # the loop carries the state fields only (CARRIED_FIELDS): the final Data holds the last state
    np.testing.assert_array_equal(np.asarray(whole.final_data.qpos), whole.qpos[-1])
    np.testing.assert_array_equal(np.asarray(whole.final_data.qvel), whole.qvel[-1])
    # rollouts run in chunks, each continuing from the last one's Data (here outputs of 32
    # rows; with progress reported, 20 chunks of 20 steps, the last of 10, the loop's trip
    # count an argument): no extra steps, the right final time and final overlap; its first
    # 30 steps (across chunk boundaries) are the whole rollout's
    monkeypatch.setattr(rollout_module, "CHUNK", 32)
    monkeypatch.setattr(rollout_module, "PROGRESS_CHUNK", 1)
    reported = []
    chunked = rollout(scene, data, None, params, 390, progress=lambda *a: reported.append(a[:2]))
    assert reported == [(min(20 * (k + 1), 390), 390) for k in range(20)]
    np.testing.assert_allclose(chunked.qpos[:31], whole.qpos, atol=1e-12)
    np.testing.assert_allclose(chunked.psi[:31], whole.psi, atol=1e-12)
    assert chunked.qpos.shape[0] == chunked.psi.shape[0] == 391
    assert float(chunked.final_data.time) == pytest.approx(390 * scene.dt)
    np.testing.assert_allclose(chunked.psi[-1], np.asarray(overlaps(scene, params, chunked.final_data)), atol=1e-15)
    # another duration (without progress: chunks of 32 steps, the last of 8) runs the compiled
    # program of the 390 steps: it does not compile again
    counts = lambda: sum(_scan_steps_compiled.counts[k] for k in ("jit", "traced", "loaded"))  # noqa: E731
    before = counts()
    shorter = rollout(scene, data, None, params, 200)
    assert counts() == before
    np.testing.assert_allclose(shorter.qpos, chunked.qpos[:201], atol=1e-12)


def test_rollout_ties_its_carry_without_changing_a_value(box_scene):
    """The scan's carry is tied to every input (one round of JAX's scan rules, not three):
    by adding zero, so every leaf keeps its value whatever the inputs hold; a rollout without
    the final overlap has the same states and the same Jacobian (to rounding)."""
    from dano.sim.dynamics import tied

    scene, qpos, qvel = box_scene
    params = scene.default_params()
    data = make_data(scene, qpos, qvel, ctrl=[1.0])
    for bad in (np.inf, -np.inf, np.nan, 1e308):
        out = tied(data, params, data.qpos, jnp.asarray([bad, 1e308, -1e308]))
        for a, b in zip(jax.tree_util.tree_leaves(out), jax.tree_util.tree_leaves(data)):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    qp, qv, psi = rollout_arrays(scene, data, None, params, 30)
    qp2, qv2, none = rollout_arrays(scene, data, None, params, 30, overlaps=False)
    assert none is None and psi.shape == (31, 1)
    # (two programs: XLA may fuse them differently, so the same to rounding, not bit for bit)
    np.testing.assert_allclose(np.asarray(qp2), np.asarray(qp), rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(np.asarray(qv2), np.asarray(qv), rtol=1e-13, atol=1e-15)

    # the Jacobian of the final state along sliding friction and mass scale
    theta = jnp.asarray([0.3, float(params.alpha[0])])
    J = {o: np.asarray(jax.jacfwd(lambda th, o=o: final_state(scene, data, params, th, 30, o))(theta))
         for o in (False, True)}
    np.testing.assert_allclose(J[False], J[True], rtol=1e-12, atol=1e-14)


def test_step_vmaps_over_data_and_params(box_scene):
    scene, qpos, qvel = box_scene
    params = scene.default_params()
    speeds = jnp.asarray([0.0, 0.5, 1.0])
    datas = jax.vmap(lambda s: make_data(scene, qpos, jnp.asarray(qvel).at[scene.dof_adr[0]].set(s)))(speeds)
    batched = jax.jit(jax.vmap(step, in_axes=(None, None, 0)))(scene, params, datas)
    single = jax.jit(step)
    for i, s in enumerate(speeds):
        one = single(scene, params, make_data(scene, qpos, jnp.asarray(qvel).at[scene.dof_adr[0]].set(s)))
        np.testing.assert_allclose(np.asarray(batched.qvel[i]), np.asarray(one.qvel), atol=1e-12)
    mus = jnp.asarray([0.1, 0.5])
    many = jax.jit(jax.vmap(lambda mu: step(scene, params.replace(contact=params.contact.replace(
        sliding_friction=jnp.full_like(params.contact.sliding_friction, mu))), datas[1]).qvel))(mus)
    assert np.all(np.isfinite(np.asarray(many)))


def test_a_nan_env_does_not_keep_a_batch_iterating(box_scene):
    """Under vmap the Newton loop runs until every env is done: an env whose state is already
    NaN returns at once (0 iterations; before, all 25 on every step), stays NaN (never
    silently finite), and the other envs' steps are what they are without it (bit for bit)
    and alone (to rounding: vmap batches the linear algebra)."""
    from dano.sim.dynamics import step_with_info

    scene, qpos, qvel = box_scene
    params = scene.default_params()
    q = np.array(qpos)
    q[scene.qpos_adr[0] + 2] = 0.05 - 0.002  # 2 mm into the ground, sliding at 0.5 m/s: contact
    good = make_data(scene, q, qvel)
    bad = make_data(scene, q, np.full_like(qvel, np.nan))
    pair = lambda a, b: jax.tree_util.tree_map(lambda x, y: jnp.stack([x, y]), a, b)  # noqa: E731
    run = jax.jit(jax.vmap(lambda d: step_with_info(scene, params, d)[::-1], in_axes=0))
    info, out = run(pair(good, bad))
    info_twice, twice = run(pair(good, good))
    info_one, one = jax.jit(lambda d: step_with_info(scene, params, d)[::-1])(good)
    iterations = np.asarray(info.newton_iterations)
    assert iterations[1] == 0 and iterations[0] == int(info_one.newton_iterations) >= 1, iterations
    assert np.array_equal(np.asarray(info_twice.newton_iterations), [iterations[0]] * 2)
    assert np.array_equal(np.asarray(out.qvel[0]), np.asarray(twice.qvel[0]))
    np.testing.assert_allclose(np.asarray(out.qvel[0]), np.asarray(one.qvel), rtol=0, atol=1e-12)
    assert np.all(np.isnan(np.asarray(out.qvel[1])))


def test_a_batch_halves_only_where_an_env_needs_it(box_scene, monkeypatch):
    """Under vmap both branches of the Newton step's line search run for every env: the
    halving loop must stop where the envs that need it are done, not run on for an env that
    took its full step or had finished (before, a box at rest beside a sliding one made the
    batch halve 21 times in 60 steps, where alone they halved 5 and 0 times), and the
    batch's steps are each env's own."""
    from dano.sim.dynamics import step_with_info

    scene, qpos, qvel = box_scene
    params = scene.default_params()
    trips = [0]
    real_while_loop = jax.lax.while_loop

    def counting_while_loop(cond, body, init):  # counts the trips of the halving loop
        if getattr(body, "__name__", "") == "halve":
            def counted(carry):
                jax.debug.callback(lambda: trips.__setitem__(0, trips[0] + 1))
                return body(carry)
            return real_while_loop(cond, counted, init)
        return real_while_loop(cond, body, init)

    monkeypatch.setattr(jax.lax, "while_loop", counting_while_loop)

    def roll(d):  # 60 steps: the final Data, qvel (nv,) and Newton iterations (60,)
        def one(d, _):
            d, info = step_with_info(scene, params, d)
            return d, info.newton_iterations
        d, its = jax.lax.scan(one, d, None, length=60)
        return d, d.qvel, its

    jroll = jax.jit(roll)
    sliding = make_data(scene, qpos, qvel)
    resting = make_data(scene, qpos, np.zeros_like(qvel))
    for _ in range(5):  # settled on the ground: 300 steps from 1 cm above it, at rest
        resting = make_data(scene, jroll(resting)[0].qpos, np.zeros_like(qvel))
    alone = []
    for d in (sliding, resting):
        trips[0] = 0
        out = jax.block_until_ready(jroll(d)[1:])
        alone.append((trips[0], out))
    trips[0] = 0
    pair = jax.tree_util.tree_map(lambda x, y: jnp.stack([x, y]), sliding, resting)
    _, qv, its = jax.block_until_ready(jax.jit(jax.vmap(roll))(pair))
    assert alone[0][0] >= 1 and alone[1][0] == 0, [a[0] for a in alone]  # the sliding box halves, the resting one not
    assert trips[0] <= alone[0][0] + alone[1][0], (trips[0], [a[0] for a in alone])
    for i, (_, (qv_one, its_one)) in enumerate(alone):
        assert np.array_equal(np.asarray(its[i]), np.asarray(its_one))
        np.testing.assert_allclose(np.asarray(qv[i]), np.asarray(qv_one), rtol=0, atol=1e-9)


def test_jacfwd_of_step_matches_central_differences(box_scene):
    scene, qpos, qvel = box_scene
    params = scene.default_params()
    data = make_data(scene, qpos, qvel)

    def after(theta):  # three steps, as a function of (sliding friction, mass scale)
        p = params.replace(contact=params.contact.replace(sliding_friction=jnp.full((len(scene.pairs),), theta[0])),
                           alpha=theta[1:])
        # a loop of 3 (not 3 copies of the step unrolled: a third of the compilation)
        d = jax.lax.fori_loop(0, 3, lambda _, d: step(scene, p, d), data)
        return jnp.concatenate([d.qpos, d.qvel])

    # start in contact: settle first
    q, v, _ = rollout_arrays(scene, data, None, params, 30)
    data = make_data(scene, q[-1], v[-1])
    theta = jnp.asarray([0.3, float(params.alpha[0])])
    J = jax.jit(jax.jacfwd(after))(theta)
    f = jax.jit(after)
    eps = 1e-6
    fd = np.stack([(np.asarray(f(theta.at[i].add(eps))) - np.asarray(f(theta.at[i].add(-eps)))) / (2 * eps)
                   for i in range(2)], axis=1)
    assert np.all(np.isfinite(np.asarray(J)))
    assert np.abs(fd[:, 0]).max() > 1e-6  # friction matters here
    np.testing.assert_allclose(np.asarray(J), fd, atol=1e-6 * max(1.0, np.abs(fd).max()), rtol=1e-4)


def test_scene_and_parameters_are_pytrees_with_replace(box_scene):
    scene, _, _ = box_scene
    params = scene.default_params()
    for tree in (scene, params, params.contact):
        leaves, treedef = jax.tree_util.tree_flatten(tree)
        assert type(jax.tree_util.tree_unflatten(treedef, leaves)) is type(tree)
    assert all(isinstance(x, jax.Array) for x in jax.tree_util.tree_leaves(params))
    stiffer = params.contact.replace(impact_spring=params.contact.impact_spring * 2)
    assert float(stiffer.impact_spring[0]) == 2 * float(params.contact.impact_spring[0])
    assert isinstance(params.replace(contact=stiffer), SimParams)
    assert isinstance(scene.replace(base_mass=scene.base_mass * 2), Scene)
    assert isinstance(ContactParams().replace(sliding_friction=0.2), ContactParams)
    # a scalar parameter applies to every pair
    scalar = params.replace(contact=params.contact.replace(sliding_friction=0.7))
    d = make_data(scene, *box_scene[1:])
    np.testing.assert_allclose(np.asarray(jax.jit(step)(scene, scalar, d).qvel),
                               np.asarray(jax.jit(step)(scene, scene.set_param(params, "sliding_friction", 0.7), d).qvel))
    # the convenience setter agrees with replace
    by_name = scene.set_param(params, "sliding_friction", 0.7)
    np.testing.assert_array_equal(np.asarray(by_name.contact.sliding_friction), 0.7)
    # a scene is an ordinary jit argument: same structure, no new compilation
    f = jax.jit(lambda s: s.base_mass.sum())
    f(scene)
    f(scene.replace(base_mass=scene.base_mass * 3))
    assert f._cache_size() == 1


def test_no_mjx_private_fields_in_the_source():
    # MJX's private fields are reached as attributes (model._impl, data._impl); a config name
    # such as jax_cpu_collectives_implementation is no offence
    offenders = [str(p.relative_to(SRC)) for p in SRC.rglob("*.py") if re.search(r"\._impl\b", p.read_text())]
    assert offenders == []


def test_importing_dano_changes_no_process_wide_setting():
    code = (
        "import jax, matplotlib\n"
        "before = (jax.config.jax_enable_x64, matplotlib.get_backend())\n"
        "import dano, dano.sim, dano.viz.plot, dano.sysid\n"
        "from dano.viz.plot import plot_samples\n"
        "after = (jax.config.jax_enable_x64, matplotlib.get_backend())\n"
        "assert before == after, (before, after)\n"
        "dano.enable_float64()\n"
        "assert jax.config.jax_enable_x64\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]


def test_float32_drop_settles_with_finite_gradients():
    from dano.sim.scenes import load_scene

    setup = load_scene("bunny-drop")
    scene = setup.scene.astype(jnp.float32)
    params = jax.tree_util.tree_map(lambda x: jnp.asarray(x, jnp.float32), setup.params)
    q0 = jnp.asarray(setup.state0.qpos, jnp.float32)
    v0 = jnp.asarray(setup.state0.qvel, jnp.float32)
    data = make_data(scene, q0, v0)
    assert {x.dtype for x in jax.tree_util.tree_leaves(data) if jnp.issubdtype(x.dtype, jnp.floating)} \
        == {jnp.dtype(jnp.float32)}
    traj = rollout(scene, data, None, params, 400)  # 4 s
    assert traj.qpos.dtype == np.float32
    assert np.all(np.isfinite(traj.qpos))
    assert np.linalg.norm(traj.qvel[-1]) < 1e-2  # settled
    k = float(params.contact.impact_spring[0])
    assert traj.psi[-1, 0] * k == pytest.approx(float(scene.assets[0].mass) * 9.81, rel=0.05)

    def final_x(mu):
        p = params.replace(contact=params.contact.replace(sliding_friction=jnp.full((1,), mu, jnp.float32)))
        return rollout_arrays(scene, data, None, p, 150)[0][-1, :3]

    J = jax.jit(jax.jacfwd(final_x))(jnp.float32(0.3))
    assert J.dtype == jnp.float32 and np.all(np.isfinite(np.asarray(J)))


@pytest.mark.parametrize("bad", [dict(constraint_passes=0), dict(max_iterations=0), dict(max_backtracks=-1),
                                 dict(constraint_passes=1.5), dict(constraint_passes=True)])
def test_newton_options_reject_counts_out_of_range(bad):
    from dano.errors import DanoError
    from dano.sim import NewtonOptions

    with pytest.raises(DanoError, match=f"NewtonOptions.{next(iter(bad))} must be an integer"):
        NewtonOptions(**bad)


def test_dense_solve_matches_lapack_with_pivoting_and_gradients():
    """The step's unrolled LU (NewtonConfig.linear_solver="unrolled") solves to LAPACK's
    accuracy, pivots where the first column is tiny, and differentiates like jnp.linalg.solve
    in both modes."""
    from dano.sim.implicit import dense_solve

    rng = np.random.default_rng(0)
    solve = jax.jit(dense_solve)
    for n in (1, 2, 6, 13):
        for trial in range(20):
            A = rng.standard_normal((n, n))
            if trial % 2:
                A[:, 0] *= 1e-9  # without row exchanges the first pivot would be ~1e-9
            b = rng.standard_normal(n)
            x = np.asarray(solve(A, b))
            backward = np.linalg.norm(A @ x - b) / (np.linalg.norm(A) * np.linalg.norm(x) + np.linalg.norm(b))
            assert backward < 1e-14, (n, trial, backward)
    A, b = jnp.asarray(rng.standard_normal((6, 6))), jnp.asarray(rng.standard_normal(6))
    for argnums in (0, 1):
        ours = jax.grad(lambda A, b: jnp.sum(jnp.sin(dense_solve(A, b))), argnums)(A, b)
        ref = jax.grad(lambda A, b: jnp.sum(jnp.sin(jnp.linalg.solve(A, b))), argnums)(A, b)
        np.testing.assert_allclose(ours, ref, rtol=1e-10, atol=1e-12)
    assert not np.any(np.isfinite(np.asarray(dense_solve(jnp.zeros((3, 3)), jnp.ones(3)))))  # singular: not silent


def test_unrolled_rollout_has_no_lapack_call_and_agrees_with_lapack():
    """linear_solver="unrolled" removes the step's only LAPACK call (what lets XLA compile the
    rollout into one kernel on the CPU) and changes the bunny drop only by rounding; "auto"
    picks it for rollouts of at least UNROLLED_MIN_STEPS steps with the centroid model."""
    from dano.errors import DanoError
    from dano.sim import NewtonConfig
    from dano.contact import Centroid
    from dano.sim.implicit import UNROLLED_MIN_STEPS, resolve_linear_solver
    from dano.sim.scenes import load_scene

    setup = load_scene("bunny-drop")
    sc, s0, p = setup.scene, setup.state0, setup.params
    runs = {}
    for solver in ("lapack", "unrolled"):
        fn = jax.jit(lambda s, p, solver=solver: rollout_arrays(sc, s, None, p, 300,
                                                                newton=NewtonConfig(linear_solver=solver)))
        assert ("lapack" in fn.lower(s0, p).as_text()) == (solver == "lapack")
        runs[solver] = [np.asarray(a) for a in fn(s0, p)[:2]]
    assert np.ptp(runs["lapack"][0][:, 2]) > 0.01  # it fell and landed
    for ours, ref in zip(runs["unrolled"], runs["lapack"]):
        np.testing.assert_allclose(ours, ref, rtol=0, atol=1e-8)

    auto = NewtonConfig()
    assert resolve_linear_solver(auto, sc, UNROLLED_MIN_STEPS).linear_solver == "unrolled"
    assert resolve_linear_solver(auto, sc, UNROLLED_MIN_STEPS - 1).linear_solver == "lapack"
    lapack = NewtonConfig(linear_solver="lapack")
    assert resolve_linear_solver(lapack, sc, 10 * UNROLLED_MIN_STEPS) is lapack
    per_sample = load_scene("bunny-drop", contact_model="per_sample").scene  # one kernel too (no YNNPACK fusions)
    assert resolve_linear_solver(auto, per_sample, UNROLLED_MIN_STEPS).linear_solver == "unrolled"

    @dataclasses.dataclass(frozen=True)
    class OpByOp(Centroid):  # a model whose rollout does not compile into one kernel
        single_kernel_rollout: ClassVar[bool] = False

    other = load_scene("bunny-drop", contact_model=OpByOp()).scene
    assert resolve_linear_solver(auto, other, UNROLLED_MIN_STEPS).linear_solver == "lapack"

    @dataclasses.dataclass(frozen=True)
    class TwoArgumentPrepare(Centroid):  # written to the protocol before prepare took the twist
        def prepare(self, g, h):
            return Centroid.prepare(self, g, h)

    # on a GPU "auto" takes the unrolled LU for any rollout length and either model (no
    # cuSOLVER call per Newton iteration), not for a scene with MuJoCo constraints; only the
    # backend's name is swapped here (the choice is made when the rollout is traced); a
    # single step resolves "auto" too (on the CPU: LAPACK)
    import dano.sim.implicit as implicit

    assert resolve_linear_solver(auto, sc, 1).linear_solver == "lapack"  # (this CPU)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(implicit, "_backend", lambda: "gpu")
        assert resolve_linear_solver(auto, sc, 1).linear_solver == "unrolled"
        assert resolve_linear_solver(auto, other, 200).linear_solver == "unrolled"
        constrained = load_scene("sphere-hits-bunny").scene  # (the sphere on the ground: MuJoCo contacts)
        assert constrained.has_constraints and resolve_linear_solver(auto, constrained, 200).linear_solver == "lapack"
        mp.setattr(implicit, "_backend", lambda: "tpu")
        assert resolve_linear_solver(auto, sc, UNROLLED_MIN_STEPS).linear_solver == "lapack"

    legacy = load_scene("bunny-drop", contact_model=TwoArgumentPrepare())
    np.testing.assert_array_equal(rollout_arrays(legacy.scene, s0, None, p, 80)[0],  # (it lands at ~48)
                                  rollout_arrays(sc, s0, None, p, 80)[0])
    with pytest.raises(DanoError, match="linear_solver must be"):
        NewtonConfig(linear_solver="lu")
    with pytest.raises(DanoError, match="reverse_mode must be True or False"):
        NewtonConfig(reverse_mode="no")


def test_compose_keeps_the_time_step_the_mjcf_states(tmp_path):
    """``compose(objects, base)`` runs at the MJCF's ``<option timestep>`` as ``dano simulate``
    does (a new user's scene stating 2 ms ran at 10 ms, silently); a given dt wins; a model
    that states none runs at 0.01 s, MuJoCo's own default (0.002) not taken for a statement."""
    import mujoco

    box = DanoObject("box", build(BoxField((0.05, 0.05, 0.05)), mass=1.0, num_samples=100, mesh_resolution=0),
                     (0, 0, 0.05))
    floor = '<geom name="floor" type="plane" size="1 1 0.1"/>'
    stated = tmp_path / "stated.xml"
    stated.write_text(f'<mujoco><option timestep="0.002"/><worldbody>{floor}</worldbody></mujoco>')
    assert compose([box], stated).dt == 0.002
    assert compose([box], str(stated)).dt == 0.002
    assert compose([box], stated, dt=0.005).dt == 0.005
    assert compose([box], f'<mujoco><option timestep="0.004"/><worldbody>{floor}</worldbody></mujoco>').dt == 0.004
    assert compose([box], f"<mujoco><worldbody>{floor}</worldbody></mujoco>").dt == 0.01
    spec = mujoco.MjSpec.from_file(str(stated))
    spec.option.timestep = 0.003
    assert compose([box], spec).dt == 0.003
    assert compose([box], mujoco.MjSpec()).dt == 0.01 and compose([box]).dt == 0.01
    zero = tmp_path / "zero.xml"
    zero.write_text(f'<mujoco><option timestep="0"/><worldbody>{floor}</worldbody></mujoco>')
    with pytest.raises(dano.DanoError, match="zero.xml: <option timestep> must be positive, got 0.0"):
        compose([box], zero)

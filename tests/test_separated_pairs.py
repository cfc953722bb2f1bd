"""Pairs that cannot touch skip their samples (a DANO-DANO pair: both fields' queries),
groups of one contact model share one wrench evaluation, and a group whose pairs are all
apart is not evaluated in the Newton iteration (issue 32: a user's wall that the object never
touched cost 2-3x the step; two mesh-made DANOs apart, 4.8x). All three are exact: the same
states and derivatives as the step without them."""

import dataclasses
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from dano.asset import build
from dano.contact import PAIR_KINDS, Centroid
from dano.contact.base import aggregates as agg, skip_separated
from dano.fields import BoxField
from dano.sim import DanoObject, compose, make_data, rollout_arrays

H = 0.04  # the DANO: a 8 cm cube
WORLD = f"""
<mujoco>
  <worldbody>
    <geom name="ground" type="plane" size="0 0 1"/>
    <geom name="wall" type="box" size="0.02 0.3 0.1" pos="0.25 0 0.1"/>
    <geom name="post" type="capsule" size="0.02 0.1" pos="-1.5 0 0.1"/>
    <geom name="ball" type="sphere" size="0.05" pos="0 1.5 0.05"/>
  </worldbody>
</mujoco>
"""
STEPS = 60


@dataclasses.dataclass(frozen=True)
class EverySample(Centroid):
    """The centroid model, with every pair's samples visited in every step and every pair's
    wrench evaluated in every Newton iteration (as before)."""

    aggregates_only: ClassVar[bool] = False
    zero_when_apart: ClassVar[bool] = False


@dataclasses.dataclass(frozen=True)
class OwnGroup(EverySample):
    """:class:`EverySample` under another name: its pairs are not joined with the others."""


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    path = tmp_path_factory.mktemp("separated") / "world.xml"
    path.write_text(WORLD)
    asset = build(BoxField((H, H, H)), mass=0.3, num_samples=600, mesh_resolution=0, name="cube")
    obj = [DanoObject("cube", asset, (0, 0, H))]
    return {"skipped": compose(obj, path, dt=0.005),
            "visited": compose(obj, path, dt=0.005, contact_model=EverySample()),
            # nothing skipped, and the wall's pair in a group of its own
            "reference": compose(obj, path, dt=0.005, contact_model=EverySample(),
                                 pair_contact_models={"cube/wall": OwnGroup()})}


def _final(scene, vx, friction):
    """Final qpos (7,) of the cube slid along x at vx [m/s] with the ground's sliding friction."""
    params = scene.default_params()
    contact = params.contact
    mu = jnp.asarray(contact.sliding_friction).at[0].set(friction)
    params = dataclasses.replace(params, contact=dataclasses.replace(contact, sliding_friction=mu))
    d = make_data(scene, qvel=jnp.zeros(6).at[0].set(vx))
    qpos, _, psi = rollout_arrays(scene, d, None, params, STEPS)
    return qpos[-1], psi


def _check_cube_reaches_the_wall(scene, psi, qpos):
    """psi (B, T+1, P), qpos (B, 7) of the batches below: the first cube reaches the wall,
    its pair going from apart to touching within the rollout; the second does not; the
    capsule and the sphere are never touched."""
    names = scene.pair_names
    assert names == ("cube/ground", "cube/wall", "cube/post", "cube/ball")
    wall, psi = names.index("cube/wall"), np.asarray(psi)
    assert psi[0, 0, wall] == 0 and psi[0, :, wall].max() > 0 and np.all(psi[1, :, wall] == 0)
    assert np.all(psi[:, :, names.index("cube/post")] == 0) and np.all(psi[:, :, names.index("cube/ball")] == 0)
    assert float(qpos[0, 0]) < 0.25 - 0.02 - H + 0.01


#: a batch where one cube reaches the wall (the wall's pair then runs its samples for both)
#: and one where neither does
BATCHES = (jnp.asarray([2.0, 0.3]), jnp.asarray([0.3, -0.4]))


def merged_models(scene):
    """The contact models of the step's groups once joined (:func:`dano.sim.dynamics.merge_groups`)."""
    from dano.sim.dynamics import merge_groups

    states = tuple(jnp.zeros((len(g.index), 1)) for g in scene.groups)
    return merge_groups(scene, tuple(g.model for g in scene.groups), states)[0]


def _compare(out, labels):
    for label in labels:
        for a, b in zip(jax.tree_util.tree_leaves(out["skipped"]), jax.tree_util.tree_leaves(out[label])):
            a, b = np.asarray(a), np.asarray(b)
            assert np.all(np.isfinite(a))
            np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-12, err_msg=label)


def test_separated_pairs_and_joined_groups_change_no_state(scenes):
    out = {}
    for label in ("skipped", "reference"):
        run = jax.jit(jax.vmap(lambda vx, scene=scenes[label]: _final(scene, vx, 0.5)))
        out[label] = [run(vx) for vx in BATCHES]
    _check_cube_reaches_the_wall(scenes["skipped"], out["skipped"][0][1], out["skipped"][0][0])
    # the ground's pair on its own, the wall, the post and the ball in one group (which idles
    # while all three are apart); the reference keeps the wall's pair apart from those two
    assert [len(m) for m in (merged_models(scenes["skipped"]), merged_models(scenes["reference"]))] == [2, 3]
    _compare(out, ("reference",))


@pytest.mark.slow
def test_separated_pairs_change_no_derivative(scenes):
    """Forward mode vmapped over trajectories (as the identification's Jacobians) and
    reverse mode, through rollouts where the wall's pair is skipped and is not."""
    out = {}
    for label in ("skipped", "visited"):
        scene = scenes[label]
        def final_and_aux(args, scene=scene):
            qpos, psi = _final(scene, *args)
            return qpos, (qpos, psi)

        jac = jax.jit(jax.vmap(jax.jacfwd(final_and_aux, has_aux=True)))
        grad = jax.jit(jax.grad(lambda vx, scene=scene: _final(scene, vx, 0.5)[0][0]))
        out[label] = ([jac((vx, jnp.full_like(vx, 0.5))) for vx in BATCHES], grad(jnp.asarray(2.0)))
    _, (qpos, psi) = out["skipped"][0][0]
    _check_cube_reaches_the_wall(scenes["skipped"], psi, qpos)
    assert np.isfinite(float(out["skipped"][1])) and float(out["skipped"][1]) != 0
    _compare(out, ("visited",))


@pytest.fixture(scope="module")
def two_cubes():
    """Two cubes (DANOs) on the ground, 25 cm apart along x: a DANO-DANO pair."""
    asset = build(BoxField((H, H, H)), mass=0.3, num_samples=600, mesh_resolution=0, name="cube")
    obj = [DanoObject("cube", asset, (0, 0, H)), DanoObject("other", asset, (0.25, 0, H))]
    return {"skipped": compose(obj, dt=0.005), "visited": compose(obj, dt=0.005, contact_model=EverySample())}


def test_separated_dano_pairs_change_no_state(two_cubes):
    """The DANO-DANO pair skips both fields' queries while the cubes are apart: the same
    states as the step that queries them, in a batch where the first cube slides into the
    other and in one where it stops short."""
    out = {}
    for label in ("skipped", "visited"):
        scene = two_cubes[label]
        def final(vx, scene=scene):
            d = make_data(scene, qvel=jnp.zeros(12).at[0].set(vx))
            qpos, _, psi = rollout_arrays(scene, d, None, scene.default_params(), STEPS)
            return qpos[-1], psi
        out[label] = [jax.jit(jax.vmap(final))(vx) for vx in BATCHES]
    assert two_cubes["skipped"].pair_names == ("cube/ground", "cube/other", "other/ground")
    psi = np.asarray(out["skipped"][0][1])[..., 1]
    assert psi[0, 0] == 0 and psi[0].max() > 0 and np.all(psi[1] == 0)  # reaches the other cube; stops short
    assert float(np.asarray(out["skipped"][0][0])[0, 7]) > 0.25  # (it pushed the other cube along)
    _compare(out, ("visited",))


@pytest.fixture(scope="module")
def two_scanned_bunnies(shared):
    """Two DANOs made from the shared data's decimated Stanford bunny (a scanned object's mesh,
    not made here; the paper's NeRF level sets are not watertight, so no field is made from
    them), scaled to 10 cm: a signed-distance grid field whose ``bounds()`` the pair's test
    relies on."""
    import trimesh

    from dano.fields import mesh_field

    mesh = trimesh.load(shared / "meshes" / "bunny_lowpoly.obj", force="mesh")
    mesh.apply_scale(0.1 / float(np.max(mesh.extents)))
    asset = build(mesh_field(mesh, resolution=32), mass=0.3, num_samples=600, mesh_resolution=0, name="bunny")
    obj = [DanoObject("bunny", asset, (0, 0, 0.1)), DanoObject("other", asset, (0.25, 0, 0.1))]
    return {"skipped": compose(obj, dt=0.005)}


@pytest.mark.parametrize("kind, where", [("box", "scenes"), ("capsule", "scenes"), ("sphere", "scenes"),
                                         ("dano", "two_cubes"), ("dano", "two_scanned_bunnies")])
def test_apart_is_conservative_and_separated_gives_the_geometrys_aggregates(request, kind, where):
    """``apart`` says True only where every sample lies outside the geom, or the other DANO's
    field (ψ = 0, every depth < 0: on a scanned mesh's field too); there ``separated`` gives the
    aggregates and the forward- and reverse-mode derivatives of the full geometry; random poses
    from touching to far."""
    from dano.sim.dynamics import model_with_alpha
    from dano._mjx import mjx

    scene = request.getfixturevalue(where)["skipped"]
    group = next(g for g in scene.groups if g.kind == kind)
    params = scene.default_params()
    m = model_with_alpha(scene, params.alpha)
    d = jax.jit(mjx.fwd_position)(m, make_data(scene))
    pk = PAIR_KINDS[kind]
    base = jax.tree_util.tree_map(lambda x: x[0], pk.inputs(scene, group, m, d, params.alpha))
    culled = skip_separated(pk, pk.geometry)

    def aggregates(g, inp):
        return agg(g(inp))

    @jax.jit
    def check(base, xa, Ra, t):
        inp = dict(base, xa=xa, Ra=Ra)
        full = pk.geometry(inp)
        f = lambda x: aggregates(pk.geometry, dict(inp, xa=x))  # noqa: E731
        c = lambda x: aggregates(culled, dict(inp, xa=x))  # noqa: E731
        return (pk.apart(inp), full.psi, jnp.max(full.depth), aggregates(culled, inp), aggregates(pk.geometry, inp),
                jax.jvp(c, (xa,), (t,))[1], jax.jvp(f, (xa,), (t,))[1],
                jax.grad(lambda x: c(x)["normal"] @ t + c(x)["chi"] @ t)(xa),
                jax.grad(lambda x: f(x)["normal"] @ t + f(x)["chi"] @ t)(xa))

    # vmapped over a batch of poses (and over pairs, as the step's groups are): the same as
    # the full geometry, whether all, some or none of the batch are apart
    # (the inputs are arguments, not constants: a cond's tracing copes badly with large constants)
    nested = jax.jit(lambda base, xa: (jax.vmap(jax.vmap(lambda x: aggregates(culled, dict(base, xa=x))))(xa),
                                       jax.vmap(jax.vmap(lambda x: aggregates(pk.geometry, dict(base, xa=x))))(xa),
                                       jax.vmap(jax.vmap(lambda x: pk.apart(dict(base, xa=x))))(xa)))
    far = np.asarray(base["xb"]) + np.array([0.5, 0.0, 0.0])
    near = np.asarray(base["xb"]) + np.array([0.0, 0.0, 0.05])
    for rows in ([far, far], [far, near], [near, near]):
        xa = jnp.asarray(np.stack([np.stack(rows), np.stack(rows) + 0.01]))
        got, want, apart = nested(base, xa)
        assert np.asarray(apart).tolist() == [[r is far for r in rows]] * 2
        for a, b in zip(jax.tree_util.tree_leaves(got), jax.tree_util.tree_leaves(want)):
            np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-12, atol=1e-12)
    rng = np.random.default_rng(0)
    verdicts = []
    for i in range(24):
        direction = rng.normal(size=3)
        distance = 0.02 + 0.4 * i / 23  # from overlapping to far apart
        xa = jnp.asarray(base["xb"] + direction / np.linalg.norm(direction) * distance)
        Ra = jnp.asarray(Rotation.random(random_state=i).as_matrix())
        apart, psi, deepest, agg_c, agg_f, jvp_c, jvp_f, grad_c, grad_f = check(base, xa, Ra,
                                                                                  jnp.asarray(rng.normal(size=3)))
        verdicts.append(bool(apart))
        if apart:
            assert float(psi) == 0 and float(deepest) < 0
        for a, b in zip(jax.tree_util.tree_leaves((agg_c, jvp_c, grad_c)), jax.tree_util.tree_leaves((agg_f, jvp_f,
                                                                                                        grad_f))):
            np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-12, atol=1e-12)
    assert any(verdicts) and not all(verdicts)

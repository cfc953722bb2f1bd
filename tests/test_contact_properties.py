"""Properties of every pair kind with every field kind (issue 7, hypothesis): ψ ≥ 0; ψ = 0
when separated; moving and rotating the whole pair moves and rotates its geometry and its
wrench; swapping the two DANOs of a pair negates the wrench; forward-mode gradients are
finite at rest, at the onset of contact and in free flight; float64 and float32."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from dano.asset import build
from dano.contact import PAIR_KINDS, Centroid, ContactParams, PerSample
from dano.fields import BoxField, SphereField, TransformedField, VoxelField, mesh_field
from dano.sim import DanoObject, compose, make_data
from dano.sim.dynamics import model_with_alpha
from dano._mjx import mjx

R_OBJ = 0.05  # every test object fits in a 5 cm ball


def _voxel_sphere():
    ax = np.linspace(-0.06, 0.06, 17)
    X, Y, Z = np.meshgrid(ax, ax, ax, indexing="ij")
    values = 1.0 / (1 + np.exp((np.sqrt(X**2 + Y**2 + Z**2) - 0.045) / 0.004))
    return VoxelField(jnp.asarray(values), jnp.asarray([-0.06] * 3), jnp.asarray([0.06] * 3))


FIELDS = {
    "sphere": lambda: SphereField(0.045),
    "box": lambda: BoxField((0.035, 0.03, 0.02)),
    "mesh": lambda: mesh_field(trimesh.creation.icosphere(2, radius=0.045), resolution=24),
    "voxel": _voxel_sphere,
    "transformed": lambda: TransformedField.create(BoxField((0.035, 0.03, 0.02)), 0.9, (0.9, 0.3, 0.2, 0.1),
                                                   (0.005, 0.0, 0.0)),
}
PRIMITIVES = {"sphere": '<geom type="sphere" size="0.04"/>',
              "capsule": '<geom type="capsule" size="0.02 0.04"/>',
              "box": '<geom type="box" size="0.04 0.03 0.02"/>'}
KINDS = ("plane", "sphere", "capsule", "box", "dano")
MODELS = (Centroid(), PerSample())


@functools.cache
def asset(field_kind):
    return build(FIELDS[field_kind](), mass=0.2, num_samples=400, mesh_resolution=0, name=field_kind, seed=1)


@functools.cache
def pair_inputs(kind, field_kind, tmp):
    """The inputs of one pair of ``kind`` (DANO A of ``field_kind``) from a composed scene."""
    a = DanoObject("a", asset(field_kind), (0, 0, 1.0))
    if kind == "plane":
        scene = compose([a])
    elif kind == "dano":
        scene = compose([a, DanoObject("b", asset("box"), (1.0, 0, 1.0))])
    else:
        path = f"{tmp}/{kind}.xml"
        with open(path, "w") as f:
            f.write(f"<mujoco><worldbody>{PRIMITIVES[kind]}</worldbody></mujoco>")
        scene = compose([a], path)
    params = scene.default_params()
    m = model_with_alpha(scene, params.alpha)
    d = mjx.fwd_position(m, make_data(scene))
    group = next(g for g in scene.groups if g.kind == kind)
    inputs = PAIR_KINDS[kind].inputs(scene, group, m, d, params.alpha)
    return jax.tree_util.tree_map(lambda x: np.asarray(x[0]), inputs)


def cast(tree, dtype):
    return jax.tree_util.tree_map(lambda x: jnp.asarray(x, dtype) if jnp.issubdtype(jnp.asarray(x).dtype,
                                                                                   jnp.floating) else x, tree)


@functools.partial(jax.jit, static_argnames=("kind",))
def evaluate(kind, inputs, u):
    """ψ, χ, n of the pair and the wrench of each contact model of MODELS, in order (one
    geometry, one compilation for all the models)."""
    g = PAIR_KINDS[kind].geometry(inputs)
    p = cast(ContactParams(), g.psi.dtype)
    return g.psi, g.chi, g.normal, tuple(model.wrench(p, model.prepare(g, 0.01), u) for model in MODELS)


def per_model(kind, inputs, u):
    """[(ψ, χ, n, wrench) of each model of MODELS] as float64 numpy arrays."""
    psi, chi, normal, wrenches = (jax.tree_util.tree_map(lambda x: np.asarray(x, np.float64), y)
                                  for y in evaluate(kind, inputs, u))
    return [(psi, chi, normal, w) for w in wrenches]


def place(inputs, kind, Ra, offset):
    """A at rotation Ra and offset from B's frame origin (for a plane: height above it)."""
    inp = dict(inputs)
    inp["Ra"] = Ra
    inp["xa"] = np.asarray(inputs["xb"]) + offset
    return inp


def moved(inputs, R0, t0):
    inp = dict(inputs)
    for x, R in (("xa", "Ra"), ("xb", "Rb")):
        inp[x] = R0 @ inputs[x] + t0
        inp[R] = R0 @ inputs[R]
    return inp


def swapped(inputs):
    inp = dict(inputs)
    for a, b in (("sa", "sb"), ("fa", "fb"), ("alpha_a", "alpha_b"), ("xa", "xb"), ("Ra", "Rb")):
        inp[a], inp[b] = inputs[b], inputs[a]
    return inp


TOL = {"float64": 1e-8, "float32": 2e-3}
rotations = st.integers(0, 2**31 - 1).map(lambda s: Rotation.random(random_state=s).as_matrix())
unit_vectors = st.integers(0, 2**31 - 1).map(
    lambda s: (lambda v: v / np.linalg.norm(v))(np.random.default_rng(s).normal(size=3)))
cases = settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


@pytest.mark.parametrize("dtype", ["float64", "float32"])
@pytest.mark.parametrize("field_kind", list(FIELDS))
@pytest.mark.parametrize("kind", KINDS)
@cases
@given(Ra=rotations, direction=unit_vectors, distance=st.floats(0.0, 0.2), R0=rotations,
       t0=st.lists(st.floats(-1, 1), min_size=3, max_size=3), u=st.lists(st.floats(-2, 2), min_size=6, max_size=6))
def test_pair_geometry_and_wrench_properties(tmp_path_factory, kind, field_kind, dtype, Ra, direction, distance, R0,
                                             t0, u):
    base = pair_inputs(kind, field_kind, str(tmp_path_factory.getbasetemp()))
    if kind == "plane":
        offset = np.asarray(base["Rb"])[:, 2] * (distance - 0.03)  # from 3 cm deep to well above
    else:
        offset = direction * distance
    inputs = cast(place(base, kind, Ra, offset), dtype)
    u = jnp.asarray(u, dtype)
    tol = TOL[dtype]
    R0_, t0_ = np.asarray(R0), np.asarray(t0)
    u2 = jnp.concatenate([R0_ @ u[:3], R0_ @ u[3:]]).astype(dtype)
    direct, whole_moved = per_model(kind, inputs, u), per_model(kind, cast(moved(inputs, R0_, t0_), dtype), u2)
    if kind == "dano":
        swap, at_rest, swap_at_rest = (per_model(kind, swapped(inputs), -u), per_model(kind, inputs, 0 * u),
                                       per_model(kind, swapped(inputs), 0 * u))
    for m, model in enumerate(MODELS):
        psi, chi, normal, w = direct[m]
        assert np.all(np.isfinite(w)) and np.isfinite(psi)
        assert psi >= 0
        gap = distance - 0.03 - R_OBJ if kind == "plane" else distance - 2 * R_OBJ - 0.01
        if gap > 0:
            assert psi == 0
        if gap > 0.05:  # out of reach within the step (h·|u| < 5 cm): no force either
            assert np.all(w == 0)
        # the whole pair moved and rotated: the same overlap, moved centroid, rotated wrench
        psi2, chi2, normal2, w2 = whole_moved[m]
        scale_w = max(1.0, np.abs(w).max())
        assert psi2 == pytest.approx(psi, rel=tol, abs=tol * 1e-3)
        if psi > 1e-6:
            np.testing.assert_allclose(chi2, R0_ @ chi + t0_, atol=10 * tol)
            np.testing.assert_allclose(normal2, R0_ @ normal, atol=100 * tol)
        np.testing.assert_allclose(w2[:3], R0_ @ w[:3], atol=100 * tol * scale_w)
        np.testing.assert_allclose(w2[3:], R0_ @ w[3:], atol=100 * tol * scale_w)
        if kind == "dano":  # B's wrench is minus A's, for the opposite relative twist
            psi3, chi3, normal3, w3 = swap[m]
            assert psi3 == pytest.approx(psi, rel=tol, abs=tol * 1e-3)
            if psi > 1e-6:
                np.testing.assert_allclose(chi3, chi, atol=10 * tol)
                np.testing.assert_allclose(normal3, -normal, atol=100 * tol)
            np.testing.assert_allclose(w3[:3], -w[:3], atol=100 * tol * scale_w)
            # the torque's implicit lever (the centroid advanced over the step) is taken in
            # B's frame, so it agrees to first order in h·u only; at u = 0 exactly
            w0, w0s = at_rest[m][3], swap_at_rest[m][3]
            np.testing.assert_allclose(w0s, -w0, atol=100 * tol * scale_w)


@pytest.mark.parametrize("dtype", ["float64", "float32"])
@pytest.mark.parametrize("kind", KINDS)
def test_forward_gradients_are_finite_at_rest_onset_and_in_flight(tmp_path_factory, kind, dtype):
    base = pair_inputs(kind, "box", str(tmp_path_factory.getbasetemp()))
    Ra = Rotation.from_euler("xyz", [0.3, -0.2, 0.1]).as_matrix()
    n = np.asarray(base["Rb"])[:, 2] if kind == "plane" else np.array([0.0, 0.0, 1.0])
    pts = Ra @ np.asarray((base["sa"] if kind == "dano" else base["samples"]).points)  # (3, N)
    if kind == "plane":
        touch = -(n @ pts).min()  # lowest sample exactly on the plane
    else:
        touch = 0.06 if kind != "dano" else 0.07
    u = jnp.asarray([0.3, -0.1, -0.5, 1.0, 0.5, -2.0], dtype)
    for height in (touch - 0.005, touch, touch + 0.2):  # resting, onset, free flight
        inputs = cast(place(base, kind, Ra, n * height), dtype)

        def f(xa, u_):  # [ψ, wrench] of each model
            psi, _, _, wrenches = evaluate(kind, {**inputs, "xa": xa}, u_)
            return [jnp.concatenate([psi[None], w]) for w in wrenches]

        Js = jax.jacfwd(f, argnums=(0, 1))(inputs["xa"], u)
        for model, J in zip(MODELS, Js):
            assert all(np.all(np.isfinite(np.asarray(j))) for j in J), (kind, model.name, height)


@pytest.mark.parametrize("kind", KINDS)
def test_pose_linearised_geometry_has_the_direct_derivatives(tmp_path_factory, kind):
    """NewtonConfig(geometry_tangents="pose"): the geometry differentiated along the frames'
    poses (6 or 12 directions) gives the direct JVP's tangents, for tangents of both frames
    (rotations as [δθ]×R) and of the mass scales, in contact (float64)."""
    from dano.contact.base import pose_linearised_geometry

    base = pair_inputs(kind, "box", str(tmp_path_factory.getbasetemp()))
    Ra = Rotation.from_euler("xyz", [0.3, -0.2, 0.1]).as_matrix()
    offset = np.asarray(base["Rb"])[:, 2] * 0.01 if kind == "plane" else np.array([0.0, 0.0, 0.03])
    inputs = cast(place(base, kind, Ra, offset), "float64")
    assert float(PAIR_KINDS[kind].geometry(inputs).psi) > 0
    rng = np.random.default_rng(0)
    fixed_b = kind == "plane"
    alphas = [k for k in inputs if k.startswith("alpha")]

    def tangent():
        t = jax.tree_util.tree_map(jnp.zeros_like, inputs)
        t["xa"], t["Ra"] = jnp.asarray(rng.normal(size=3)), jnp.asarray(np.cross(rng.normal(size=3), np.eye(3)) @ Ra)
        if not fixed_b:
            t["xb"] = jnp.asarray(rng.normal(size=3))
            t["Rb"] = jnp.asarray(np.cross(rng.normal(size=3), np.eye(3)) @ np.asarray(inputs["Rb"]))
        for k in alphas:
            t[k] = jnp.asarray(rng.normal(size=np.shape(inputs[k])))
        return t

    # both JVPs in one program (one compilation)
    both_jvps = jax.jit(lambda i, t: (jax.jvp(PAIR_KINDS[kind].geometry, (i,), (t,)),
                                      jax.jvp(lambda i_: pose_linearised_geometry(PAIR_KINDS[kind], fixed_b, i_),
                                              (i,), (t,))))
    for _ in range(3):
        t = tangent()
        direct, pose = both_jvps(inputs, t)
        for a, b in zip(jax.tree_util.tree_leaves(direct), jax.tree_util.tree_leaves(pose)):
            a, b = np.asarray(a), np.asarray(b)
            np.testing.assert_allclose(b, a, rtol=1e-9, atol=1e-9 * max(1.0, np.abs(a).max()))


@settings(max_examples=25, deadline=None)
@given(kind=st.sampled_from(["sphere", "capsule", "box"]), seed=st.integers(0, 2**31 - 1),
       size=st.tuples(*[st.floats(0.01, 0.5)] * 3))
def test_primitive_sdf_gradients_in_closed_form_are_the_sdfs_derivatives(kind, seed, size):
    # dano.contact.primitive writes ∇sdf out; JAX's derivative of the same sdf, sample by
    # sample, at points inside, outside and near the surface (ties have probability 0)
    from dano.contact.primitive import SDFS

    sdf, grad = SDFS[kind]
    r, h = size[0], size[1]
    extent = {"sphere": (r, r, r), "capsule": (r, r, h + r), "box": size}[kind]  # half-extents of the geom
    size = jnp.asarray(size, dtype=jnp.float64)
    y = jnp.asarray(np.random.default_rng(seed).normal(size=(3, 400)) * np.asarray(extent)[:, None] * 1.5)
    by_jax = jax.vmap(jax.grad(lambda c: sdf(c[:, None], size)[0]), in_axes=1, out_axes=1)(y)
    closed = grad(y, size)
    np.testing.assert_allclose(closed, by_jax, rtol=0, atol=1e-14)
    inside = sdf(y, size) < 0
    assert inside.any() and (~inside).any()
    np.testing.assert_allclose(jnp.linalg.norm(closed, axis=0), 1.0, rtol=1e-14)

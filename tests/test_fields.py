"""Density fields: values, gradients, frames, bad input."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dano.errors import DanoError
from dano.fields import BoxField, SphereField, TransformedField, VoxelField, from_arrays, mesh_field, to_arrays


def grad_density(field, x):
    return jax.vmap(jax.grad(lambda y: field.density(y[None])[0]))(jnp.asarray(x))


def test_sphere_values_and_finite_gradient_at_centre():
    f = SphereField(0.5, edge_width=0.01)
    phi = f.density(jnp.array([[0.0, 0, 0], [0.5, 0, 0], [2.0, 0, 0]]))
    np.testing.assert_allclose(phi, [1.0, 0.5, 0.0], atol=1e-12)
    g = grad_density(f, [[0.0, 0.0, 0.0], [0.5, 0, 0]])
    assert np.all(np.isfinite(g))
    assert g[1, 0] < 0 and abs(g[1, 1]) < 1e-12  # density falls outward along +x


def test_box_gradient_finite_everywhere_including_centre_and_corners():
    f = BoxField((0.1, 0.2, 0.3))
    x = np.array([[0.0, 0, 0], [0.1, 0.2, 0.3], [0.1, 0, 0], [0.5, 0.5, 0.5]])
    assert np.all(np.isfinite(grad_density(f, x)))


def test_density_rejects_wrong_point_shapes():
    with pytest.raises(DanoError, match=r"shape \(N, 3\)"):
        SphereField(1.0).density(jnp.zeros((4, 2)))


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda: SphereField(-1.0), "radius"),
        (lambda: BoxField((0.1, 0.0, 0.1)), "half_extents"),
        (lambda: VoxelField.create(np.full((4, 4, 4), np.nan), [[0, 0, 0], [1, 1, 1]]), "NaN"),
        (lambda: VoxelField.create(-np.ones((4, 4, 4)), [[0, 0, 0], [1, 1, 1]]), "non-negative"),
        (lambda: VoxelField.create(np.ones((4, 4)), [[0, 0, 0], [1, 1, 1]]), "3-D"),
        (lambda: VoxelField.create(np.ones((4, 4, 4)), [[0, 0, 0], [1, 1]]), r"\(2, 3\)"),
        (lambda: TransformedField.create(SphereField(1.0), scale=0.0), "scale"),
    ],
)
def test_bad_field_parameters_are_refused(make, message):
    with pytest.raises(DanoError, match=message):
        make()


def test_voxel_field_interpolates_trilinearly_and_ramps_to_zero_outside():
    values = np.zeros((2, 2, 2))
    values[1, :, :] = 2.0  # linear in x from 0 to 2 over [0, 1]
    f = VoxelField.create(values, [[0, 0, 0], [1, 1, 1]])
    x = jnp.array([[0.25, 0.5, 0.5], [0.5, 0.1, 0.9], [1.5, 0.5, 0.5], [2.0, 0.5, 0.5], [0.5, 0.5, -1.5]])
    np.testing.assert_allclose(f.density(x), [0.5, 1.0, 1.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(f.bounds(), [[-1, -1, -1], [2, 2, 2]])


@settings(max_examples=25, deadline=None)
@given(
    scale=st.floats(0.2, 5.0),
    quat=st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(lambda q: np.linalg.norm(q) > 0.1),
    offset=st.lists(st.floats(-2, 2), min_size=3, max_size=3),
    x=st.lists(st.floats(-1, 1), min_size=3, max_size=3),
)
def test_transformed_field_maps_points_consistently(scale, quat, offset, x):
    base = BoxField((0.3, 0.2, 0.1), edge_width=0.05)
    f = TransformedField.create(base, scale, quat, offset)
    R = np.asarray(f.rotation)
    x = np.asarray(x)
    world = scale * (R @ x) + np.asarray(offset)
    np.testing.assert_allclose(f.density(world[None]), base.density(x[None]), rtol=1e-9, atol=1e-12)
    b = f.bounds()
    assert np.all(b[0] <= world + 1e-9) or not np.all(np.abs(x) <= base.bounds()[1])


def test_field_serialisation_round_trip(shared):
    fields = [
        mesh_field(shared / "meshes" / "bunny_lowpoly.obj", resolution=24),
        SphereField(0.4, 0.01, 2.0, (0.1, 0.0, 0.0)),
        BoxField((0.1, 0.2, 0.3)),
        VoxelField.create(np.random.default_rng(0).random((5, 6, 7)), [[0, 0, 0], [1, 2, 3]]),
        TransformedField.create(SphereField(0.4), 2.0, (0.9, 0.1, 0.0, 0.3), (1, 2, 3)),
    ]
    pts = jnp.asarray(np.random.default_rng(1).uniform(-1, 3, (50, 3)))
    for f in fields:
        g = from_arrays(to_arrays(f))
        np.testing.assert_allclose(g.density(pts), f.density(pts), rtol=1e-12, atol=1e-14)


def test_mesh_field_is_inside_out_consistent(shared):
    f = mesh_field(shared / "meshes" / "bunny_lowpoly.obj", resolution=48)
    lo, hi = f.bounds()
    assert f.density(jnp.asarray([lo, hi])).max() < 1e-6  # corners: outside
    # the sign of the distance agrees with libigl's winding number on random points
    import igl
    import trimesh

    mesh = trimesh.load(shared / "meshes" / "bunny_lowpoly.obj", process=False)
    pts = np.random.default_rng(0).uniform(lo, hi, (2000, 3))
    wn = igl.winding_number(np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64), pts)
    sd = np.asarray(f.signed_distance(jnp.asarray(pts)))
    far = np.abs(sd) > 0.03  # away from the surface, where interpolation cannot flip the sign
    assert np.all((sd[far] < 0) == (np.abs(wn[far]) > 0.5))


def test_non_watertight_mesh_is_refused(shared):
    with pytest.raises(DanoError, match="bunny_high.obj: mesh is not watertight"):
        mesh_field(shared / "dano" / "bunny_high.obj")

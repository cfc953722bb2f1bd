"""Mass properties against exact references (issue: within 0.5 % analytic, 1 % mesh)."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh

from dano.asset import mass_properties
from dano.errors import DanoError
from dano.fields import BoxField, SphereField, mesh_field


def rel(a, b):
    return np.max(np.abs(np.asarray(a) - np.asarray(b))) / np.max(np.abs(b))


@pytest.mark.parametrize("method", ["sobol", "grid"])
def test_sphere_exact(method):
    R, rho, alpha = 0.5, 3.0, 2.0
    f = SphereField(R, edge_width=0.005, density_scale=rho, center=(0.2, -0.1, 0.3))
    mp = mass_properties(f, alpha=alpha, method=method)
    m = alpha * rho * 4 / 3 * np.pi * R**3
    assert abs(mp.mass / m - 1) < 0.005
    assert np.max(np.abs(mp.center_of_mass - [0.2, -0.1, 0.3])) < 0.005 * 2 * R
    assert rel(mp.inertia, 0.4 * m * R**2 * np.eye(3)) < 0.005


@pytest.mark.parametrize("method", ["sobol", "grid"])
def test_box_exact(method):
    h = np.array([0.1, 0.25, 0.4])
    f = BoxField(tuple(h), edge_width=0.001, center=(1.0, 2.0, 3.0))
    mp = mass_properties(f, mass=2.5, method=method)
    m = 2.5
    J = m / 3 * np.diag([h[1] ** 2 + h[2] ** 2, h[0] ** 2 + h[2] ** 2, h[0] ** 2 + h[1] ** 2])
    assert mp.mass == pytest.approx(m)
    assert mp.alpha == pytest.approx(m / (8 * h.prod()), rel=0.005)
    assert np.max(np.abs(mp.center_of_mass - [1, 2, 3])) < 0.005 * 2 * h.max()
    assert rel(mp.inertia, J) < 0.005
    np.testing.assert_allclose(mp.principal_moments, np.sort(np.diag(J)), rtol=0.005)


def test_error_estimate_covers_actual_error():
    f = SphereField(0.5, edge_width=0.02)
    exact = 4 / 3 * np.pi * (0.5**3 + np.pi**2 * 0.02**2 * 0.5)  # logistic-edge sphere to 2nd order
    mp = mass_properties(f, num_points=1 << 16, seed=3)
    assert 0 < mp.mass_std < 1e-2 * mp.mass
    assert abs(mp.mass - exact) < 5 * mp.mass_std + 1e-5 * exact


def test_spot_mesh_matches_trimesh_exact_properties(shared):
    mesh = trimesh.load(shared / "meshes" / "spot.obj", process=False)
    mesh.merge_vertices(merge_tex=True, merge_norm=True)
    assert mesh.is_watertight and mesh.euler_number == 2
    f = mesh_field(mesh)
    mp = mass_properties(f, mass=mesh.volume * 1000.0)  # water density: 1000 kg/m³
    extent = mesh.extents.max()
    assert mp.alpha == pytest.approx(1000.0, rel=0.01)
    assert np.max(np.abs(mp.center_of_mass - mesh.center_mass)) / extent < 0.01
    assert rel(mp.inertia, mesh.moment_inertia * 1000.0) < 0.01


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(alpha=1.0, mass=1.0), "either alpha or mass"),
        (dict(alpha=-1.0), "alpha must be"),
        (dict(mass=float("nan")), "mass must be"),
        (dict(method="trapezoid"), "unknown integration method"),
    ],
)
def test_bad_arguments(kwargs, message):
    with pytest.raises(DanoError, match=message):
        mass_properties(SphereField(0.5), **kwargs)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class ConstantHalfSpace:
    """A user-defined field: ``value`` for x > 0, else 0."""

    value: float

    def density(self, points):
        return jnp.where(points[:, 0] > 0, self.value, 0.0)

    def bounds(self):
        return np.array([[-1.0, -1, -1], [1, 1, 1]])


@pytest.mark.parametrize("value, message", [(np.nan, "NaN"), (-1.0, "negative"), (0.0, "integrates to zero")])
def test_nan_negative_and_zero_fields_are_refused(value, message):
    with pytest.raises(DanoError, match=message):
        mass_properties(ConstantHalfSpace(value), num_points=4096)

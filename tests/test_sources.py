"""A DANO from any source at the size the user states (`dano build --scale/--size`):
lengths scale exactly, volumes and masses at fixed density as the cube."""

import numpy as np
import pytest

from dano.errors import DanoError
from dano.sources import build_from_source, occupied_extent

from .conftest import sphere_voxels


@pytest.mark.parametrize("size", [0.2, 1.5])
def test_mesh_size_sets_the_longest_extent(shared, size):
    mesh = shared / "meshes" / "bunny_lowpoly.obj"
    asset = build_from_source(mesh, size=size, mass=0.7, resolution=48, samples=500).asset
    assert asset.name == "bunny_lowpoly"
    s = asset.summary()
    assert max(s["extents"]) == pytest.approx(size, rel=0.03)  # marching cubes at 48 nodes
    assert asset.mass == pytest.approx(0.7)


def test_voxel_scale_scales_lengths_and_mass(tmp_path):
    path = sphere_voxels(tmp_path / "sphere.npz", radius=0.3, n=33)
    plain = build_from_source(path, samples=500).asset
    scaled = build_from_source(path, scale=2.0, samples=500).asset
    # a uniformly scaled density keeps its values: mass (alpha = 1) grows as the cube, inertia as the fifth power
    assert scaled.mass == pytest.approx(8.0 * plain.mass, rel=1e-3)
    assert np.trace(scaled.inertia) == pytest.approx(32.0 * np.trace(plain.inertia), rel=1e-3)
    sized = build_from_source(path, size=0.1, samples=500)
    assert occupied_extent(sized.field) == pytest.approx(0.1, rel=1e-9)


def test_scale_and_size_refused_where_they_do_not_apply(tmp_path, shared):
    path = sphere_voxels(tmp_path / "sphere.npz")
    with pytest.raises(DanoError, match="either --scale or --size"):
        build_from_source(path, scale=2.0, size=0.1)
    with pytest.raises(DanoError, match="--scale must be a finite positive number"):
        build_from_source(path, scale=-1.0)
    with pytest.raises(DanoError, match="do not apply to a .jld2"):
        build_from_source(shared / "dano" / "bunny.jld2", size=0.1)

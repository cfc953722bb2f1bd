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
    # --field-scale is --scale for a trained field: both would multiply (a new user's 0.12 mm object)
    with pytest.raises(DanoError, match="either --field-scale or --scale/--size"):
        build_from_source(path, scale=0.001, field_scale=0.5)


def test_build_warns_of_a_mesh_in_millimetres(tmp_path, capsys):
    """`dano build` of a mesh written in millimetres with its mass in kg: the mean density is
    implausible, so build warns as `dano inspect` does (the warning on stderr, the JSON's
    "warnings"), naming --scale 0.001; with --scale 0.001 it does not."""
    import json

    import trimesh

    from dano.cli import main

    mesh = tmp_path / "bracket_mm.stl"
    trimesh.creation.box((100.0, 50.0, 30.0)).export(mesh)  # 0.1 x 0.05 x 0.03 m written in mm
    common = ["build", str(mesh), "--mass", "0.05", "--resolution", "16", "--samples", "200", "--quiet", "--json"]
    assert main([*common, "-o", str(tmp_path / "mm.dano")]) == 0
    cap = capsys.readouterr()
    (warning,) = json.loads(cap.out)["warnings"]
    assert "mean density" in warning and "--scale 0.001" in cap.err and "mean density" in cap.err
    assert main([*common, "--scale", "0.001", "-o", str(tmp_path / "m.dano")]) == 0
    cap = capsys.readouterr()
    assert json.loads(cap.out)["warnings"] == [] and "warning" not in cap.err


def test_up_turns_a_y_up_mesh_onto_its_feet(shared):
    """--up y: the mesh's +y (Spot's and the Stanford bunny's up) becomes +z, its -z faces +y."""
    mesh = shared / "meshes" / "bunny_lowpoly.obj"
    plain = build_from_source(mesh, size=0.2, mass=0.7, resolution=32, samples=500)
    upright = build_from_source(mesh, size=0.2, mass=0.7, resolution=32, samples=500, up="y")
    R = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])
    a, b = plain.asset, upright.asset
    # the same object turned (the signed-distance grid is laid out anew in the turned frame: equal to
    # integration error, 0.06 mm in the centre of mass of a 0.2 m object, not exactly)
    assert b.center_of_mass == pytest.approx(R @ a.center_of_mass, abs=1e-4)
    assert b.inertia == pytest.approx(R @ a.inertia @ R.T, rel=0.01, abs=1e-7)
    assert np.ptp(b.points, 0) == pytest.approx(np.abs(R) @ np.ptp(a.points, 0), rel=0.02)
    assert b.mass == pytest.approx(0.7) and b.name == "bunny_lowpoly"


@pytest.mark.parametrize("up", ["x", "y", "z", "-x", "-y", "+y", "-z"])
def test_up_turns_a_voxel_grid_exactly(tmp_path, up):
    from dano.fields import VoxelField
    from dano.sources import rotate_grid, up_rotation

    rng = np.random.default_rng(0)
    grid = VoxelField.create(rng.random((4, 5, 6)), [[-0.1, -0.2, -0.3], [0.2, 0.3, 0.4]])
    R = up_rotation(up)
    axis = np.zeros(3)
    axis["xyz".index(up[-1])] = -1.0 if up.startswith("-") else 1.0
    assert R @ axis == pytest.approx([0, 0, 1]) and np.linalg.det(R) == pytest.approx(1.0)
    points = rng.uniform([-0.1, -0.2, -0.3], [0.2, 0.3, 0.4], (64, 3))
    turned = rotate_grid(grid, R)
    assert np.asarray(turned.density(points @ R.T)) == pytest.approx(np.asarray(grid.density(points)), abs=1e-12)
    path = tmp_path / "block.npz"
    np.savez(path, density=np.asarray(grid.values), bounds=grid.node_bounds)
    built = build_from_source(path, up=up, samples=200)
    assert built.asset.name == "block" and np.asarray(built.field.values) == pytest.approx(np.asarray(turned.values))


def test_bad_up_refused_naming_the_option(tmp_path, shared, capsys):
    from dano.cli import main

    mesh = shared / "meshes" / "bunny_lowpoly.obj"
    code = main(["build", str(mesh), "-o", str(tmp_path / "b.dano"), "--up", "w"])
    err = capsys.readouterr().err
    assert code == 1 and "--up 'w': must be the source's axis that points up: z, y, x, -z, -y, -x" in err, err
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(DanoError, match="--up do not apply to a .jld2"):
        build_from_source(shared / "dano" / "bunny.jld2", up="y")

"""An asset built in Python from a bare field is named as ``dano build`` names it: after the
source file's stem (mesh_field, voxel grids read from files), else after the field's kind; the
name reaches tables, scenes and exports, and is not part of the field's pytree."""

import dataclasses

import jax
import numpy as np
import pytest

import dano
from dano.errors import DanoError
from dano.fields import BoxField, SphereField, TransformedField, VoxelField, field_name, mesh_field
from dano.fields.mesh import load_mesh

SMALL = {"num_samples": 200, "integration_points": 4096, "mesh_resolution": 12}


def test_mesh_field_asset_is_named_after_the_file(shared, tmp_path):
    path = shared / "meshes" / "bunny_lowpoly.obj"
    field = mesh_field(path, resolution=16)
    assert field.name == "bunny_lowpoly"
    asset = dano.build(field, mass=0.7, **SMALL)
    assert asset.name == "bunny_lowpoly"
    assert dano.build(field, mass=0.7, name="toy", **SMALL).name == "toy"  # an explicit name wins
    # scaled into metres, it keeps the name; a Trimesh loaded from the file too
    assert TransformedField.create(field, scale=0.2).name == "bunny_lowpoly"
    assert mesh_field(load_mesh(path), resolution=16).name == "bunny_lowpoly"
    # what a new user sees: the export's body, a scene's DANO (parse_object), the saved file
    from dano.io import export

    export(asset, tmp_path / "b.xml")
    assert '<body name="bunny_lowpoly"' in (tmp_path / "b.xml").read_text()
    dano.save(asset, tmp_path / "saved.dano")
    assert dano.load(tmp_path / "saved.dano").name == "bunny_lowpoly"


def test_analytic_and_grid_fields_are_named_after_their_kind(tmp_path):
    assert dano.build(SphereField(0.05), mass=0.1, **SMALL).name == "sphere"
    assert dano.build(BoxField((0.05, 0.05, 0.02)), mass=0.1, **SMALL).name == "box"
    values = np.zeros((6, 6, 6))
    values[1:5, 1:5, 1:5] = 1.0
    bounds = np.array([[-0.05] * 3, [0.05] * 3])
    assert VoxelField.create(values, bounds).name == "voxel"
    np.savez(tmp_path / "block.npz", density=values, bounds=bounds)
    loaded = VoxelField.load(tmp_path / "block.npz")
    assert loaded.name == "block" and dano.build(loaded, mass=0.1, **SMALL).name == "block"

    @jax.tree_util.register_dataclass
    @dataclasses.dataclass(frozen=True)
    class TorusField:  # a user's field without a name
        def density(self, points):
            return SphereField(0.05).density(points)

        def bounds(self):
            return SphereField(0.05).bounds()

    assert field_name(TorusField()) == "torus"
    assert dano.build(TorusField(), mass=0.1, **SMALL).name == "torus"


def test_name_is_not_part_of_the_pytree():
    """Fields of one structure share compilations and DANO-DANO pair groups whatever they are
    called; transformations give back the kind's name, the field itself keeps its own."""
    a, b = SphereField(0.05), SphereField(0.05).named("ball")
    assert (a.name, b.name) == ("sphere", "ball")
    assert jax.tree_util.tree_structure(a) == jax.tree_util.tree_structure(b)
    assert jax.tree_util.tree_map(lambda x: x, b).name == "sphere" and b.name == "ball"
    assert float(jax.jit(lambda f: f.density(np.zeros((1, 3)))[0])(b)) > 0.99
    for bad in ("", "  ", None):
        with pytest.raises(DanoError, match="name must be a non-empty string"):
            a.named(bad)


def test_a_dano_file_saved_without_a_name_loads_named_after_the_file(tmp_path):
    asset = dataclasses.replace(dano.build(SphereField(0.05), mass=0.1, **SMALL), name="")
    dano.save(asset, tmp_path / "marble.dano")
    assert dano.load(tmp_path / "marble.dano").name == "marble"

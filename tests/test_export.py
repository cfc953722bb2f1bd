"""Export to MJCF/URDF (MuJoCo and a URDF parser read back the .dano's mass properties) and
the mesh route measured against the DANO (compare-mesh)."""

import json

import mujoco
import numpy as np
import pytest
import trimesh

import dano
from dano.cli import main
from dano.errors import DanoError
from dano.fields import BoxField, mesh_field
from dano.io.exporters import Decomposition, add_to_spec, body_meshes, export


def _inertia(m: mujoco.MjModel, b: int) -> np.ndarray:
    R = np.zeros(9)
    mujoco.mju_quat2Mat(R, m.body_iquat[b])
    R = R.reshape(3, 3)
    return R @ np.diag(m.body_inertia[b]) @ R.T


def _check_mass_properties(m: mujoco.MjModel, body: str, asset) -> None:
    b = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, body)
    assert b > 0
    assert abs(m.body_mass[b] - asset.mass) <= 1e-9 * asset.mass
    assert np.abs(m.body_ipos[b]).max() <= 1e-9  # body frame: origin at the centre of mass
    assert np.abs(_inertia(m, b) - asset.inertia).max() <= 1e-9 * np.abs(asset.inertia).max()


@pytest.fixture(scope="module")
def spot(shared):
    field = mesh_field(shared / "meshes" / "spot.obj", resolution=48)
    return dano.build(field, mass=1.3, num_samples=2000, integration_points=1 << 16, mesh_resolution=48, name="spot")


@pytest.mark.parametrize("which", ["bunny", "spot"])
def test_export_round_trip_mjcf_and_urdf(which, spot, tmp_path):
    import yourdfpy

    asset = dano.load_builtin("bunny") if which == "bunny" else spot
    for suffix in (".xml", ".urdf"):
        path = export(asset, tmp_path / f"{which}{suffix}", collision="hull")
        m = mujoco.MjModel.from_xml_path(str(path))
        _check_mass_properties(m, asset.name, asset)
        colliding = (m.geom_contype | m.geom_conaffinity) != 0
        assert m.ngeom == 2 and colliding.sum() == 1  # the visual mesh and one convex hull
        hull = body_meshes(asset, "hull").collision[0]
        assert hull.is_convex and hull.is_watertight
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        [f"{which}.xml", f"{which}.urdf", f"{which}_meshes"])
    urdf = yourdfpy.URDF.load(str(tmp_path / f"{which}.urdf"))
    inertial = urdf.link_map[asset.name].inertial
    assert abs(inertial.mass - asset.mass) <= 1e-9 * asset.mass
    assert np.abs(np.asarray(inertial.inertia) - asset.inertia).max() <= 1e-9 * np.abs(asset.inertia).max()
    assert np.abs(inertial.origin[:3, 3]).max() == 0.0


def test_urdf_body_gets_a_free_joint_in_mujoco(tmp_path):
    asset = dano.load_builtin("bunny")
    path = export(asset, tmp_path / "bunny.urdf")
    spec = mujoco.MjSpec.from_file(str(path))
    spec.body("bunny").add_freejoint()
    m = spec.compile()
    d = mujoco.MjData(m)
    d.qpos[2] = 1.0
    mujoco.mj_step(m, d)
    assert d.qvel[2] < 0  # it falls
    _check_mass_properties(m, "bunny", asset)


def test_add_to_spec_equals_the_exported_mjcf(tmp_path):
    asset = dano.load_builtin("bunny_lowpoly")
    meshes = body_meshes(asset, "hull")
    spec = mujoco.MjSpec()
    add_to_spec(spec, asset, "obj", meshes=meshes, pos=(0.1, 0.2, 0.3))
    m1 = spec.compile()
    m2 = mujoco.MjModel.from_xml_path(str(export(asset, tmp_path / "obj.xml", meshes=meshes, name="obj")))
    for m in (m1, m2):
        _check_mass_properties(m, "obj", asset)
    assert m1.ngeom == m2.ngeom == 2 and m1.nmeshvert == m2.nmeshvert
    np.testing.assert_allclose(m1.mesh_vert, m2.mesh_vert, atol=1e-8)


def test_decomposition_pieces_are_convex_and_fill_the_mesh(tmp_path):
    asset = dano.load_builtin("bunny_lowpoly")
    meshes = body_meshes(asset, "decomposition", decomposition=Decomposition(threshold=0.3, preprocess_resolution=20))
    pieces = meshes.collision
    assert len(pieces) >= 2
    assert all(p.is_convex for p in pieces)
    visual = trimesh.Trimesh(asset.mesh_vertices, asset.mesh_faces)
    # the pieces cover the solid: their total volume is at least the mesh's and far below its hull's
    total = sum(p.volume for p in pieces)
    assert visual.volume <= total < visual.convex_hull.volume
    m = mujoco.MjModel.from_xml_path(str(export(asset, tmp_path / "b.xml", meshes=meshes)))
    assert int(np.sum(m.geom_group == 3)) == len(pieces)


def test_level_set_from_the_field(tmp_path):
    asset = dano.load_builtin("bunny_lowpoly")  # queryable: signed-distance field of the mesh
    low = body_meshes(asset, "hull", level=0.05, resolution=32).collision[0]
    high = body_meshes(asset, "hull", level=0.95, resolution=32).collision[0]
    assert low.volume > high.volume  # a lower density level lies further out
    with pytest.raises(DanoError, match="density field"):
        body_meshes(dano.load_builtin("bluesoap"), "hull", level=50.0)
    with pytest.raises(DanoError, match="no visual mesh"):  # a decomposition needs a surface
        body_meshes(dano.load_builtin("bluesoap"), "decomposition")
    # without a mesh the hull is the boundary samples' (issue 30: a .jld2 collider exports by default)
    assert body_meshes(dano.load_builtin("bluesoap"), "hull").source == "convex hull of the boundary samples"


def test_export_errors_leave_nothing(tmp_path):
    asset = dano.load_builtin("bunny")
    with pytest.raises(DanoError, match="unknown export format"):
        export(asset, tmp_path / "bunny.sdf")
    with pytest.raises(DanoError, match="unknown collision mode"):
        export(asset, tmp_path / "bunny.xml", collision="sphere")
    assert list(tmp_path.iterdir()) == []
    code = main(["export", "builtin:bluesoap", "-o", str(tmp_path / "soap.urdf"), "--collision", "decomposition"])
    assert code == 1 and list(tmp_path.iterdir()) == []


def test_export_cli_json(tmp_path, capsys):
    code = main(["export", "builtin:bunny", "-o", str(tmp_path / "b.xml"), "--collision", "none", "--json"])
    assert code == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["pieces"] == 0 and summary["format"] == "mjcf"
    assert summary["mass"] == dano.load_builtin("bunny").mass


@pytest.mark.slow
def test_convex_object_agrees_across_engines(tmp_path, capsys):
    """A box DANO and the convex hull of its own level set: the mesh route in MuJoCo C and the
    DANO in dano must agree (mass properties, rest height, tilt, slide) - a check of the
    comparison itself on an object where the mesh route is exact."""
    h = 0.1048 / 2
    box = dano.build(BoxField((h, h, 0.6 * h)), mass=0.37, num_samples=3000, integration_points=1 << 18,
                     mesh_resolution=40, name="box")
    path = tmp_path / "box.dano"
    dano.save(box, path)
    code = main(["compare-mesh", str(path), "--levels", "0.5", "--collision", "hull", "--rest-time", "1.5",
                 "--slide-time", "1.0", "--json", "--quiet", "--figure", str(tmp_path / "fig.png")])
    assert code == 0
    report = json.loads(capsys.readouterr().out)
    r = report["levels"][0]["collision"]["hull"]
    assert report["levels"][0]["components"] == 1 and report["levels"][0]["watertight"]
    assert abs(r["mass_error"]) < 0.03  # the φ = 0.5 level encloses the box's volume
    assert r["com_error"] < 1e-3 and r["inertia_error"] < 0.05
    assert abs(r["rest_height_error"]) < 2e-3  # dano's contact at the surface (issue 7): same face, same height
    assert r["rest_tilt_deg"] < 1.0
    # Coulomb slide from 1 m/s with friction 0.2: v²/(2μg) = 0.255 m in both engines
    assert abs(report["dano"]["slide_distance"] - 1 / (2 * 0.2 * 9.81)) < 0.02
    assert r["slide_divergence"] < 0.02
    assert (tmp_path / "fig.png").stat().st_size > 10_000


def test_write_errors_name_the_output_not_a_temporary_file(tmp_path, capsys):
    blocker = tmp_path / "afile"
    blocker.write_text("")
    out = blocker / "x.xml"
    assert main(["export", "builtin:bunny", "-o", str(out)]) == 1
    err = " ".join(capsys.readouterr().err.split())
    assert err.startswith(f"error: {out}: cannot write") and ".x." not in err


def test_the_compare_mesh_table_shows_the_mass_error():
    """`dano compare-mesh`'s table has the mass error column of docs/mesh-route.md (the JSON's
    ``mass_error``; "-" where the source has no interior density to define it)."""
    from rich.console import Console

    from dano._tables import compare_table

    row = {"pieces": 1, "com_error": 0.041, "inertia_error": 0.161, "rest_height_error": -0.0005,
           "rest_tilt_deg": 0.21, "slide_divergence": 0.008}
    report = {"source": "bunny", "dano": {"rest_height": 0.2981, "slide_distance": 0.2617},
              "levels": [{"label": "φ = 0.5", "components": 1,
                          "collision": {"hull": {**row, "mass_error": 0.56}, "decomposition": {**row, "mass_error": None}}}]}
    console = Console(width=200, record=True)
    console.print(compare_table(report))
    text = console.export_text()
    assert "mass err" in text and "+56 %" in text
    hull, decomposition = (line for line in text.splitlines() if "0.0410" in line)
    assert "+56 %" in hull and "+56 %" not in decomposition and " - " in decomposition

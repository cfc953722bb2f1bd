"""`dano export` keeps what was identified (--params result.json → MuJoCo geom friction) and
exports a DANO without a mesh (the paper's .jld2 colliders) with the boundary samples' hull."""

import json
import xml.etree.ElementTree as ET

import mujoco
import numpy as np
import pytest

from dano.cli import main
from dano.data import load_builtin
from dano.errors import DanoError, FileFormatError
from dano.io.exporters import export, read_contact_params
from dano.sysid import SysIdResult


def test_identified_friction_reaches_mujoco(tmp_path, capsys):
    result = tmp_path / "result.json"
    result.write_text(json.dumps({"bunny/ground:sliding_friction": 0.42, "rolling_friction": 0.003,
                                  "impact_spring": 3e4, "rms_residual": 1e-3}))
    out = tmp_path / "bunny.xml"
    assert main(["export", "builtin:bunny_lowpoly", "-o", str(out), "--params", str(result), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["friction"] == [0.42, 0.005, 0.003]
    m = mujoco.MjModel.from_xml_path(str(out))
    collision = [g for g in range(m.ngeom) if m.geom_contype[g] or m.geom_conaffinity[g]]
    assert collision and all(np.allclose(m.geom_friction[g], [0.42, 0.005, 0.003]) for g in collision)
    text = out.read_text()
    assert "Not carried: impact_spring" in text  # said, not silently dropped
    # on a floor of MuJoCo's default friction (1), the contact takes the identified friction:
    # the exported geoms have priority (MuJoCo otherwise takes the larger of the two geoms')
    spec = mujoco.MjSpec.from_file(str(out))
    spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_PLANE, size=[1, 1, 0.1])
    floor = spec.compile()
    data = mujoco.MjData(floor)
    mujoco.mj_forward(floor, data)  # (the bunny's centre of mass at the floor: half of it below)
    assert data.ncon > 0 and np.allclose(data.contact.friction[:, :3], [0.42, 0.42, 0.005]), data.contact.friction
    exported = [g for g in range(floor.ngeom) if floor.geom_bodyid[g] == 1 and floor.geom_contype[g]]
    assert exported and all(floor.geom_priority[g] == 1 for g in exported)
    assert "condim stays MuJoCo's 3" in " ".join(text.split())
    # only the sliding friction identified (as a sysid result.json often has): the comment still
    # says that the spring, damper and drags do not cross over (docs/own-object.md)
    result.write_text(json.dumps({"sliding_friction": 0.5, "rms_residual": 1e-3}))
    assert main(["export", "builtin:bunny_lowpoly", "-o", str(out), "--params", str(result)]) == 0
    text = " ".join(out.read_text().split())
    assert "friction = sliding_friction identified by dano (the rest: MuJoCo defaults)" in text
    assert "contact spring, damper and drags act on the density overlap psi" in text


def test_an_identifications_answer_exports_from_python(tmp_path):
    """``export(asset, path, contact=...)`` takes what ``identify`` returns, or its
    ``as_dict()`` (estimates under "parameters"). A new user passed ``as_dict()`` and got
    MuJoCo's default friction with no error: the export's comment said "none identified", and
    the exported object slid 0.055 m where the recording slid 0.105. A table with no contact
    parameter is refused and nothing is written."""
    asset = load_builtin("bunny_lowpoly")
    answer = SysIdResult(labels=["sliding_friction", "slide_1:vx"], estimates=np.array([0.5055, 1.02]),
                         standard_errors=np.array([0.01, 0.02]), initial=np.array([0.3, 1.0]), cost_history=[],
                         final_cost=1e-3, rms_residual=2e-3, num_residuals=60, nfev=10, njev=10, wall_time_s=1.0,
                         compile_time_s=0.0, success=True, message="", jacobian="ad")
    for contact in (answer, answer.as_dict()):
        out = export(asset, tmp_path / "identified.xml", contact=contact)
        m = mujoco.MjModel.from_xml_path(str(out))
        collision = [g for g in range(m.ngeom) if m.geom_contype[g] or m.geom_conaffinity[g]]
        assert collision and all(np.allclose(m.geom_friction[g], [0.5055, 0.005, 0.0001]) for g in collision)
        assert all(m.geom_priority[g] == 1 for g in collision)
    # NumPy's and JAX's scalars are numbers too (a review found np.float32 dropped without a word)
    import jax.numpy as jnp

    for value in (np.float32(0.5), jnp.asarray(0.5), np.int64(1)):
        out = export(asset, tmp_path / "scalar.xml", contact={"sliding_friction": value, "rolling_friction": 0.001})
        m = mujoco.MjModel.from_xml_path(str(out))
        g = next(g for g in range(m.ngeom) if m.geom_contype[g] or m.geom_conaffinity[g])
        assert np.allclose(m.geom_friction[g], [float(value), 0.005, 0.001]), (value, m.geom_friction[g])
    assert export(asset, tmp_path / "defaults.xml", contact={}).exists()  # {} as None: MuJoCo's defaults
    with pytest.raises(DanoError, match="no contact parameter found"):
        export(asset, tmp_path / "none.xml", contact={"parameters": {"slide_1:vx": 1.0}, "rms_residual": 1e-3})
    assert not (tmp_path / "none.xml").exists()


def test_ambiguous_or_missing_parameters_refused(tmp_path):
    two = tmp_path / "two.json"
    two.write_text(json.dumps({"a/ground:sliding_friction": 0.3, "b/ground:sliding_friction": 0.5}))
    with pytest.raises(FileFormatError, match="several pairs"):
        read_contact_params(two)
    none = tmp_path / "none.json"
    none.write_text(json.dumps({"rms_residual": 0.1}))
    with pytest.raises(FileFormatError, match="no contact parameter"):
        read_contact_params(none)


def test_paper_collider_exports_with_the_samples_hull(tmp_path):
    asset = load_builtin("bunny")
    stripped = asset.__class__(**{**{k: getattr(asset, k) for k in asset.__dataclass_fields__},
                                  "mesh_vertices": np.zeros((0, 3)), "mesh_faces": np.zeros((0, 3), dtype=np.int64)})
    path = export(stripped, tmp_path / "bunny.xml")  # default collision: hull
    m = mujoco.MjModel.from_xml_path(str(path))  # compiles
    assert m.body_mass[1] == pytest.approx(asset.mass)
    meshes = ET.parse(path).getroot().find("asset").findall("mesh")
    collision = [e for e in meshes if "collision" in e.get("name")]
    assert len(collision) == 1
    verts = np.array(collision[0].get("vertex").split(), dtype=float).reshape(-1, 3)
    # every vertex of the hull is a boundary sample (body frame), and the extreme samples are on it
    dist = np.min(np.linalg.norm(verts[:, None] - asset.points[None], axis=-1), axis=1)
    assert len(verts) >= 4 and np.max(dist) < 1e-8
    assert np.allclose(verts.max(0), asset.points.max(0)) and np.allclose(verts.min(0), asset.points.min(0))

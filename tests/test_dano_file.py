"""The .dano file: round trip, versioning, bad files, atomic writes."""

import json
import zipfile

import numpy as np
import pytest

from dano.asset import DanoAsset, build, load, save
from dano.errors import DanoError, FileFormatError
from dano.fields import SphereField


@pytest.fixture(scope="module")
def sphere_asset():
    return build(SphereField(0.2, center=(0.0, 0.1, 0.0)), mass=1.5, num_samples=300, mesh_resolution=24,
                 name="ball", source="test")


def test_round_trip_keeps_everything(tmp_path, sphere_asset):
    path = save(sphere_asset, tmp_path / "ball.dano")
    back = load(path)
    for name in ("center_of_mass", "inertia", "points", "normals", "densities", "weights", "band",
                 "mesh_vertices", "mesh_faces"):
        np.testing.assert_array_equal(getattr(back, name), getattr(sphere_asset, name))
    assert back.mass == sphere_asset.mass and back.alpha == sphere_asset.alpha and back.name == "ball"
    pts = np.random.default_rng(0).uniform(-0.3, 0.3, (20, 3))
    np.testing.assert_allclose(back.field.density(pts), sphere_asset.field.density(pts))
    meta = json.loads(str(np.load(path)["metadata"]))
    assert meta["format"] == "dano" and meta["version"] == 1
    assert meta["units"]["length"] == "m" and meta["seed"] == 0 and meta["source"] == "test"


def test_paper_bunny_round_trip(tmp_path, paper_bunny):
    back = load(save(paper_bunny, tmp_path / "b.dano"))
    np.testing.assert_array_equal(back.points, paper_bunny.points)
    assert back.field is None and back.metadata["license"].startswith("MIT")


def _rewrite(src, dst, change):
    with np.load(src) as d:
        arrays = {k: d[k] for k in d.files}
    change(arrays)
    with open(dst, "wb") as f:
        np.savez(f, **arrays)
    return dst


def test_other_version_is_refused(tmp_path, sphere_asset):
    src = save(sphere_asset, tmp_path / "a.dano")

    def bump(arrays):
        meta = json.loads(str(arrays["metadata"]))
        meta["version"] = 2
        arrays["metadata"] = np.asarray(json.dumps(meta))

    bad = _rewrite(src, tmp_path / "v2.dano", bump)
    with pytest.raises(FileFormatError, match=r"v2.dano: .dano format version 2; this dano .* reads version 1"):
        load(bad)


def test_wrong_shapes_are_refused(tmp_path, sphere_asset):
    src = save(sphere_asset, tmp_path / "a.dano")
    bad = _rewrite(src, tmp_path / "shape.dano", lambda a: a.update(normals=a["normals"][:, :2]))
    with pytest.raises(FileFormatError, match=r"shape.dano: normals has shape \(300, 2\), expected \(300, 3\)"):
        load(bad)


def test_not_a_dano_file(tmp_path):
    p = tmp_path / "x.dano"
    p.write_text("hello")
    with pytest.raises(FileFormatError, match="x.dano: not a .dano file"):
        load(p)
    np.savez(tmp_path / "y.npz", a=np.ones(3))
    with pytest.raises(FileFormatError, match="y.npz: not a .dano file"):
        load(tmp_path / "y.npz")
    with pytest.raises(FileFormatError, match="no such file"):
        load(tmp_path / "missing.dano")


def test_asset_arrays_are_read_only_and_validated(sphere_asset):
    with pytest.raises(ValueError):
        sphere_asset.points[0, 0] = 1.0
    with pytest.raises(DanoError, match=r"weights has shape"):
        DanoAsset(name="x", mass=1.0, alpha=1.0, center_of_mass=np.zeros(3), inertia=np.eye(3),
                  points=np.zeros((5, 3)), normals=np.zeros((5, 3)), densities=np.ones(5), weights=np.ones(4),
                  band=np.array([0.1, 0.9]))


def test_with_mass_scales_inertia_and_weights(sphere_asset):
    heavy = sphere_asset.with_mass(3.0)
    assert heavy.alpha == pytest.approx(2 * sphere_asset.alpha)
    np.testing.assert_allclose(heavy.inertia, 2 * sphere_asset.inertia)
    np.testing.assert_allclose(heavy.weights.sum(), 3.0)


def test_failed_save_leaves_no_file(tmp_path, sphere_asset, monkeypatch):
    target = tmp_path / "out.dano"

    def boom(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(np, "savez_compressed", boom)
    with pytest.raises(OSError, match="disk full"):
        save(sphere_asset, target)
    assert list(tmp_path.iterdir()) == []


def test_file_is_a_plain_npz(tmp_path, sphere_asset):
    path = save(sphere_asset, tmp_path / "z.dano")
    assert zipfile.is_zipfile(path)


def _meta(**changes):
    def change(arrays):
        meta = json.loads(str(arrays["metadata"]))
        meta.update(changes)
        arrays["metadata"] = np.asarray(json.dumps(meta))
    return change


def _set(name, fn):
    return lambda arrays: arrays.update({name: fn(arrays[name].copy())})


def _at(a, index, value):
    a[index] = value
    return a


_CORRUPTIONS = {
    "band reversed": (_set("band", lambda b: b[::-1].copy()), "band must be two densities"),
    "face out of range": (_set("mesh_faces", lambda f: _at(f, (0, 0), 10**6)), "mesh_faces index vertices outside"),
    "negative face": (_set("mesh_faces", lambda f: _at(f, (0, 0), -1)), "mesh_faces index vertices outside"),
    "non-integer faces": (_set("mesh_faces", lambda f: f.astype(float) + 0.5), "integer vertex indices"),
    "inertia not positive definite": (_set("inertia", lambda J: -J), "not positive definite"),
    "triangle inequality": (_set("inertia", lambda J: np.diag([1.0, 1.0, 3.0]) * J.trace()), "triangle inequality"),
    "NaN normal": (_set("normals", lambda n: _at(n, 3, np.nan)), "normals contains NaN"),
    "zero normal": (_set("normals", lambda n: _at(n, 3, 0.0)), "not unit vectors"),
    "all-zero weights": (_set("weights", np.zeros_like), "weights sum to 0"),
    "weights disagree with the mass": (_set("weights", lambda w: 2 * w), "not to the mass"),
    "NaN alpha": (_meta(alpha=float("nan")), "alpha must be finite and positive"),
    "negative alpha": (_meta(alpha=-1.0), "alpha must be finite and positive"),
    "mass disagrees with the weights": (_meta(mass=123.0), "not to the mass"),
    "metadata a list": (lambda a: a.update(metadata=np.asarray("[1, 2]")), "expected an object"),
    "field spec a list": (lambda a: a.update({"field/spec": np.asarray("[1]")}), "field spec is a JSON list"),
    "field spec not JSON": (lambda a: a.update({"field/spec": np.asarray("{kind")}), "not valid JSON"),
}


def _refused(asset, tmp_path, change, message):
    """``asset`` saved, then changed by ``change``: reading it raises FileFormatError naming the
    file and matching ``message``, and ``dano inspect`` exits 1. Returns the bad file."""
    from dano.cli import main

    bad = _rewrite(save(asset, tmp_path / "a.dano"), tmp_path / "bad.dano", change)
    with pytest.raises(FileFormatError, match=message) as info:
        load(bad)
    assert str(info.value).startswith(str(bad))
    assert main(["inspect", str(bad)]) == 1
    return bad


@pytest.mark.parametrize("case", sorted(_CORRUPTIONS))
def test_physically_invalid_files_are_refused(case, tmp_path, sphere_asset):
    from dano.cli import main

    bad = _refused(sphere_asset, tmp_path, *_CORRUPTIONS[case])
    assert main(["export", str(bad), "-o", str(tmp_path / "out.xml")]) == 1
    assert not (tmp_path / "out.xml").exists()


def test_inspect_shows_size_volume_and_warns_on_implausible_density(tmp_path, sphere_asset, capsys):
    """inspect reports the extents [m], the volume and the mean density; a density outside
    10-25,000 kg/m³ (e.g. an object in the wrong units) gets a one-line warning on stderr and
    the JSON on stdout stays one object."""
    from dano.cli import main

    size = sphere_asset.size()
    r = float(np.max(size["extents"])) / 2
    assert size["volume"] == pytest.approx(4 / 3 * np.pi * r**3, rel=0.1)
    assert size["mean_density"] == pytest.approx(sphere_asset.mass / size["volume"])
    light, heavy = tmp_path / "light.dano", tmp_path / "heavy.dano"
    save(sphere_asset.with_mass(1e-6 * size["volume"] * 1000), light)  # 1e-3 kg/m³: wrong units
    save(sphere_asset.with_mass(1000 * size["volume"]), heavy)  # water
    assert main(["inspect", str(heavy), "--json"]) == 0
    cap = capsys.readouterr()
    assert json.loads(cap.out)["mean_density"] == pytest.approx(1000, rel=1e-6) and "warning" not in cap.err
    assert main(["inspect", str(light), "--json"]) == 0
    cap = capsys.readouterr()
    assert json.loads(cap.out)["extents"] == pytest.approx(size["extents"])
    assert "mean density 0.001 kg/m³" in cap.err and "metres" in cap.err and len(cap.err.strip().splitlines()) == 1


def _field(spec, **arrays):
    """Replace the stored field by ``spec`` and ``arrays`` (names under field/)."""
    def change(a):
        for k in [k for k in a if k.startswith("field/")]:
            del a[k]
        a["field/spec"] = np.asarray(json.dumps(spec))
        a.update({"field/" + k: v for k, v in arrays.items()})
    return change


_GRID = np.ones((4, 4, 4))
_BOX = np.array([[-0.3, -0.3, -0.3], [0.3, 0.3, 0.3]])
_SPHERE = {"kind": "sphere", "radius": 0.2, "edge_width": 0.01, "density_scale": 1.0, "center": [0, 0, 0]}
_STORED_FIELDS = {
    "voxel with NaN": (_field({"kind": "voxel"}, values=_at(_GRID.copy(), (1, 2, 3), np.nan), bounds=_BOX),
                       "voxel densities contains 1 NaN"),
    "complex voxel grid": (_field({"kind": "voxel"}, values=_GRID + 1j, bounds=_BOX), "must be real numbers"),
    "voxel of wrong shape": (_field({"kind": "voxel"}, values=np.ones((4, 4)), bounds=_BOX), "3-D array"),
    "voxel bounds reversed": (_field({"kind": "voxel"}, values=_GRID, bounds=_BOX[::-1].copy()),
                              "lower < upper"),
    "sdf grid with infinity": (_field({"kind": "sdf_grid", "edge_width": 0.01, "density_scale": 1.0},
                                      sdf=_at(_GRID.copy(), (0, 0, 0), np.inf), bounds=_BOX),
                               "signed distances contains 1 NaN or infinite"),
    "sdf grid of wrong shape": (_field({"kind": "sdf_grid", "edge_width": 0.01, "density_scale": 1.0},
                                       sdf=np.ones(5), bounds=_BOX), "3-D array"),
    "sdf grid without bounds": (_field({"kind": "sdf_grid", "edge_width": 0.01, "density_scale": 1.0},
                                       sdf=_GRID), "lacks 'field/bounds'"),
    "sdf edge width zero": (_field({"kind": "sdf_grid", "edge_width": 0.0, "density_scale": 1.0},
                                   sdf=_GRID, bounds=_BOX), "edge_width must be a finite positive"),
    "negative sphere radius": (_field({**_SPHERE, "radius": -0.2}), "radius must be a finite positive"),
    "transform not a rotation": (_field({"kind": "transformed", "scale": 1.0, "rotation": (2 * np.eye(3)).tolist(),
                                         "offset": [0, 0, 0], "base": _SPHERE}), "rotation matrix"),
    "transform scale NaN": (_field({"kind": "transformed", "scale": float("nan"), "rotation": np.eye(3).tolist(),
                                    "offset": [0, 0, 0], "base": _SPHERE}), "scale must be a finite positive"),
}


@pytest.mark.parametrize("case", sorted(_STORED_FIELDS))
def test_bad_stored_fields_are_refused(case, tmp_path, sphere_asset, capsys):
    """A .dano whose stored density field holds NaN, a wrong shape, bad bounds or bad
    parameters is refused when read, naming the file (inspect and simulate exit 1)."""
    from dano.cli import main

    bad = _refused(sphere_asset, tmp_path, *_STORED_FIELDS[case])
    capsys.readouterr()
    floor = tmp_path / "floor.xml"
    floor.write_text('<mujoco><worldbody><geom type="plane" size="1 1 0.1"/></worldbody></mujoco>')
    out = tmp_path / "out.npz"
    assert main(["simulate", str(floor), "--object", f"{bad}@0,0,0.5", "--duration", "0.05", "-o", str(out)]) == 1
    err = capsys.readouterr().err
    assert "bad.dano" in err and "Traceback" not in err and not out.exists()


def test_a_complex_voxel_grid_is_not_built(tmp_path):
    from dano.cli import main

    np.savez(tmp_path / "grid.npz", density=np.ones((8, 8, 8)) * (1 + 0.5j), bounds=_BOX)
    assert main(["build", str(tmp_path / "grid.npz"), "-o", str(tmp_path / "g.dano")]) == 1
    assert not (tmp_path / "g.dano").exists()

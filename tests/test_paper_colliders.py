"""Import of the paper's colliders (../shared/data/dano/*.jld2)."""

import shutil

import numpy as np
import pytest

from dano.errors import DanoError, FileFormatError
from dano.io import load_mesh, load_paper_collider, normals_from_mesh


def test_bunny_mass_and_centre_of_mass(paper_bunny):
    assert paper_bunny.mass == pytest.approx(3.21985, abs=5e-6)
    np.testing.assert_allclose(paper_bunny.center_of_mass, [0.03746, -0.01419, -0.04771], atol=5e-6)
    assert paper_bunny.weights.sum() == pytest.approx(paper_bunny.mass)
    assert paper_bunny.num_samples == 5000 and paper_bunny.metadata["unique_points"] == 2926


def test_bunny_inertia_is_converted_from_second_moment(paper_bunny, shared):
    import h5py

    with h5py.File(shared / "dano" / "bunny.jld2") as f:
        S = f["inertia"][()]
    J = paper_bunny.inertia
    np.testing.assert_allclose(J, np.trace(S) * np.eye(3) - S)
    np.testing.assert_allclose(J, J.T)
    p = np.linalg.eigvalsh(J)
    assert p.min() > 0
    assert p[0] + p[1] >= p[2] and p[0] + p[2] >= p[1] and p[1] + p[2] >= p[0]


def test_bunny_normals_are_the_stored_gradients(paper_bunny):
    assert paper_bunny.normals_valid_fraction == 1.0
    assert paper_bunny.metadata["normals"] == "stored density gradients"


def test_mesh_normals_agree_with_true_gradients_on_bunny(paper_bunny, shared):
    # the only collider with real gradients tells how good mesh-derived normals are
    mesh = load_mesh(shared / "dano" / "bunny_high.obj", require_watertight=False)
    n = normals_from_mesh(paper_bunny.points + paper_bunny.center_of_mass, mesh)
    angle = np.degrees(np.arccos(np.clip(np.sum(n * paper_bunny.normals, axis=1), -1, 1)))
    assert np.median(angle) < 15.0
    assert np.mean(angle < 90.0) > 0.95


def test_bluesoap_zero_gradients_are_detected(shared):
    with pytest.raises(DanoError, match="5000 of 5000 stored density gradients are zero"):
        load_paper_collider(shared / "dano" / "bluesoap.jld2")


def test_bluesoap_normals_recomputed_from_level_set_mesh(shared):
    soap = load_paper_collider(shared / "dano" / "bluesoap.jld2",
                               normals_mesh=shared / "dano" / "bluesoap_level_70.stl")
    assert soap.normals_valid_fraction == 1.0
    assert soap.mass == pytest.approx(3.21517, abs=5e-6)
    assert "recomputed from bluesoap_level_70.stl" in soap.metadata["normals"]


def test_not_hdf5_is_refused(tmp_path):
    bad = tmp_path / "bad.jld2"
    bad.write_text("this is not HDF5")
    with pytest.raises(FileFormatError, match="bad.jld2: cannot read as a JLD2/HDF5 file"):
        load_paper_collider(bad)


def test_truncated_file_is_refused(tmp_path, shared):
    src = (shared / "dano" / "bunny.jld2").read_bytes()
    bad = tmp_path / "truncated.jld2"
    bad.write_bytes(src[: len(src) // 2])
    with pytest.raises(FileFormatError, match="truncated.jld2"):
        load_paper_collider(bad)


def test_missing_datasets_and_wrong_shapes_are_refused(tmp_path, shared):
    import h5py

    path = tmp_path / "partial.jld2"
    shutil.copy(shared / "dano" / "bunny.jld2", path)
    path.chmod(0o644)
    with h5py.File(path, "a") as f:
        del f["densities"]
        f["densities"] = np.ones(10)
    with pytest.raises(FileFormatError, match=r"partial.jld2: inconsistent shapes.*densities \(10,\)"):
        load_paper_collider(path)
    with h5py.File(path, "a") as f:
        del f["mass"]
    with pytest.raises(FileFormatError, match=r"partial.jld2: not a paper DANO collider \(missing datasets \['mass'\]\)"):
        load_paper_collider(path)


def _corrupt_copy(shared, tmp_path, change):
    import h5py

    path = tmp_path / "bunny.jld2"
    shutil.copy(shared / "dano" / "bunny.jld2", path)
    with h5py.File(path, "r+") as f:
        change(f)
    return path


def _far_particle(f):
    p = f["particles"][()]
    p[7]["data"]["2"] = 13000.0  # what a flipped exponent byte does
    f["particles"][...] = p


@pytest.mark.parametrize("change, message", [
    (_far_particle, "outside the paper's sampling box"),
    (lambda f: f["inertia"].write_direct(-np.abs(f["inertia"][()]) - np.eye(3)), "not positive definite"),
    (lambda f: f["densities"].write_direct(-f["densities"][()]), "densities are negative"),
])
def test_physically_absurd_colliders_are_refused(shared, tmp_path, change, message):
    bad = _corrupt_copy(shared, tmp_path, change)
    with pytest.raises(FileFormatError, match=message):
        load_paper_collider(bad)

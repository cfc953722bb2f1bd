"""Boundary samples and normals (paper §IV-B)."""

import numpy as np
import pytest

from dano.asset import boundary_samples, build
from dano.errors import DanoError
from dano.fields import BoxField, SphereField


def test_sphere_normals_are_radial_within_2_degrees():
    f = SphereField(0.5, edge_width=0.01, center=(0.1, 0.2, -0.3))
    bs = boundary_samples(f, 5000, seed=1)
    r = bs.points - np.array([0.1, 0.2, -0.3])
    radial = r / np.linalg.norm(r, axis=1, keepdims=True)
    angle = np.degrees(np.arccos(np.clip(np.sum(radial * bs.normals, axis=1), -1, 1)))
    assert len(angle) == 5000
    assert angle.max() < 2.0


def test_samples_lie_in_band_and_are_deterministic():
    f = BoxField((0.2, 0.1, 0.05), edge_width=0.005)
    a = boundary_samples(f, 800, band=(0.2, 0.8), seed=7)
    b = boundary_samples(f, 800, band=(0.2, 0.8), seed=7)
    c = boundary_samples(f, 800, band=(0.2, 0.8), seed=8)
    assert np.all((a.densities >= 0.2) & (a.densities <= 0.8))
    np.testing.assert_allclose(f.density(a.points), a.densities, rtol=1e-12)
    np.testing.assert_array_equal(a.points, b.points)
    assert not np.array_equal(a.points, c.points)
    assert len(np.unique(a.points, axis=0)) == 800
    np.testing.assert_allclose(np.linalg.norm(a.normals, axis=1), 1.0, rtol=1e-12)


def test_auto_band_is_documented_rule():
    bs = boundary_samples(SphereField(0.5, density_scale=40.0), 200)
    np.testing.assert_allclose(bs.band, (2.0, 38.0), rtol=1e-6)


def test_stencil_averaging_keeps_normals_radial():
    f = SphereField(0.5, edge_width=0.01)
    bs = boundary_samples(f, 500, stencil=0.005)
    radial = bs.points / np.linalg.norm(bs.points, axis=1, keepdims=True)
    assert np.degrees(np.arccos(np.min(np.sum(radial * bs.normals, axis=1)))) < 2.0


def test_no_samples_in_band_names_the_range():
    with pytest.raises(DanoError, match=r"no samples in the density band \[5, 6\].*range over \[.*, 1\]"):
        boundary_samples(SphereField(0.5), 100, band=(5.0, 6.0))


def test_too_thin_band_reports_count():
    with pytest.raises(DanoError, match="only .* of 100000 requested samples"):
        boundary_samples(SphereField(0.5, edge_width=0.001), 100000, band=(0.49, 0.51), max_candidates=1 << 17)


@pytest.mark.parametrize("band", [(0.5, 0.1), (-1.0, 0.5), (0.0, float("inf"))])
def test_bad_band(band):
    with pytest.raises(DanoError, match="band must be"):
        boundary_samples(SphereField(0.5), 10, band=band)


def test_build_stores_samples_relative_to_centre_of_mass_with_mass_weights():
    f = SphereField(0.3, center=(1.0, 0.0, 0.0))
    a = build(f, mass=2.0, num_samples=1000, mesh_resolution=32)
    np.testing.assert_allclose(a.center_of_mass, [1, 0, 0], atol=2e-3)
    assert a.weights.sum() == pytest.approx(2.0)
    np.testing.assert_allclose(a.weights, a.densities / a.densities.sum() * 2.0)
    r = np.linalg.norm(a.points, axis=1)
    assert np.all(np.abs(r - 0.3) < 0.05)
    # visual mesh: closed, outward (positive volume), close to the sphere, body frame
    import trimesh

    m = trimesh.Trimesh(a.mesh_vertices, a.mesh_faces)
    assert m.is_watertight and m.volume > 0
    assert m.volume == pytest.approx(4 / 3 * np.pi * 0.3**3, rel=0.03)
    np.testing.assert_allclose(m.center_mass, 0.0, atol=5e-3)


def test_scene_samples_come_in_compact_blocks_and_keep_every_sample():
    from dano.contact.samples import SAMPLE_BLOCK, Samples

    rng = np.random.default_rng(0)
    points = [rng.normal(size=(1001, 3)), rng.normal(size=(37, 3))]
    normals = [p / np.linalg.norm(p, axis=1, keepdims=True) for p in points]
    weights = [rng.uniform(0.5, 1.0, len(p)) for p in points]
    s = Samples.stack(points, normals, weights, [0.01, 0.01], np.zeros((2, 3)), [1.0, 1.0])
    n = s.points.shape[-1]
    assert n % SAMPLE_BLOCK == 0 and n >= 1001
    for k in range(2):
        P, W, Nn = np.asarray(s.points[k]).T, np.asarray(s.weights[k]), np.asarray(s.normals[k]).T
        real = W > 0
        assert real.sum() == len(points[k]) and not real[len(points[k]):].any()  # padding at the end
        order = np.lexsort(points[k].T)  # the same samples, each with its own weight and normal
        order_s = np.lexsort(P[real].T)
        np.testing.assert_array_equal(P[real][order_s], points[k][order])
        np.testing.assert_array_equal(W[real][order_s], weights[k][order])
        np.testing.assert_array_equal(Nn[real][order_s], normals[k][order])
        np.testing.assert_allclose(np.asarray(s.wp[k]), np.vstack([(P * W[:, None]).T, W]))
        np.testing.assert_allclose(np.asarray(s.wpp[k, [0, 3, 5]]), [W * P[:, 0] ** 2, W * P[:, 0] * P[:, 1],
                                                                   W * P[:, 1] * P[:, 2]])
    # blocks of neighbours: a block spans far less than the cloud (random order: about all of it)
    blocks = np.asarray(s.points[0]).T[:1000].reshape(-1, SAMPLE_BLOCK, 3)
    span = np.median(np.ptp(blocks, axis=1).max(axis=1))
    assert span < 0.35 * np.ptp(points[0], axis=0).max()

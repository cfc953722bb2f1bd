"""Import the paper's DANO colliders (Dojo.jl ``.jld2`` files, HDF5 inside).

Layout (``../shared/README.md``): datasets ``mass`` (), ``inertia`` (3, 3),
``center_of_mass`` (3,), ``particles``, ``densities``, ``density_gradients``
(N, compound 3-vectors). Facts established from the paper's code and data:

* the stored ``inertia`` is the second moment S = Σ m_i (x_i − c)(x_i − c)ᵀ, not an
  inertia tensor; we convert it, J = tr(S)·I − S (the paper's simulations used S
  as if it were J);
* mass = 0.1·(2/30)³·Σφ on a 30³ grid over [−1, 1]³: the paper's mass scale α = 0.1;
* the bluesoap gradients are all zero (a bug of the original export): such normals
  are detected and recomputed from a level-set mesh, or the import is refused.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..asset import DanoAsset
from ..errors import DanoError, FileFormatError
from .mesh import load_mesh

PAPER_ALPHA = 0.1
_REQUIRED = ("mass", "inertia", "center_of_mass", "particles", "densities", "density_gradients")


def _vec3(ds, path: Path, name: str) -> np.ndarray:
    arr = ds[()]
    if arr.dtype.names == ("data",):
        arr = arr["data"]
    if arr.dtype.names and len(arr.dtype.names) == 3:
        arr = np.stack([arr[k] for k in arr.dtype.names], axis=-1)
    arr = np.asarray(arr, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise FileFormatError(f"{path}: dataset {name!r} has shape {arr.shape}, expected (N, 3)")
    return arr


def normals_from_mesh(points: np.ndarray, mesh) -> np.ndarray:
    """Outward unit normals at ``points`` (N, 3) from the nearest point of ``mesh``.

    Uses the vertex normals interpolated barycentrically at the closest surface
    point (libigl); the mesh orientation is taken from the sign of its volume, so
    inward-wound level-set meshes (the paper's) work. Returns (N, 3).
    On the paper bunny (whose true gradients are known) normals from
    ``bunny_high.obj`` are within 11.5° median of −∇φ/|∇φ|.
    """
    import igl
    import trimesh

    V = np.ascontiguousarray(mesh.vertices, dtype=np.float64)
    F = np.ascontiguousarray(mesh.faces, dtype=np.int64)
    _, face, closest = igl.point_mesh_squared_distance(np.ascontiguousarray(points, dtype=np.float64), V, F)
    bary = trimesh.triangles.points_to_barycentric(mesh.triangles[face], closest)
    n = np.einsum("nk,nkj->nj", bary, mesh.vertex_normals[mesh.faces[face]])
    n *= np.sign(mesh.volume) if mesh.volume != 0 else 1.0
    return n / np.linalg.norm(n, axis=1, keepdims=True)


# The paper drew its particles from a jittered 79³ grid over [−1, 1]³ (collider frame).
PAPER_BOX = 1.0 + 2.0 / 79


def _check_physical(path: Path, mass: float, S: np.ndarray, com: np.ndarray, pts: np.ndarray, phi: np.ndarray):
    """Refuse a collider whose values no paper export can have (corrupt or edited files)."""
    for name, arr in (("mass", np.asarray(mass)), ("inertia", S), ("center_of_mass", com), ("particles", pts),
                      ("densities", phi)):
        if not np.all(np.isfinite(arr)):
            raise FileFormatError(f"{path}: {name} contains NaN or infinite values")
    if not mass > 0:
        raise FileFormatError(f"{path}: mass must be positive, got {mass}")
    far = np.abs(pts).max(axis=1) > PAPER_BOX
    if far.any():
        i = int(np.argmax(far))
        raise FileFormatError(f"{path}: {int(far.sum())} particles lie outside the paper's sampling box [-1, 1]^3 "
                              f"(first: particle {i} at {pts[i].tolist()}); the file is corrupt")
    if np.abs(com).max() > PAPER_BOX:
        raise FileFormatError(f"{path}: center_of_mass {com.tolist()} lies outside the sampling box [-1, 1]^3")
    moments = np.linalg.eigvalsh(0.5 * (S + S.T))
    if moments[0] <= 0:
        raise FileFormatError(f"{path}: the stored second moment is not positive definite (eigenvalues "
                              f"{moments.tolist()})")
    if np.any(phi < 0):
        raise FileFormatError(f"{path}: {int(np.sum(phi < 0))} densities are negative")
    if not phi.sum() > 0:
        raise FileFormatError(f"{path}: all densities are zero (the weights w_i = φ_i/Σφ·m are undefined)")


def load_paper_collider(
    path: str | Path,
    *,
    normals_mesh: str | Path | None = None,
    visual_mesh: str | Path | None = None,
    name: str | None = None,
) -> DanoAsset:
    """Read a paper collider (``bunny.jld2``, ``bluesoap.jld2``) as a :class:`DanoAsset`.

    Units and frame are the paper's (scene units, "collider frame"). The stored
    second moment is converted to the inertia tensor; weights are the paper's
    w_i = φ_i/Σφ·m; normals n_i = −∇φ_i/|∇φ_i|. All 5000 particles are kept, duplicates
    included (the bunny has 2926 unique ones), as the paper's contact sums did.

    normals_mesh: a level-set mesh in the collider frame used to recompute normals
    whose stored gradient is zero or non-finite. Without it such a file is refused.
    visual_mesh: a mesh (collider frame) to store for rendering.
    Raises FileFormatError if the file is not HDF5/JLD2, is truncated or lacks
    datasets; DanoError for degenerate normals without ``normals_mesh``.
    """
    import h5py

    path = Path(path)
    if not path.is_file():
        raise FileFormatError(f"{path}: no such file")
    try:
        with h5py.File(path, "r") as f:
            missing = [k for k in _REQUIRED if k not in f]
            if missing:
                raise FileFormatError(f"{path}: not a paper DANO collider (missing datasets {missing})")
            mass = float(np.asarray(f["mass"][()]))
            S = np.asarray(f["inertia"][()], dtype=np.float64)
            com = np.asarray(f["center_of_mass"][()], dtype=np.float64)
            pts = _vec3(f["particles"], path, "particles")
            phi = np.asarray(f["densities"][()], dtype=np.float64)
            grad = _vec3(f["density_gradients"], path, "density_gradients")
    except FileFormatError:
        raise
    except (OSError, KeyError, ValueError, TypeError) as exc:
        raise FileFormatError(f"{path}: cannot read as a JLD2/HDF5 file ({exc})") from exc
    n = len(pts)
    if S.shape != (3, 3) or com.shape != (3,) or phi.shape != (n,) or grad.shape != (n, 3):
        raise FileFormatError(
            f"{path}: inconsistent shapes: inertia {S.shape}, center_of_mass {com.shape}, particles "
            f"{pts.shape}, densities {phi.shape}, density_gradients {grad.shape}"
        )
    S = S.T  # JLD2 writes column-major; S is symmetric anyway
    _check_physical(path, mass, S, com, pts, phi)
    J = np.trace(S) * np.eye(3) - S
    gnorm = np.linalg.norm(grad, axis=1)
    valid = np.isfinite(gnorm) & (gnorm > 0)
    normals = np.where(valid[:, None], -grad / np.where(valid, gnorm, 1.0)[:, None], 0.0)
    normals_source = "stored density gradients"
    if not valid.all():
        if normals_mesh is None:
            raise DanoError(
                f"{path}: {int((~valid).sum())} of {n} stored density gradients are zero or non-finite "
                "(a known bug of the paper's bluesoap export), so normals cannot be formed; pass a level-set "
                "mesh in the collider frame to recompute them (e.g. --normals-mesh bluesoap_level_70.stl)"
            )
        mesh = load_mesh(normals_mesh, require_watertight=False)
        normals[~valid] = normals_from_mesh(pts[~valid], mesh)
        normals_source = f"{int((~valid).sum())} of {n} recomputed from {Path(normals_mesh).name}"
    verts, faces = np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    if visual_mesh is not None:
        vm = load_mesh(visual_mesh, require_watertight=False)
        if vm.volume < 0:
            vm.invert()
        verts, faces = np.asarray(vm.vertices) - com, np.asarray(vm.faces)
    return DanoAsset(
        name=name or path.stem,
        mass=mass,
        alpha=PAPER_ALPHA,
        center_of_mass=com,
        inertia=J,
        points=pts - com,
        normals=normals,
        densities=phi,
        weights=phi / phi.sum() * mass,
        band=np.array([phi.min(), phi.max()]),
        mesh_vertices=verts,
        mesh_faces=faces,
        metadata={
            "source": f"{path.name}: DANO collider of Le Cleac'h et al., Dojo.jl DANO branch (MIT)",
            "license": "MIT, Copyright (c) 2022 Simon Le Cleac'h, Taylor Howell, Jan Bruedigam, Zachary Manchester",
            "units": "paper scene units (length) and mass units",
            "inertia_note": "stored second moment S converted to the inertia tensor J = tr(S) I - S",
            "normals": normals_source,
            "unique_points": int(len(np.unique(pts, axis=0))),
        },
    )

"""Triangle-mesh input via trimesh."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from ..errors import DanoError, FileFormatError

MESH_SUFFIXES = (".obj", ".stl", ".ply", ".off", ".glb", ".gltf")


def _check_binary_stl(path: Path) -> None:
    """A binary STL states its triangle count: refuse a file too short to hold them
    (trimesh would otherwise retry it as ASCII and report an unrelated error). Trailing
    bytes after the triangles, which some exporters write, are allowed (readers ignore them)."""
    size = path.stat().st_size
    with open(path, "rb") as f:
        head = f.read(84)
    if head[:5].lower() == b"solid":
        return  # ASCII STL (or a binary one whose header starts with "solid": trimesh tells them apart)
    if size < 84:
        raise FileFormatError(f"{path}: truncated binary STL ({size} bytes, shorter than the 84-byte header)")
    n = int.from_bytes(head[80:84], "little")
    if size < 84 + 50 * n:
        raise FileFormatError(f"{path}: truncated or corrupt binary STL: the header states {n} triangles "
                              f"({84 + 50 * n} bytes), the file has {size} bytes")


def load_mesh(path: str | Path, require_watertight: bool = True) -> trimesh.Trimesh:
    """Load a triangle mesh, merging vertices split at UV/normal seams.

    Returns a :class:`trimesh.Trimesh` in the file's frame and units (taken as [m]),
    faces wound outward (positive volume).
    Raises FileFormatError if the file cannot be read or holds no triangles, and
    DanoError if ``require_watertight`` and the mesh has holes (boundary edges),
    since a solid's mass properties and inside/outside test need a closed surface.
    """
    path = Path(path)
    if not path.is_file():
        raise FileFormatError(f"{path}: no such file")
    if path.suffix.lower() == ".stl":
        _check_binary_stl(path)
    try:
        loaded = trimesh.load(path, process=False, force="mesh")
    except Exception as exc:
        raise FileFormatError(f"{path}: cannot read mesh ({exc})") from exc
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise FileFormatError(f"{path}: no triangles found")
    mesh = loaded
    mesh.merge_vertices(merge_tex=True, merge_norm=True)
    mesh.remove_unreferenced_vertices()
    if not np.all(np.isfinite(mesh.vertices)):
        raise FileFormatError(f"{path}: vertex coordinates contain NaN or infinity")
    if require_watertight:
        if not mesh.is_watertight:
            _, counts = np.unique(mesh.edges_sorted, axis=0, return_counts=True)
            raise DanoError(
                f"{path}: mesh is not watertight ({int(np.sum(counts == 1))} boundary edges, "
                f"{int(np.sum(counts > 2))} non-manifold edges); a solid needs a closed surface "
                "(repair it, e.g. with trimesh.repair.fill_holes, or build from a voxel grid)"
            )
        if not mesh.is_winding_consistent:
            raise DanoError(f"{path}: mesh faces are not consistently wound")
        if mesh.volume < 0:
            mesh.invert()
        if not mesh.volume > 1e-9 * float(np.max(mesh.extents)) ** 3:
            raise DanoError(f"{path}: the closed mesh encloses no volume ({mesh.volume:.3g}); a solid needs one")
    return mesh

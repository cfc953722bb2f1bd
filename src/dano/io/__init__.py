"""Importers (the paper's ``.jld2`` colliders, meshes, voxel grids) and exporters (MJCF,
URDF, MjSpec bodies: :mod:`dano.io.exporters`)."""

from __future__ import annotations

from pathlib import Path

from ..errors import FileFormatError
from .jld2 import PAPER_ALPHA, load_paper_collider, normals_from_mesh
from .mesh import MESH_SUFFIXES, load_mesh

__all__ = ["PAPER_ALPHA", "MESH_SUFFIXES", "Decomposition", "add_to_spec", "body_meshes", "export", "load_mesh",
           "load_paper_collider", "normals_from_mesh", "source_kind"]


_EXPORTERS = ("Decomposition", "add_to_spec", "body_meshes", "export")


def __getattr__(name: str):
    """The exporters' names, loaded on first use (they import trimesh: ``import dano`` stays light)."""
    if name in _EXPORTERS:
        from . import exporters

        return getattr(exporters, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def source_kind(path: str | Path) -> str:
    """'mesh', 'voxel', 'jld2' from the file suffix, or 'field' for a folder (a field
    directory written by ``dano train-field``); raises FileFormatError otherwise."""
    if Path(path).is_dir():
        return "field"
    suffix = Path(path).suffix.lower()
    if suffix in MESH_SUFFIXES:
        return "mesh"
    if suffix in (".npy", ".npz"):
        return "voxel"
    if suffix == ".jld2":
        return "jld2"
    raise FileFormatError(
        f"{path}: unknown source type {suffix!r}; expected a mesh ({', '.join(MESH_SUFFIXES)}), "
        "a voxel grid (.npy/.npz), a paper collider (.jld2) or a trained field's folder"
    )

"""Importers (the paper's ``.jld2`` colliders, meshes, voxel grids) and exporters (MJCF,
URDF, MjSpec bodies: :mod:`dano.io.exporters`)."""

from __future__ import annotations

from .._files import source_kind
from .jld2 import PAPER_ALPHA, load_paper_collider, normals_from_mesh
from .mesh import MESH_SUFFIXES, load_mesh

__all__ = ["PAPER_ALPHA", "MESH_SUFFIXES", "Decomposition", "add_to_spec", "body_meshes", "export", "load_mesh",
           "load_paper_collider", "normals_from_mesh", "read_contact_params", "contact_params", "source_kind"]


_EXPORTERS = ("Decomposition", "add_to_spec", "body_meshes", "contact_params", "export", "read_contact_params")


def __getattr__(name: str):
    """The exporters' names, loaded on first use (they import trimesh: ``import dano`` stays light)."""
    if name in _EXPORTERS:
        from . import exporters

        return getattr(exporters, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))

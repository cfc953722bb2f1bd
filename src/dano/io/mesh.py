"""Triangle-mesh input: :func:`load_mesh` lives with the mesh-derived fields
(:mod:`dano.fields.mesh`, the lowest layer that reads meshes); re-exported here."""

from ..fields.mesh import MESH_SUFFIXES, load_mesh

__all__ = ["MESH_SUFFIXES", "load_mesh"]

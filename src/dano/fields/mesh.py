"""Density fields derived from watertight triangle meshes."""

from __future__ import annotations

from pathlib import Path

import igl
import jax.numpy as jnp
import numpy as np
import trimesh

from ..errors import DanoError
from .grid import SdfGridField


def mesh_field(
    mesh: trimesh.Trimesh | str | Path,
    resolution: int = 96,
    edge_width: float | None = None,
    density_scale: float = 1.0,
    progress=None,
) -> SdfGridField:
    """Uniform-density field of a watertight mesh: ρ·σ(−d(x)/w).

    The signed distance d is computed by libigl (winding-number sign, robust to
    small defects) on a node grid of ``resolution`` nodes along the longest axis,
    padded by 8 edge widths + 2 cells; the field interpolates it trilinearly.

    mesh: a Trimesh (vertices in the object frame [m]) or a path to a mesh file.
    edge_width: logistic width w [m]; default a quarter grid cell. The smooth edge
    adds mass in thin parts (measured on Spot at 96 nodes: +0.02 % mass, +0.09 %
    inertia with w = cell/4; +2 % / +4.5 % with w = one cell).
    Raises DanoError if the mesh is not watertight or the resolution is below 8.
    """
    if not isinstance(mesh, trimesh.Trimesh):
        from ..io.mesh import load_mesh  # io imports the asset module, which imports fields

        mesh = load_mesh(mesh)
    elif not mesh.is_watertight:
        raise DanoError("mesh is not watertight; a solid needs a closed surface")
    if resolution < 8:
        raise DanoError(f"resolution must be at least 8, got {resolution}")
    lo, hi = mesh.bounds
    extent = float(np.max(hi - lo))
    cell = extent / (resolution - 1)
    w = float(edge_width) if edge_width is not None else 0.25 * cell
    if not np.isfinite(w) or w <= 0:
        raise DanoError(f"edge_width must be positive, got {edge_width}")
    pad = 8.0 * w + 2.0 * cell
    lo, hi = lo - pad, hi + pad
    shape = np.maximum(np.ceil((hi - lo) / cell).astype(int) + 1, 2)
    hi = lo + (shape - 1) * cell
    axes = [np.linspace(lo[k], hi[k], shape[k]) for k in range(3)]
    pts = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    V = np.ascontiguousarray(mesh.vertices, dtype=np.float64)
    F = np.ascontiguousarray(mesh.faces, dtype=np.int64)
    sdf = np.empty(len(pts))
    chunk = 1 << 17
    for start in range(0, len(pts), chunk):
        sdf[start : start + chunk] = igl.signed_distance(
            pts[start : start + chunk], V, F, sign_type=igl.SIGNED_DISTANCE_TYPE_FAST_WINDING_NUMBER
        )[0]
        if progress is not None:
            progress(min(start + chunk, len(pts)), len(pts))
    return SdfGridField(
        sdf=jnp.asarray(sdf.reshape(shape)),
        lower=jnp.asarray(lo),
        upper=jnp.asarray(hi),
        edge_width=w,
        density_scale=float(density_scale),
    )

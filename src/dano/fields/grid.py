"""Fields sampled on regular grids: voxel densities and mesh-derived signed distances.

Both interpolate trilinearly with :func:`jax.scipy.ndimage.map_coordinates`
(order 1), which is differentiable in the query points. Grid values live on the
nodes: ``values[i, j, k]`` is the value at ``lower + (i, j, k) * (upper - lower) /
(shape - 1)`` in the object frame [m].
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.ndimage import map_coordinates

from ..errors import DanoError, FileFormatError
from .base import NamedField, as_points, check_bounds, smooth_occupancy


def _grid_coords(points: jax.Array, lower: jax.Array, upper: jax.Array, shape) -> list[jax.Array]:
    scale = (jnp.asarray(shape) - 1) / (upper - lower)
    idx = (points - lower) * scale
    return [idx[:, k] for k in range(3)]


def _check_grid(values: np.ndarray, what: str) -> np.ndarray:
    raw = np.asarray(values)
    if raw.dtype.kind not in "biuf":  # complex, text, objects: no density (numpy would drop an imaginary part)
        raise DanoError(f"{what} must be real numbers, got an array of dtype {raw.dtype}")
    v = raw.astype(np.float64)
    if v.ndim != 3 or min(v.shape) < 2:
        raise DanoError(f"{what} must be a 3-D array with at least 2 nodes per axis, got shape {v.shape}")
    if not np.all(np.isfinite(v)):
        raise DanoError(f"{what} contains {int(np.sum(~np.isfinite(v)))} NaN or infinite values")
    return v


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class VoxelField(NamedField):
    """Density on a voxel grid, trilinear in between; beyond the outer nodes it falls
    linearly to zero over one cell (continuous), so :meth:`bounds` is the node box
    grown by one cell.

    values: (nx, ny, nz) float, density φ >= 0 at the grid nodes;
    lower, upper: (3,) float, object frame [m], positions of the first and last node.
    ``name``: the file's stem when read by :meth:`load`, else "voxel" (:meth:`named` sets one).
    Raises DanoError on negative or non-finite densities or bad shapes.
    """

    kind: ClassVar[str] = "voxel"

    values: jax.Array
    lower: jax.Array
    upper: jax.Array

    @classmethod
    def create(cls, values, bounds) -> "VoxelField":
        v = _check_grid(values, "voxel densities")
        if np.any(v < 0):
            raise DanoError(
                f"voxel densities must be non-negative; {int(np.sum(v < 0))} values are negative "
                f"(min {v.min():.4g})"
            )
        b = check_bounds(bounds, "voxel grid bounds")
        return cls(jnp.asarray(v), jnp.asarray(b[0]), jnp.asarray(b[1]))

    @classmethod
    def load(cls, path: str | Path, bounds=None) -> "VoxelField":
        """Read a volume from ``.npz`` (arrays ``density`` (nx, ny, nz) and ``bounds``
        (2, 3) [m]) or ``.npy`` (the density array; ``bounds`` must then be given), named
        after the file's stem.

        Raises FileFormatError naming the file if it cannot be read or lacks arrays.
        """
        path = Path(path)
        try:
            data = np.load(path, allow_pickle=False)
        except Exception as exc:
            raise FileFormatError(f"{path}: cannot read voxel grid ({exc})") from exc
        try:
            if isinstance(data, np.ndarray):
                if bounds is None:
                    raise FileFormatError(f"{path}: a .npy volume needs explicit bounds (2, 3) [m]")
                values = data
            else:
                missing = {"density", "bounds"} - set(data.files) if bounds is None else {"density"} - set(data.files)
                if missing:
                    raise FileFormatError(f"{path}: missing array(s) {sorted(missing)}; expected 'density' and 'bounds'")
                values = data["density"]
                bounds = data["bounds"] if bounds is None else bounds
            return cls.create(values, bounds).named(path.stem)
        except DanoError as exc:
            if str(exc).startswith(str(path)):
                raise
            raise FileFormatError(f"{path}: {exc}") from exc

    def density(self, points: jax.Array) -> jax.Array:
        coords = _grid_coords(as_points(points), self.lower, self.upper, self.values.shape)
        return map_coordinates(self.values, coords, order=1, mode="constant", cval=0.0)

    def bounds(self) -> np.ndarray:
        lo, hi = np.asarray(self.lower), np.asarray(self.upper)
        cell = (hi - lo) / (np.asarray(self.values.shape) - 1)
        return np.stack([lo - cell, hi + cell])

    @property
    def node_bounds(self) -> np.ndarray:
        """(2, 3) positions of the first and last node, object frame [m]."""
        return np.stack([np.asarray(self.lower), np.asarray(self.upper)])

    def interior_density(self) -> float:
        """Density of full occupancy: the largest voxel value (a voxel grid states no
        interior density; the surface is taken at half of it)."""
        return float(np.max(np.asarray(self.values)))


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class SdfGridField(NamedField):
    """Smoothed occupancy of a signed-distance grid: φ(x) = ρ·σ(−d(x)/w).

    sdf: (nx, ny, nz) float, signed distance at the nodes [m], negative inside;
    lower, upper: (3,) object frame [m]; edge_width w [m]; density_scale ρ.
    Outside the grid the nearest node's distance is used (the grid is padded so
    that this is far outside the surface). Build one from a mesh with
    :func:`dano.fields.mesh_field` (named after the mesh file's stem; else "sdf_grid").
    """

    kind: ClassVar[str] = "sdf_grid"

    sdf: jax.Array
    lower: jax.Array
    upper: jax.Array
    edge_width: float
    density_scale: float = 1.0

    @classmethod
    def create(cls, sdf, bounds, edge_width: float, density_scale: float = 1.0) -> "SdfGridField":
        """sdf: (nx, ny, nz) [m] at the nodes; bounds: (2, 3) positions of the first and last
        node [m]. Raises DanoError on bad shapes, non-finite distances or bounds, or a
        non-positive edge width or density scale."""
        d = _check_grid(sdf, "signed distances")
        b = check_bounds(bounds, "signed-distance grid bounds")
        for name, value in (("edge_width", edge_width), ("density_scale", density_scale)):
            if not (isinstance(value, (int, float, np.number)) and np.isfinite(value) and value > 0):
                raise DanoError(f"{name} must be a finite positive number, got {value!r}")
        return cls(jnp.asarray(d), jnp.asarray(b[0]), jnp.asarray(b[1]), float(edge_width), float(density_scale))

    def signed_distance(self, points: jax.Array) -> jax.Array:
        """Trilinearly interpolated signed distance [m], (N,)."""
        coords = _grid_coords(as_points(points), self.lower, self.upper, self.sdf.shape)
        return map_coordinates(self.sdf, coords, order=1, mode="nearest")

    def density(self, points: jax.Array) -> jax.Array:
        return self.density_scale * smooth_occupancy(self.signed_distance(points), self.edge_width)

    def bounds(self) -> np.ndarray:
        return np.stack([np.asarray(self.lower), np.asarray(self.upper)])

    def interior_density(self) -> float:
        """Density of full occupancy, ρ (the surface, d = 0, is the level ρ/2)."""
        return float(self.density_scale)

"""The :class:`DensityField` protocol and helpers shared by all fields."""

from __future__ import annotations

import copy
import re
from typing import Any, ClassVar, Protocol, runtime_checkable

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import DanoError


@runtime_checkable
class DensityField(Protocol):
    """A non-negative density φ(x) over the object frame.

    ``density(points)``: ``points`` (N, 3) float, object frame [m] -> (N,) float,
    density φ >= 0 [1/m³ up to the mass scale α, i.e. mass = α∫φ dV]. Must be
    JAX-traceable and differentiable in ``points``.

    ``bounds()``: (2, 3) float, object frame [m]: an axis-aligned box (rows: lower,
    upper corner) outside of which φ is (numerically) zero.

    Optional ``interior_density()`` -> float: the density of full occupancy (the surface
    is the level at half of it; contact begins there). Without it dano takes the largest
    density on a grid over the bounds.

    Optional ``name`` (str): what the object is called; :func:`dano.build` names the asset
    after it (:func:`field_name`).
    """

    def density(self, points: jax.Array) -> jax.Array: ...

    def bounds(self) -> np.ndarray: ...


class NamedField:
    """What a built-in field is called: ``name``, the stem of the file it was read from
    (:func:`~dano.fields.mesh_field`, :meth:`~dano.fields.VoxelField.load`) or given by
    :meth:`named`, else the field's kind (``"sphere"``, ``"box"``, ``"voxel"``, ``"sdf_grid"``;
    a transformed field: its base's name). :func:`dano.build` names its asset so.

    The name is not part of the pytree (no leaf, no static metadata: fields of one structure
    share compilations and DANO-DANO pair groups whatever they are called), so JAX
    transformations and :func:`dataclasses.replace` return fields called by their kind."""

    kind: ClassVar[str] = ""

    @property
    def name(self) -> str:
        return self.__dict__.get("_name") or self._default_name()

    def _default_name(self) -> str:
        return self.kind

    def named(self, name: str):
        """A copy of this field called ``name`` (a non-empty string). Raises DanoError otherwise."""
        if not isinstance(name, str) or not name.strip():
            raise DanoError(f"a field's name must be a non-empty string, got {name!r}")
        new = copy.copy(self)
        object.__setattr__(new, "_name", name)
        return new


def field_name(field) -> str:
    """The name of an asset built from ``field`` when none is given: the field's ``name``
    when it is a non-empty string (built-in fields: :class:`NamedField`), else its class name
    in snake case without a ``Field`` suffix (a user's ``TorusField`` -> ``"torus"``), else
    ``"dano"``."""
    name = getattr(field, "name", None)
    if isinstance(name, str) and name.strip():
        return name
    stem = re.sub(r"_?field$", "", re.sub(r"(?<=[a-z0-9])(?=[A-Z])", "_", type(field).__name__).lower())
    return stem or "dano"


def smooth_occupancy(signed_distance: jax.Array, edge_width: float) -> jax.Array:
    """Occupancy in [0, 1] from a signed distance d (negative inside) [m].

    σ(−d / w), the logistic function: 0.5 on the surface, 0.95 at d = −2.94w,
    0.05 at d = +2.94w. A smooth, everywhere-differentiable step whose integral
    differs from the sharp one by O((w/R)²) for a surface of curvature radius R
    (for a sphere exactly by a factor 1 + π²w²/R² to second order).
    """
    return jax.nn.sigmoid(-signed_distance / edge_width)


def safe_norm(x: jax.Array, axis: int = -1) -> jax.Array:
    """Euclidean norm with a finite (zero) gradient at x = 0."""
    sq = jnp.sum(x * x, axis=axis)
    pos = sq > 0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, sq, 1.0)), 0.0)


def as_points(points: Any) -> jax.Array:
    """Check and convert ``points`` to a (N, 3) float array.

    Raises DanoError if the shape is not (N, 3).
    """
    pts = jnp.asarray(points)
    if pts.ndim != 2 or pts.shape[-1] != 3:
        raise DanoError(f"points must have shape (N, 3), got {tuple(pts.shape)}")
    if not jnp.issubdtype(pts.dtype, jnp.floating):
        pts = pts.astype(jnp.float64)
    return pts


def check_bounds(bounds: Any, what: str = "bounds") -> np.ndarray:
    """Validate a (2, 3) [lower; upper] box with lower < upper and finite values."""
    try:
        b = np.asarray(bounds, dtype=np.float64)
    except (ValueError, TypeError) as exc:
        raise DanoError(f"{what} must be a (2, 3) array of numbers (lower; upper corner): {exc}") from exc
    if b.shape != (2, 3):
        raise DanoError(f"{what} must have shape (2, 3) (lower; upper corner), got {b.shape}")
    if not np.all(np.isfinite(b)) or not np.all(b[1] > b[0]):
        raise DanoError(f"{what} must be finite with lower < upper on every axis, got {b.tolist()}")
    return b


def grid_points(bounds: np.ndarray, resolution: int | tuple[int, int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Cell-centre grid over ``bounds``.

    Returns ``(points (nx*ny*nz, 3), shape (3,))``, C order (x slowest).
    """
    res = np.broadcast_to(np.asarray(resolution, dtype=int), (3,))
    axes = [
        bounds[0, k] + (np.arange(res[k]) + 0.5) * (bounds[1, k] - bounds[0, k]) / res[k]
        for k in range(3)
    ]
    mesh = np.meshgrid(*axes, indexing="ij")
    return np.stack([m.ravel() for m in mesh], axis=-1), res



def evaluate(field: DensityField, points: np.ndarray, chunk: int = 1 << 18,
             signed_distance: bool = False) -> np.ndarray:
    """Evaluate ``field.density`` (or, with ``signed_distance``, ``field.signed_distance`` [m])
    on many points (N, 3), field frame [m], in jitted chunks; returns float64 numpy (N,)."""
    pts = np.asarray(points, dtype=np.float64)
    out = np.empty(len(pts))
    for start in range(0, len(pts), chunk):
        block = pts[start : start + chunk]
        n = len(block)
        if n < chunk and len(pts) > chunk:  # pad to keep one compiled shape
            block = np.concatenate([block, np.repeat(block[-1:], chunk - n, axis=0)])
        out[start : start + n] = np.asarray((_DISTANCE_JIT if signed_distance else _DENSITY_JIT)(field, block))[:n]
    return out


_DENSITY_JIT = jax.jit(lambda f, p: f.density(p))
_DISTANCE_JIT = jax.jit(lambda f, p: f.signed_distance(p))


def interior_density(field) -> float:
    """Density of full occupancy of a field (its interior value; the surface is half of it):
    the field's optional ``interior_density()``, else the largest density on a 33³ grid over
    its bounds. Raises DanoError if that is not positive and finite."""
    fn = getattr(field, "interior_density", None)
    if fn is not None:
        rho = float(fn())
    else:
        b = np.asarray(field.bounds(), dtype=np.float64)
        axes = [np.linspace(b[0, k], b[1, k], 33) for k in range(3)]
        grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        rho = float(np.max(np.asarray(field.density(jnp.asarray(grid)))))
    if not np.isfinite(rho) or rho <= 0:
        raise DanoError(f"the {type(field).__name__}'s interior density must be positive and finite, got {rho}")
    return rho


#: largest accepted grid resolution (nodes along the longest axis of a signed-distance or marching-cubes grid)
MAX_RESOLUTION = 512  # 1.3e8 nodes: about 5 GB while a signed-distance or marching-cubes grid is built


def check_resolution(resolution: int) -> None:
    """Raises DanoError unless 8 ≤ ``resolution`` ≤ :data:`MAX_RESOLUTION` (with the memory a
    grid of that size would take)."""
    if not 8 <= resolution <= MAX_RESOLUTION:
        raise DanoError(f"--resolution {resolution}: must be 8 to {MAX_RESOLUTION} (a grid of about resolution^3 "
                        f"nodes at ~40 bytes each: {40 * float(resolution) ** 3 / 1e9:.3g} GB)")

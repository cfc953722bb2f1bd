"""A field given in another frame: scaled, rotated and offset."""

from __future__ import annotations

from dataclasses import dataclass
from itertools import product
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import DanoError
from ..pose import quat_to_matrix
from .base import NamedField, as_points, field_name


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class TransformedField(NamedField):
    """φ(x) = φ_base(Rᵀ(x − t) / s): the base field scaled by s, then rotated by R,
    then offset by t.

    base: any density field; scale s > 0 (uniform); rotation: (3, 3) rotation
    matrix R; offset t: (3,) [m]. Densities keep their values (a uniformly scaled
    object keeps its density; its mass grows as s³).
    Build with :meth:`create`, which accepts a wxyz quaternion (MuJoCo's convention).
    ``name``: the base field's (:func:`~dano.fields.base.field_name`) unless :meth:`named`.
    """

    base: Any
    scale: float
    rotation: jax.Array
    offset: jax.Array

    @classmethod
    def create(cls, base, scale: float = 1.0, quat_wxyz=(1.0, 0.0, 0.0, 0.0), offset=(0.0, 0.0, 0.0)):
        """Raises DanoError for a non-positive scale, a zero quaternion or bad shapes."""
        scale = float(scale)
        if not np.isfinite(scale) or scale <= 0:
            raise DanoError(f"scale must be a finite positive number, got {scale}")
        q = np.asarray(quat_wxyz, dtype=np.float64)
        if q.shape != (4,) or not np.all(np.isfinite(q)) or np.linalg.norm(q) < 1e-12:
            raise DanoError(f"rotation must be a non-zero wxyz quaternion (4,), got {q.tolist()}")
        t = np.asarray(offset, dtype=np.float64)
        if t.shape != (3,) or not np.all(np.isfinite(t)):
            raise DanoError(f"offset must be 3 finite numbers, got {t.tolist()}")
        R = quat_to_matrix(q)  # normalises
        return cls(base, scale, jnp.asarray(R), jnp.asarray(t))

    @classmethod
    def from_matrix(cls, base, scale: float, rotation, offset) -> "TransformedField":
        """The same from a (3, 3) rotation matrix (as stored in a ``.dano`` file). Raises
        DanoError for a non-positive scale, a matrix that is not a rotation (to 1e-6) or a
        bad offset."""
        scale = float(scale)
        if not np.isfinite(scale) or scale <= 0:
            raise DanoError(f"scale must be a finite positive number, got {scale}")
        R = np.asarray(rotation, dtype=np.float64)
        if (R.shape != (3, 3) or not np.all(np.isfinite(R)) or not np.allclose(R.T @ R, np.eye(3), atol=1e-6)
                or np.linalg.det(R) < 0):
            raise DanoError(f"rotation must be a (3, 3) rotation matrix, got {R.tolist()}")
        t = np.asarray(offset, dtype=np.float64)
        if t.shape != (3,) or not np.all(np.isfinite(t)):
            raise DanoError(f"offset must be 3 finite numbers, got {t.tolist()}")
        return cls(base, scale, jnp.asarray(R), jnp.asarray(t))

    def _default_name(self) -> str:
        return field_name(self.base)

    def density(self, points: jax.Array) -> jax.Array:
        p = as_points(points)
        local = ((p - self.offset) @ self.rotation) / self.scale
        return self.base.density(local)

    def bounds(self) -> np.ndarray:
        b = self.base.bounds()
        corners = np.array([[b[i, 0], b[j, 1], b[k, 2]] for i, j, k in product((0, 1), repeat=3)])
        world = corners * self.scale @ np.asarray(self.rotation).T + np.asarray(self.offset)
        return np.stack([world.min(0), world.max(0)])

    def interior_density(self) -> float:
        """The base field's interior density (densities keep their values)."""
        return float(self.base.interior_density())

"""Analytic density fields: exact references for tests and simple objects."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import DanoError
from .base import NamedField, as_points, safe_norm, smooth_occupancy


def _concrete(*values) -> bool:
    """True when constructing from user values (not when JAX rebuilds the pytree
    from tracers or placeholders during transformations)."""
    return all(isinstance(v, (int, float, tuple, list, np.ndarray, np.generic)) for v in values)


def _positive(name: str, value: float) -> float:
    value = float(value)
    if not np.isfinite(value) or value <= 0:
        raise DanoError(f"{name} must be a finite positive number, got {value}")
    return value


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class SphereField(NamedField):
    """Solid sphere with a smooth edge: φ(x) = ρ·σ((R − |x − c|)/w).

    radius R [m]; edge_width w [m] (logistic scale, see :func:`smooth_occupancy`);
    density ρ (interior value); center c (3,) object frame [m].
    The exact mass of the sharp sphere is α·ρ·4/3·πR³; the smooth edge adds a relative
    π²(w/R)² to second order. ``name``: "sphere" unless :meth:`named`.
    """

    kind: ClassVar[str] = "sphere"

    radius: float
    edge_width: float = field(default=0.0)
    density_scale: float = 1.0
    center: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self):
        if _concrete(self.radius, self.edge_width):
            _positive("radius", self.radius)
            w = self.edge_width if self.edge_width else 0.01 * self.radius
            object.__setattr__(self, "edge_width", _positive("edge_width", w))
            _positive("density_scale", self.density_scale)

    def density(self, points: jax.Array) -> jax.Array:
        p = as_points(points) - jnp.asarray(self.center)
        d = safe_norm(p) - self.radius
        return self.density_scale * smooth_occupancy(d, self.edge_width)

    def bounds(self) -> np.ndarray:
        pad = float(self.radius) + 12.0 * float(self.edge_width)
        c = np.asarray(self.center, dtype=np.float64)
        return np.stack([c - pad, c + pad])

    def interior_density(self) -> float:
        """Density of full occupancy, ρ (the surface is the level ρ/2)."""
        return float(self.density_scale)


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class BoxField(NamedField):
    """Solid axis-aligned box with a smooth edge: φ(x) = ρ·σ(−d_box(x − c)/w).

    half_extents h (3,) [m]; d_box is the exact signed distance to the box surface
    (negative inside); edge_width w [m]; density ρ; center c (3,) object frame [m].
    Exact sharp-box references: mass α·ρ·8·h_x·h_y·h_z, inertia about the centre
    m/3·diag(h_y²+h_z², h_x²+h_z², h_x²+h_y²). ``name``: "box" unless :meth:`named`.
    """

    kind: ClassVar[str] = "box"

    half_extents: tuple[float, float, float]
    edge_width: float = 0.0
    density_scale: float = 1.0
    center: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self):
        if _concrete(self.half_extents, self.edge_width):
            h = np.asarray(self.half_extents, dtype=np.float64)
            if h.shape != (3,) or not np.all(np.isfinite(h)) or np.any(h <= 0):
                raise DanoError(f"half_extents must be 3 finite positive numbers, got {h.tolist()}")
            object.__setattr__(self, "half_extents", tuple(float(v) for v in h))
            w = self.edge_width if self.edge_width else 0.01 * float(h.min())
            object.__setattr__(self, "edge_width", _positive("edge_width", w))
            _positive("density_scale", self.density_scale)

    def density(self, points: jax.Array) -> jax.Array:
        p = as_points(points) - jnp.asarray(self.center)
        q = jnp.abs(p) - jnp.asarray(self.half_extents)
        outside = safe_norm(jnp.maximum(q, 0.0))
        inside = jnp.minimum(jnp.max(q, axis=-1), 0.0)
        return self.density_scale * smooth_occupancy(outside + inside, self.edge_width)

    def bounds(self) -> np.ndarray:
        pad = np.asarray(self.half_extents) + 12.0 * float(self.edge_width)
        c = np.asarray(self.center, dtype=np.float64)
        return np.stack([c - pad, c + pad])

    def interior_density(self) -> float:
        """Density of full occupancy, ρ (the surface is the level ρ/2)."""
        return float(self.density_scale)

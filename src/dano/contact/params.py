"""Contact parameters (paper Table I) and the smoothed Coulomb direction."""

from __future__ import annotations

from dataclasses import dataclass, fields

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import DanoError


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class ContactParams:
    """The paper's eight contact parameters (Table I), one value per contact pair.

    Each field is a float or a (P,) array (P contact pairs of a scene).
    impact_spring k [N per unit overlap]: F_n = ψ·(k − c·v_n), ψ in mass units (paper: 1e4-1e5);
    impact_damper c [N·s/m per unit overlap] (paper: 1e5-1e6);
    sliding_friction μ [-]: Coulomb coefficient of the tangential force;
    sliding_drag [N·s/m per unit overlap]: viscous tangential force −drag·ψ·v_t;
    torsional_friction [m]: Coulomb torque about the normal per unit normal force;
    torsional_drag [N·m·s per unit overlap];
    rolling_friction [m]: Coulomb torque about tangent axes per unit normal force;
    rolling_drag [N·m·s per unit overlap].
    Defaults are the paper's: 3e4, 3e5, 0.2, 0.1, 0.01, 0, 0.01, 0.
    """

    impact_spring: jax.Array | float = 3e4
    impact_damper: jax.Array | float = 3e5
    sliding_friction: jax.Array | float = 0.2
    sliding_drag: jax.Array | float = 0.1
    torsional_friction: jax.Array | float = 0.01
    torsional_drag: jax.Array | float = 0.0
    rolling_friction: jax.Array | float = 0.01
    rolling_drag: jax.Array | float = 0.0

    @staticmethod
    def names() -> tuple[str, ...]:
        return tuple(f.name for f in fields(ContactParams))

    def broadcast(self, num_pairs: int) -> "ContactParams":
        """Every field as a (P,) float64 array."""
        return ContactParams(**{n: jnp.broadcast_to(jnp.asarray(getattr(self, n), dtype=jnp.float64), (num_pairs,))
                                for n in self.names()})

    def validate(self) -> "ContactParams":
        """Raises DanoError if a value is non-finite or negative (springs must be > 0)."""
        for n in self.names():
            v = np.asarray(getattr(self, n), dtype=np.float64)
            if not np.all(np.isfinite(v)):
                raise DanoError(f"contact parameter {n} must be finite, got {v.tolist()}")
            if np.any(v < 0) or (n == "impact_spring" and np.any(v <= 0)):
                raise DanoError(f"contact parameter {n} must be {'positive' if n == 'impact_spring' else 'non-negative'}, got {v.tolist()}")
        return self


#: smoothing of the Coulomb direction (paper code): steepness s [s/m] and regulariser r [m/s]
FRICTION_STEEPNESS = 30.0
FRICTION_REGULARIZER = 1e-3


def smooth_direction(v: jax.Array, steepness: float = FRICTION_STEEPNESS,
                     regularizer: float = FRICTION_REGULARIZER) -> jax.Array:
    """Smoothed −v/|v|: −(2/π)·atan(s|v|)·v/(r + |v|), for (..., 3) velocities.

    The paper's code used −atan(s|v|)·v/(r+|v|) with s = 30, r = 1e-3; a later revision
    multiplied by 2/π so that the magnitude tends to 1 (full Coulomb friction) at
    speed; we use that revision. At 1 cm/s the magnitude is 0.17, at 10 cm/s 0.80,
    at 1 m/s 0.98; it is 0 (and smooth, with zero derivative) at v = 0, so there is
    no NaN at rest.
    """
    sq = jnp.sum(v * v, axis=-1, keepdims=True)
    speed = jnp.sqrt(jnp.where(sq > 0, sq, 1.0)) * (sq > 0)
    return -(2.0 / jnp.pi) * jnp.arctan(steepness * speed) * v / (regularizer + speed)

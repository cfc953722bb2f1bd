"""Contact parameters (paper Table I) and the smoothed Coulomb direction."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, fields

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import DanoError


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class ContactParams:
    """The paper's eight contact parameters (Table I), one value per contact pair.

    Every field is a float or a (P,) array (P contact pairs of a scene). ‖F_n‖ below is the
    magnitude of the normal force ψ·max(k − c·v_n, 0) [N], damper included (paper Eq. 8).
    """

    impact_spring: jax.Array | float = 3e4
    """Impact spring k [N per unit overlap]: normal force ψ·k at rest, ψ in mass units (paper: 1e4–1e5)."""
    impact_damper: jax.Array | float = 3e5
    """Impact damper c [N·s/m per unit overlap]: normal force −ψ·c·v_n (paper: 1e5–1e6)."""
    sliding_friction: jax.Array | float = 0.2
    """Sliding friction μ [-]: Coulomb force μ·‖F_n‖ against the slip (Eq. 9)."""
    sliding_drag: jax.Array | float = 0.1
    """Sliding drag [s/m]: viscous force −drag·‖F_n‖·v_t (Eq. 9)."""
    torsional_friction: jax.Array | float = 0.01
    """Torsional friction [m]: Coulomb torque about the normal, per newton of ‖F_n‖ (Eq. 10)."""
    torsional_drag: jax.Array | float = 0.0
    """Torsional drag [m·s]: viscous torque −drag·‖F_n‖·ω_n about the normal (Eq. 10)."""
    rolling_friction: jax.Array | float = 0.01
    """Rolling friction [m]: Coulomb torque about tangent axes, per newton of ‖F_n‖ (Eq. 11)."""
    rolling_drag: jax.Array | float = 0.0
    """Rolling drag [m·s]: viscous torque −drag·‖F_n‖·ω_t about tangent axes (Eq. 11)."""

    @staticmethod
    def names() -> tuple[str, ...]:
        """The 8 parameter names, in the paper's order."""
        return tuple(f.name for f in fields(ContactParams))

    def replace(self, **changes) -> "ContactParams":
        """A copy with the given fields replaced (trace-safe; no validation)."""
        return dataclasses.replace(self, **changes)

    def broadcast(self, num_pairs: int, dtype=None) -> "ContactParams":
        """Every field as a (P,) array of ``dtype`` (default: JAX's default float type). Raises
        ValueError where a field's value does not broadcast to (P,)."""
        dtype = dtype or jax.dtypes.canonicalize_dtype(np.float64)
        values = {n: getattr(self, n) for n in self.names()}
        if any(isinstance(v, jax.core.Tracer) for v in values.values()):
            return ContactParams(**{n: jnp.broadcast_to(jnp.asarray(v, dtype=dtype), (num_pairs,))
                                    for n, v in values.items()})
        # concrete values on the host (jnp.asarray would compile a small program per shape and dtype)
        host = [np.broadcast_to(np.asarray(v, dtype=np.dtype(dtype)), (num_pairs,)) for v in values.values()]
        return ContactParams(**dict(zip(values, jax.device_put(host))))

    def validate(self) -> "ContactParams":
        """Raises DanoError if a value is non-finite or negative (springs must be > 0)."""
        for n in self.names():
            v = np.asarray(getattr(self, n), dtype=np.float64)
            if not np.all(np.isfinite(v)):
                raise DanoError(f"contact parameter {n} must be finite, got {v.tolist()}")
            if np.any(v < 0) or (n == "impact_spring" and np.any(v <= 0)):
                raise DanoError(f"contact parameter {n} must be {'positive' if n == 'impact_spring' else 'non-negative'}, got {v.tolist()}")
        return self


#: smoothing of the Coulomb direction: steepness s [s/m] (the paper's code: 30) and regulariser r [m/s]
FRICTION_STEEPNESS = 100.0
FRICTION_REGULARIZER = 1e-3


def smooth_direction(v: jax.Array, steepness: float = FRICTION_STEEPNESS,
                     regularizer: float = FRICTION_REGULARIZER, axis: int = -1) -> jax.Array:
    """Smoothed −v/|v|: −(2/π)·atan(s|v|)·v/(r + |v|), for velocities along ``axis`` (3).

    The paper's code used −atan(s|v|)·v/(r+|v|) with s = 30, r = 1e-3, whose magnitude
    tends to π/2 (so its friction coefficients act as 1.57·μ at speed); a later revision
    multiplied by 2/π so that the magnitude tends to 1 (full Coulomb friction); we use that
    revision with s = 100 (:data:`FRICTION_STEEPNESS`). The magnitude is 0.46 at 1 cm/s,
    0.80 at 3.5 cm/s, 0.93 at 10 cm/s, 0.985 at 0.5 m/s and 0.993 at 1 m/s, and an object
    held by friction against half its limit creeps at 1.1 cm/s (with the paper's s = 30: 0.80
    at 10.7 cm/s, 0.96 at 0.5 m/s, 0.98 at 1 m/s, so that a slide felt 2–5 % less than
    μ·‖F_n‖, and the creep was 3.5 cm/s). Measured against hard Coulomb friction (plain
    MuJoCo C slides of a box, Spot and a bunny at μ = 0.2–0.8) in docs/sysid.md. Steeper is
    nearer Coulomb still (300 fitted those slides a little better), but the steeper the
    friction, the harder the step's solve: with the grasp's stiff pads (spring 1e6) at 10 ms
    steps, 200 and 300 dropped the bunny, 100 pushed a finger 3.6 cm past its joint limit,
    and 30 held it within 1 cm (docs/simulation.md). Contact models take
    ``friction_steepness`` (``Centroid(friction_steepness=30.0)``: the paper code's). It is 0
    (and smooth, with a finite derivative) at v = 0, so there is no NaN at rest.
    """
    _, _, phi, _ = direction_profile(v, steepness, regularizer, axis)
    return -(2.0 / jnp.pi) * phi * v


def direction_profile(v: jax.Array, steepness: float = FRICTION_STEEPNESS,
                      regularizer: float = FRICTION_REGULARIZER, axis: int = -1):
    """The parts of :func:`smooth_direction` (= −(2/π)·φ(|v|)·v) for velocities v along
    ``axis``: (speed |v|, unit v/|v| (0 where v = 0), φ = atan(s·|v|)/(r + |v|) and its
    slope dφ/d|v| [s/m per m/s]), the speed-shaped arrays keeping ``axis`` with length 1.
    All are finite at v = 0 (the square root is taken of a positive stand-in there)."""
    sq = jnp.sum(v * v, axis=axis, keepdims=True)
    moving = sq > 0
    speed = jnp.sqrt(jnp.where(moving, sq, 1.0)) * moving
    unit = v / jnp.where(moving, speed, 1.0)
    angle = jnp.arctan(steepness * speed)
    denom = regularizer + speed
    phi = angle / denom
    dphi = steepness / ((1.0 + (steepness * speed) ** 2) * denom) - phi / denom
    return speed, unit, phi, dphi

"""The contact force law (paper §IV-D, Eqs. 8–12).

For an overlap ψ (mass units), a unit normal n from B into A, and the velocity of A
relative to B at the contact point (linear v [m/s], angular ω [rad/s], world frame):

    v_n = n·v,  v_t = v − v_n n,  ω_n = n·ω,  ω_t = ω − ω_n n
    ‖F_n‖ = ψ·max⁺(k − c·v_n)                                     normal force (Eq. 8)
    F = ‖F_n‖·n + ‖F_n‖·(μ_s d(v_t) − β_s v_t)                     sliding (Eq. 9)
    τ = ‖F_n‖·(μ_τ d(ω_n n) − β_τ ω_n n) + ‖F_n‖·(μ_r d(ω_t) − β_r ω_t)   torsion, rolling (Eqs. 10–11)

with d the smoothed Coulomb direction (:func:`~dano.contact.params.smooth_direction`,
pointing against its argument). F acts on A at the contact point, −F on B (Eq. 12).

Differences from the paper's code (Dojo.jl), all documented in docs/simulation.md:
the normal force is kept from turning attractive by max⁺(x) = w·softplus(x/w), a smooth
max(x, 0) over w = 1 % of k (the linear law pulls separating bodies together when
c·v_n > k; the smooth clamp keeps the implicit step's equation C¹, so Newton's method
converges); d carries the 2/π factor of its later revision (|d| → 1); the torsional term
uses ω_n and the rolling term ω_t. ``drag="overlap"`` restores dano 0.1's weaker law in
which the drags scale with ψ instead of ‖F_n‖.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import DanoError
from .params import FRICTION_STEEPNESS, ContactParams, direction_profile, smooth_direction

#: how the viscous drags scale: by ‖F_n‖ (paper Eqs. 9–11) or by ψ (dano 0.1)
DRAG_SCALINGS = ("normal_force", "overlap")


def check_drag(drag: str) -> str:
    """``drag`` if it is one of :data:`DRAG_SCALINGS`; raises DanoError otherwise."""
    if drag not in DRAG_SCALINGS:
        raise DanoError(f"drag must be one of {DRAG_SCALINGS}, got {drag!r}")
    return drag


def check_steepness(steepness) -> float:
    """``friction_steepness`` [s/m] as a float if it is finite and positive; raises DanoError
    otherwise (a contact model's static field: it is part of the compiled program)."""
    value = float(steepness) if isinstance(steepness, (int, float)) and not isinstance(steepness, bool) else np.nan
    if not (np.isfinite(value) and value > 0):
        raise DanoError(f"friction_steepness must be a positive number [s/m], got {steepness!r}")
    return value


#: width of the smooth clamp of the normal force, relative to the impact spring k
CLAMP_WIDTH = 0.01


def smooth_max0(x, width):
    """max(x, 0) smoothed over ``width``: width·softplus(x/width) (> 0, C^∞, ≤ x + 0.7·width)."""
    return width * jax.nn.softplus(x / width)


def normal_force(p: ContactParams, psi, vn):
    """‖F_n‖ = ψ·max⁺(k − c·v_n) [N] (Eq. 8, kept from turning attractive by a smooth clamp
    over 1 % of k); broadcasts over samples."""
    return psi * smooth_max0(p.impact_spring - p.impact_damper * vn, CLAMP_WIDTH * p.impact_spring)


def pair_wrench(p: ContactParams, psi, normal, v, w, drag: str = "normal_force",
                steepness: float = FRICTION_STEEPNESS):
    """Force (3,) [N] and torque (3,) [N·m] on A, world frame, of one contact pair.

    p: parameters of this pair (scalars); psi: overlap (mass units); normal: (3,) from B
    into A; v, w: (3,) relative linear [m/s] and angular [rad/s] velocity of A w.r.t. B
    at the centroid χ; steepness: of the smoothed Coulomb direction [s/m]
    (:func:`~dano.contact.params.smooth_direction`). Eqs. 8–11.
    """
    vn = jnp.dot(normal, v)
    vt = v - vn * normal
    wn = jnp.dot(normal, w)
    wt = w - wn * normal
    fn = normal_force(p, psi, vn)
    s = fn if drag == "normal_force" else psi
    # the three smoothed Coulomb directions in one call (fewer, larger XLA kernels per step)
    d_slide, d_twist, d_roll = smooth_direction(jnp.stack([vt, wn * normal, wt]), steepness)
    force = fn * normal + fn * p.sliding_friction * d_slide - s * p.sliding_drag * vt
    torque = (fn * p.torsional_friction * d_twist - s * p.torsional_drag * wn * normal
              + fn * p.rolling_friction * d_roll - s * p.rolling_drag * wt)
    return force, torque


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class SampleForceSlopes:
    """The derivatives of :func:`sample_forces` of S samples, in closed form (for the step's
    Newton Jacobian: one structured 3×3 block per sample instead of forward-mode tangents).

    ∂F_i/∂v_i = kappa_i·I + along_normal_i ⊗ n_i + along_slip_i ⊗ t̂_i (3×3), with t̂_i
    = slip_direction (3, S) the unit tangential velocity (0 where there is no slip);
    ∂F_i/∂weight_i = per_weight (3, S). kappa (S,) [N·s/m]; along_normal, along_slip (3, S)
    [N·s/m]; per_weight (3, S) [N per unit weight]."""

    kappa: jax.Array
    along_normal: jax.Array
    along_slip: jax.Array
    slip_direction: jax.Array
    per_weight: jax.Array


def sample_forces(p: ContactParams, weight, normal, v, drag: str = "normal_force",
                  steepness: float = FRICTION_STEEPNESS):
    """Forces (3, S) [N] on A of S contact samples, each with its own share of the overlap.

    weight: (S,) α·w_i·o_i, the sample's share of ψ (mass units); normal: (3, S) from B
    into A at each sample; v: (3, S) relative velocity of A w.r.t. B at each sample. Each
    sample applies the normal force and the sliding terms of Eqs. 8–9 with ψ replaced by its
    share, so the forces add up to the pair's normal force at rest; torsional and rolling
    resistance then come from how the forces are distributed.
    """
    return sample_forces_and_slopes(p, weight, normal, v, drag, steepness)[0]


def sample_forces_and_slopes(p: ContactParams, weight, normal, v, drag: str = "normal_force",
                             steepness: float = FRICTION_STEEPNESS):
    """:func:`sample_forces` (3, S) and its :class:`SampleForceSlopes` (same arguments).

    With v_n = n·v, v_t = v − v_n·n (speed ρ, direction t̂), x = k − c·v_n, the clamp
    G = max⁺(x) (slope G' = sigmoid(x/width)), ‖F_n‖ = w·G and the smoothed direction
    d = −(2/π)·φ(ρ)·v_t (:func:`~dano.contact.params.direction_profile`), the force is
    F = ‖F_n‖·(n + μ·d) − s·β·v_t with s = ‖F_n‖ (drag "normal_force") or w ("overlap"):
    ∂F/∂v = γ·e ⊗ n + κ·(I − n ⊗ n) − (2/π)·‖F_n‖·μ·φ'(ρ)·ρ·t̂ ⊗ t̂, with γ = −w·G'·c,
    e = n + μ·d − β·v_t (drag "normal_force"; n + μ·d for "overlap") and
    κ = −(2/π)·‖F_n‖·μ·φ(ρ) − s·β; ∂F/∂w = G·e ("normal_force") or G·(n + μ·d) − β·v_t."""
    normal = jnp.broadcast_to(normal, v.shape)
    vn = jnp.sum(normal * v, axis=0)
    vt = v - vn * normal
    width = CLAMP_WIDTH * p.impact_spring
    x = p.impact_spring - p.impact_damper * vn
    clamp = smooth_max0(x, width)
    fn = weight * clamp
    speed, unit, phi, dphi = direction_profile(vt, steepness, axis=0)
    speed, phi, dphi = speed[0], phi[0], dphi[0]  # (S,)
    mu, beta = p.sliding_friction, p.sliding_drag
    push = normal + mu * (-(2.0 / jnp.pi) * phi * vt)  # n + μ·d
    if drag == "normal_force":
        e = push - beta * vt
        forces = fn * e
        per_weight = clamp * e
        s = fn
    else:
        e = push
        forces = fn * push - (weight * beta) * vt
        per_weight = clamp * push - beta * vt
        s = weight
    gamma = -weight * jax.nn.sigmoid(x / width) * p.impact_damper
    kappa = -(2.0 / jnp.pi) * fn * mu * phi - s * beta
    slopes = SampleForceSlopes(kappa, gamma * e - kappa * normal, (-(2.0 / jnp.pi) * fn * mu * dphi * speed) * unit,
                               unit, per_weight)
    return forces, slopes

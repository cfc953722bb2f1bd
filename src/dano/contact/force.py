"""The contact force law (paper §IV-D, Eqs. 8-12).

Given the overlap ψ, the normal n (from B into A) and the relative velocity of A
with respect to B at the centroid (linear v, angular ω, world frame):

    v_n = n·v,  v_t = v − v_n n,  ω_n = n·ω,  ω_t = ω − ω_n n
    f_n = ψ·max(k − c·v_n, 0)                         normal force magnitude (Eq. 8)
    F   = f_n n + μ_s f_n d(v_t) − β_s ψ v_t          force on A at χ (Eqs. 8-9)
    τ   = μ_τ f_n d(ω_n n) − β_τ ψ ω_n n              torsional torque (Eq. 10)
        + μ_r f_n d(ω_t) − β_r ψ ω_t                  rolling torque (Eqs. 11-12)

with d the smoothed Coulomb direction (:func:`~dano.contact.params.smooth_direction`).
B receives −F at χ and −τ. The clamp at 0 keeps the damper from pulling bodies
together while they separate (the paper's linear law can turn attractive).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .params import ContactParams, smooth_direction


def contact_wrench(p: ContactParams, psi, normal, v, w):
    """Force (3,) and torque (3,) on body A, world frame [N], [N·m].

    p: parameters of this pair (scalars); psi: overlap (mass units); normal: (3,);
    v, w: relative linear [m/s] and angular [rad/s] velocity of A w.r.t. B at χ.
    """
    vn = jnp.dot(normal, v)
    vt = v - vn * normal
    wn = jnp.dot(normal, w)
    wt = w - wn * normal
    fn = psi * jnp.maximum(p.impact_spring - p.impact_damper * vn, 0.0)
    force = fn * normal + p.sliding_friction * fn * smooth_direction(vt) - p.sliding_drag * psi * vt
    torque = (p.torsional_friction * fn * smooth_direction(wn * normal) - p.torsional_drag * psi * wn * normal
              + p.rolling_friction * fn * smooth_direction(wt) - p.rolling_drag * psi * wt)
    return force, torque


def generalized_force(p: ContactParams, psi, normal, jacp, jacr, qvel):
    """Generalized contact force Q = Jp F + Jr τ (nv,) for a batch of P pairs.

    p: fields (P,); psi (P,); normal (P, 3); jacp, jacr: (P, nv, 3) difference of the
    point Jacobians of A and B at χ (world frame); qvel (nv,).
    """
    v = jnp.einsum("pvk,v->pk", jacp, qvel)
    w = jnp.einsum("pvk,v->pk", jacr, qvel)
    force, torque = jax.vmap(contact_wrench)(p, psi, normal, v, w)
    return jnp.einsum("pvk,pk->v", jacp, force) + jnp.einsum("pvk,pk->v", jacr, torque)

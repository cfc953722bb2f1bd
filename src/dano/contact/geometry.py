"""Contact geometry of a DANO against another body (paper §IV-C, Eqs. 5-7).

For a DANO A with boundary samples p_i (body frame), weights w_i = φ_i/Σφ·m and a
body B, the overlap is ψ = Σ_i w_i·o_B(x_i) (mass units; o_B ∈ [0, 1] is B's
occupancy at the sample's world position x_i), the centroid is χ = Σ w_i o_B x_i / ψ,
and n is the unit contact normal pointing from B into A (the direction A is pushed).

For primitives (plane, sphere, capsule, box) o_B is a smoothed inside test of B's
signed distance d_B: every sample stands for a small blob of radius r (the
``sample_radius``), o_B = smoothstep((r − d_B)/(2r)), exactly 0 outside and 1
deeper than r, C¹ in between. This keeps ψ, χ and so the force continuous in the
configuration (a hard test makes them piecewise constant, with zero gradients)
while contact stays exactly zero when nothing touches. n is ∇d_B at χ.

For DANO-DANO contact both directions are summed (A's samples in B's field and B's
samples in A's field, ψ = average of the two) and n is the overlap-weighted average
of the sampled normals (−n_A of A's samples, +n_B of B's), as in the paper.

All functions take body poses (x: (3,) world [m], R: (3, 3) world-from-body) and
return ``(psi, chi (3,) world [m], normal (3,) world)``; they are pure JAX, finite
(no NaN) when nothing overlaps (ψ = 0; χ = the DANO's origin, or for two DANOs the
midpoint of their origins).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ..fields.base import safe_norm


def smoothstep_occupancy(d: jax.Array, radius: jax.Array | float) -> jax.Array:
    """Fraction of a sample blob of radius r inside a body at signed distance d [m]."""
    t = jnp.clip((radius - d) / (2.0 * radius), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _unit(v: jax.Array, fallback: jax.Array) -> jax.Array:
    n = safe_norm(v)
    return jnp.where(n > 1e-12, v / jnp.where(n > 1e-12, n, 1.0), fallback)


def _finish(wp: jax.Array, occ: jax.Array, alpha, x, R):
    """Weighted sums as one matrix-vector product: wp = [w·p; w] (4, N)."""
    s = wp @ occ  # (4,)
    psi0 = s[3]
    lever = s[:3] / jnp.where(psi0 > 0, psi0, 1.0)  # body frame, 0 when ψ = 0
    return alpha * psi0, x + R @ lever


def plane(wp, points, radius, alpha, x, R, plane_pos, plane_normal):
    """DANO vs half-space {y : (y − plane_pos)·plane_normal < 0} (MuJoCo plane geom).

    wp: (4, N) [w·p; w] with p body frame; points (3, N) body frame [m]; radius [m].
    Only the height row is computed: h = (Rᵀn)·p + (n·x − n·plane_pos).
    """
    h = (R.T @ plane_normal) @ points + jnp.dot(plane_normal, x - plane_pos)
    psi, chi = _finish(wp, smoothstep_occupancy(h, radius), alpha, x, R)
    return psi, chi, plane_normal


# Signed distances of MuJoCo primitives: y (3, N) points in the geom frame [m], size: the
# geom's MuJoCo size vector; return (N,) [m], negative inside.


def sdf_sphere(y, size):
    return safe_norm(y, axis=0) - size[0]


def sdf_capsule(y, size):
    """Capsule along local z: radius size[0], half-length size[1]."""
    z = jnp.clip(y[2], -size[1], size[1])
    return safe_norm(jnp.stack([y[0], y[1], y[2] - z]), axis=0) - size[0]


def sdf_box(y, size):
    """Box with half-extents size[:3]."""
    q = jnp.abs(y) - size[:3, None]
    outside = safe_norm(jnp.maximum(q, 0.0), axis=0)
    inside = jnp.minimum(jnp.max(q, axis=0), 0.0)
    return outside + inside


SDFS = {"sphere": sdf_sphere, "capsule": sdf_capsule, "box": sdf_box}


def primitive(kind, wp, points, radius, alpha, x, R, geom_pos, geom_mat, size):
    """DANO vs a sphere, capsule or box geom (MuJoCo sizes; geom frame geom_pos, geom_mat)."""
    sdf = SDFS[kind]
    A = geom_mat.T @ R
    b = geom_mat.T @ (x - geom_pos)
    y = A @ points + b[:, None]  # samples in the geom frame (3, N)
    psi, chi = _finish(wp, smoothstep_occupancy(sdf(y, size), radius), alpha, x, R)
    chi_local = geom_mat.T @ (chi - geom_pos)
    grad = jax.grad(lambda c: sdf(c[:, None], size)[0])(chi_local)
    fallback = _unit(x - geom_pos, jnp.array([0.0, 0.0, 1.0]))
    return psi, chi, _unit(geom_mat @ grad, fallback)


def dano_pair(a, b, alpha_a, alpha_b, xa, Ra, xb, Rb):
    """DANO A vs DANO B, both fields queried (paper §IV-C).

    a, b: objects with ``points`` (3, N) body frame, ``normals`` (3, N), ``weights``
    (N,) per unit α, ``field`` (object frame), ``com`` (3,) object-frame centre of
    mass and ``rho_ref`` (density of full occupancy). Returns the normal on A.
    """

    def one_side(s, o, alpha_s, xs, Rs, xo, Ro):
        # s's samples expressed in o's object frame
        y = (Ro.T @ Rs) @ s.points + (Ro.T @ (xs - xo) + o.com)[:, None]
        occ = jnp.clip(o.field.density(y.T) / o.rho_ref, 0.0, 1.0)
        wo = s.weights * occ
        psi = alpha_s * jnp.sum(wo)
        centroid_sum = alpha_s * (Rs @ (s.points @ wo) + xs * jnp.sum(wo))
        normal_sum = alpha_s * (Rs @ (s.normals @ wo))
        return psi, centroid_sum, normal_sum

    pa, ca, na = one_side(a, b, alpha_a, xa, Ra, xb, Rb)
    pb, cb, nb = one_side(b, a, alpha_b, xb, Rb, xa, Ra)
    total = pa + pb
    chi = jnp.where(total > 0, (ca + cb) / jnp.where(total > 0, total, 1.0), 0.5 * (xa + xb))
    normal = _unit(nb - na, _unit(xa - xb, jnp.array([0.0, 0.0, 1.0])))
    return 0.5 * total, chi, normal

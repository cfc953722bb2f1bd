"""Contact points on the surface: boundary samples moved onto the field's surface level.

Boundary samples are drawn in a density band around the surface (paper §IV-B), so they
sit up to a band's half-width outside or inside it; used as contact points as they are,
a flat face rests on its outermost samples, above its true surface. When the DANO has a
queryable field, each sample is moved along its normal onto the level set φ = ρ/2 (ρ the
field's interior density: the sharp surface of analytic and mesh-derived fields), found by
bisection of t ↦ φ(p − t·n) − ρ/2 on [−max_shift, max_shift] (φ rises inward along −n;
robust on the steep edges of analytic and mesh-derived fields). Samples whose normal is
invalid or whose segment does not cross the level keep their position. Without a field
(the paper's colliders) the samples are the best surface estimate there is.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np


@jax.jit
def _project(field, points, normals, level, max_shift):
    def g(p, n, t):
        return field.density((p - t * n)[None])[0] - level

    def one(p, n):
        lo, hi = -max_shift, max_shift
        g_lo, g_hi = g(p, n, lo), g(p, n, hi)
        bracketed = (g_lo < 0) & (g_hi > 0)

        def body(_, bounds):
            a, b = bounds
            mid = 0.5 * (a + b)
            inside = g(p, n, mid) > 0
            return jnp.where(inside, a, mid), jnp.where(inside, mid, b)

        a, b = jax.lax.fori_loop(0, 48, body, (jnp.asarray(lo, points.dtype), jnp.asarray(hi, points.dtype)))
        t = 0.5 * (a + b)
        return jnp.where(bracketed, p - t * n, p), bracketed

    return jax.vmap(one)(points, normals)


def surface_points(field, points_object: np.ndarray, normals: np.ndarray, level: float,
                   max_shift: float) -> tuple[np.ndarray, np.ndarray]:
    """Samples moved onto the level set φ = ``level`` along their normals.

    points_object: (N, 3) object frame [m]; normals: (N, 3) outward unit normals (rows of
    zeros for invalid ones); level: density of the surface; max_shift: largest move [m].
    Returns ((N, 3) points, object frame [m]; (N,) bool, True where a sample was moved).
    """
    valid = np.linalg.norm(normals, axis=1) > 0.5
    pts, moved = _project(field, jnp.asarray(points_object), jnp.asarray(normals), level, max_shift)
    moved = np.asarray(moved) & valid
    return np.where(moved[:, None], np.asarray(pts), points_object), moved

"""Pair kinds ``sphere``, ``capsule`` and ``box``: a DANO against a MuJoCo primitive geom,
through the primitive's exact signed distance (paper §IV-C)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

from ..fields.base import safe_norm
from .base import PairGeometry, centroid_rates, occupancy, register_pair_kind, unit, weighted_centroid, world_frame

# Signed distances of MuJoCo primitives: y (3, N) points in the geom frame [m], size: the
# geom's MuJoCo size vector (3,); return (N,) [m], negative inside.


def sdf_sphere(y, size):
    """Sphere of radius size[0]."""
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


@dataclass(frozen=True)
class PrimitiveKind:
    """A DANO against a primitive with signed distance ``sdf``; the pair normal is ∇sdf at χ,
    each sample's normal ∇sdf at the sample (both in the world frame)."""

    name: str
    sdf: Callable

    def inputs(self, scene, group, m, d, alpha):
        a, ba, g = (np.asarray(v, dtype=np.int32) for v in (group.a, group.body_a, group.geom))
        return dict(samples=scene.samples.take(a), alpha=alpha[a], xa=d.xpos[ba], Ra=d.xmat[ba],
                    xb=d.geom_xpos[g], Rb=d.geom_xmat[g], size=m.geom_size[g])

    def geometry(self, inp) -> PairGeometry:
        s, R, x, size = inp["samples"], inp["Ra"], inp["xa"], inp["size"]
        gpos, gmat = inp["xb"], inp["Rb"]
        A = gmat.T @ R
        y = A @ s.points + (gmat.T @ (x - gpos))[:, None]  # samples in the geom frame (3, N)
        depth = -self.sdf(y, size) / s.radius
        psi, _, chi = weighted_centroid(s.wp, occupancy(depth), inp["alpha"], x, R)
        grad = jax.grad(lambda c: self.sdf(c[:, None], size)[0])
        fallback = unit(x - gpos, jnp.array([0.0, 0.0, 1.0], dtype=x.dtype))
        normal = unit(gmat @ grad(gmat.T @ (chi - gpos)), fallback)
        sdf_grad = gmat @ jax.vmap(grad, in_axes=1, out_axes=1)(y)  # (3, N) world
        points = R @ s.points + x[:, None]
        weight, grad, moves = inp["alpha"] * s.weights, -sdf_grad / s.radius, jnp.ones_like(depth)
        return PairGeometry(psi, chi, normal, *centroid_rates(weight, depth, grad, moves, points, chi), weight, depth,
                            grad, moves, points, unit(sdf_grad, normal[:, None], axis=0), *world_frame(x.dtype))


SDFS = {"sphere": sdf_sphere, "capsule": sdf_capsule, "box": sdf_box}
for _name, _sdf in SDFS.items():
    register_pair_kind(PrimitiveKind(_name, _sdf))

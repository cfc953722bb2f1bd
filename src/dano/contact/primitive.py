"""Pair kinds ``sphere``, ``capsule`` and ``box``: a DANO against a MuJoCo primitive geom,
through the primitive's exact signed distance (paper §IV-C) and its gradient in closed form.

The gradients are written out rather than taken by ``jax.vmap(jax.grad(sdf))``: both give the
same columns (tested, to rounding, away from the measure-zero ties where a derivative is not
defined), but the closed form is a few elementwise operations per sample. On the 2-core VM
(one XLA thread), the identification residual of a user's mug sliding beside a box geom it
never touches took 0.10–0.11 s instead of 0.21 s and its Jacobian 0.27–0.29 s instead of
0.48–0.54 s; without the box 0.021–0.026 s, unchanged (``benchmarks/results-cpu.json``,
``primitive_pairs_closed_form_gradient``)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import jax.numpy as jnp
import numpy as np

from ..fields.base import safe_norm
from .base import PairGeometry, centroid_rates, occupancy, register_pair_kind, unit, weighted_centroid, world_frame

# Signed distances of MuJoCo primitives: y (3, N) points in the geom frame [m], size: the
# geom's MuJoCo size vector (3,); return (N,) [m], negative inside.


def sdf_sphere(y, size):
    """Sphere of radius size[0]."""
    return safe_norm(y, axis=0) - size[0]


def _unit_columns(w):
    """w / |w| column by column (3, N); 0 where w = 0 (as :func:`safe_norm`'s gradient)."""
    n = safe_norm(w, axis=0)
    return w / jnp.where(n > 0, n, 1.0)


def grad_sphere(y, size):
    """∇ of :func:`sdf_sphere` at y (3, N): y / |y| (0 at the centre)."""
    return _unit_columns(y)


def _capsule_offset(y, size):
    """y minus its nearest point on the capsule's axis segment (3, N)."""
    return jnp.stack([y[0], y[1], y[2] - jnp.clip(y[2], -size[1], size[1])])


def sdf_capsule(y, size):
    """Capsule along local z: radius size[0], half-length size[1]."""
    return safe_norm(_capsule_offset(y, size), axis=0) - size[0]


def grad_capsule(y, size):
    """∇ of :func:`sdf_capsule` at y (3, N): the unit offset from the axis segment (0 on it)."""
    return _unit_columns(_capsule_offset(y, size))


def sdf_box(y, size):
    """Box with half-extents size[:3]."""
    q = jnp.abs(y) - size[:3, None]
    outside = safe_norm(jnp.maximum(q, 0.0), axis=0)
    inside = jnp.minimum(jnp.max(q, axis=0), 0.0)
    return outside + inside


def grad_box(y, size):
    """∇ of :func:`sdf_box` at y (3, N): outside, the unit offset from the nearest point of
    the box; inside, the outward normal of the nearest face (shared equally by faces equally
    near, as JAX's derivative of ``max`` shares it; a coordinate at 0 counts as positive, as
    in JAX's derivative of ``abs``)."""
    q = jnp.abs(y) - size[:3, None]
    sign = jnp.where(y >= 0, 1.0, -1.0).astype(y.dtype)
    out = jnp.maximum(q, 0.0)
    n = safe_norm(out, axis=0)
    nearest = (q == jnp.max(q, axis=0)).astype(y.dtype)
    return sign * jnp.where(n > 0, out / jnp.where(n > 0, n, 1.0), nearest / jnp.sum(nearest, axis=0))


@dataclass(frozen=True)
class PrimitiveKind:
    """A DANO against a primitive with signed distance ``sdf`` and its gradient ``grad``
    (both (3, N) geom-frame points, the geom's size → (N,) [m] and (3, N)); the pair normal is
    ∇sdf at χ, each sample's normal ∇sdf at the sample (both in the world frame)."""

    name: str
    sdf: Callable
    grad: Callable

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
        normal = self._normal(inp, chi)
        sdf_grad = gmat @ self.grad(y, size)  # (3, N) world
        points = R @ s.points + x[:, None]
        weight, grad, moves = inp["alpha"] * s.weights, -sdf_grad / s.radius, jnp.ones_like(depth)
        return PairGeometry(psi, chi, normal, *centroid_rates(weight, depth, grad, moves, points, chi), weight, depth,
                            grad, moves, points, unit(sdf_grad, normal[:, None], axis=0), *world_frame(x.dtype),
                            x)

    def _normal(self, inp, chi):
        """The pair normal (3,): ∇sdf at χ, world (away from the geom's centre where ∇sdf is 0)."""
        gpos, gmat = inp["xb"], inp["Rb"]
        fallback = unit(inp["xa"] - gpos, jnp.array([0.0, 0.0, 1.0], dtype=chi.dtype))
        return unit(gmat @ self.grad((gmat.T @ (chi - gpos))[:, None], inp["size"])[:, 0], fallback)

    def apart(self, inp):
        """() bool: True where no sample can reach the geom: the body's position lies farther
        from the geom's surface than the samples' extent plus one sample radius (the signed
        distance is 1-Lipschitz, so every sample then lies outside, every occupancy and its
        slope are 0). Conservative: False says nothing."""
        s, gmat = inp["samples"], inp["Rb"]
        centre = self.sdf((gmat.T @ (inp["xa"] - inp["xb"]))[:, None], inp["size"])[0]
        return centre > s.extent + s.radius

    def separated(self, inp) -> dict:
        """The aggregates of :meth:`geometry` where :meth:`apart` holds (ψ = 0, its rates 0,
        χ at the body's position, the same normal: the values :meth:`geometry` gives there, as
        are their derivatives), without visiting the samples
        (:func:`~dano.contact.base.skip_separated`)."""
        x = inp["xa"]
        return dict(psi=jnp.zeros((), x.dtype), chi=x, normal=self._normal(inp, x), psi_rate=jnp.zeros(6, x.dtype),
                    moment_rate=jnp.zeros((3, 6), x.dtype))


SDFS = {"sphere": (sdf_sphere, grad_sphere), "capsule": (sdf_capsule, grad_capsule), "box": (sdf_box, grad_box)}
for _name, (_sdf, _grad) in SDFS.items():
    register_pair_kind(PrimitiveKind(_name, _sdf, _grad))

"""Pair kind ``plane``: a DANO against a MuJoCo plane geom (a half-space; paper §IV-C)."""

from __future__ import annotations

from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np

from .base import PairGeometry, occupancy, occupancy_slope, register_pair_kind, skew


@dataclass(frozen=True)
class PlaneKind:
    """Half-space {y : (y − p)·n < 0} of a plane geom at p with normal n (its local z).

    Only the height row of the samples is computed, h_i = (Rᵀn)·p_i + n·(x − p), and the
    overlap, its centroid and their rates come from two matrix–vector products of the
    body-frame weighted moments with the occupancies and with their slopes (the depth
    gradient −n/r is the same for every sample)."""

    name: str = "plane"

    def inputs(self, scene, group, m, d, alpha):
        a, ba, g = (np.asarray(v, dtype=np.int32) for v in (group.a, group.body_a, group.geom))
        return dict(samples=scene.samples.take(a), alpha=alpha[a], xa=d.xpos[ba], Ra=d.xmat[ba],
                    xb=d.geom_xpos[g], Rb=d.geom_xmat[g])

    def geometry(self, inp) -> PairGeometry:
        s, R, x = inp["samples"], inp["Ra"], inp["xa"]
        n = inp["Rb"][:, 2]
        height = (R.T @ n) @ s.points + jnp.dot(n, x - inp["xb"])
        depth = -height / s.radius
        slope = occupancy_slope(depth)
        s0 = inp["alpha"] * (s.wp @ occupancy(depth))  # [Σw·o·p; Σw·o]
        s1 = inp["alpha"] * (s.wp @ slope)  # the same with o'
        q = inp["alpha"] * (s.wpp @ slope)  # Σw·o'·p·pᵀ
        psi, d0 = s0[3], s1[3]
        lever = s0[:3] / jnp.where(psi > 0, psi, 1.0)
        d1 = s1[:3]
        d2 = jnp.array([[q[0], q[3], q[4]], [q[3], q[1], q[5]], [q[4], q[5], q[2]]])
        chi = x + R @ lever
        first = R @ (d1 - d0 * lever)  # Σ w·o'·(x_i − χ), world
        second = R @ (d2 - jnp.outer(d1, lever) - jnp.outer(lever, d1) + d0 * jnp.outer(lever, lever)) @ R.T
        psi_rate = -jnp.concatenate([d0 * n, jnp.cross(first, n)]) / s.radius
        moment_rate = jnp.concatenate([psi * jnp.eye(3, dtype=x.dtype) - jnp.outer(first, n) / s.radius,
                                       -(second @ skew(n)) / s.radius], axis=1)
        # the samples stay in the body frame and the normal is one column: a model that needs
        # few samples (per_sample) transforms only those
        return PairGeometry(psi, chi, n, psi_rate, moment_rate, inp["alpha"] * s.weights, depth,
                            -n[:, None] / s.radius, jnp.ones_like(depth), s.points, n[:, None], R, x, x)


register_pair_kind(PlaneKind())

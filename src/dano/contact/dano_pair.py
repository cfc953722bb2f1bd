"""Pair kind ``dano``: two DANOs, each one's samples tested against the other's density
field (paper §IV-C)."""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from .base import PairGeometry, centroid_rates, occupancy, register_pair_kind, unit, world_frame


def field_depth(phi, rho_ref):
    """Depth coordinate 2φ/ρ − 1 of a point at density φ of a field whose interior density is
    ρ: its occupancy smoothstep(2φ/ρ − 1) is 0 on and outside the surface level φ = ρ/2, 1 at
    full density, C¹ in between (contact begins at the other object's surface)."""
    return 2.0 * phi / rho_ref - 1.0


def _stack_fields(fields):
    return fields[0] if len(fields) == 1 else jax.tree_util.tree_map(lambda *x: jnp.stack(x), *fields)


@dataclass(frozen=True)
class DanoPairKind:
    """A's samples are mapped into B's object frame and B's field is queried, and the
    other way round; ψ is the mean of the two directions (each sample's share halved), χ
    the overlap-weighted mean point, n the overlap-weighted mean of −n_A (A's samples) and
    +n_B (B's samples). Both bodies receive equal and opposite wrenches."""

    name: str = "dano"

    def inputs(self, scene, group, m, d, alpha):
        a, b = np.asarray(group.a, dtype=np.int32), np.asarray(group.b, dtype=np.int32)
        ba, bb = np.asarray(group.body_a, dtype=np.int32), np.asarray(group.body_b, dtype=np.int32)
        fa = _stack_fields([scene.fields[i] for i in group.a])
        fb = _stack_fields([scene.fields[i] for i in group.b])
        if len(group.a) == 1:  # a single pair: give vmap a leading axis
            fa, fb = (jax.tree_util.tree_map(lambda x: jnp.asarray(x)[None], f) for f in (fa, fb))
        return dict(sa=scene.samples.take(a), sb=scene.samples.take(b), fa=fa, fb=fb, alpha_a=alpha[a],
                    alpha_b=alpha[b], xa=d.xpos[ba], Ra=d.xmat[ba], xb=d.xpos[bb], Rb=d.xmat[bb])

    def geometry(self, inp) -> PairGeometry:
        def one_side(s, field_o, o, alpha_s, xs, Rs, xo, Ro):
            y = (Ro.T @ Rs) @ s.points + (Ro.T @ (xs - xo) + o.com)[:, None]  # in o's object frame
            phi, dphi = jax.vmap(jax.value_and_grad(lambda q: field_o.density(q[None])[0]), in_axes=1,
                                 out_axes=(0, 1))(y)
            depth = field_depth(phi, o.rho_ref)
            grad = (2.0 / o.rho_ref) * (Ro @ dphi)  # ∂z/∂x, world (3, N)
            w = alpha_s * s.weights
            world = Rs @ s.points + xs[:, None]  # (3, N)
            return w, depth, grad, w * occupancy(depth), world, Rs @ s.normals

        sa, sb = inp["sa"], inp["sb"]
        ua, za, ga, wa, pa, na = one_side(sa, inp["fb"], sb, inp["alpha_a"], inp["xa"], inp["Ra"], inp["xb"], inp["Rb"])
        ub, zb, gb, wb, pb, nb = one_side(sb, inp["fa"], sa, inp["alpha_b"], inp["xb"], inp["Rb"], inp["xa"], inp["Ra"])
        total = jnp.sum(wa) + jnp.sum(wb)
        safe = jnp.where(total > 0, total, 1.0)
        chi = jnp.where(total > 0, (pa @ wa + pb @ wb) / safe, 0.5 * (inp["xa"] + inp["xb"]))
        up = jnp.array([0.0, 0.0, 1.0], dtype=chi.dtype)
        normal = unit(nb @ wb - na @ wa, unit(inp["xa"] - inp["xb"], up))
        moves = jnp.concatenate([jnp.ones_like(za), jnp.zeros_like(zb)])  # A's samples move with A
        cat = lambda a, b: jnp.concatenate([a, b], axis=-1)  # noqa: E731
        weight, depth, grad, points = 0.5 * cat(ua, ub), cat(za, zb), cat(ga, gb), cat(pa, pb)
        return PairGeometry(0.5 * total, chi, normal, *centroid_rates(weight, depth, grad, moves, points, chi), weight,
                            depth, grad, moves, points, cat(-na, nb), *world_frame(chi.dtype), inp["xa"])

    def apart(self, inp):
        """() bool: True where neither DANO's samples can reach the other's field: each body's
        position, in the other's object frame, lies farther from that field's box (outside of
        which its density is zero: ``bounds()``) than its samples' extent plus one sample
        radius. Every sample then sees density 0 (depth −1), every occupancy and its slope are
        0. Conservative: False says nothing. (A NeRF's floaters lie inside its box.)"""
        sa, sb = inp["sa"], inp["sb"]
        return (_beyond(sb.field_box, inp["Rb"].T @ (inp["xa"] - inp["xb"]) + sb.com, sa.extent + sa.radius)
                & _beyond(sa.field_box, inp["Ra"].T @ (inp["xb"] - inp["xa"]) + sa.com, sb.extent + sb.radius))

    def separated(self, inp) -> dict:
        """The aggregates of :meth:`geometry` where :meth:`apart` holds (ψ = 0, its rates 0, χ
        halfway between the bodies, the normal along their offset: the values, and
        derivatives, :meth:`geometry` gives there), without querying either field
        (:func:`~dano.contact.base.skip_separated`)."""
        xa, xb = inp["xa"], inp["xb"]
        up = jnp.array([0.0, 0.0, 1.0], dtype=xa.dtype)
        return dict(psi=jnp.zeros((), xa.dtype), chi=0.5 * (xa + xb), normal=unit(xa - xb, up),
                    psi_rate=jnp.zeros(6, xa.dtype), moment_rate=jnp.zeros((3, 6), xa.dtype))


def _beyond(box, centre, reach):
    """Whether the ball of radius ``reach`` [m] about ``centre`` (3,) lies outside ``box``
    (2, 3) (lower and upper corners; an unbounded box: never)."""
    gap = jnp.maximum(jnp.maximum(box[0] - centre, centre - box[1]), 0.0)
    return jnp.sum(gap * gap) > reach * reach


register_pair_kind(DanoPairKind())

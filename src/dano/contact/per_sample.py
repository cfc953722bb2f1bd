"""Contact model ``per_sample`` (beyond the paper; its limitation (i)): every sample in
contact applies its own force at its own point."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import jax
import jax.numpy as jnp

from .base import PairGeometry, cross_columns, occupancy, register_contact_model, sample_rates
from .law import check_drag, sample_forces


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class PerSampleState:
    """A pair prepared for the step: weight (S,), depth (S,), rate (6, S) dz/du, arm (3, S)
    x_i − χ, moves (S,), normal (3, S), h ()."""

    weight: jax.Array
    depth: jax.Array
    rate: jax.Array
    arm: jax.Array
    moves: jax.Array
    normal: jax.Array
    h: jax.Array


@register_contact_model("per_sample")
@dataclass(frozen=True)
class PerSample:
    """Sample i, with its share α·w_i·o_i of the overlap, its normal n_i and the relative
    velocity v + ω × (x_i − χ) at its point x_i, applies the normal force, damping, sliding
    friction and drag of Eqs. 8–9; the pair's wrench about χ is their sum. The shares add up
    to ψ, so the normal force at rest equals the centroid model's. Torsional and rolling
    resistance emerge from the distribution of the forces: the torsional and rolling
    parameters are not used. Over a step each sample's depth advances to first order
    (z_i + h·ż_i, its occupancy following), so samples entering contact during the step
    push back within it. drag: as for the centroid model."""

    name: ClassVar[str] = "per_sample"
    drag: str = "normal_force"

    def __post_init__(self):
        check_drag(self.drag)

    def prepare(self, g: PairGeometry, h) -> PerSampleState:
        return PerSampleState(g.weight, g.depth, sample_rates(g), g.points - g.chi[:, None], g.moves,
                              g.sample_normal, jnp.asarray(h, g.psi.dtype))

    def wrench(self, p, st: PerSampleState, u):
        motion = u[:3, None] + cross_columns(u[3:, None], st.arm)  # (3, S) relative velocity at each sample
        arm = st.arm + st.h * st.moves * motion
        share = st.weight * occupancy(st.depth + st.h * (u @ st.rate))
        forces = sample_forces(p, share, st.normal, motion, self.drag)
        return jnp.concatenate([jnp.sum(forces, axis=1), jnp.sum(cross_columns(arm, forces), axis=1)])

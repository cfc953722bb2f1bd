"""Contact model ``per_sample`` (beyond the paper; its limitation (i)): every sample in
contact applies its own force at its own point."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import ClassVar

import jax
import jax.numpy as jnp

from ..errors import DanoError
from .base import (Compacted, PairGeometry, cross_columns, occupancy, register_contact_model, sample_rates,
                   world_points)
from .law import check_drag, sample_forces
from .samples import SAMPLE_BLOCK


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class PerSampleState:
    """A pair prepared for the step: weight (K,), depth (K,), rate (6, K) dz/du, arm (3, K)
    x_i − χ (world), moves (K,), normal (3, K) or (3, 1) of the K samples taken into account;
    h ()."""

    weight: jax.Array
    depth: jax.Array
    rate: jax.Array
    arm: jax.Array
    moves: jax.Array
    normal: jax.Array
    h: jax.Array


def _state(g: PairGeometry, h, valid) -> PerSampleState:
    return PerSampleState(jnp.where(valid, g.weight, 0.0), g.depth, sample_rates(g), world_points(g) - g.chi[:, None],
                          g.moves, g.sample_normal, jnp.asarray(h, g.psi.dtype))


def _take(g: PairGeometry, idx) -> PairGeometry:
    """``g`` with its per-sample arrays reduced to the samples ``idx`` (K,) (arrays of one
    column, the same for every sample, stay as they are)."""
    take = lambda a: a if a.shape[-1] == 1 else jnp.take(a, idx, axis=-1)  # noqa: E731
    return dataclasses.replace(g, weight=take(g.weight), depth=take(g.depth), depth_grad=take(g.depth_grad),
                               moves=take(g.moves), points=take(g.points), sample_normal=take(g.sample_normal))


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class _AllSamples:
    """The fallback of a pair whose samples within reach overflow ``max_active``: its whole
    geometry, prepared inside the branch that uses it (so a step that does not overflow
    never computes the rates of every sample)."""

    geometry: PairGeometry
    reach: jax.Array
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
    push back within it. drag: as for the centroid model.

    Only samples within one sample radius of contact at the step's start can act in it (as
    in the centroid model, a pair acts once it overlaps at the start of a step). The step
    then works on the first ``max_active`` of them, gathered once per step, instead of all
    samples. The search is in two levels: the scene stores samples in spatially compact
    blocks of :data:`~dano.contact.samples.SAMPLE_BLOCK` (:class:`~dano.contact.samples.Samples`);
    the step finds the first ``blocks_searched`` blocks holding a sample within reach, then
    the samples within reach among theirs (a prefix count over all samples cost as much as
    the rest of the step). If more blocks or samples are within reach, it uses all samples
    (same result, full cost). Measured on the paper bunny resting on the ground (2926
    distinct samples in 366 blocks): 104 samples within reach, in 28 blocks; 30 in contact.
    A flat face of a finely sampled box can hold more and then runs at full cost."""

    name: ClassVar[str] = "per_sample"
    #: no: XLA makes YNNPACK fusions of its sums over samples, and its all-samples fallback's
    #: Newton loop reads more than the one-kernel threshold (docs/simulation.md, Speed); the
    #: unrolled solve measured 36.7 µs per step against LAPACK's 36.3 µs
    single_kernel_rollout: ClassVar[bool] = False
    drag: str = "normal_force"
    max_active: int = 128
    blocks_searched: int = 48

    def __post_init__(self):
        check_drag(self.drag)
        for name in ("max_active", "blocks_searched"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise DanoError(f"PerSample.{name} must be a positive integer, got {value!r}")

    def prepare(self, g: PairGeometry, h):
        reach = (g.depth > -1.0) & (g.weight > 0)  # padded samples have weight 0
        if g.depth.shape[-1] <= self.max_active:
            return _state(g, h, reach)
        full = _AllSamples(g, reach, jnp.asarray(h, g.psi.dtype))
        block, S = SAMPLE_BLOCK, g.depth.shape[-1]
        if S % block or S <= self.blocks_searched * block:  # search the samples one by one
            candidates, within = jnp.arange(S), reach
            over = jnp.zeros((), bool)
        else:  # the first blocks holding a sample within reach, then the samples in them
            blocks = jnp.any(reach.reshape(-1, block), axis=1)
            first = jnp.nonzero(blocks, size=self.blocks_searched, fill_value=0)[0]
            candidates = (first[:, None] * block + jnp.arange(block)).reshape(-1)
            kept = jnp.repeat(jnp.arange(self.blocks_searched) < jnp.sum(blocks), block)
            within = reach[candidates] & kept
            over = jnp.sum(blocks) > self.blocks_searched
        count = jnp.sum(within)
        idx = candidates[jnp.nonzero(within, size=self.max_active, fill_value=0)[0]]
        valid = jnp.arange(self.max_active) < count
        return Compacted(_state(_take(g, idx), h, valid), full, over | (count > self.max_active))

    def wrench(self, p, st: PerSampleState | Compacted | _AllSamples, u):
        if isinstance(st, Compacted):  # one pair evaluated on its own (the step does this per group)
            return jax.lax.cond(st.overflow, lambda: self.wrench(p, st.full, u), lambda: self.wrench(p, st.active, u))
        if isinstance(st, _AllSamples):
            st = _state(st.geometry, st.h, st.reach)
        motion = u[:3, None] + cross_columns(u[3:, None], st.arm)  # (3, K) relative velocity at each sample
        arm = st.arm + st.h * st.moves * motion
        share = st.weight * occupancy(st.depth + st.h * (u @ st.rate))
        forces = sample_forces(p, share, st.normal, motion, self.drag)
        return jnp.concatenate([jnp.sum(forces, axis=1), jnp.sum(cross_columns(arm, forces), axis=1)])

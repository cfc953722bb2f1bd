"""Contact model ``per_sample`` (beyond the paper; its limitation (i)): every sample in
contact applies its own force at its own point."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import ClassVar

import jax
import jax.numpy as jnp

from ..errors import DanoError
from .base import (Compacted, PairGeometry, batch_all, cross_columns, occupancy, occupancy_slope,
                   register_contact_model, sample_rates, skew, twist_rows, world_points)
from .law import check_drag, check_steepness, sample_forces_and_slopes
from .params import FRICTION_STEEPNESS
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
    geometry and which samples are within reach (S,), prepared chunk by chunk inside the
    branch or loop that uses it (so a step that does not overflow never computes the rates
    of every sample)."""

    geometry: PairGeometry
    reach: jax.Array
    h: jax.Array


#: samples within reach gathered per pair and step where :attr:`PerSample.max_active` is None
#: and the object has no large flat face (the paper's bunny resting on the ground: 51 within reach)
DEFAULT_MAX_ACTIVE = 64
#: blocks searched per pair and step where :attr:`PerSample.blocks_searched` is None (at least)
DEFAULT_BLOCKS_SEARCHED = 48


def room_for(samples: int) -> int:
    """The smallest of 64, 96, 128, 192, 256, 384, ... (64 and 96 times a power of two) that
    holds ``samples``: few sizes, so that objects of similar faces share compiled programs,
    each at most 1.5 times the next smaller one, so that little of the room goes unused."""
    size = DEFAULT_MAX_ACTIVE
    while size < samples:
        size = size * 3 // 2 if size & (size - 1) == 0 else size * 4 // 3
    return size


#: a sample is within reach of a step when its depth z_i, advanced over the step at the
#: step's start velocity where that deepens it, is above −REACH_MARGIN (in sample radii):
#: the margin covers the step's change of velocity
REACH_MARGIN = 0.25


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
    push back within it. drag, friction_steepness: as for the centroid model.

    Only samples within reach can act in a step: those whose depth, advanced over the step
    at the step's start velocity where that deepens it, comes within :data:`REACH_MARGIN`
    sample radii of contact (the margin covers the step's change of velocity; a sample
    that would reach contact later acts from a later step, as a pair acts once it overlaps
    at the start of a step in the centroid model). The step then works on the first
    ``max_active`` of them, gathered once per step, instead of all samples. The search is
    in two levels: the scene stores samples in spatially compact
    blocks of :data:`~dano.contact.samples.SAMPLE_BLOCK` (:class:`~dano.contact.samples.Samples`);
    the step finds the first ``blocks_searched`` blocks holding a sample within reach, then
    the samples within reach among theirs (a prefix count over all samples cost as much as
    the rest of the step). If more blocks or samples are within reach, it takes every sample
    within reach, a chunk at a time (the same result). The Newton iteration evaluates the
    gathered samples in chunks of :func:`chunk_size` in one loop, which runs the chunks that
    hold a sample within reach, or, where a pair overflows, the chunks of all samples within
    reach (under ``jax.vmap``, only where a pair of the batch overflows:
    :attr:`~dano.contact.base.Compacted.reverse_mode`): one copy of the evaluation in the
    program, and a room larger than the samples within reach costs little. Measured on the
    paper bunny resting on the ground (2926 distinct samples in 366 blocks): 51 samples within reach, 30 in
    contact (104 within one radius, the reach before 2026-11-25, which needed 128 slots and
    cost 1.5× the step); falling at 1 m/s it reaches 0.41 radii further. A flat face can hold
    far more (a 10 × 6 × 3 cm box's largest face 1,462 of its 5000 samples): :func:`~dano.sim.compose`
    gives each pair room for the largest face of its object (:meth:`sized_for`), so that the
    object resting or sliding on it gathers them once per step. The Newton Jacobian is in
    closed form (:meth:`wrench_and_jacobian`)."""

    name: ClassVar[str] = "per_sample"
    #: yes, compiled without YNNPACK fusions (:func:`dano._jax_setup.rollout_compiler_options`) and
    #: with the all-samples fallback evaluated max_active samples at a time: the bunny drop's
    #: step 22 µs with the unrolled LU, 41 µs with LAPACK (2-core CPU)
    single_kernel_rollout: ClassVar[bool] = True
    #: yes: every sample's depth and lever arm advance linearly with the step's velocity, and at
    #: a fast spin (hundreds of rad/s) the forces of samples advanced deep into the other body
    #: can balance the spin: a 3.9 m/s random bunny drop's step converged there (490 rad/s) from
    #: the start velocity (:attr:`~dano.sim.NewtonConfig.second_try`)
    spurious_roots: ClassVar[bool] = True
    drag: str = "normal_force"
    max_active: int | None = None
    """Samples within reach gathered per pair and step (>= 1); more in a step take the
    all-samples fallback. None: chosen per pair where the scene is composed
    (:meth:`sized_for`): :data:`DEFAULT_MAX_ACTIVE`, or room for an object's flat face."""
    blocks_searched: int | None = None
    """Blocks of :data:`~dano.contact.samples.SAMPLE_BLOCK` samples searched per pair and step
    (>= 1); None: :data:`DEFAULT_BLOCKS_SEARCHED`, or 3/4 of ``max_active`` where that is more."""
    friction_steepness: float = FRICTION_STEEPNESS

    def __post_init__(self):
        check_drag(self.drag)
        object.__setattr__(self, "friction_steepness", check_steepness(self.friction_steepness))
        for name in ("max_active", "blocks_searched"):
            value = getattr(self, name)
            if value is not None and (isinstance(value, bool) or not isinstance(value, int) or value < 1):
                raise DanoError(f"PerSample.{name} must be a positive integer or None, got {value!r}")

    @property
    def capacity(self) -> tuple[int, int]:
        """(max_active, blocks_searched) as the step uses them (None's defaults filled in)."""
        active = DEFAULT_MAX_ACTIVE if self.max_active is None else self.max_active
        blocks = self.blocks_searched
        if blocks is None:
            blocks = max(DEFAULT_BLOCKS_SEARCHED, -(-3 * active // 4))
        return active, blocks

    def sized_for(self, face_samples: int | None) -> "PerSample":
        """This model for a pair whose samples can rest ``face_samples`` at once on the other
        body (:func:`~dano.contact.samples.face_sample_count`; None: not known, e.g. against a
        sphere or capsule), called by :func:`~dano.sim.compose`. Where ``max_active`` is None
        and the face holds more than :data:`DEFAULT_MAX_ACTIVE` samples, ``max_active`` becomes
        :func:`room_for` them (``blocks_searched`` then 3/4 of that, if None), so that the
        object resting or sliding on that face gathers its samples once per step instead of
        taking the all-samples fallback in every one; otherwise the model itself. The same
        motion to rounding; measured on the 2-core CPU (float64, docs/simulation.md, "Room for
        a flat face"): a 10 × 6 × 3 cm box sliding on its largest face (1,462 samples, room
        1536) 335 µs a step against 826 µs with 64; a 76 mm puck's identification from three
        slides 64–71 s against 125–132 s; the paper bunny upright (111, room 128) 29 against
        62 µs. A room larger than the samples touching costs little since the Newton iteration
        evaluates only its chunks that hold one (:func:`chunk_size`): the bunny's drop, resting
        with 51 within reach, 1.14–1.24× the time with 64 (30 against 19 µs before 2026-12-02)."""
        if self.max_active is not None or face_samples is None or face_samples <= DEFAULT_MAX_ACTIVE:
            return self
        return dataclasses.replace(self, max_active=room_for(face_samples))

    def prepare(self, g: PairGeometry, h, u=None):
        # within reach: z_i + h·max(ż_i, 0) > −REACH_MARGIN at the start twist u (padded
        # samples have weight 0)
        rise = 0.0 if u is None else h * jnp.maximum(depth_rates(g, u), 0.0)
        reach = (g.depth + rise > -REACH_MARGIN) & (g.weight > 0)
        active, blocks = self.capacity
        if g.depth.shape[-1] <= active:
            return _state(g, h, reach)
        full = _AllSamples(g, reach, jnp.asarray(h, g.psi.dtype))
        block, S = SAMPLE_BLOCK, g.depth.shape[-1]
        if S % block or S <= blocks * block:  # search the samples one by one
            candidates, within = jnp.arange(S), reach
            over = jnp.zeros((), bool)
        else:  # the first blocks holding a sample within reach, then the samples in them
            first, found = _first_true(jnp.any(reach.reshape(-1, block), axis=1), blocks)
            candidates = (first[:, None] * block + jnp.arange(block)).reshape(-1)
            kept = jnp.repeat(jnp.arange(blocks) < found, block)
            within = reach[candidates] & kept
            over = found > blocks
        slots, count = _first_true(within, active)
        valid = jnp.arange(active) < count
        return Compacted(_state(_take(g, candidates[slots]), h, valid), full, over | (count > active))

    def wrench(self, p, st: PerSampleState | Compacted | _AllSamples, u):
        return self._wrench(p, st, u, jacobian=False)

    def wrench_and_jacobian(self, p, st: PerSampleState | Compacted | _AllSamples, u):
        """(wrench (6,), ∂wrench/∂u (6, 6)), the Jacobian in closed form from the force
        law's :class:`~dano.contact.law.SampleForceSlopes` (the step's Newton Jacobian;
        forward-mode AD of :meth:`wrench` gives the same to rounding, at 1.6× the cost on
        the resting bunny's 128 samples)."""
        return self._wrench(p, st, u, jacobian=True)

    def _wrench(self, p, st, u, jacobian: bool):
        if isinstance(st, Compacted) and not st.reverse_mode:  # the Newton iteration's
            return self._evaluate_chunks(p, st, u, jacobian)
        if isinstance(st, Compacted):  # one pair evaluated on its own (the step does this per group)
            return jax.lax.cond(st.overflow, lambda: self._wrench(p, st.full, u, jacobian),
                                lambda: self._wrench(p, st.active, u, jacobian))
        if isinstance(st, _AllSamples):
            return self._evaluate_all(p, st, u, jacobian)
        return self._evaluate(p, st, u, jacobian)

    def _evaluate_chunks(self, p, st: Compacted, u, jacobian: bool):
        """:meth:`_evaluate` of a pair's samples within reach, :func:`chunk_size` at a time in
        a ``while_loop`` (one copy of the evaluation in the program: each copy costs seconds
        of compilation), for :attr:`~dano.contact.base.Compacted.reverse_mode` False: the
        chunks of the gathered samples that hold one, or, where the gathering overflowed (under
        ``jax.vmap``: for any pair of the batch, :func:`~dano.contact.base.batch_all`), the next
        chunk of all samples within reach in each trip (a prefix count over all samples)."""
        act, full = st.active, st.full
        g, R, S = full.geometry, act.depth.shape[-1], full.reach.shape[-1]
        C = chunk_size(R)
        gathered = batch_all(~st.overflow)
        zero = jnp.zeros(6, u.dtype)
        zero = (zero, jnp.zeros((6, 6), u.dtype)) if jacobian else zero

        def prepared(i, start):  # chunk i of the gathered samples; more after it (filled from the first slot)?
            part = jax.tree_util.tree_map(
                lambda a: jax.lax.dynamic_slice_in_dim(a, i * C, C, axis=-1) if a.ndim and a.shape[-1] == R else a,
                act)
            after = (i + 1) * C
            return part, start, (after < R) & (act.weight[jnp.minimum(after, R - 1)] > 0)

        def everything(i, start):  # the next C samples within reach from index start on
            slots, count = _first_true(full.reach & (jnp.arange(S) >= start), C)
            return (_state(_take(g, slots), full.h, jnp.arange(C) < count), (slots[-1] + 1).astype(jnp.int32),
                    count > C)

        def body(carry):
            i, start, total, _ = carry
            part, start, more = jax.lax.cond(gathered, prepared, everything, i, start)
            out = self._evaluate(p, part, u, jacobian)
            return i + 1, start, jax.tree_util.tree_map(jnp.add, total, out), more

        init = (jnp.int32(0), jnp.int32(0), zero, jnp.ones((), bool))
        return jax.lax.while_loop(lambda c: c[3], body, init)[2]

    def _evaluate_all(self, p, full: _AllSamples, u, jacobian: bool):
        """:meth:`_evaluate` over every sample within reach, ``max_active`` at a time (each
        chunk the next ``max_active`` after the last one taken: a prefix count over all
        samples and a binary search, as the step's gathering), summed: a loop of
        ceil(S / max_active) trips, each chunk past the last sample within reach skipped by a
        branch (differentiable in reverse mode; the Newton iteration's is
        :meth:`_evaluate_chunks`). It costs as many chunks as there are samples within reach,
        not all samples: the upright bunny at rest has 111 within reach, two chunks of 64,
        where the 46 chunks of its 2926 samples made its slide's step 439 µs."""
        g, K = full.geometry, self.capacity[0]
        S = g.depth.shape[-1]
        zero = jnp.zeros(6, u.dtype)
        zero = (zero, jnp.zeros((6, 6), u.dtype)) if jacobian else zero

        def add(total, slots, valid):
            out = self._evaluate(p, _state(_take(g, slots), full.h, valid), u, jacobian)
            return jax.tree_util.tree_map(jnp.add, total, out)

        ranks = jnp.cumsum(full.reach)

        def chunk(i, total):  # samples within reach number i·K + 1 … (i + 1)·K
            slots, wanted = _ranked(ranks, i * K, K)
            return jax.lax.cond(i * K < ranks[-1], lambda: add(total, slots, wanted <= ranks[-1]), lambda: total)

        return jax.lax.fori_loop(0, -(-S // K), chunk, zero)

    def _evaluate(self, p, st: PerSampleState, u, jacobian: bool):
        motion = u[:3, None] + cross_columns(u[3:, None], st.arm)  # (3, K) relative velocity at each sample
        moved = st.h * st.moves
        arm = st.arm + moved * motion
        depth = st.depth + st.h * (u @ st.rate)
        forces, slopes = sample_forces_and_slopes(p, st.weight * occupancy(depth), st.normal, motion, self.drag,
                                                  self.friction_steepness)
        wrench = jnp.concatenate([jnp.sum(forces, axis=1), jnp.sum(cross_columns(arm, forces), axis=1)])
        if not jacobian:
            return wrench
        # ∂F_i/∂u = κ_i·[I, −[a_i]×] + Σ_t x_t ⊗ y_t over three rank-one terms: the motion
        # v + ω × a_i has ∂/∂u = [I, −[a_i]×] (a row yᵀ becomes [yᵀ, (a_i × y)ᵀ]), the share
        # w_i·o(z_i + h·c_i·u) has ∂/∂u = w_i·o'·h·c_i; the arm a_i + h·m_i·(v + ω × a_i)
        # adds −[F_i]×·h·m_i·[I, −[a_i]×] to the torque's
        normal = jnp.broadcast_to(st.normal, motion.shape)
        terms = ((slopes.along_normal, twist_rows(normal, st.arm)),
                 (slopes.along_slip, twist_rows(slopes.slip_direction, st.arm)),
                 (slopes.per_weight, (st.weight * occupancy_slope(depth) * st.h) * st.rate))
        x = jnp.concatenate([t[0] for t in terms], axis=1)  # (3, 3K), the terms side by side
        y = jnp.concatenate([t[1] for t in terms], axis=1)  # (6, 3K)
        j_force = _outer_sum(x, y)
        j_torque = _outer_sum(cross_columns(jnp.concatenate([arm] * len(terms), axis=1), x), y)
        kappa = slopes.kappa
        eye = jnp.eye(3, dtype=u.dtype)
        lever = kappa * arm - moved * forces  # (3, K); Σ [b_i]×[a_i]× = Σ a_i b_iᵀ − (a_i·b_i)·I
        ab = _outer_sum(st.arm, lever)
        j_force = j_force + jnp.concatenate([jnp.sum(kappa) * eye, -skew(st.arm @ kappa)], axis=1)
        j_torque = j_torque + jnp.concatenate([skew(jnp.sum(lever, axis=1)), jnp.trace(ab) * eye - ab], axis=1)
        return wrench, jnp.concatenate([j_force, j_torque], axis=0)


def depth_rates(g: PairGeometry, u) -> jax.Array:
    """ż_i (S,) of every sample at the relative twist u (6,) [1/s]: c_i·u of
    :func:`~dano.contact.base.sample_rates` without forming the (6, S) columns. Where the depth
    gradient is one column ∇z (plane pairs), ż_i = ∇z·(v + ω × a_i) is affine in the
    stored points p_i (a_i = R·p_i + x − χ): 3 products per sample."""
    v, w = u[:3], u[3:]
    sign = 2.0 * g.moves - 1.0
    if g.depth_grad.shape[-1] == 1:
        grad = g.depth_grad[:, 0]
        offset = jnp.dot(grad, v + jnp.cross(w, g.points_offset - g.chi))
        return sign * (offset + (g.points_rotation.T @ jnp.cross(grad, w)) @ g.points)
    arm = world_points(g) - g.chi[:, None]
    return sign * jnp.sum(g.depth_grad * (v[:, None] + cross_columns(w[:, None], arm)), axis=0)


def chunk_size(room: int) -> int:
    """Samples evaluated at a time in the Newton iteration from a room of ``room`` gathered
    samples: the largest divisor of the room up to a quarter of it or
    :data:`DEFAULT_MAX_ACTIVE`, whichever is more (the room itself where that divisor is
    below half of it): the bunny's 128 in two chunks of 64, so that its drop, resting on 51
    samples within reach, evaluates one; 96 in two of 48; a box face's 1536 in four of 384."""
    cap = max(DEFAULT_MAX_ACTIVE, room // 4)
    if room <= cap:
        return room
    size = max(d for d in range(1, cap + 1) if room % d == 0)
    return size if 2 * size >= cap else room


def _first_true(mask, size: int):
    """(indices (size,) of the first ``size`` True entries of ``mask`` (N,), in order, the
    slots past the last True holding N − 1; the number of True entries ()): a prefix count
    and a binary search of it (``jnp.nonzero`` scatters element by element: 2 µs more per
    bunny step)."""
    ranks = jnp.cumsum(mask)
    return _ranked(ranks, 0, size)[0], ranks[-1]


def _ranked(ranks, skip, size: int):
    """(indices (size,) of the True entries number skip + 1 … skip + size of the mask whose
    prefix count is ``ranks`` (N,), slots past the last True holding N − 1; those numbers
    (size,))."""
    wanted = skip + jnp.arange(1, size + 1, dtype=ranks.dtype)
    return jnp.minimum(jnp.searchsorted(ranks, wanted), ranks.shape[0] - 1), wanted


#: columns (3 per sample) from which :func:`_outer_sum` is a matrix product: inside a one-kernel
#: rollout on the CPU the products and sum are faster at the default 64 samples and at 128 (the
#: bunny's 10,000-step per-sample drop 29.7 against 38.2 µs a step), the product at a flat face's
#: thousands (a puck's 2048: 411 against 439 µs; a scan of the Jacobian alone at 1024 samples:
#: 85 against 156 µs)
OUTER_SUM_AS_DOT = 1536


def _outer_sum(x, y):
    """Σ_i x_i ⊗ y_i (m, n) of columns x (m, K), y (n, K), as products and one sum: in XLA's
    CPU kernel the resting bunny's Jacobian (128 samples) took 6.5 µs so, 16.9 µs as a dot,
    9.1 µs with one such sum per term, 10.4 µs by forward-mode AD."""
    if x.shape[-1] > OUTER_SUM_AS_DOT:
        return jnp.dot(x, y.T, precision=jax.lax.Precision.HIGHEST)
    return jnp.sum(x[:, None, :] * y[None, :, :], axis=-1)

"""Contact model ``centroid`` (the paper's, the default): one wrench at the centroid χ."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import jax
import jax.numpy as jnp

from .base import PairGeometry, register_contact_model
from .law import check_drag, check_steepness, pair_wrench, smooth_max0
from .params import FRICTION_STEEPNESS


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class CentroidState:
    """A pair prepared for the step: psi () overlap at q; psi_rate (6,) dψ/du; moment_rate
    (3, 6) dM/du of the first moment M = Σ w·o·(x − χ) (zero at q); normal (3,); h ();
    anchor (3,) A's body position relative to χ, world [m]."""

    psi: jax.Array
    psi_rate: jax.Array
    moment_rate: jax.Array
    normal: jax.Array
    h: jax.Array
    anchor: jax.Array


@register_contact_model("centroid")
@dataclass(frozen=True)
class Centroid:
    """Each pair applies one force and torque at its centroid χ with the pair's overlap ψ,
    normal n and the relative velocity at χ (paper Eqs. 8–12). drag: "normal_force" (the
    paper) or "overlap" (drags scaled by ψ, dano 0.1). friction_steepness: s [s/m] of the
    smoothed Coulomb direction (:func:`~dano.contact.params.smooth_direction`; 30 is the
    paper's code), finite and positive (else DanoError).

    Over a step with relative twist u the overlap and the centroid advance to first order,
    ψ + h·ψ̇u and χ + h·Ṁu/ψ (M the first moment of the overlap about χ), so the contact
    spring, including the shift of χ that makes a tilted face push back, is implicit; the
    force acts at the centroid's shift relative to A's body position (its centre of mass),
    which advances by h·(v + ω × (x_A − χ)): the lever A has at the step's end (a shift of χ
    with A's own motion is no lever: a rolling ball keeps rolling, a sliding plate flat). The
    advanced overlap is kept positive by a smooth max over ψ/20 and the arm's denominator
    by one at ψ/2, so the wrench stays C¹ as the linearised overlap reaches 0 (the pair
    separates) and Newton's method converges."""

    name: ClassVar[str] = "centroid"
    #: a rollout of its step compiles into one XLA kernel on the CPU (docs/simulation.md, Speed)
    single_kernel_rollout: ClassVar[bool] = True
    #: its prepare reads ψ, χ, n and their rates only (:data:`~dano.contact.base.AGGREGATES`), not the
    #: per-sample arrays: the step skips the samples of a pair that none of them can touch
    #: (:func:`~dano.contact.base.skip_separated`)
    aggregates_only: ClassVar[bool] = True
    #: its wrench is 0, with all its derivatives, for a pair whose overlap ψ is 0 at the step's
    #: start (``touching`` below): the Newton iteration skips a group of such pairs
    zero_when_apart: ClassVar[bool] = True
    drag: str = "normal_force"
    friction_steepness: float = FRICTION_STEEPNESS

    def __post_init__(self):
        check_drag(self.drag)
        object.__setattr__(self, "friction_steepness", check_steepness(self.friction_steepness))

    def prepare(self, g: PairGeometry, h, u=None) -> CentroidState:
        return CentroidState(g.psi, g.psi_rate, g.moment_rate, g.normal, jnp.asarray(h, g.psi.dtype), g.anchor - g.chi)

    def wrench(self, p, st: CentroidState, u):
        touching = st.psi > 0
        # the smooth clamps' widths scale with ψ, floored so that a vanishing overlap cannot
        # overflow them (1e-9 kg: far below any resting overlap)
        ref = jnp.where(touching, jnp.maximum(st.psi, 1e-9), 1.0)
        psi_lin = st.psi + st.h * (st.psi_rate @ u)
        clamped = smooth_max0(jnp.stack([psi_lin, psi_lin - 0.5 * ref]), 0.05 * ref)  # (one call: fewer kernels)
        psi = jnp.where(touching, clamped[0], 0.0)
        denom = 0.5 * ref + clamped[1]
        # the centroid's shift over the step relative to A's body position, which moves with
        # A's velocity there (u is taken at χ): the lever A's torque has at the step's end
        carried = u[:3] + jnp.cross(u[3:], st.anchor)
        arm = jnp.where(touching, st.h * ((st.moment_rate @ u) / denom - carried), 0.0)
        force, torque = pair_wrench(p, psi, st.normal, u[:3], u[3:], self.drag, self.friction_steepness)  # at χ
        return jnp.concatenate([force, torque + jnp.cross(arm, force)])

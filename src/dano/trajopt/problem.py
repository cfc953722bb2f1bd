"""Trajectory-optimisation problems: dynamics, costs and constraints over a fixed horizon.

A :class:`Problem` holds user functions of the state x (nx,), the control u (nu,), the
stage index t (int, traced) and a parameter pytree p (traced: goals, weights or simulation
parameters change without recompiling):

- ``dynamics(x, u, t, p) -> x'`` (nx,), e.g. one :func:`dano.sim.step`;
- ``stage_cost(x, u, t, p) -> ()`` and ``terminal_cost(x, p) -> ()``;
- optional ``inequality(x, u, t, p) -> (ni,)`` (≤ 0), ``equality(x, u, t, p) -> (ne,)``
  (= 0), ``terminal_inequality(x, p)``, ``terminal_equality(x, p)``;
- control bounds ``u_lower``/``u_upper`` (nu,) (±inf where unbounded).

The solver (:func:`dano.trajopt.solve`) differentiates these with JAX; they must be pure
and jittable. States of MuJoCo scenes are ``x = [qpos, qvel]`` (:func:`mjx_dynamics`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import DanoError
from ..sim import NewtonConfig, make_data, step


@dataclass(frozen=True, eq=False)
class Problem:
    """An optimal-control problem over ``horizon`` steps (T controls, T + 1 states).

    Minimise Σ_t stage_cost(x_t, u_t, t) + terminal_cost(x_T) subject to
    x_{t+1} = dynamics(x_t, u_t, t), inequality ≤ 0, equality = 0 at every stage,
    terminal_inequality ≤ 0 and terminal_equality = 0 at x_T, u_lower ≤ u_t ≤ u_upper.
    nx, nu: state and control sizes. The solver's compiled functions are kept on the
    problem: every solve with the same problem reuses them.

    key: None, or a value that names the problem's functions and everything they close
    over (the solver adds the horizon, sizes, bounds and which constraints are given),
    digested by content (numbers, strings, arrays, tuples, dicts, dataclasses such as scenes;
    e.g. ``("my-push", scene, weights)``): problems with equal keys must have the same
    functions. With a key and the compilation cache on (:func:`dano.enable_compilation_cache`,
    as the command line does), the solver's programs are kept on disk (:mod:`dano._compiled`):
    another process, or another problem with an equal key, loads them instead of tracing them
    again (``dano trajopt push-sphere`` warm: 27.7 s -> 21.4 s, medians of three alternating
    runs on the 2-core VM; a cold run about 4 s more for the export). Values that change from
    problem to problem (goals; the scene itself, with :func:`scene_dynamics`) belong in ``p``,
    not in the functions, so that one key serves them all (docs/trajopt.md). A key that misses something the functions read gives another
    problem's programs: leave it None when unsure.
    """

    dynamics: Callable[..., jax.Array]
    stage_cost: Callable[..., jax.Array]
    terminal_cost: Callable[..., jax.Array]
    horizon: int
    nx: int
    nu: int
    inequality: Callable[..., jax.Array] | None = None
    equality: Callable[..., jax.Array] | None = None
    terminal_inequality: Callable[..., jax.Array] | None = None
    terminal_equality: Callable[..., jax.Array] | None = None
    u_lower: Any = None
    u_upper: Any = None
    key: Any = None

    def __post_init__(self):
        if int(self.horizon) < 1:
            raise DanoError(f"horizon must be at least 1 step, got {self.horizon}")
        if int(self.nx) < 1 or int(self.nu) < 1:
            raise DanoError(f"nx and nu must be positive, got nx={self.nx}, nu={self.nu}")
        for name in ("u_lower", "u_upper"):
            v = getattr(self, name)
            if v is not None and np.shape(v) != (self.nu,):
                raise DanoError(f"{name} must have shape ({self.nu},), got {np.shape(v)}")
        if self.u_lower is not None and self.u_upper is not None and np.any(np.asarray(self.u_lower)
                                                                             > np.asarray(self.u_upper)):
            raise DanoError("u_lower exceeds u_upper for some control: the bounds are infeasible")

    # constraint functions with the control bounds folded in as inequalities ------------
    def stage_inequality(self, x, u, t, p):
        """All stage inequalities (ni,) ≤ 0: the user's, then finite upper and lower bounds."""
        parts = [] if self.inequality is None else [jnp.atleast_1d(self.inequality(x, u, t, p))]
        if self.u_upper is not None:
            hi = np.asarray(self.u_upper, dtype=float)
            idx = np.flatnonzero(np.isfinite(hi))
            parts.append(u[idx] - hi[idx])
        if self.u_lower is not None:
            lo = np.asarray(self.u_lower, dtype=float)
            idx = np.flatnonzero(np.isfinite(lo))
            parts.append(lo[idx] - u[idx])
        return jnp.concatenate(parts) if parts else jnp.zeros((0,), u.dtype)

    def stage_equality(self, x, u, t, p):
        return jnp.zeros((0,), u.dtype) if self.equality is None else jnp.atleast_1d(self.equality(x, u, t, p))

    def final_inequality(self, x, p):
        f = self.terminal_inequality
        return jnp.zeros((0,), x.dtype) if f is None else jnp.atleast_1d(f(x, p))

    def final_equality(self, x, p):
        f = self.terminal_equality
        return jnp.zeros((0,), x.dtype) if f is None else jnp.atleast_1d(f(x, p))

    def clip(self, u):
        """u clipped to the control bounds (the forward pass never leaves them)."""
        lo = -jnp.inf if self.u_lower is None else jnp.asarray(self.u_lower, u.dtype)
        hi = jnp.inf if self.u_upper is None else jnp.asarray(self.u_upper, u.dtype)
        return jnp.clip(u, lo, hi)


def quadratic(weight, reference=None):
    """½·(z − z_ref)ᵀ W (z − z_ref) as a function of z: weight a scalar, (n,) diagonal or
    (n, n) matrix; reference (n,) or None (zero)."""
    W = jnp.asarray(weight)

    def cost(z):
        e = z if reference is None else z - jnp.asarray(reference, z.dtype)
        if W.ndim == 2:
            return 0.5 * e @ (W.astype(z.dtype) @ e)
        return 0.5 * jnp.sum(W.astype(z.dtype) * e * e)

    return cost


def quadratic_problem(dynamics, Q, R, Qf, horizon: int, nx: int, nu: int, x_goal=None, **constraints) -> Problem:
    """A :class:`Problem` with stage cost ½(x − x_goal)ᵀQ(x − x_goal) + ½uᵀRu and terminal
    cost ½(x − x_goal)ᵀQf(x − x_goal) (Q, R, Qf scalars, diagonals or matrices);
    ``dynamics(x, u, t, p)``; constraints as keyword arguments of :class:`Problem`."""
    lx, lu, lf = quadratic(Q, x_goal), quadratic(R), quadratic(Qf, x_goal)
    return Problem(dynamics, lambda x, u, t, p: lx(x) + lu(u), lambda x, p: lf(x), horizon, nx, nu, **constraints)


def mjx_dynamics(scene, apply: str = "ctrl", dofs=None, newton=None) -> Callable:
    """``dynamics(x, u, t, p)`` of a dano scene: one :func:`dano.sim.step` from
    x = [qpos (nq,), qvel (nv,)] with controls u, p a :class:`~dano.sim.SimParams`.

    apply: "ctrl" (u (nu,) is ``data.ctrl``, the model's actuators) or "qfrc" (u is a
    generalised force on the dofs ``dofs`` (indices into qvel), e.g. a free body's force
    (world frame [N]) and torque (body frame [N m])). newton: the step's
    :class:`~dano.sim.NewtonConfig` (default: its defaults with ``geometry_tangents="pose"``,
    since the solver differentiates the step along all nx + nu directions at once). The
    scene is a constant of the programs the solver compiles; :func:`scene_dynamics` takes it
    as an argument instead, so that one set of programs serves every scene of one structure
    (another object). Raises DanoError for an unknown ``apply``."""
    dynamics = scene_dynamics(apply, dofs, newton)
    return lambda x, u, t, p: dynamics(x, u, t, (scene, p))


def scene_dynamics(apply: str = "ctrl", dofs=None, newton=None) -> Callable:
    """``dynamics(x, u, t, (scene, params))``: :func:`mjx_dynamics` with the scene an
    argument, ``p = (scene, params)`` (a :class:`~dano.sim.Scene` and its
    :class:`~dano.sim.SimParams`): the scene's arrays (masses, samples, geom sizes) are then
    values, not constants, of the solver's programs, which serve every scene of the same
    structure (:mod:`dano._compiled`; with a :class:`Problem` key that leaves the scene out).
    apply, dofs, newton: as :func:`mjx_dynamics`'s. Raises DanoError for an unknown ``apply``."""
    opts = newton or NewtonConfig(geometry_tangents="pose")
    if apply not in ("ctrl", "qfrc"):
        raise DanoError(f"apply must be 'ctrl' or 'qfrc', got {apply!r}")
    idx = None if dofs is None else np.asarray(dofs, dtype=np.int32)

    def dynamics(x, u, t, p):
        scene, params = p
        nq = scene.nq
        qpos, qvel = x[:nq], x[nq:]
        if apply == "ctrl":
            d = make_data(scene, qpos, qvel, ctrl=u)
        else:
            d = make_data(scene, qpos, qvel)
            d = d.replace(qfrc_applied=d.qfrc_applied.at[idx].set(u.astype(d.qfrc_applied.dtype)))
        d = step(scene, params, d, opts)
        return jnp.concatenate([d.qpos, d.qvel]).astype(x.dtype)

    return dynamics

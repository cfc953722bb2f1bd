"""Receding-horizon control: re-solve from the measured state every few steps, warm-started.

The plan keeps the problem's final time: after k executed steps the remaining T − k
steps are solved. So that every re-solve reuses one compilation, the horizon keeps its
length T and the last k stages are padding: there the dynamics hold the state, the cost
is ½|u|² (driving those controls to zero) and the stage constraints are inactive; the
terminal cost and constraints apply to the final real state.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import DanoError
from .ilqr import ILQRConfig, Multipliers, Solution, solve
from .problem import Problem


def shifted(problem: Problem) -> Problem:
    """The problem of the remaining steps: parameters ``(p, k)``, stage t of the new
    problem is stage t + k of ``problem``; stages with t + k ≥ T are padding."""
    T = problem.horizon

    def real(t, k):
        return t + k < T

    def dynamics(x, u, t, pk):
        p, k = pk
        return jnp.where(real(t, k), problem.dynamics(x, u, t + k, p), x)

    def stage_cost(x, u, t, pk):
        p, k = pk
        return jnp.where(real(t, k), problem.stage_cost(x, u, t + k, p), 0.5 * jnp.sum(u**2))

    def inequality(x, u, t, pk):
        p, k = pk
        return jnp.where(real(t, k), problem.inequality(x, u, t + k, p), -1.0)

    def equality(x, u, t, pk):
        p, k = pk
        return jnp.where(real(t, k), problem.equality(x, u, t + k, p), 0.0)

    return Problem(
        dynamics, stage_cost, lambda x, pk: problem.terminal_cost(x, pk[0]), T, problem.nx, problem.nu,
        inequality=None if problem.inequality is None else inequality,
        equality=None if problem.equality is None else equality,
        terminal_inequality=None if problem.terminal_inequality is None else (
            lambda x, pk: problem.terminal_inequality(x, pk[0])),
        terminal_equality=None if problem.terminal_equality is None else (
            lambda x, pk: problem.terminal_equality(x, pk[0])),
        u_lower=problem.u_lower, u_upper=problem.u_upper,
        key=None if problem.key is None else ("dano.trajopt.mpc.shifted", problem.key))


@dataclass(frozen=True)
class RecedingHorizonResult:
    """states (T + 1, nx) and controls (T, nu) as executed in the world; solves: the
    :class:`Solution` of each re-plan (its ``log`` and status); replan_steps: the step at
    which each was made; wall_time_s: seconds in all."""

    states: np.ndarray
    controls: np.ndarray
    solves: tuple[Solution, ...]
    replan_steps: tuple[int, ...]
    wall_time_s: float


def receding_horizon(problem: Problem, x0, world: Callable, U0, params=None, *, every: int = 5,
                     options: ILQRConfig = ILQRConfig(max_iterations=30), first: Solution | None = None,
                     callback: Callable[[int, Solution], None] | None = None) -> RecedingHorizonResult:
    """Run ``problem`` closed-loop in a world that may differ from its model.

    world: ``world(x (nx,), u (nu,)) -> x'``, the true system (e.g. the simulator with
    other parameters), called once per executed step; U0 (T, nu): the initial plan (a
    warm start); every: steps executed between re-plans (≥ 1); options: solver settings
    of each re-plan; first: a solution of the full problem from x0 under ``params`` to
    start from instead of the first solve (its controls, multipliers and penalty);
    callback(step, solution) after each re-plan. Each re-plan starts from the measured
    state, warm-started with the previous plan's remaining controls, multipliers and
    penalty. Raises DanoError if ``every`` < 1.
    """
    if int(every) < 1:
        raise DanoError(f"every must be at least 1 step, got {every}")
    start = time.perf_counter()
    T = problem.horizon
    if "_shifted" not in problem.__dict__:  # one shifted problem (one compilation) per problem, kept on it
        problem.__dict__["_shifted"] = shifted(problem)
    pr = problem.__dict__["_shifted"]
    x = jnp.asarray(x0)
    U = jnp.asarray(U0, x.dtype)
    lam, mu = None, None
    states, controls, solves, steps = [np.asarray(x)], [], [], []
    k = 0
    while k < T:
        pk = (params, jnp.asarray(k))
        if k == 0 and first is not None:
            sol = first
        else:
            sol = solve(pr, x, U, pk, options, multipliers=lam, penalty=mu)
        solves.append(sol)
        steps.append(k)
        if callback is not None:
            callback(k, sol)
        n = min(int(every), T - k)
        for j in range(n):
            u = sol.controls[j]
            x = jnp.asarray(world(x, u), x.dtype)
            if not np.all(np.isfinite(np.asarray(x))):
                raise DanoError(f"the world's state became non-finite at step {k + j + 1}")
            states.append(np.asarray(x))
            controls.append(np.asarray(u))
        k += n
        # warm start: the plan's remaining controls and stage multipliers, shifted by n
        U = jnp.concatenate([sol.controls[n:], jnp.zeros((n, problem.nu), x.dtype)])
        m = sol.multipliers
        lam = Multipliers(_shift(m.inequality, n), _shift(m.equality, n), m.terminal_inequality,
                          m.terminal_equality)
        mu = sol.penalty
    return RecedingHorizonResult(np.stack(states), np.stack(controls), tuple(solves), tuple(steps),
                                 time.perf_counter() - start)


def _shift(a: jax.Array, n: int) -> jax.Array:
    return jnp.concatenate([a[n:], jnp.zeros((n,) + a.shape[1:], a.dtype)]) if a.shape[0] else a

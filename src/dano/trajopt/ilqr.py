"""Constrained iterative LQR with an augmented Lagrangian (ALTRO-style, as the paper used).

Outer loop: the augmented Lagrangian of the constraints c (inequalities g ≤ 0, equalities
h = 0, control bounds folded in as inequalities),

    L = J + Σ λᵀc + ½ Σ cᵀ I_μ c,   I_μ = μ on equalities and on inequalities that are
                                         violated or have λ > 0, else 0

is minimised by iLQR, then λ ← λ + μc (λ ≥ 0 for inequalities) and μ ← φμ until the
largest violation is below tolerance (Howell, Jackson & Manchester, "ALTRO", IROS 2019).

Inner loop (iLQR): dynamics linearised by forward-mode AD (``jax.jacfwd``, over the
horizon a stage at a time on the CPU: :data:`STAGE_BATCH`), the cost's second-order
expansion by AD, constraint terms Gauss–Newton;
Riccati backward pass with state regularisation ρ (Tassa, Erez & Todorov, IROS 2012),
raised when Q_uu is not positive definite; forward pass with a backtracking line search
on the merit L (accepted when the actual decrease is at least 1e-4 of the predicted
one); controls are clipped to their bounds in the forward pass.

Each piece is one jitted function of the problem's shape: a problem compiles once, every
later solve (other x0, warm starts, parameters p) reuses it. The loop itself runs in
Python so that it can report progress and stop early.
"""

from __future__ import annotations

import dataclasses
import functools
import time
from dataclasses import dataclass
from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np

from .._compiled import cached_jit, compile_seconds
from .._threads import in_background
from ..errors import DanoError
from .problem import Problem


@dataclass(frozen=True)
class ILQRConfig:
    """Solver settings of :func:`solve`. Raises DanoError for iteration counts below 1, a
    penalty schedule that does not grow, or step sizes outside (0, 1]."""

    max_iterations: int = 300
    """iLQR iterations in all (every backward + forward pass counts), >= 1."""
    inner_iterations: int = 50
    """At most this many iLQR iterations per penalty value, >= 1."""
    cost_tolerance: float = 1e-4
    """The inner loop stops when an accepted step decreases the merit by less than this (relative), once the
    constraints are met."""
    cost_tolerance_intermediate: float = 1e-3
    """The same while the constraints are not met (a loose inner solve before each multiplier update, as ALTRO
    does)."""
    gradient_tolerance: float = 1e-5
    """... or when the feed-forward step max|k|/(|u| + 1), averaged over the horizon, is below this."""
    constraint_tolerance: float = 1e-4
    """Largest allowed constraint violation (the constraints' units)."""
    penalty_initial: float = 1.0
    """Initial augmented-Lagrangian penalty μ₀, > 0."""
    penalty_scaling: float = 10.0
    """Penalty growth φ (μ ← φμ), > 1."""
    penalty_max: float = 1e8
    """Largest μ, >= μ₀ (reaching it with the constraints still violated means the problem is reported
    infeasible)."""
    penalty_keep: float = 0.25
    """After an inner solve that cut the violation to below this fraction of the previous one, only the
    multipliers are updated, μ is kept (Nocedal & Wright, Numerical Optimization, Framework 17.3); else μ ← φμ
    too."""
    regularization_initial: float = 0.0
    """Initial state regularisation ρ of the backward pass."""
    regularization_min: float = 1e-8
    """Smallest ρ once raised."""
    regularization_max: float = 1e10
    """Largest ρ (the backward pass fails beyond it)."""
    line_search: tuple[float, ...] = tuple(0.5**i for i in range(11))
    """Step sizes tried by the forward pass, largest first, each in (0, 1]."""

    def __post_init__(self):
        if self.max_iterations < 1 or self.inner_iterations < 1:
            raise DanoError("max_iterations and inner_iterations must be at least 1")
        if not (self.penalty_scaling > 1 and self.penalty_initial > 0 and self.penalty_max >= self.penalty_initial):
            raise DanoError("need penalty_initial > 0, penalty_scaling > 1 and penalty_max >= penalty_initial")
        if not self.line_search or any(not 0 < a <= 1 for a in self.line_search):
            raise DanoError("line_search step sizes must lie in (0, 1]")


Options = ILQRConfig  # old name, kept


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class Multipliers:
    """Lagrange multipliers: inequality (T, ni) ≥ 0, equality (T, ne), terminal_inequality
    (niT,) ≥ 0, terminal_equality (neT,)."""

    inequality: jax.Array
    equality: jax.Array
    terminal_inequality: jax.Array
    terminal_equality: jax.Array


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class Solution:
    """A solve's result (a pytree).

    states: (T + 1, nx); controls: (T, nu); gains: (T, nu, nx) feedback K of the last
    backward pass (u = U + K (x − X) stabilises the plan); multipliers; cost: J without
    constraint terms; max_violation: largest constraint violation; penalty: final μ;
    iterations: iLQR iterations run; converged: constraints within tolerance and the
    inner loop converged; status: "converged", "infeasible" (penalty at its maximum with
    the constraints still violated, or their violation no longer decreasing as μ grows)
    or "max_iterations"; log: per iteration, a dict of arrays
    ``iteration, outer, cost, merit, max_violation, step, penalty, regularization,
    gradient``; wall_time_s, compile_time_s: seconds in all, and of those in compiling;
    restarts: other solves of the same problem from other first guesses, not kept, each a
    dict ``guess, status, iterations, max_violation`` (empty for one solve; their seconds
    are counted in wall_time_s and compile_time_s).
    """

    states: jax.Array
    controls: jax.Array
    gains: jax.Array
    multipliers: Multipliers
    cost: float = dataclasses.field(metadata=dict(static=True))
    max_violation: float = dataclasses.field(metadata=dict(static=True))
    penalty: float = dataclasses.field(metadata=dict(static=True))
    iterations: int = dataclasses.field(metadata=dict(static=True))
    converged: bool = dataclasses.field(metadata=dict(static=True))
    status: str = dataclasses.field(metadata=dict(static=True))
    log: Any = dataclasses.field(default=None, metadata=dict(static=True))
    wall_time_s: float = dataclasses.field(default=0.0, metadata=dict(static=True))
    compile_time_s: float = dataclasses.field(default=0.0, metadata=dict(static=True))
    restarts: tuple = dataclasses.field(default=(), metadata=dict(static=True))


#: stages linearised at once in the expansion on the CPU (jax.lax.map's batch_size). One: on
#: the 2-core CPU (2026-11-29, the command line, warm cache, side by side) an iteration took 2x less time
#: than with 16 on push-sphere (0.15 against 0.33 s), 1.4x on push-panda (18.5 against 25.4 s
#: for 43 iterations) and 3.9x on `push --object` Spot with 5000 samples (0.44 against
#: 1.70 s), at equal memory. (Not profiled further: a vmapped batch's Newton loops run to its
#: slowest stage, and its conditionals compute both branches.) A plain scan over the stages
#: (lax.map without a batch size) took 1.24 s per iteration on the Spot push.
STAGE_BATCH = 1
#: the same on other backends (a GPU): 16 as before, where one stage at a time was not measured
ACCELERATOR_STAGE_BATCH = 16

LOG_KEYS = ("iteration", "outer", "cost", "merit", "max_violation", "step", "penalty", "regularization", "gradient")


class _Compiled:
    """The jitted pieces of one problem (cached on the problem object)."""

    def __init__(self, pr: Problem):
        T = pr.horizon
        ts = jnp.arange(T)

        def rollout(x0, U, p):
            def body(x, tu):
                t, u = tu
                xn = pr.dynamics(x, u, t, p).astype(x.dtype)
                return xn, xn

            _, X = jax.lax.scan(body, x0, (ts, U))
            return jnp.concatenate([x0[None], X])

        def constraint_values(X, U, p):
            gi = jax.vmap(pr.stage_inequality, (0, 0, 0, None))(X[:-1], U, ts, p)
            ge = jax.vmap(pr.stage_equality, (0, 0, 0, None))(X[:-1], U, ts, p)
            return gi, ge, pr.final_inequality(X[-1], p), pr.final_equality(X[-1], p)

        def active(g, lam, mu):
            return jnp.where((g > 0) | (lam > 0), mu, 0.0)

        def merit(X, U, lam: Multipliers, mu, p):
            cost = jnp.sum(jax.vmap(pr.stage_cost, (0, 0, 0, None))(X[:-1], U, ts, p)) + pr.terminal_cost(X[-1], p)
            gi, ge, gT, hT = constraint_values(X, U, p)
            al = (jnp.sum(lam.inequality * gi) + 0.5 * jnp.sum(active(gi, lam.inequality, mu) * gi**2)
                  + jnp.sum(lam.equality * ge) + 0.5 * mu * jnp.sum(ge**2)
                  + jnp.sum(lam.terminal_inequality * gT)
                  + 0.5 * jnp.sum(active(gT, lam.terminal_inequality, mu) * gT**2)
                  + jnp.sum(lam.terminal_equality * hT) + 0.5 * mu * jnp.sum(hT**2))
            viol = jnp.concatenate([jnp.maximum(gi, 0).ravel(), jnp.abs(ge).ravel(), jnp.maximum(gT, 0),
                                    jnp.abs(hT), jnp.zeros((1,), X.dtype)])
            return cost, cost + al, jnp.max(viol)

        def forward(x0, X, U, K, k, alpha, lam, mu, p):
            def body(x, inp):
                t, xr, ur, Kt, kt = inp
                u = ur + alpha * kt + Kt @ (x - xr)
                xn = pr.dynamics(x, u, t, p).astype(x.dtype)
                return xn, (xn, u)

            _, (Xn, Un) = jax.lax.scan(body, x0, (ts, X[:-1], U, K, k))
            Xn = jnp.concatenate([x0[None], Xn])
            return (Xn, Un) + merit(Xn, Un, lam, mu, p)

        def expand(X, U, lam: Multipliers, mu, p):
            """Linearised dynamics and the merit's quadratic expansion along (X, U)."""

            def stage(x, u, t, li, le):
                z = jnp.concatenate([x, u])
                nx = x.shape[0]

                def split(f):
                    return lambda z_: f(z_[:nx], z_[nx:], t, p)

                F = jax.jacfwd(split(pr.dynamics))(z)
                lz = jax.grad(split(pr.stage_cost))(z)
                lzz = jax.hessian(split(pr.stage_cost))(z)
                g, Jg = split(pr.stage_inequality)(z), jax.jacfwd(split(pr.stage_inequality))(z)
                h, Jh = split(pr.stage_equality)(z), jax.jacfwd(split(pr.stage_equality))(z)
                Ig = active(g, li, mu)
                lz = lz + Jg.T @ (li + Ig * g) + Jh.T @ (le + mu * h)
                lzz = lzz + Jg.T @ (Ig[:, None] * Jg) + mu * Jh.T @ Jh
                return F, lz, lzz

            # stages in batches (lax.map over vmapped batches; STAGE_BATCH), the horizon padded
            # with copies of its last stage where they do not divide it (lax.map would trace and
            # compile a remainder batch a second time)
            count = -(-T // (STAGE_BATCH if jax.default_backend() == "cpu" else ACCELERATOR_STAGE_BATCH))
            size = -(-T // count)
            pad = lambda a: jnp.concatenate([a, jnp.repeat(a[-1:], size * count - T, axis=0)])  # noqa: E731
            F, lz, lzz = jax.lax.map(lambda a: stage(*a), tuple(pad(a) for a in (X[:-1], U, ts, lam.inequality,
                                                                                   lam.equality)), batch_size=size)
            F, lz, lzz = F[:T], lz[:T], lzz[:T]
            xT = X[-1]

            def fT(x):
                return pr.terminal_cost(x, p)

            gT, JgT = pr.final_inequality(xT, p), jax.jacfwd(lambda x: pr.final_inequality(x, p))(xT)
            hT, JhT = pr.final_equality(xT, p), jax.jacfwd(lambda x: pr.final_equality(x, p))(xT)
            IgT = active(gT, lam.terminal_inequality, mu)
            Vx = (jax.grad(fT)(xT) + JgT.T @ (lam.terminal_inequality + IgT * gT)
                  + JhT.T @ (lam.terminal_equality + mu * hT))
            Vxx = jax.hessian(fT)(xT) + JgT.T @ (IgT[:, None] * JgT) + mu * JhT.T @ JhT
            return F, lz, lzz, Vx, Vxx

        def duals(X, U, lam: Multipliers, mu, p):
            gi, ge, gT, hT = constraint_values(X, U, p)
            return Multipliers(jnp.maximum(lam.inequality + mu * gi, 0), lam.equality + mu * ge,
                               jnp.maximum(lam.terminal_inequality + mu * gT, 0), lam.terminal_equality + mu * hT)

        def sizes(x0, U, p):  # shapes only: the constraints traced on states of the rollout's shape, never compiled
            X = jax.ShapeDtypeStruct((U.shape[0] + 1, x0.shape[0]), x0.dtype)  # (the dynamics need no trace)
            return tuple(a.shape for a in jax.eval_shape(lambda X: constraint_values(X, U, p), X))

        # the traced pieces: jitted per problem object, or, for a problem with a key, exported
        # programs kept on disk by dano._compiled (loaded by later processes, not traced again)
        self.raw = {"forward": forward, "expand": expand, "duals": duals}
        if pr.key is None:
            self.forward, self.expand, self.duals = (jax.jit(f) for f in (forward, expand, duals))
        else:
            # the key's functions with what the problem itself adds to every trace
            optional = (pr.inequality, pr.equality, pr.terminal_inequality, pr.terminal_equality)
            bounds = tuple(None if b is None else np.asarray(b, dtype=float) for b in (pr.u_lower, pr.u_upper))
            keyed = _Keyed((pr.key, pr.horizon, pr.nx, pr.nu, bounds, tuple(f is None for f in optional)), pr)
            self.forward, self.expand, self.duals = (functools.partial(_CACHED[name], keyed)
                                                     for name in ("forward", "expand", "duals"))
        # (a problem's pieces are all exported or all plain jit: an exported program's outputs
        # are committed to a device, and a plain jit call on a mix of committed and uncommitted
        # arguments compiles again: the Panda's expansion twice, +100 s cold)
        self.backward = _JIT_BACKWARD if pr.key is None else _CACHED_BACKWARD
        self.sizes = sizes
        self.expanded = set()  # (controls' shape, dtype) of the solves begun: their expansion compiled

    def evaluate(self, x0, U, lam, mu, p):
        """(X, cost, merit, violation) of the open-loop rollout: the forward pass with no
        feedback and no step (u = U exactly), so it shares that pass's compilation."""
        X0 = jnp.zeros((U.shape[0] + 1, x0.shape[0]), x0.dtype)
        K0 = jnp.zeros((U.shape[0], U.shape[1], x0.shape[0]), x0.dtype)
        X, _, cost, merit_, viol = self.forward(x0, X0, U, K0, jnp.zeros_like(U), 0.0, lam, mu, p)
        return X, cost, merit_, viol


@dataclass(frozen=True, eq=False)
class _Keyed:
    """A problem with its key: the key (by content) names the exported programs, the problem
    (left out of the key) traces them the first time."""

    key: Any
    problem: Problem = dataclasses.field(metadata={"cache_key": False})


def _piece(name: str):
    def run(keyed: _Keyed, *args):
        return _compiled(keyed.problem).raw[name](*args)

    run.__name__ = run.__qualname__ = f"ilqr_{name}"  # (the exported program's name, in its key)
    return cached_jit(run, static_argnums=(0,))


_CACHED = {name: _piece(name) for name in ("forward", "expand", "duals")}


def _backward(F, lz, lzz, Vx, Vxx, rho):
    """The Riccati backward pass over the expansion (F, lz, lzz, Vx, Vxx) with state
    regularisation ρ: gains K (T, nu, nx), feed-forward k (T, nu), the expected merit change
    terms (2,) and whether every Q_uu was positive definite. It depends on the problem only
    through its sizes: one program for every problem of the same sizes."""
    nx = Vx.shape[0]
    eye = jnp.eye(nx, dtype=Vx.dtype)

    def body(carry, inp):
        Vx, Vxx = carry
        Ft, lzt, lzzt = inp
        A, B = Ft[:, :nx], Ft[:, nx:]
        Qx = lzt[:nx] + A.T @ Vx
        Qu = lzt[nx:] + B.T @ Vx
        Qxx = lzzt[:nx, :nx] + A.T @ Vxx @ A
        Quu = lzzt[nx:, nx:] + B.T @ Vxx @ B
        Qux = lzzt[nx:, :nx] + B.T @ Vxx @ A
        Vreg = Vxx + rho * eye
        Quu_r = lzzt[nx:, nx:] + B.T @ Vreg @ B
        Qux_r = lzzt[nx:, :nx] + B.T @ Vreg @ A
        Quu_r = 0.5 * (Quu_r + Quu_r.T)
        L = jnp.linalg.cholesky(Quu_r)
        ok = jnp.all(jnp.isfinite(L))
        sol = jax.scipy.linalg.cho_solve((L, True), jnp.concatenate([Qu[:, None], Qux_r], axis=1))
        k, K = -sol[:, 0], -sol[:, 1:]
        Vx_n = Qx + K.T @ Quu @ k + K.T @ Qu + Qux.T @ k
        Vxx_n = Qxx + K.T @ Quu @ K + K.T @ Qux + Qux.T @ K
        Vxx_n = 0.5 * (Vxx_n + Vxx_n.T)
        dv = jnp.stack([k @ Qu, 0.5 * k @ Quu @ k])
        return (Vx_n, Vxx_n), (K, k, dv, ok)

    _, (K, k, dv, ok) = jax.lax.scan(body, (Vx, Vxx), (F, lz, lzz), reverse=True)
    return K, k, jnp.sum(dv, axis=0), jnp.all(ok) & jnp.all(jnp.isfinite(K)) & jnp.all(jnp.isfinite(k))


_CACHED_BACKWARD = cached_jit(_backward)
_JIT_BACKWARD = jax.jit(_backward)


def _compiled(problem: Problem) -> _Compiled:
    """The problem's jitted pieces, built on first use and kept on the problem (so they are
    freed with it)."""
    if "_ilqr" not in problem.__dict__:
        problem.__dict__["_ilqr"] = _Compiled(problem)
    return problem.__dict__["_ilqr"]


def _check_inputs(problem: Problem, x0, U0, params=None):
    x0 = jnp.asarray(x0)
    U0 = jnp.asarray(U0, dtype=x0.dtype)
    if x0.shape != (problem.nx,):
        raise DanoError(f"x0 must have shape ({problem.nx},), got {x0.shape}")
    if U0.shape != (problem.horizon, problem.nu):
        raise DanoError(f"initial controls must have shape ({problem.horizon}, {problem.nu}), got {U0.shape}")
    if not (np.all(np.isfinite(np.asarray(x0))) and np.all(np.isfinite(np.asarray(U0)))):
        raise DanoError("x0 and the initial controls must be finite")
    if "_shapes_checked" not in problem.__dict__:  # once per problem object
        _check_function_shapes(problem, x0, U0[0], params)
        problem.__dict__["_shapes_checked"] = True
    return x0, problem.clip(U0)


def _check_function_shapes(problem: Problem, x, u, p) -> None:
    """Raises DanoError naming the problem's function whose output has the wrong shape: the
    costs must return scalars, the constraints 1-D arrays and, for a problem without a key
    (whose programs are traced in this process anyway), the dynamics the next state (nx,).
    Shapes only (``jax.eval_shape``): nothing is computed or compiled; a keyed problem's
    dynamics are not traced here, since its programs may come from disk untraced."""
    def shape(name, f, *args):
        try:
            return tuple(getattr(jax.eval_shape(f, *args), "shape", ()))
        except (TypeError, ValueError, IndexError) as exc:
            raise DanoError(f"{name} fails on x ({problem.nx},), u ({problem.nu},): {exc}") from None

    if problem.key is None and (s := shape("dynamics", problem.dynamics, x, u, 0, p)) != (problem.nx,):
        raise DanoError(f"dynamics(x, u, t, p) must return the next state, shape ({problem.nx},), got {s}")
    for name, f, args in (("stage_cost(x, u, t, p)", problem.stage_cost, (x, u, 0, p)),
                          ("terminal_cost(x, p)", problem.terminal_cost, (x, p))):
        if (s := shape(name, f, *args)) != ():
            raise DanoError(f"{name} must return a scalar, got shape {s}")
    for name, args in (("inequality", (x, u, 0, p)), ("equality", (x, u, 0, p)), ("terminal_inequality", (x, p)),
                       ("terminal_equality", (x, p))):
        f = getattr(problem, name)
        if f is not None and len(s := shape(name, f, *args)) != 1:
            raise DanoError(f"{name} must return a 1-D array (one value per constraint), got shape {s}")


def solve(problem: Problem, x0, U0, params=None, options: ILQRConfig = ILQRConfig(),
          multipliers: Multipliers | None = None, penalty: float | None = None,
          callback: Callable[[dict], None] | None = None) -> Solution:
    """Solve ``problem`` from state x0 (nx,) with initial controls U0 (T, nu) (clipped to
    the bounds; a warm start), parameters ``params`` (the problems' p, any pytree).

    multipliers, penalty: warm-start the augmented Lagrangian (e.g. from a previous
    :class:`Solution`); callback: called with each iteration's log entry (a dict of
    floats), e.g. to draw progress. Returns a :class:`Solution`; never raises for lack
    of convergence (its ``status`` says why it stopped). Raises DanoError for inputs of
    the wrong shape or non-finite inputs, for a problem function whose output has the wrong
    shape (checked on the first solve of the problem: :func:`_check_function_shapes`), or if
    the initial rollout is not finite.
    """
    start, started = time.perf_counter(), time.time()
    fns = _compiled(problem)
    x0, U = _check_inputs(problem, x0, U0, params)

    def ready(fn, *args):  # (compiling is counted by dano._compiled.compile_seconds)
        return jax.block_until_ready(fn(*args))

    if multipliers is None:
        shapes = fns.sizes(x0, U, params)
        multipliers = Multipliers(*(jnp.zeros(s, x0.dtype) for s in shapes))
    lam = multipliers
    mu = jnp.asarray(options.penalty_initial if penalty is None else penalty, x0.dtype)
    expanded = None
    if (U.shape, x0.dtype) not in fns.expanded:  # the first solve of these shapes: the expansion's program
        # (the largest) compiles in the background while the first rollout's traces and runs
        fns.expanded.add((U.shape, x0.dtype))
        X_guess = jnp.broadcast_to(x0, (problem.horizon + 1, problem.nx))
        expanded = in_background(lambda: ready(fns.expand, X_guess, U, lam, mu, params))
    X, cost, merit, viol = ready(fns.evaluate, x0, U, lam, mu, params)
    if not np.isfinite(float(merit)):
        if expanded is not None:
            expanded()  # (not left compiling)
        raise DanoError("the initial rollout or its cost is not finite; check x0, the initial controls and the "
                        "dynamics")
    rho = options.regularization_initial
    log = {k: [] for k in LOG_KEYS}
    K = jnp.zeros((problem.horizon, problem.nu, problem.nx), x0.dtype)
    status, outer, inner, it = "max_iterations", 0, 0, 0
    # the violation after each inner solve (not the start's: a warm start may begin feasible
    # and leave the constraints while its multipliers are rebuilt), for the stagnation test
    violations: list[float] = []
    last_violation = float(viol)
    expansion = None
    while it < options.max_iterations:
        if expansion is None:  # the expansion changes only when the trajectory, λ or μ do
            if expanded is not None:
                expanded()
                expanded = None
            expansion = ready(fns.expand, X, U, lam, mu, params)
        # backward pass, raising the regularisation until Q_uu is positive definite
        while True:
            K_new, k, dV, ok = ready(fns.backward, *expansion, jnp.asarray(rho, x0.dtype))
            if bool(ok) or rho >= options.regularization_max:
                break
            rho = max(rho * 10.0, options.regularization_min * 1e2)
        it += 1
        inner += 1
        gradient = float(jnp.mean(jnp.max(jnp.abs(k) / (jnp.abs(U) + 1.0), axis=1)))
        accepted, step = False, 0.0
        if bool(ok):
            for alpha in options.line_search:
                Xn, Un, cost_n, merit_n, viol_n = ready(fns.forward, x0, X, U, K_new, k, alpha, lam, mu, params)
                expected = -(alpha * float(dV[0]) + alpha**2 * float(dV[1]))
                actual = float(merit) - float(merit_n)
                if np.isfinite(float(merit_n)) and (actual >= 1e-4 * expected if expected > 0 else actual >= 0):
                    accepted, step = True, alpha
                    break
        previous = float(merit)
        if accepted:
            X, U, cost, merit, viol, K = Xn, Un, cost_n, merit_n, viol_n, K_new
            expansion = None
            rho = 0.0 if rho <= options.regularization_min * 1e2 else rho / 10.0
        else:
            rho = max(rho * 10.0, options.regularization_min * 1e2)
        entry = dict(iteration=it, outer=outer, cost=float(cost), merit=float(merit), max_violation=float(viol),
                     step=step, penalty=float(mu), regularization=rho, gradient=gradient)
        for key in LOG_KEYS:
            log[key].append(entry[key])
        if callback is not None:
            callback(entry)
        feasible = float(viol) <= options.constraint_tolerance
        tol = options.cost_tolerance if feasible else options.cost_tolerance_intermediate
        change = (previous - float(merit)) / max(abs(previous), 1.0)
        stalled = not accepted and rho > options.regularization_max
        if not ((accepted and change < tol) or gradient < options.gradient_tolerance or stalled
                or inner >= options.inner_iterations):
            continue
        # the inner solve is done: converged, or an augmented-Lagrangian update
        if feasible:
            status = "converged"
            break
        if float(mu) >= options.penalty_max or _stagnant(violations + [float(viol)]):
            status = "infeasible"
            break
        lam = ready(fns.duals, X, U, lam, mu, params)
        if float(viol) > options.penalty_keep * last_violation:  # too slow: stiffen the penalty
            mu = jnp.minimum(mu * options.penalty_scaling, options.penalty_max)
        violations.append(float(viol))
        last_violation = float(viol)
        outer += 1
        inner = 0
        rho = options.regularization_initial
        expansion = None
        _, cost, merit, viol = ready(fns.evaluate, x0, U, lam, mu, params)
    return Solution(X, U, K, lam, float(cost), float(viol), float(mu), it, status == "converged", status,
                    {k: np.asarray(v) for k, v in log.items()}, time.perf_counter() - start,
                    compile_seconds(started))


def _stagnant(violations: list[float], rounds: int = 5) -> bool:
    """The violation decreased by less than 1 % over the last ``rounds`` penalty increases
    (each ×φ): more penalty no longer helps, the constraints cannot be met."""
    if len(violations) <= rounds:
        return False
    return violations[-1] > 0.99 * violations[-1 - rounds]


def rollout(problem: Problem, x0, U, params=None) -> jax.Array:
    """States (T + 1, nx) of ``problem``'s dynamics from x0 (nx,) under controls U (T, nu)
    (clipped to the bounds)."""
    x0, U = _check_inputs(problem, x0, U, params)
    fns = _compiled(problem)
    lam = Multipliers(*(jnp.zeros(s, x0.dtype) for s in fns.sizes(x0, U, params)))
    return fns.evaluate(x0, U, lam, jnp.asarray(1.0, x0.dtype), params)[0]


__all__ = ["ILQRConfig", "LOG_KEYS", "Multipliers", "Options", "Solution", "rollout", "solve"]

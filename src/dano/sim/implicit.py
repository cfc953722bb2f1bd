"""The step's implicit velocity equation, solved by Newton's method to a tolerance and
differentiated by the implicit function theorem.

The next velocity v' solves

    G(v') = (M + h·B)(v' − v) − h·(f + Q(v')) = 0,

M the joint-space inertia, B = diag(dof_damping), f every other generalized force (MuJoCo's
smooth forces and constraint forces), Q(v') = Σ_pairs J·wrench(Jᵀv') the DANO contact force,
J the (nv, 6) relative point Jacobian of each pair at its centroid χ (frozen at q), and the
wrench that of the pair's contact model at the end of the step: the contact geometry is
advanced over the step with the relative twist u = Jᵀv' to first order (each model says
how, :class:`~dano.contact.ContactModel`). Damping, friction and the contact spring are thus
evaluated at the *new* velocity and configuration (backward Euler) and can only remove
energy, and the stiff spring of a flat face resting on its whole surface stays stable at
large steps. A single linearisation with the geometry frozen at q (dano 0.1) overshoots a
saturated friction force and reverses the slip (energy appears), and lets a stiff spring
ring. At rest (v' = 0) nothing advances: resting states and ψ = m·g/k are unchanged.

Newton: A = M + h·B − h·∂Q/∂v', step −A⁻¹G, backtracking on ‖G‖² (Armijo), stop when the
residual is at roundoff level relative to the step's impulses or the step is below
``tolerance``. Where the contact model asks for it (``NewtonConfig.second_try``), a step
that has not converged after ``max_iterations``, or converged to a velocity that turns a
contact pair by more than a radian, tries again with Powell's dogleg steps in a trust region
in place of the backtracking. ∂Q/∂v' = Σ J·(∂wrench/∂u)·Jᵀ, the 6×6 wrench Jacobians by
forward-mode AD. The tangent of the converged
solution is −A⁻¹·(∂G/∂θ·dθ) (implicit function theorem), so gradients are exact and cost
one linear solve, whatever the iteration count.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass

import jax
import jax.numpy as jnp

from ..contact.base import Compacted
from ..errors import DanoError


@dataclass(frozen=True)
class NewtonConfig:
    """Settings of a step's implicit contact solve (the ``newton`` argument of
    :func:`~dano.sim.step`). Raises DanoError for a count below 1 (0 for max_backtracks) or
    not an integer."""

    max_iterations: int = 25
    """Newton iterations per step, >= 1 (with :attr:`second_try`: up to twice as many in all, both tries')."""
    tolerance: float | None = None
    """Relative step size below which the solve has converged; None: 1e-10 in float64, 1e-5 in float32."""
    max_backtracks: int = 12
    """Line-search halvings per iteration, >= 0 (not in a step's second try, :attr:`second_try`)."""
    constraint_passes: int = 2
    """How many times MuJoCo's constraint solver (joint limits, equalities, MuJoCo contacts) and the implicit
    contact solve alternate in a step at most, >= 1: 1 shows the constraint solver the contact force at the step's
    start velocity only; each further pass, taken only when the contact force at the solved velocity differs from
    the one the solver saw by more than 5 %, shows it that force and solves again (stiff DANO contact on light
    constrained bodies, e.g. fingers against their limits, diverged with 1 pass: docs/simulation.md)."""
    geometry_tangents: str = "direct"
    """How forward-mode derivatives (``jax.jvp``, ``jax.jacfwd``) pass through the contact geometry: ``direct``
    (every tangent through every sample) or ``pose`` (the geometry's Jacobian along the 6 or 12 directions of the
    pair's frames, taken once per step, then applied to every tangent). The same derivatives either way (to
    rounding); ``pose`` is faster with many tangents (the iLQR's dynamics Jacobians: push-sphere's expansion 2.2x
    faster), ``direct`` with few (identification: 30 % faster on the soap's 3)."""
    linear_solver: str = "auto"
    """How the undifferentiated step solves its Newton systems: ``lapack`` (``jnp.linalg.solve``), ``unrolled``
    (:func:`dense_solve`: an LU in plain operations, with no LAPACK call, so that on the CPU XLA compiles a rollout
    of the step into one kernel: the bunny drop's step 20.2 -> 7.3 µs, its compile 1.5 -> 3.6 s) or ``auto``: for a
    scene without MuJoCo constraints, with at most :data:`UNROLLED_LU_MAX` degrees of freedom, ``unrolled`` on a
    GPU, for single steps and rollouts alike (no cuSOLVER call per iteration: 16,384 vmapped float32 bunny drops
    7.56M env-steps/s against 7.18M on one H200, compiling in 6.3 s against 6.6 s), and on the CPU for a rollout of
    at least :data:`UNROLLED_MIN_STEPS` steps whose contact models compile into one kernel
    (``single_kernel_rollout``: the centroid model, not the per-sample one), where the faster steps repay the
    longer compile; ``lapack`` otherwise (on the CPU also for single steps). Derivatives always use LAPACK."""
    second_try: bool | None = None
    """Whether a step whose Newton solve has not converged in ``max_iterations``, or has converged where a contact
    pair turns by more than :data:`MAX_TURN` over the step, tries again from the start velocity with Powell's
    dogleg steps in a trust region in place of the halvings (:func:`solve_velocity`); None: where a pair's contact
    model has ``spurious_roots`` (the per-sample model: without, 2 of 2000 random stiff bunny drops went
    non-finite). The same loop carries on from the start velocity with a flag set: a few operations more per
    iteration, no second loop (docs/simulation.md)."""
    reverse_mode: bool = True
    """False: the step's derivatives in forward mode only (``jax.jvp``, ``jax.jacfwd``; reverse mode then fails with
    JAX's error on ``while_loop``). Only contact models that gather their samples (:class:`~dano.contact.base.Compacted`
    states: ``per_sample``) are affected: the tangents then evaluate a pair's all-samples fallback in a loop that
    runs only where the pair overflows, where a ``vmap``'s batch otherwise pays for it in every step (eight vmapped
    per-sample bunny drops under ``jax.jacfwd``: 413 -> 124 µs per env-step; slides 725 -> 446). The identification
    sets it (forward-mode Jacobians of rollouts vmapped over trajectories)."""

    failure_substeps: int | None = None
    """A step whose Newton solve fails is taken again from its start as this many substeps of ``dt / n`` (each
    kept as it ends); 1: never; None: :data:`DEFAULT_FAILURE_SUBSTEPS` where :attr:`reverse_mode` is False, 1 where
    it is True (the default of :func:`~dano.sim.step` and :func:`~dano.sim.rollout_arrays`): the substeps are trips
    of a ``while_loop``, which JAX cannot differentiate in reverse mode; a value above 1 with ``reverse_mode=True``
    raises DanoError. :func:`~dano.sim.rollout` (``dano simulate``) and :func:`~dano.sysid.identify` run without
    them and turn them on where their rollouts diverge: the loop costs compile time (``dano sysid soap`` cold
    about 3-5 s more) and 2-12 % per step. Failed:
    not converged in its iterations (both tries'), or converged to a velocity that changes a contact pair's rotation
    over the step by more than :data:`MAX_TURN_CHANGE` (a spurious root, or an impact the step is too long to
    resolve: a light object's thin part hit at 2.5 m/s spun it up from 4.6 to 322 rad/s in one 10 ms step, and its
    free flight then diverged). The loop runs one trip where the step does not fail (one copy of the step in the
    program, its length an argument); under ``jax.vmap`` it runs the substeps for the whole batch at a step where one
    member needs them, keeping only that member's result (docs/simulation.md)."""

    def __post_init__(self):
        if self.geometry_tangents not in ("direct", "pose"):
            raise DanoError(f"NewtonOptions.geometry_tangents must be 'direct' or 'pose', got {self.geometry_tangents!r}")
        if self.linear_solver not in ("auto", "lapack", "unrolled"):
            raise DanoError(f"NewtonOptions.linear_solver must be 'auto', 'lapack' or 'unrolled', "
                            f"got {self.linear_solver!r}")
        if self.second_try is not None and not isinstance(self.second_try, bool):
            raise DanoError(f"NewtonOptions.second_try must be True, False or None, got {self.second_try!r}")
        if not isinstance(self.reverse_mode, bool):
            raise DanoError(f"NewtonOptions.reverse_mode must be True or False, got {self.reverse_mode!r}")
        for name in ("max_iterations", "max_backtracks", "constraint_passes", "failure_substeps"):
            value = getattr(self, name)
            if name == "failure_substeps" and value is None:
                continue
            least = 0 if name == "max_backtracks" else 1
            if isinstance(value, bool) or not isinstance(value, int) or value < least:
                raise DanoError(f"NewtonOptions.{name} must be an integer >= {least}, got {value!r}")
        if self.reverse_mode and self.failure_substeps is not None and self.failure_substeps > 1:
            raise DanoError(f"NewtonOptions.failure_substeps={self.failure_substeps} needs reverse_mode=False (the "
                            "substeps of a failed step are trips of a while_loop, which JAX cannot differentiate in "
                            "reverse mode)")


NewtonOptions = NewtonConfig  # old name, kept (and in its error messages)


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class ImplicitProblem:
    """The frozen data of one step's velocity equation (all arrays; see module doc).

    Mh: (nv, nv) M + h·diag(damping); v0: (nv,) velocity at the step's start; f: (nv,)
    generalized forces other than DANO contact; jac: per pair group, (G, nv, 6) [Jp | Jr]
    relative point Jacobians at the centroids; state: per group, the contact model's
    prepared state of each pair (leading axis G); params: per group, ContactParams with
    (G,) fields; idle: per group, () bool, True where the group's wrenches are 0 with all
    their derivatives (every pair apart at the step's start, for a model with
    ``zero_when_apart``), or None (always evaluated); empty: none idles. An idle group's
    wrenches are not evaluated (:func:`_each_group`).
    """

    Mh: jax.Array
    v0: jax.Array
    f: jax.Array
    jac: tuple
    state: tuple
    params: tuple
    idle: tuple = ()


def _each_group(pr: ImplicitProblem, value, zero):
    """Σ over the groups of ``value(group index)`` (a pytree like ``zero``), skipping, in a
    branch, the groups marked idle (:attr:`ImplicitProblem.idle`)."""
    total = zero
    idle = pr.idle or (None,) * len(pr.jac)
    for i, flag in enumerate(idle):
        part = value(i) if flag is None else jax.lax.cond(flag, lambda: zero, lambda i=i: value(i))
        total = jax.tree_util.tree_map(jnp.add, total, part)
    return total


def _pick(pr: ImplicitProblem, full: bool) -> ImplicitProblem:
    """``pr`` with each :class:`~dano.contact.base.Compacted` state replaced by its ``full``
    or its ``active`` part."""
    pick = tuple((st.full if full else st.active) if isinstance(st, Compacted) else st for st in pr.state)
    return dataclasses.replace(pr, state=pick)


def _undifferentiated(pr: ImplicitProblem) -> ImplicitProblem:
    """``pr`` with its :class:`~dano.contact.base.Compacted` states marked
    ``reverse_mode=False``: for the Newton iteration and the Jacobian at its solution,
    which nothing differentiates in reverse mode (the solution's derivatives come from
    :func:`_solve_velocity_jvp`'s residual, evaluated on ``pr`` as it is). Their models then
    choose between the gathered samples and all samples per pair, in a loop that runs no
    trip where no pair of a ``vmap``'s batch overflows (:func:`_on_problem`)."""
    mark = tuple(dataclasses.replace(st, reverse_mode=False) if isinstance(st, Compacted) else st for st in pr.state)
    return dataclasses.replace(pr, state=mark)


def _on_problem(fn, pr: ImplicitProblem):
    """fn(pr) with every group's prepared state plain: for
    :class:`~dano.contact.base.Compacted` states, on their active parts unless a pair of any
    group of ``pr`` overflows (then on the full ones: the same result at full cost). One
    branch per evaluation of the force, so that the program holds one Newton loop: with a
    branch per solve (two Newton loops) the per-sample bunny's one-kernel rollout compiled
    in 12.5 s instead of 10.5 s, its step as fast. Under ``jax.vmap`` both branches run, so
    states marked ``reverse_mode=False`` (:func:`_undifferentiated`) are passed to their
    models as they are, which choose per pair."""
    flags = [jnp.any(st.overflow) for st in pr.state if isinstance(st, Compacted) and st.reverse_mode]
    if not flags:
        return fn(pr)
    return jax.lax.cond(functools.reduce(jnp.logical_or, flags), lambda: fn(_pick(pr, True)),
                        lambda: fn(_pick(pr, False)))


def contact_force(models, pr: ImplicitProblem, v, reverse_mode: bool = True):
    """Generalized DANO contact force Q(v) (nv,) at the end of the step; reverse_mode=False:
    differentiable in forward mode only (:attr:`NewtonConfig.reverse_mode`)."""
    return _on_problem(lambda p: _contact_force(models, p, v), pr if reverse_mode else _undifferentiated(pr))


def _contact_force(models, pr: ImplicitProblem, v):
    def group(i):
        J = pr.jac[i]
        W = jax.vmap(models[i].wrench)(pr.params[i], pr.state[i], jnp.einsum("gvk,v->gk", J, v))
        return jnp.einsum("gvk,gk->v", J, W)

    return _each_group(pr, group, jnp.zeros_like(v))


def contact_force_and_jacobian(models, pr: ImplicitProblem, v):
    """Q(v) (nv,) and ∂Q/∂v (nv, nv) = Σ J·(∂W/∂u)·Jᵀ (6×6 wrench Jacobians, forward mode)."""
    return _on_problem(lambda p: _contact_force_and_jacobian(models, p, v), pr)


def _contact_force_and_jacobian(models, pr: ImplicitProblem, v):
    def group(i):
        model, J = models[i], pr.jac[i]

        def value_and_jac(p_, st_, u_):
            if hasattr(model, "wrench_and_jacobian"):  # the model's own (closed-form) Jacobian
                return model.wrench_and_jacobian(p_, st_, u_)

            def w(x):
                out = model.wrench(p_, st_, x)
                return out, out

            K, W = jax.jacfwd(w, has_aux=True)(u_)
            return W, K

        W, K = jax.vmap(value_and_jac)(pr.params[i], pr.state[i], jnp.einsum("gvk,v->gk", J, v))
        return jnp.einsum("gvk,gk->v", J, W), jnp.einsum("gvi,gij,gwj->vw", J, K, J)

    return _each_group(pr, group, (jnp.zeros_like(v), jnp.zeros((v.shape[0], v.shape[0]), v.dtype)))


def _residual(models, h, pr: ImplicitProblem, v, reverse_mode: bool = True):
    return pr.Mh @ (v - pr.v0) - h * (pr.f + contact_force(models, pr, v, reverse_mode))


# ------------------------------------------------------------------ the step's dense solves
#: systems up to this size are solved by :func:`dense_solve`'s unrolled LU; larger ones by LAPACK
UNROLLED_LU_MAX = 16
#: rollouts of at least this many steps use the unrolled LU (``linear_solver="auto"``): it
#: costs about 2 s more compiling once and saves 9–13 µs per step (bunny drop, 2-core CPU;
#: 9 since the weighted moments are two arrays), repaid by the compilation cache's reuse
UNROLLED_MIN_STEPS = 10_000


def _backend() -> str:
    """The default backend's name (``cpu``, ``gpu``, ``tpu``): where the step is compiled."""
    return jax.default_backend()


def resolve_linear_solver(newton: NewtonConfig, scene, steps: int) -> NewtonConfig:
    """``newton`` with ``linear_solver="auto"`` resolved for a rollout of ``steps`` steps of
    ``scene`` (:attr:`NewtonConfig.linear_solver`); other settings returned as they are."""
    if newton.linear_solver != "auto":
        return newton
    unrolled = not scene.has_constraints and scene.nv <= UNROLLED_LU_MAX and bool(scene.groups)
    backend = _backend()
    if backend == "cpu":  # where the rollout compiles into one kernel, and the faster steps repay the compile
        unrolled = (unrolled and steps >= UNROLLED_MIN_STEPS
                    and all(getattr(g.model, "single_kernel_rollout", False) for g in scene.groups))
    elif backend != "gpu":  # (on a GPU it saves a cuSOLVER call per Newton iteration and compiles as fast)
        unrolled = False
    return dataclasses.replace(newton, linear_solver="unrolled" if unrolled else "lapack")


def lu_factor(A: jax.Array) -> tuple[jax.Array, jax.Array]:
    """LU factorisation with partial pivoting, P·A = L·U, of a small square A (n, n), in
    plain element-wise and dot operations unrolled over the n columns (no LAPACK call).

    On the CPU, XLA compiles a while loop with no custom call in it (a LAPACK solve is one)
    into a single kernel when dano's ``xla_cpu_small_while_loop_byte_threshold`` lets it
    (:mod:`dano._jax_setup`), instead of dispatching each of its ~240 operations per step
    through the runtime: the bunny drop's step went from 20.2 to 7.3 µs. Returns
    (LU (n, n): U on and above the diagonal, L's multipliers below it (unit diagonal
    implied), P (n, n) the row permutation). A singular A gives non-finite factors, as
    LAPACK's getrf does."""
    n = A.shape[-1]
    rows = jnp.arange(n)
    eye = jnp.eye(n, dtype=A.dtype)
    M, P = A, eye
    for k in range(n):
        pivot = jnp.argmax(jnp.where(rows >= k, jnp.abs(M[:, k]), -1.0))
        swap = eye[k] - eye[pivot]  # rows k and pivot exchanged by adding outer(swap, row_p − row_k)
        M = M + jnp.outer(swap, eye[pivot] @ M - M[k])
        P = P + jnp.outer(swap, eye[pivot] @ P - P[k])
        below = rows > k
        f = jnp.where(below, M[:, k] / M[k, k], 0.0)
        M = M - jnp.outer(f, jnp.where(rows >= k, M[k], 0.0))  # eliminated: column k below is 0
        M = M + jnp.outer(f, eye[k])  # where L's multipliers are kept
    return M, P


def lu_solve(factors: tuple[jax.Array, jax.Array], b: jax.Array) -> jax.Array:
    """x (n,) with A·x = b from :func:`lu_factor`'s (LU, P) of A; linear in b (so JAX
    transposes it for reverse mode)."""
    LU, P = factors
    n = LU.shape[-1]
    rows = jnp.arange(n)
    y = P @ b
    for k in range(n - 1):  # L·y = P·b, forward
        y = y - jnp.where(rows > k, LU[:, k], 0.0) * y[k]
    for k in reversed(range(n)):  # U·x = y, backward
        xk = y[k] / LU[k, k]
        y = jnp.where(rows == k, xk, y - jnp.where(rows < k, LU[:, k], 0.0) * xk)
    return y


def dense_solve(A: jax.Array, b: jax.Array) -> jax.Array:
    """x (n,) with A·x = b for a square A (n, n): :func:`lu_factor` and :func:`lu_solve` up
    to :data:`UNROLLED_LU_MAX` unknowns (n = the scene's nv), ``jnp.linalg.solve`` (LAPACK)
    beyond (unrolled, larger systems cost more compiling than they save)."""
    if A.shape[-1] > UNROLLED_LU_MAX:
        return jnp.linalg.solve(A, b)
    return lu_solve(lu_factor(A), b)


def _tolerance(opts: NewtonConfig, dtype) -> float:
    if opts.tolerance is not None:
        return opts.tolerance
    return 1e-10 if jnp.dtype(dtype) == jnp.float64 else 1e-5


#: a root of the step's equation at which a pair turns further than this over the step [rad]
#: is not trusted: the contact geometry's first-order advance has no meaning there, and the
#: per-sample model's equation can have spurious roots there (a bunny dropped at 3.9 m/s,
#: Newton's method converged to it leaving at 19 m/s spinning at 490 rad/s, where the root
#: near the start velocity turns it 0.017 rad over the step): the solve tries again with
#: dogleg steps in a trust region, whose root is taken if it converges
MAX_TURN = 1.0


#: the substeps of a failed step where :attr:`NewtonConfig.failure_substeps` is None and the
#: step is differentiated in forward mode only: the Spot tosses that diverged at 10 ms (7 of 24
#: at friction 0) ran without divergence at 2.5 ms
DEFAULT_FAILURE_SUBSTEPS = 4

#: a step whose solution changes a contact pair's rotation over the step (h·|Δω|, ω its
#: relative angular velocity) by more than this [rad] has failed (:attr:`NewtonConfig.failure_substeps`):
#: the contact geometry is advanced to first order in the twist, and a light object's impact
#: on a thin part, resolved in one 10 ms step, found roots that spun it from 4.6 to 322 rad/s
#: (3.2 rad) and from 7 to 91 rad/s (0.84 rad), its energy rising from 3.0 to 129 and 22.6 J,
#: where the same impacts in 2.5 ms steps changed the turn by at most 0.1 rad
MAX_TURN_CHANGE = 0.5


def _second_try(opts: NewtonConfig, models) -> bool:
    """Whether a step's solve tries again (:attr:`NewtonConfig.second_try`)."""
    if opts.second_try is not None:
        return opts.second_try
    return any(getattr(m, "spurious_roots", False) for m in models)


def iteration_limit(scene, newton: NewtonConfig = NewtonConfig()) -> int:
    """The most Newton iterations a step of ``scene`` can report: ``max_iterations``, twice
    that where the solve has a second try (:attr:`NewtonConfig.second_try`). A step reporting
    as many has used them all (and converged only if at the very last)."""
    return newton.max_iterations * (2 if _second_try(newton, tuple(g.model for g in scene.groups)) else 1)


def _newton(models, opts: NewtonConfig, h: float, pr: ImplicitProblem):
    # the undifferentiated step (the derivatives' path, the jvp below, keeps LAPACK)
    solve = dense_solve if opts.linear_solver == "unrolled" else jnp.linalg.solve
    return _newton_plain(models, opts, h, pr, solve=solve)


def _newton_plain(models, opts: NewtonConfig, h: float, pr: ImplicitProblem, solve=jnp.linalg.solve):
    """Returns (v', [iterations, final residual relative to the step's impulses, 1.0 where
    converged (or the start was not finite: nothing to solve) else 0.0]).

    An iteration solves A·Δ = −G, evaluates the residual at v + Δ (the force only), and
    stops there when it is at roundoff level; otherwise it accepts the point if ‖G‖²
    decreased enough (Armijo) or halves Δ until it does, and evaluates the Jacobian for the
    next iteration. Near the solution an iteration thus costs one solve, one force and one
    Jacobian evaluation; the last one skips the Jacobian. With a second try
    (:attr:`NewtonConfig.second_try`): if it has not converged after ``max_iterations``, or
    has converged where a pair turns more than :data:`MAX_TURN` over the step, it tries again
    from the start velocity with Powell's dogleg steps in place of the halved Newton steps
    (MINPACK's hybrid method: within a trust region |√diag(M + h·B)·Δ| <= r, the Newton step
    where it fits, else towards it from the Cauchy point of the linearised ‖G‖²; r grows and
    shrinks with the ratio of the actual to the predicted decrease, a step that does not
    decrease ‖G‖² is rejected), until 2·``max_iterations`` iterations in all, and takes that
    root if it converges. Not converged: the iterate (of both tries) with the smallest
    residual. A step whose
    residual at the start velocity is not finite (a state already NaN, a non-finite force)
    returns the start velocity at once, with 0 iterations: under ``vmap`` such an env
    otherwise ran all ``max_iterations`` on every step for the whole batch, to the same
    answer (no iterate can beat a non-finite residual)."""
    pr = _undifferentiated(pr)
    tol = _tolerance(opts, pr.v0.dtype)
    eps = jnp.finfo(pr.v0.dtype).eps
    impulse = h * jnp.max(jnp.abs(pr.f)) + jnp.max(jnp.abs(pr.Mh)) * (jnp.max(jnp.abs(pr.v0)) + 1.0) * eps

    residual = functools.partial(_residual, models, h, pr)

    def matrix(v):
        return pr.Mh - h * contact_force_and_jacobian(models, pr, v)[1]

    def small(G, G_ref):
        return jnp.max(jnp.abs(G)) <= 64 * eps * (impulse + jnp.max(jnp.abs(G_ref)))

    def turn(v):  # the largest rotation of a pair over the step at velocity v [rad]
        turns = [jnp.max(jnp.linalg.norm(jnp.einsum("gvk,v->gk", J, v)[:, 3:], axis=1)) for J in pr.jac]
        return h * functools.reduce(jnp.maximum, turns, jnp.zeros((), v.dtype))

    n = opts.max_iterations
    retries = _second_try(opts, models)
    limit = 2 * n if retries else n  # the loop's trips at most

    scale = jnp.sqrt(jnp.diag(pr.Mh))  # the trust region's norm |scale·d|: kinetic-energy-like

    def dogleg(A, G, dn, radius):
        """Powell's dogleg step within |scale·d| <= radius: the Newton step dn where it fits,
        else along the Cauchy point (the minimum of the linearised ‖G‖² along steepest
        descent) towards it, to the boundary."""
        gs = (A.T @ G) / scale
        As = A @ (gs / scale)
        dc = -(gs @ gs) / (As @ As) * gs / scale
        nc, nn = jnp.linalg.norm(scale * dc), jnp.linalg.norm(scale * dn)
        a_, b_ = scale * dc, scale * (dn - dc)
        qa, qb, qc = b_ @ b_, 2.0 * (a_ @ b_), a_ @ a_ - radius**2
        t = (-qb + jnp.sqrt(jnp.maximum(qb * qb - 4.0 * qa * qc, 0.0))) / (2.0 * qa)
        return jnp.where(nn <= radius, dn, jnp.where(nc >= radius, dc * radius / nc, dc + t * (dn - dc)))

    def body(state):
        # (the second try's state, its flag ``damped`` and trust radius, is in the loop's state
        # only where there is a second try: without, the program is the same as before)
        k, v, G, A, finished, v_best, G_best, *more = state
        # (always True where this body runs unbatched; under vmap the body runs for the whole
        # batch, and this keeps an env that has finished, converged or out of iterations, out
        # of the halving loop below)
        active = ~finished & (k < limit)
        damped, radius = more if retries else (jnp.zeros((), bool), None)
        dn = -solve(A, G)
        phi0 = jnp.sum(G * G)
        if retries:  # the second try: Powell's dogleg in a trust region, the first radius the Newton step's
            def trust_region(_):
                r = jnp.where(jnp.isinf(radius), jnp.linalg.norm(scale * dn), radius)
                return dogleg(A, G, dn, r), r

            dv, radius = jax.lax.cond(damped, trust_region, lambda _: (dn, radius), None)
        else:
            dv = dn
        G1 = residual(v + dv)

        # a full step that lands at roundoff level is taken as it is: no line search can
        # decrease a residual that is already noise (at rest it would halve to its limit)
        accept = (jnp.sum(G1 * G1) <= (1.0 - 1e-4) * phi0) | ~jnp.isfinite(phi0) | small(G1, G_first)

        def backtrack(_):
            def cond(ls):
                a, j, Gn = ls
                # "not decreased enough" (Armijo; a non-finite residual counts as not decreased);
                # ``~accept & active`` is True wherever this runs unbatched, but under vmap both
                # branches run for every env: without it an env that took its full step (or had
                # finished) kept the whole batch halving to max_backtracks
                go_on = (~(jnp.sum(Gn * Gn) <= (1.0 - 1e-4 * a) * phi0) & (j < opts.max_backtracks)
                         & ~accept & active)
                return go_on & ~damped if retries else go_on

            def halve(ls):
                a, j, _ = ls
                return 0.5 * a, j + 1, residual(v + 0.5 * a * dv)

            a, _, Gn = jax.lax.while_loop(cond, halve, (jnp.ones((), v.dtype), 0, G1))
            return a * dv, Gn

        step, Gn = jax.lax.cond(accept, lambda _: (dv, G1), backtrack, None)
        if retries:  # (in the second try the halving ran no trip: step = dv, Gn = G1)
            def judge(_):
                # the trust region's test: the actual decrease of ‖G‖² over the linearised one;
                # a rejected dogleg step leaves v where it is
                linear = G + A @ dv
                rho = (phi0 - jnp.sum(G1 * G1)) / (phi0 - jnp.sum(linear * linear))
                rho = jnp.where(jnp.isfinite(rho), rho, -1.0)
                taken = jnp.linalg.norm(scale * dv)
                r = jnp.where(rho < 0.25, 0.25 * taken,
                              jnp.where((rho > 0.75) & (taken >= 0.99 * radius), 2.0 * radius, radius))
                moved = rho > 1e-4
                return jnp.where(moved, dv, 0.0), jnp.where(moved, G1, G), r, moved

            step, Gn, radius, moved = jax.lax.cond(damped, judge, lambda _: (step, Gn, radius, jnp.ones((), bool)),
                                                   None)
        v_new = v + step
        # converged when the full Newton step is small (not a step shortened by the line
        # search) or the residual is at roundoff level
        done = (jnp.max(jnp.abs(dn)) <= tol * (1.0 + jnp.max(jnp.abs(v_new)))) | small(Gn, G_first)
        better = jnp.sum(Gn * Gn) < jnp.sum(G_best * G_best)  # (False for a non-finite residual)
        v_best, G_best = jnp.where(better, v_new, v_best), jnp.where(better, Gn, G_best)
        if not retries:
            A_new = jax.lax.cond(done | (k + 1 >= n), lambda _: A, lambda _: matrix(v_new), None)
            return k + 1, v_new, Gn, A_new, done, v_best, G_best
        # the second try starts from the start velocity where the first has not converged in
        # n iterations or converged where a pair turns further than MAX_TURN (its root then
        # kept as the answer should the second try not converge: its residual is the smallest)
        suspect = jax.lax.cond(done & ~damped, lambda: turn(v_new) > MAX_TURN, lambda: jnp.zeros((), bool))
        again = (suspect | ((k + 1 == n) & ~done)) & ~damped
        done = done & ~suspect
        A_new = jax.lax.cond(done | again | (k + 1 >= limit) | ~moved, lambda _: A, lambda _: matrix(v_new), None)
        v_new, Gn, A_new = (jnp.where(again, x0, x) for x, x0 in ((v_new, pr.v0), (Gn, G_first), (A_new, A0)))
        radius = jnp.where(again, jnp.inf, radius)  # (the second try's first radius: its first Newton step's)
        return k + 1, v_new, Gn, A_new, done, v_best, G_best, damped | again, radius

    def cond(state):
        k, _, _, _, done, *_ = state
        return (k < limit) & ~done

    Q0, D0 = contact_force_and_jacobian(models, pr, pr.v0)
    G_first = -h * (pr.f + Q0)
    A0 = pr.Mh - h * D0
    start = (0, pr.v0, G_first, A0, ~jnp.all(jnp.isfinite(G_first)), pr.v0, G_first)
    start = start + ((jnp.zeros((), bool), jnp.asarray(jnp.inf, pr.v0.dtype)) if retries else ())
    k, v, G, _, done, v_best, G_best, *_ = jax.lax.while_loop(cond, body, start)
    # not converged: the iterate with the smallest residual (of both tries; never worse than
    # the step's start), not wherever the last iteration ended
    v, G = jnp.where(done, v, v_best), jnp.where(done, G, G_best)
    rel = jnp.max(jnp.abs(G)) / (impulse + jnp.max(jnp.abs(G_first)) + jnp.finfo(v.dtype).tiny)
    return v, jnp.stack([jnp.asarray(k, v.dtype), rel, done.astype(v.dtype)])


def solve_velocity(models: tuple, opts: NewtonConfig, h, pr: ImplicitProblem):
    """The next velocity v' (nv,) with G(v') = 0, and diagnostics [Newton iterations,
    final residual relative to the step's impulses, 1.0 where converged else 0.0] (3,).
    ``models``: the contact model of each pair group (static); h: time step [s], a float or
    a traced scalar (the failed step's substeps, :attr:`NewtonConfig.failure_substeps`).
    Differentiable (forward and, unless ``opts.reverse_mode`` is False, reverse mode)
    through the implicit function theorem."""
    return _solve_velocity(models, opts, jnp.asarray(h, pr.v0.dtype), pr)


@functools.partial(jax.custom_jvp, nondiff_argnums=(0, 1))
def _solve_velocity(models: tuple, opts: NewtonConfig, h, pr: ImplicitProblem):
    return _newton(models, opts, h, pr)


@_solve_velocity.defjvp
def _solve_velocity_jvp(models, opts, primals, tangents):
    (h, pr), (dh, dpr) = primals, tangents
    v, info = _newton_plain(models, opts, h, pr)
    _, D = contact_force_and_jacobian(models, _undifferentiated(pr), v)
    _, dG = jax.jvp(lambda h_, p: _residual(models, h_, p, v, opts.reverse_mode), (h, pr), (dh, dpr))
    dv = -jnp.linalg.solve(pr.Mh - h * D, dG)
    return (v, info), (dv, jnp.zeros_like(info))

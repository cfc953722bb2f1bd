"""The public step: ``step(scene, params, data) -> data`` on MuJoCo MJX with DANO contact.

One step of length h = ``scene.dt`` from MJX ``Data`` ``d`` (its qpos, qvel, act, time,
ctrl, qfrc_applied, xfrc_applied and solver warm start):

1. ``mjx.fwd_position`` at q (kinematics, mass matrix, MuJoCo's own collisions and
   constraints), with the DANOs' masses and inertias scaled by α;
2. each pair group's contact geometry (ψ, χ, n and per-sample data, paper Eqs. 5–7)
   and the relative point Jacobians at χ, frozen for the step (as in Dojo);
3. MJX's velocity, actuation and acceleration stages and, when the model has
   constraints, its solver, with the contact force at the current velocity applied;
4. the implicit velocity equation (M + h·B)(v' − v) = h·(f + Q(v')) solved by Newton's
   method to a tolerance (:mod:`dano.sim.implicit`), damping and friction evaluated at v';
5. ``mjx.euler`` (EULERDAMP disabled) advances qvel to v', positions with v',
   activations and time; the quaternions of free and ball joints are then recomputed
   by the same rotation, q ⊗ exp(h·ω/2), written so that its derivative is also right at
   ω = 0 (MJX's normalises ω first: its derivative there is zero, not h/2).

Where the step is differentiated in forward mode only (``NewtonConfig.reverse_mode`` False),
a step whose solve of 4 fails (not converged, or a contact pair's rotation over the step
changed by more than half a radian) is taken again from its start in substeps
(:attr:`~dano.sim.NewtonConfig.failure_substeps`; :func:`~dano.sim.rollout` and the
identification turn them on where their rollouts diverge).

The returned ``Data`` keeps the caller's ``qfrc_applied`` (the contact force is not left
in it) and carries act, time and the constraint solver's warm start to the next step.
Everything is pure JAX: ``jax.jit``, ``jax.vmap``, ``jax.jacfwd`` and ``jax.grad`` apply.
Only public MJX functions and fields are used.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from .._mjx import mjx
from ..contact import PAIR_KINDS
from ..contact.base import batch_all, pose_linearised_geometry, prepare_pair, skip_separated
from .._compiled import under_trace
from ..errors import DanoError
from ..pose import normalize_quat, quat_multiply, rotvec_to_quat
from .implicit import (DEFAULT_FAILURE_SUBSTEPS, MAX_TURN_CHANGE, ImplicitProblem, NewtonConfig, contact_force,
                       resolve_linear_solver, solve_velocity)
from .scene import Scene, SimParams, cast_floats


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class State:
    """A configuration and velocity, the part of MJX ``Data`` most users set.

    qpos: (nq,) MuJoCo generalized positions (free joints: CoM position [m], wxyz
    quaternion); qvel: (nv,) generalized velocities (free joints: linear velocity, world
    frame [m/s], then angular velocity, body frame [rad/s])."""

    qpos: jax.Array
    qvel: jax.Array


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class StepInfo:
    """Diagnostics of one step: psi (P,) overlap of each contact pair at the step's start
    (mass units, ``scene.pair_names`` order); newton_iterations (): of both tries where the
    solve had a second (:attr:`~dano.sim.NewtonConfig.second_try`; up to 2·``max_iterations``,
    :func:`~dano.sim.implicit.iteration_limit`), of the substeps too where it had them;
    newton_residual (): final residual of the velocity equation relative to the step's
    impulses (the last substep's); substeps () int: 1, or
    :attr:`~dano.sim.NewtonConfig.failure_substeps` where the whole step failed and was
    taken again in that many substeps; failed () bool: the whole step's solve failed (not
    converged in its iterations, or a contact pair turned by more than
    :data:`~dano.sim.implicit.MAX_TURN_CHANGE` over the step), whether or not it was taken
    again in substeps (with single steps the failed step is kept as it is)."""

    psi: jax.Array
    newton_iterations: jax.Array
    newton_residual: jax.Array
    substeps: jax.Array = 1
    failed: jax.Array = False


def make_data(scene: Scene, qpos=None, qvel=None, *, act=None, ctrl=None, time: float = 0.0):
    """MJX ``Data`` for ``scene`` at (qpos (nq,), qvel (nv,)) (default: the model's qpos0, at
    rest), with optional activations act (na,) and controls ctrl (nu,); every floating-point
    field in the scene's dtype. Jittable (the shapes are checked at trace time). Raises
    DanoError for an array of the wrong shape (e.g. a free body's qpos needs 7 numbers:
    position and the wxyz quaternion) or a zero or non-finite quaternion
    (:func:`check_quaternions`)."""
    return _make_data(scene, qpos, qvel, act, ctrl, time, "make_data: qpos")


def _make_data(scene: Scene, qpos, qvel, act, ctrl, time, qpos_name: str):
    """:func:`make_data`, its quaternion errors naming the qpos ``qpos_name``."""
    dt = scene.dtype
    m = scene.model
    for what, x, n in (("qpos", qpos, m.nq), ("qvel", qvel, m.nv), ("act", act, m.na), ("ctrl", ctrl, m.nu)):
        if x is not None and np.shape(x) != (n,):
            raise DanoError(f"make_data: {what} must have shape ({n},) for this scene, got {np.shape(x)}"
                            + (" (a free body's qpos is x, y, z, qw, qx, qy, qz)" if what == "qpos" else ""))
    if qpos is not None:
        check_quaternions(scene, qpos, qpos_name)
    # (MJX makes its float fields in JAX's default float type; on this process's first device, not
    # jax.devices()[0], which is process 0's in a multi-process run)
    device = jax.local_devices()[0]
    d = mjx.make_data(scene.model, device=device)
    d = cast_floats(d, dt)
    repl = {"time": jnp.asarray(time, dt)}
    if qpos is not None:
        repl["qpos"] = jnp.asarray(qpos, dt)
    if qvel is not None:
        repl["qvel"] = jnp.asarray(qvel, dt)
    if act is not None:
        repl["act"] = jnp.asarray(act, dt)
    if ctrl is not None:
        repl["ctrl"] = jnp.asarray(ctrl, dt)
    d = d.replace(**repl)
    if under_trace(qpos, qvel, act, ctrl, time):
        return d
    # every field committed to the device, as a jitted step's output is: otherwise a user's
    # `jax.jit(step)` loop compiles twice (first for this mix of committed and uncommitted
    # arrays, then for its own output), 1.5 s more on the bunny
    return jax.device_put(d, device)


def check_quaternions(scene: Scene, qpos, what: str = "qpos") -> None:
    """Raises DanoError if a free or ball joint's w-x-y-z quaternion in ``qpos`` (nq,) is zero
    (below 1e-6 in norm) or not finite: it has no rotation to normalise to, and the step would make the
    whole state NaN. Only concrete values are checked (under a JAX transformation nothing);
    other quaternions need not be unit (the step normalises them)."""
    if under_trace(qpos) or not scene.info.quaternion_slots:
        return
    q = np.asarray(qpos, dtype=np.float64)
    if q.shape != (scene.nq,):
        return  # (the caller reports the shape)
    for adr, _ in scene.info.quaternion_slots:
        if not np.linalg.norm(q[adr:adr + 4]) > 1e-6:  # (NaN fails too)
            body = scene.mj_model.body(_body_of_quaternion(scene.mj_model, adr)).name
            raise DanoError(f"{what}: the quaternion of {body!r} (qpos[{adr}:{adr + 4}] = "
                            f"{q[adr:adr + 4].tolist()}) is zero or not finite; give a w-x-y-z orientation, e.g. 1 0 0 0")


def _body_of_quaternion(m, qpos_adr: int) -> int:
    """The body of the free or ball joint whose quaternion starts at ``qpos_adr`` of MuJoCo
    model ``m``'s qpos (a free joint's 3 after its address, a ball joint's at it)."""
    free, ball = m.jnt_type == mujoco.mjtJoint.mjJNT_FREE, m.jnt_type == mujoco.mjtJoint.mjJNT_BALL
    starts = m.jnt_qposadr + 3 * free
    return int(m.jnt_bodyid[np.flatnonzero((free | ball) & (starts == qpos_adr))[0]])


def as_data(scene: Scene, state):
    """``state`` as MJX Data: a :class:`State` (qpos/qvel, the rest at rest) or Data itself."""
    if isinstance(state, State):
        return _make_data(scene, state.qpos, state.qvel, None, None, 0.0, "initial qpos")
    return state


def model_with_alpha(scene: Scene, alpha):
    """The MJX model with each DANO's mass and inertia scaled by its α (D,)."""
    return model_with_params(scene, SimParams(None, alpha))


def second_moments(inertia):
    """Principal second moments of mass Σ (..., 3) [kg m²] (Σ_x = ∫x² dm in the principal
    frame) from principal moments of inertia (..., 3) [kg m²]: Σ_x = (I_y + I_z − I_x)/2.
    NumPy or JAX arrays."""
    return 0.5 * (inertia.sum(-1, keepdims=True) - 2 * inertia)


def moments_of_inertia(second):
    """Principal moments of inertia (..., 3) [kg m²] from second moments Σ (..., 3):
    I_x = Σ_y + Σ_z (the inverse of :func:`second_moments`). NumPy or JAX arrays."""
    return second.sum(-1, keepdims=True) - second


def model_with_params(scene: Scene, params: SimParams):
    """The MJX model with each DANO's inertial properties from ``params``: mass and inertia
    scaled by α, and, where given, the centre of mass offset (body_ipos), the principal
    second moments scaled (body_inertia: I_x = α(Σ_y + Σ_z), ...) and the principal axes
    rotated (body_iquat). Differentiable in all of them."""
    m = scene.model
    if not scene.info.dano_bodies:
        return m
    ids = np.asarray(scene.info.dano_bodies, dtype=np.int32)
    alpha = params.alpha
    mass = scene.base_mass * alpha
    inertia = scene.base_inertia
    if params.second_moment_scale is not None:
        inertia = moments_of_inertia(second_moments(inertia) * params.second_moment_scale)
    repl = dict(body_mass=m.body_mass.at[ids].set(mass), body_subtreemass=m.body_subtreemass.at[ids].set(mass),
                body_inertia=m.body_inertia.at[ids].set(inertia * alpha[:, None]))
    if params.com_offset is not None:
        repl["body_ipos"] = m.body_ipos.at[ids].add(params.com_offset)
    if params.principal_axes is not None:  # (a NaN-free exponential map at zero rotation)
        turn = quat_multiply(m.body_iquat[ids], rotvec_to_quat(jnp.asarray(params.principal_axes)))
        repl["body_iquat"] = m.body_iquat.at[ids].set(turn)
    return m.replace(**repl)


def _group_params(params: SimParams, group, num_pairs: int):
    idx = np.asarray(group.index, dtype=np.int32)
    return jax.tree_util.tree_map(lambda x: jnp.broadcast_to(jnp.asarray(x), (num_pairs,))[idx], params.contact)


def contact_geometry(scene: Scene, params: SimParams, m, d, tangents: str = "direct"):
    """Per pair group: the batched :class:`~dano.contact.PairGeometry` and the relative point
    Jacobians (G, nv, 6) [Jp | Jr] of A minus B at each centroid, for Data ``d`` after
    ``fwd_position`` on model ``m``. tangents: how forward-mode derivatives go through the
    geometry (:attr:`NewtonConfig.geometry_tangents`)."""
    geos, jacs = [], []
    for group in scene.groups:
        kind = PAIR_KINDS[group.kind]
        world_b = all(b == 0 for b in group.body_b)  # fixed geoms: B does not move
        if tangents == "pose":
            geometry = functools.partial(pose_linearised_geometry, kind, world_b)
        else:
            geometry = kind.geometry
        if getattr(group.model, "aggregates_only", False) and hasattr(kind, "apart"):
            # a pair no sample can touch skips its samples (a wall never touched cost 2-3x the step)
            geometry = skip_separated(kind, geometry)
        g = jax.vmap(geometry)(kind.inputs(scene, group, m, d, params.alpha))

        def rel_jac(chi, ba, bb):
            jpa, jra = mjx.jac(m, d, chi, ba)
            if not world_b:
                jpb, jrb = mjx.jac(m, d, chi, bb)
                jpa, jra = jpa - jpb, jra - jrb
            # (mjx.jac builds its result in the default float type: 64-bit under x64 mode)
            return jnp.concatenate([jpa, jra], axis=1).astype(d.qpos.dtype)

        geos.append(g)
        jacs.append(jax.vmap(rel_jac)(g.chi, jnp.asarray(group.body_a), jnp.asarray(group.body_b)))
    return tuple(geos), tuple(jacs)


def _psi(scene: Scene, geos, dtype):
    psi = jnp.zeros((len(scene.pairs),), dtype)
    for group, g in zip(scene.groups, geos):
        psi = psi.at[np.asarray(group.index, dtype=np.int32)].set(g.psi)
    return psi


def overlaps(scene: Scene, params: SimParams, data) -> jax.Array:
    """ψ (P,) of every contact pair at ``data``'s configuration (mass units)."""
    m = model_with_params(scene, params)
    d = mjx.fwd_position(m, data)
    geos, _ = contact_geometry(scene, params, m, d)
    return _psi(scene, geos, d.qpos.dtype)


#: a further constraint pass runs when the contact force at the solved velocity differs from
#: the one MuJoCo's constraint solver saw by more than this fraction (NewtonConfig.constraint_passes)
PASS_CHANGE = 0.05


def _leaf_shapes(tree):
    return jax.tree_util.tree_structure(tree), tuple((x.shape[1:], x.dtype) for x in jax.tree_util.tree_leaves(tree))


def merge_groups(scene, models, *columns):
    """The step's pair groups with those of equal contact models and prepared states of the
    same structure (a centroid pair's is the same whatever its kind) joined into one, except
    that plane pairs keep a group of their own: a ground is touched nearly always, while the
    rest (walls, posts, other objects) are often all apart and their group then idles
    (:attr:`~dano.sim.implicit.ImplicitProblem.idle`). Returns (models, columns): the models
    of the joined groups and each column (a tuple with an entry per group: Jacobians,
    states, parameters, ...) joined alike, the pairs of a joined group in the order of the
    groups. The Newton iteration evaluates each group's wrenches as one vmapped call (the
    same forces, summed in another order). The bunny drop beside a box, a capsule and a
    sphere it never reaches, 2-core CPU: 1.47x the drop's time joined so, 1.63x not joined,
    2.24x all joined with the ground (``benchmarks/results-cpu.json``)."""
    keys, joined = [], {}
    for i, (group, model) in enumerate(zip(scene.groups, models)):
        key = (model, i if group.kind == "plane" else -1) + tuple(_leaf_shapes(col[i]) for col in columns)
        if key not in joined:
            keys.append(key)
            joined[key] = []
        joined[key].append(i)
    if len(keys) == len(models):
        return models, columns

    def cat(parts):
        return parts[0] if len(parts) == 1 else jax.tree_util.tree_map(lambda *x: jnp.concatenate(x), *parts)

    groups = [joined[k] for k in keys]
    return (tuple(models[idx[0]] for idx in groups),
            tuple(tuple(cat([col[i] for i in idx]) for idx in groups) for col in columns))


def step_with_info(scene: Scene, params: SimParams, data, newton: NewtonConfig = NewtonConfig()):
    """:func:`step`, also returning its :class:`StepInfo`."""
    newton = resolve_linear_solver(newton, scene, 1)  # ("auto": the unrolled LU on a GPU, LAPACK on the CPU)
    n = failure_substeps(newton)
    if n <= 1 or not scene.groups:
        return _attempt(scene, params, data, newton, scene.dt)
    lengths = jnp.asarray([scene.dt] + [scene.dt / n] * n, data.qvel.dtype)

    def trip(carry):
        # trip 0: the whole step from ``data``; where it failed, trips 1..n: its substeps from
        # ``data`` on (under vmap the loop runs while any member needs it, the others' carries
        # kept as they are by the loop's batching)
        k, state, failed, info = carry
        d_new, info_new = _attempt(scene, params, data.replace(**state), newton, lengths[k])
        bad = info_new.failed
        keep = (k > 0) | ~bad
        d = jax.tree_util.tree_map(lambda a, b: jnp.where(keep, a, b), _stepped(d_new), state)
        info = dataclasses.replace(info_new, psi=jnp.where(k == 0, info_new.psi, info.psi),
                                   newton_iterations=info.newton_iterations + info_new.newton_iterations)
        return k + 1, d, jnp.where(k == 0, bad, failed), info

    def more(carry):
        k, _, failed, _ = carry
        return (k == 0) | ((k <= n) & failed)

    zero = jnp.zeros((), data.qvel.dtype)
    info0 = StepInfo(jnp.zeros((len(scene.pairs),), data.qpos.dtype), zero, zero, jnp.ones((), jnp.int32),
                     jnp.zeros((), bool))
    start = tied((0, _stepped(data), jnp.zeros((), bool), info0), data.qpos, data.qvel, params)
    _, state, failed, info = jax.lax.while_loop(more, trip, start)
    return data.replace(**state), dataclasses.replace(info, substeps=jnp.where(failed, n, 1).astype(jnp.int32),
                                                      failed=failed)


#: the fields of MJX Data a step changes (the others are computed from them or set by the caller)
STEPPED_FIELDS = ("time", "qpos", "qvel", "act", "qacc", "act_dot", "qacc_warmstart", "history", "plugin_state")


def _stepped(d) -> dict:
    return {n: getattr(d, n) for n in STEPPED_FIELDS if hasattr(d, n)}


def failure_substeps(newton: NewtonConfig) -> int:
    """The substeps a failed step is taken again in (:attr:`NewtonConfig.failure_substeps`;
    None resolved: 4 where the step is differentiated in forward mode only, 1 otherwise)."""
    if newton.failure_substeps is not None:
        return newton.failure_substeps
    return 1 if newton.reverse_mode else DEFAULT_FAILURE_SUBSTEPS


def _attempt(scene: Scene, params: SimParams, data, newton: NewtonConfig, h):
    """One step of length ``h`` [s] (a float, or a traced scalar) from MJX ``data``: (Data,
    :class:`StepInfo`, its ``failed``: the solve did not converge, or the step changes a
    pair's rotation over it by more than :data:`MAX_TURN_CHANGE`,
    :attr:`NewtonConfig.failure_substeps`)."""
    m = model_with_params(scene, params)
    if not isinstance(h, float):  # (the substeps of a failed step: MJX's stages read the model's time step)
        m = m.replace(opt=m.opt.replace(timestep=jnp.asarray(h, m.opt.timestep.dtype)))
    user_qfrc = data.qfrc_applied
    d = mjx.fwd_position(m, data)
    geos, jacs = contact_geometry(scene, params, m, d, newton.geometry_tangents)
    models = tuple(g.model for g in scene.groups)
    gparams = tuple(_group_params(params, g, len(scene.pairs)) for g in scene.groups)
    # each pair's relative twist at its centroid at the step's start (J·v: the contact models' look-ahead)
    twists = tuple(jnp.einsum("gvk,v->gk", J, data.qvel.astype(J.dtype)) for J in jacs)
    states = tuple(jax.vmap(lambda g_, u_, model=model: prepare_pair(model, g_, h, u_))(g, u)
                   for model, g, u in zip(models, geos, twists))
    psis = tuple(g.psi for g in geos)
    models, (jacs, states, gparams, psis) = merge_groups(scene, models, jacs, states, gparams, psis)
    # a group all of whose pairs are apart is not evaluated in the Newton iteration
    idle = tuple(batch_all(jnp.all(psi == 0)) if getattr(model, "zero_when_apart", False) else None
                 for model, psi in zip(models, psis))
    d = mjx.fwd_velocity(m, d)
    d = mjx.fwd_actuation(m, d)
    # some MJX stages compute in the default float type (64-bit under x64 mode): keep the
    # scene's dtype, so a float32 scene runs in float32 whatever JAX's mode
    dtype = data.qvel.dtype
    Mh = (mjx.full_m(m, d) + h * jnp.diag(m.dof_damping)).astype(dtype)
    failed = jnp.zeros((), bool)
    if scene.groups:
        problem = ImplicitProblem(Mh, d.qvel, jnp.zeros_like(d.qvel, dtype), jacs, states, gparams, idle)
        if scene.has_constraints:
            d, v_next, diag = _constraint_passes(m, d, user_qfrc, newton, h, models, problem)
        else:
            d = mjx.fwd_acceleration(m, d)
            v_next, diag = solve_velocity(models, newton, h, dataclasses.replace(problem, f=d.qfrc_smooth.astype(dtype)))
        spun = _turn(jacs, v_next - d.qvel.astype(dtype), h) > MAX_TURN_CHANGE
        failed = jax.lax.stop_gradient((diag[2] == 0) | spun)
    else:
        d = mjx.fwd_acceleration(m, d)
        f = d.qfrc_smooth
        if scene.has_constraints:
            d = mjx.solve(m, d)
            f = f + d.qfrc_constraint
        v_next = d.qvel + jnp.linalg.solve(Mh, h * f.astype(dtype))
        diag = jnp.asarray([1.0, 0.0, 1.0], d.qvel.dtype)
    qacc = (v_next - d.qvel) / h
    d = mjx.euler(m, d.replace(qacc=qacc))
    d = d.replace(qpos=_rotate_quaternions(scene, data.qpos, v_next, h, d.qpos))
    d = d.replace(qfrc_applied=user_qfrc)
    # same structure and dtypes as the input (MJX makes some integer fields int32 in
    # make_data but int64 in its stages under 64-bit mode), so that steps chain in a scan
    d = jax.tree_util.tree_map(lambda new, old: new.astype(old.dtype), d, data)
    return d, StepInfo(_psi(scene, geos, d.qpos.dtype), diag[0], diag[1], jnp.ones((), jnp.int32), failed)


def _turn(jacs, v, h):
    """The largest rotation of a contact pair over a step of ``h`` [s] at velocity v (nv,) [rad]."""
    turns = [jnp.max(jnp.linalg.norm(jnp.einsum("gvk,v->gk", J, v)[:, 3:], axis=1)) for J in jacs]
    return h * functools.reduce(jnp.maximum, turns)


def tied(carry, *inputs):
    """``carry`` (a pytree) with every leaf made to depend, by adding zero, on every
    floating-point leaf of ``inputs``: where any of them is batched (``jax.vmap``) or carries
    a tangent (``jax.jvp``, ``jax.jacfwd``), so does every leaf of a loop's carry from the
    start. JAX's ``scan`` rules find which carries are batched or differentiated by a fixed
    point that transforms the whole loop body once per round: a rollout's MJX ``Data``, only
    some of whose fields depend on the inputs at the start, took 3 rounds of differentiation
    and 2 + 3 of batching in the soap's Jacobian (about half of its tracing time); tied, one
    each. The values are unchanged (x + 0, whatever the inputs hold: non-finite entries count
    as 0; integer leaves go through a select of themselves)."""
    floats = [x for x in jax.tree_util.tree_leaves(inputs) if jnp.issubdtype(jnp.result_type(x), jnp.floating)]
    if not floats:
        return carry
    dtype = jnp.result_type(*floats)
    total = sum(jnp.sum(jnp.where(jnp.isfinite(x), x, 0)).astype(dtype) for x in floats)
    zero = 0.0 * jnp.tanh(total)  # (tanh: finite even where the sum overflows)
    keep = zero == 0  # (either way the select below gives x: only the dependence matters)

    def tie(x):
        x = jnp.asarray(x)
        if jnp.issubdtype(x.dtype, jnp.floating):
            return x + zero.astype(x.dtype)
        return jnp.where(keep, x, x)

    return jax.tree_util.tree_map(tie, carry)


def _constraint_passes(m, d, user_qfrc, newton: NewtonConfig, h: float, models, problem: ImplicitProblem):
    """Steps 3–5 of the module doc for a model with MuJoCo constraints and DANO contact:
    MuJoCo's constraint solver and the implicit contact solve, alternated. Pass 0 shows the
    solver the contact force Q at the step's start velocity; each further pass (at most
    ``newton.constraint_passes`` in all) runs only when Q at the solved velocity differs from
    the one the solver saw by more than :data:`PASS_CHANGE`, and shows it that force.
    ``d``: Data after the velocity and actuation stages; ``problem``: the velocity equation,
    its ``f`` filled in by each pass. Returns (Data after the last pass's constraint solve,
    v' (nv,), Newton diagnostics (2,)). The passes are one ``lax.scan`` over a single traced
    pass: a copy per pass made a robot's step program a third larger (the Panda pushing the
    bunny, 200 steps, optimised HLO: 45.9k lines with two copies, 35.1k as this scan, 33.1k
    with one pass only)."""
    dtype = d.qvel.dtype

    def one_pass(d_in, Q):
        d1 = mjx.solve(m, mjx.fwd_acceleration(m, d_in.replace(qfrc_applied=user_qfrc + Q)))
        f = (d1.qfrc_smooth + d1.qfrc_constraint - Q).astype(dtype)
        v, diag = solve_velocity(models, newton, h, dataclasses.replace(problem, f=f))
        # the input's dtypes (MJX makes some integer fields int64 under 64-bit mode), so that
        # a pass not taken can return its input unchanged
        return jax.tree_util.tree_map(lambda new, old: new.astype(old.dtype), d1, d_in), Q, v, diag

    def body(carry, first):
        d_in, Q_seen, v, _ = carry
        Q = contact_force(models, problem, v, newton.reverse_mode).astype(dtype)
        changed = jnp.linalg.norm(Q - Q_seen) > PASS_CHANGE * (jnp.linalg.norm(Q_seen) + jnp.linalg.norm(Q))
        return jax.lax.cond(first | changed, lambda: one_pass(d_in, Q), lambda: carry), None

    first = jnp.arange(newton.constraint_passes) == 0
    init = tied((d, jnp.zeros_like(d.qvel, dtype), d.qvel.astype(dtype), jnp.zeros((3,), dtype)),
                d.qpos, d.qvel, d.qfrc_smooth, problem)  # (one round of the scan's rules: see tied)
    (d, _, v, diag), _ = jax.lax.scan(body, init, first)
    return d, v, diag


def _rotate_quaternions(scene: Scene, qpos0, v, h: float, qpos):
    """``qpos`` with each free/ball joint's quaternion set to normalize(q0 ⊗ exp(h·ω)),
    q0 from ``qpos0``, ω (body frame) from ``v``; the exponential map of :mod:`dano.pose`
    (Taylor series near 0), so that value and derivatives are exact at ω = 0 too."""
    slots = scene.info.quaternion_slots
    if not slots:
        return qpos
    qa = np.asarray([a for a, _ in slots])[:, None] + np.arange(4)
    wa = np.asarray([b for _, b in slots])[:, None] + np.arange(3)
    q = normalize_quat(quat_multiply(qpos0[qa], rotvec_to_quat(h * v[wa])))
    return qpos.at[qa].set(q.astype(qpos.dtype))


def step(scene: Scene, params: SimParams, data, newton: NewtonConfig = NewtonConfig()):
    """Advance MJX ``data`` by one time step ``scene.dt`` with DANO contact (paper §IV on
    MuJoCo MJX; see the module documentation). Pure and jittable; ``jax.vmap`` over data,
    params or scene arrays; differentiable in data, params and scene arrays, in forward mode
    always and in reverse mode where MuJoCo's constraint solver does not run
    (``scene.has_constraints`` False: no joint limits, equalities, friction loss or MuJoCo
    geoms that can collide; its loop is a ``while_loop``). Controls and applied forces for
    the step are ``data.ctrl``, ``data.qfrc_applied`` and ``data.xfrc_applied``. newton: options of the implicit solve."""
    return step_with_info(scene, params, data, newton)[0]

"""Rollouts: :func:`~dano.sim.dynamics.step` inside one jitted ``jax.lax.scan``."""

from __future__ import annotations

import dataclasses
import warnings

import jax
import jax.numpy as jnp
import numpy as np

from .._compiled import cached_jit
from .._jax_setup import rollout_compiler_options
from ..errors import DanoError, DanoWarning
from ..trajectory import Trajectory
from .implicit import DEFAULT_FAILURE_SUBSTEPS, NewtonConfig, resolve_linear_solver
from .scene import Scene, SimParams
from .dynamics import State, as_data, check_quaternions, failure_substeps, overlaps, step_with_info, tied


class SimulationDiverged(DanoError):
    """The state became non-finite, too fast or too deeply interpenetrating; ``step`` and
    ``time`` [s] tell when."""

    def __init__(self, step: int, time: float, reason: str):
        self.step, self.time = step, time
        super().__init__(f"simulation diverged at step {step} (t = {time:.4g} s): {reason}; "
                         "reduce the time step or check the parameters")


#: the MJX Data fields a rollout's loop carries from step to step: MuJoCo's state and inputs
#: (mjSTATE_INTEGRATION: time, qpos, qvel, act, warm start, controls, applied forces, mocap,
#: equality flags, user data) and the step's qacc and act_dot. A step computes every other
#: field (positions, inertias, forces, contacts, ...) afresh from these; carried, XLA computed
#: each of them every step only to overwrite it (23 of the bunny drop's 204 operations per
#: step; a 10,000-step drop, alternating runs: 28.2–28.6 → 24.5–25.2 µs per step).
CARRIED_FIELDS = ("time", "qpos", "qvel", "act", "history", "qacc_warmstart", "plugin_state", "ctrl", "qfrc_applied",
                  "xfrc_applied", "eq_active", "mocap_pos", "mocap_quat", "userdata", "qacc", "act_dot")


def carried(data) -> dict:
    """The fields of MJX ``data`` that a loop of steps carries (:data:`CARRIED_FIELDS`, those
    this MJX has), by name; ``data.replace(**carried(d))`` continues from ``d``."""
    return {n: getattr(data, n) for n in CARRIED_FIELDS if hasattr(data, n)}


def _scan_steps(scene: Scene, params: SimParams, data, controls, qfrc, newton: NewtonConfig, final_overlaps: bool,
                active=None):
    state0 = tied(carried(data), params, controls, qfrc, data.qpos, data.qvel)

    def advance(state, ctrl, f):
        d = data.replace(**state)
        d = d.replace(ctrl=ctrl.astype(d.ctrl.dtype), qfrc_applied=f.astype(d.qfrc_applied.dtype))
        d_next, info = step_with_info(scene, params, d, newton)
        return carried(d_next), (d_next.qpos, d_next.qvel, info.psi, info.newton_iterations,
                                 jnp.asarray(info.failed, bool))

    if active is None:
        last, (qpos, qvel, psi, iters, failed) = jax.lax.scan(lambda s, x: advance(s, *x), state0, (controls, qfrc))
    else:  # a loop of ``active`` steps (a value, not a shape) filling the first rows of the outputs
        def one_step(k, carry):
            state, outs = carry
            state, (q, v, p, it, bad) = advance(state, controls[k], qfrc[k])
            new = (q, v, p.astype(q.dtype), it.astype(v.dtype), bad)
            return state, tuple(o.at[k].set(x) for o, x in zip(outs, new))

        q0, v0 = state0["qpos"], state0["qvel"]
        rows = controls.shape[0]
        outs = (jnp.zeros((rows,) + q0.shape, q0.dtype), jnp.zeros((rows,) + v0.shape, v0.dtype),
                jnp.zeros((rows, len(scene.pairs)), q0.dtype), jnp.zeros((rows,), v0.dtype),
                jnp.zeros((rows,), bool))
        last, (qpos, qvel, psi, iters, failed) = jax.lax.fori_loop(0, active, one_step, (state0, outs))
    d_last = data.replace(**last)
    if final_overlaps:  # (each step reported ψ at its start)
        psi = jnp.concatenate([psi, overlaps(scene, params, d_last)[None]])
    return (d_last, jnp.concatenate([data.qpos[None], qpos]), jnp.concatenate([data.qvel[None], qvel]), psi, iters,
            failed)


_scan_steps_compiled = cached_jit(_scan_steps, static_argnums=(5, 6), compiler_options=rollout_compiler_options)


def scan_steps(scene: Scene, params: SimParams, data, controls, qfrc, newton: NewtonConfig = NewtonConfig(),
               final_overlaps: bool = True, *, failures: bool = False):
    """T steps from MJX ``data`` with controls (T, nu) and applied generalized forces
    (T, nv) per step. Returns (final Data, qpos (T+1, nq), qvel (T+1, nv), psi (T+1, P),
    Newton iterations (T,)), with ``failures=True`` also whether each step failed (T,) bool
    (:attr:`~dano.sim.dynamics.StepInfo.failed`); the final Data holds the state after the last step
    (:data:`CARRIED_FIELDS`: time, qpos, qvel, act, warm start, ...) and ``data``'s other
    fields (xpos, contacts, ...: ``mjx.forward`` computes them for the final state);
    ``final_overlaps=False``: psi (T, P), without the final state's (its contact geometry is
    then not evaluated, nor traced: a third of the tracing of an identification's residual,
    whose rollouts need no ψ). Jitted; compiled once per scene
    structure and T, and, with the compilation cache on, traced once per structure across
    processes (:mod:`dano._compiled`). ``newton.linear_solver="auto"`` is resolved here for
    T steps (:func:`~dano.sim.implicit.resolve_linear_solver`)."""
    newton = resolve_linear_solver(newton, scene, controls.shape[0])
    out = _scan_steps_compiled(scene, params, data, controls, qfrc, newton, final_overlaps)
    return out if failures else out[:5]


def _inputs(scene: Scene, data, controls, qfrc, steps: int, xp=jnp):
    """(controls (T, nu), qfrc (T, nv)): those given, or the data's ctrl and qfrc_applied held
    for ``steps`` steps; ``xp``: jnp inside traced code, np for host-side arrays."""
    ctrl = xp.broadcast_to(xp.asarray(data.ctrl), (steps, scene.nu)) if controls is None else controls
    f = xp.broadcast_to(xp.asarray(data.qfrc_applied), (steps, scene.nv)) if qfrc is None else qfrc
    return ctrl, f


def rollout_arrays(scene: Scene, state0, controls, params: SimParams, steps: int, qfrc=None, *,
                   overlaps: bool = True, newton: NewtonConfig = NewtonConfig(), iterations: bool = False,
                   failures: bool = False):
    """The jitted, differentiable core of :func:`rollout`: returns (qpos (T+1, nq),
    qvel (T+1, nv), psi (T+1, P)) as JAX arrays. state0: a :class:`State` or MJX Data;
    controls (T, nu) or None (hold the data's ctrl: zeros for a State); qfrc (T, nv) or None
    (hold its qfrc_applied); overlaps=False: psi None (the final state's contact geometry
    not evaluated: :func:`scan_steps`); newton: the step's solver settings; iterations=True:
    the step's Newton iterations (T,) int appended to the tuple; failures=True: then whether
    each step failed (T,) bool (:attr:`~dano.sim.dynamics.StepInfo.failed`). Use it inside
    ``jax.jacfwd``."""
    data = as_data(scene, state0)
    ctrl, f = _inputs(scene, data, controls, qfrc, steps)
    _, qpos, qvel, psi, its, failed = scan_steps(scene, params, data, ctrl, f, newton, overlaps, failures=True)
    out = (qpos, qvel, (psi if overlaps else None))
    return out + (its,) * iterations + (failed,) * failures


#: :func:`rollout` runs in chunks of at most this many steps: a loop whose trip count is an
#: argument, filling the first rows of outputs of this length, so that one compiled program per
#: scene structure serves every duration
CHUNK = 10_000
#: with progress reported, chunks of a twentieth of the run, but at least this many steps (the
#: same program: only the trip count differs)
PROGRESS_CHUNK = 1000


def _chunk(x: np.ndarray, start: int, active: int) -> jax.Array:
    """Rows start … start + active of (T, k) ``x``, the last one repeated up to :data:`CHUNK`
    rows (the rows past ``active`` are not stepped)."""
    part = x[start : start + active]
    return jax.device_put(np.concatenate([part, np.repeat(part[-1:], CHUNK - active, axis=0)]))


def _as_array(x, shape, what, dtype):
    arr = np.asarray(x, dtype=np.float64)
    if arr.shape != shape:
        raise DanoError(f"{what} must have shape {shape}, got {tuple(arr.shape)}")
    if not np.all(np.isfinite(arr)):
        raise DanoError(f"{what} contains NaN or infinite values")
    return jax.device_put(arr.astype(np.dtype(dtype)))  # (jnp.asarray compiled a small program per shape)


def check_params(scene: Scene, params: SimParams) -> None:
    """Raises DanoError for non-finite or invalid parameters (concrete values only)."""
    leaves = jax.tree_util.tree_leaves(params)
    if any(isinstance(x, jax.core.Tracer) for x in leaves):
        return
    params.contact.validate()
    alpha = np.asarray(params.alpha)
    if alpha.shape != (len(scene.dano_names),) or not np.all(np.isfinite(alpha)) or np.any(alpha <= 0):
        raise DanoError(f"alpha must be {len(scene.dano_names)} finite positive mass scales, got {alpha.tolist()}")
    for name in ("com_offset", "second_moment_scale", "principal_axes"):
        v = getattr(params, name)
        if v is not None and (np.shape(v) != (len(scene.dano_names), 3) or not np.all(np.isfinite(np.asarray(v)))):
            raise DanoError(f"{name} must be ({len(scene.dano_names)}, 3) finite values, got shape {np.shape(v)}")
    if params.second_moment_scale is not None and np.any(np.asarray(params.second_moment_scale) < 0):
        raise DanoError("second_moment_scale must be >= 0 (a physical inertia), got "
                        f"{np.asarray(params.second_moment_scale).tolist()}")


def rollout(
    scene: Scene,
    state0,
    controls=None,
    params: SimParams | None = None,
    steps: int | None = None,
    *,
    qfrc=None,
    max_speed: float = 1e3,
    progress=None,
    newton: NewtonConfig = NewtonConfig(),
) -> Trajectory:
    """Simulate ``steps`` steps of ``scene.dt`` from ``state0`` inside ``jax.lax.scan``.

    state0: a :class:`State` (qpos, qvel) or MJX Data (its act, time, ctrl and warm start
    carry on); controls: (T, nu) actuator controls per step (default: hold state0's); qfrc:
    optional (T, nv) generalized forces per step [N, N·m]; params: :class:`SimParams`
    (default :meth:`Scene.default_params`); steps: T (default len(controls)).
    Returns a :class:`~dano.trajectory.Trajectory` (its ``final_data`` continues the run).
    Raises DanoError for bad shapes or parameters and :class:`SimulationDiverged` (with the
    step number) if the state becomes non-finite, a speed exceeds ``max_speed`` [m/s or
    rad/s] or an overlap exceeds half the DANO's mass (bodies passed through each other).
    For gradients use :func:`rollout_arrays` (or :func:`~dano.sim.dynamics.step`) under JAX.
    A run that diverges or has a failed step (:attr:`~dano.sim.dynamics.StepInfo.failed`),
    where ``newton`` leaves ``failure_substeps`` None, is simulated once more with each step
    whose Newton solve fails taken again in substeps
    (:attr:`~dano.sim.NewtonConfig.failure_substeps`; a DanoWarning says so) and kept if that
    one does not diverge: a second program, compiled only where it is needed. The trajectory's
    ``metadata["failure_substeps"]`` says which ran: 1 (single steps) or the substeps' count;
    ``metadata["failed_steps"]`` how many of its steps failed.
    progress: optional ``progress(done, total, description)``, called after each chunk.
    The rollout runs in chunks of up to :data:`CHUNK` steps (with progress, a twentieth of
    the run, at least :data:`PROGRESS_CHUNK`), each continuing from the last one's Data, their
    step count an argument of one compiled program: a new duration does not compile again.
    """
    params = scene.default_params() if params is None else params
    check_params(scene, params)
    if steps is None:
        if controls is None:
            raise DanoError("give the number of steps or a (T, nu) control sequence")
        steps = len(controls)
    if int(steps) < 1:
        raise DanoError(f"steps must be positive, got {steps}")
    steps = int(steps)
    dt = scene.dtype
    if isinstance(state0, State):
        data = as_data(scene, State(_as_array(state0.qpos, (scene.nq,), "initial qpos", dt),
                                    _as_array(state0.qvel, (scene.nv,), "initial qvel", dt)))
    else:
        _as_array(state0.qpos, (scene.nq,), "initial qpos", dt)
        _as_array(state0.qvel, (scene.nv,), "initial qvel", dt)
        check_quaternions(scene, state0.qpos, "initial qpos")
        data = state0
    ctrl = None if controls is None else _as_array(controls, (steps, scene.nu), "controls", dt)
    f = None if qfrc is None else _as_array(qfrc, (steps, scene.nv), "qfrc", dt)
    ctrl, f = (np.asarray(x) for x in _inputs(scene, data, ctrl, f, steps, np))
    newton = resolve_linear_solver(newton, scene, steps)  # on the whole rollout, not a chunk
    time = np.arange(steps + 1) * scene.dt
    qpos, qvel, psi, it, failed, final = _chunked(scene, params, data, ctrl, f, steps, newton, progress)
    k, _ = first_divergence(scene, params, qpos, qvel, psi, max_speed)
    substeps = failure_substeps(newton)
    if (k is not None or failed.any()) and newton.failure_substeps is None and substeps == 1:  # again, in substeps
        again = _chunked(scene, params, data, ctrl, f, steps, dataclasses.replace(newton, reverse_mode=False),
                         progress, "simulating again in substeps")
        first = int(np.argmax(failed)) if k is None else k
        what = (f"the simulation diverged at step {k}" if k is not None else f"the simulation had {int(failed.sum())} "
                f"of {steps} steps whose Newton solve failed, the first at step {first}")
        what += f" (t = {time[first]:.4g} s) with single steps"
        if first_divergence(scene, params, *again[:3], max_speed)[0] is None:
            substeps = DEFAULT_FAILURE_SUBSTEPS
            warnings.warn(f"{what}: simulated again with each step whose Newton solve failed taken in "
                          f"{DEFAULT_FAILURE_SUBSTEPS} substeps (docs/simulation.md, 'Substeps where a step fails')",
                          DanoWarning, stacklevel=2)
            qpos, qvel, psi, it, failed, final = again
        elif k is None:  # (a run that diverges either way is reported below)
            warnings.warn(f"{what}; simulated again with each taken in {DEFAULT_FAILURE_SUBSTEPS} substeps, it "
                          "diverged: the single steps' run is kept (reduce the time step)", DanoWarning, stacklevel=2)
    for line in deep_start_lines(scene, params, psi[0]):
        warnings.warn(line, DanoWarning, stacklevel=2)
    _check_divergence(scene, params, time, qpos, qvel, psi, max_speed)
    return Trajectory(
        time=time, qpos=qpos, qvel=qvel, psi=psi, body_names=scene.body_names, dano_names=scene.dano_names,
        qpos_adr=scene.qpos_adr, dof_adr=scene.dof_adr, pair_names=scene.pair_names,
        metadata={"scene": scene.name, "dt": scene.dt, "params": params_to_dict(scene, params),
                  "contact_models": {p.name: p.model.name for p in scene.pairs},
                  "newton_iterations": {"max": int(it.max()), "mean": float(it.mean())},
                  "failure_substeps": substeps, "failed_steps": int(failed.sum())},
        final_data=final,
    )


def _chunked(scene: Scene, params: SimParams, data, ctrl: np.ndarray, f: np.ndarray, steps: int,
             newton: NewtonConfig, progress, description: str = "simulating"):
    """:func:`rollout`'s loop over chunks: (qpos (T+1, nq), qvel (T+1, nv), psi (T+1, P),
    Newton iterations (T,), failed steps (T,) bool, the final Data or None where it stopped
    early at a non-finite state, the rest then NaN, the steps not taken not failed);
    ``progress(done, total, description)`` after each chunk."""
    size = CHUNK if progress is None else min(CHUNK, max(PROGRESS_CHUNK, -(-steps // 20)))
    starts = range(0, steps, size)
    parts, iters, fails = [], [], []
    for k, start in enumerate(starts):
        active = min(size, steps - start)
        data, qpos, qvel, psi, it, bad = _scan_steps_compiled(scene, params, data, _chunk(ctrl, start, active),
                                                              _chunk(f, start, active), newton, True, np.int32(active))
        psi = np.asarray(psi)  # (CHUNK + 1, P): ψ at each step's start, the last row the final state's
        arrs = [np.asarray(qpos)[: active + 1], np.asarray(qvel)[: active + 1], np.concatenate([psi[:active], psi[-1:]])]
        parts.append(arrs if k == 0 else [x[1:] for x in arrs])
        iters.append(np.asarray(it)[:active])
        fails.append(np.asarray(bad)[:active])
        if progress is not None:
            progress(start + active, steps, description)
        if not (np.all(np.isfinite(arrs[0])) and np.all(np.isfinite(arrs[1]))):
            break  # diverged: the check below finds the step
    qpos, qvel, psi = (np.concatenate([p[i] for p in parts])[: steps + 1] for i in range(3))
    if len(qpos) < steps + 1:  # stopped early; pad with NaN so that the check finds the step
        fill = lambda a: np.concatenate([a, np.full((steps + 1 - len(a),) + a.shape[1:], np.nan)])  # noqa: E731
        qpos, qvel, psi = fill(qpos), fill(qvel), fill(psi)
    failed = np.zeros(steps, bool)
    failed[: sum(map(len, fails))] = np.concatenate(fails)
    return qpos, qvel, psi, np.concatenate(iters)[:steps], failed, data if len(parts) == len(starts) else None


#: a pair whose overlap at the start exceeds this many times its resting overlap m·g/k is
#: reported (:func:`deep_start_lines`): the object was placed inside the other body
DEEP_START = 20.0


def deep_start_lines(scene: Scene, params: SimParams, psi0) -> list[str]:
    """One line per contact pair that starts deep in contact: its overlap ψ at t = 0
    (``psi0``: (pairs,) float) above :data:`DEEP_START` times the resting overlap m·g/k of its
    DANO (m its mass [kg] under ``params``' mass scale α, k the pair's impact spring
    [N per unit overlap], g the scene's gravity [m/s²]). The contact then pushes the object
    out over the first steps, as if launched: a pose's position is the centre of mass, not
    the object's lowest point. Empty without gravity (no resting overlap to compare with)."""
    gravity = float(np.linalg.norm(scene.mj_model.opt.gravity))
    psi0 = np.asarray(psi0, float)
    if gravity == 0.0 or not len(scene.pairs):
        return []
    spring = np.broadcast_to(np.asarray(params.contact.impact_spring, float), (len(scene.pairs),))
    mass = np.asarray(scene.base_mass, float) * np.asarray(params.alpha, float)  # (ψ scales with α: so does m)
    lines = []
    for i, pair in enumerate(scene.pairs):
        rest = mass[pair.a] * gravity / float(spring[i])
        if psi0[i] > DEEP_START * rest:
            lines.append(f"{pair.name} starts {psi0[i] / rest:.0f}x deeper in contact than at rest (overlap ψ = "
                         f"{psi0[i]:.3g} at t = 0, m·g/k = {rest:.3g}): the object was placed inside the other "
                         f"body and is pushed out as if launched; a pose's x,y,z is the centre of mass (raise z)")
    return lines


def _check_divergence(scene, params, time, qpos, qvel, psi, max_speed):
    """Raise SimulationDiverged at the first step with a non-finite state, a speed above
    ``max_speed``, or an overlap above half the DANO's mass (bodies passed through each
    other: the time step is too large for the contact stiffness)."""
    k, reason = first_divergence(scene, params, qpos, qvel, psi, max_speed)
    if k is not None:
        raise SimulationDiverged(k, float(time[k]), reason)


def first_divergence(scene, params, qpos, qvel, psi, max_speed: float = 1e3):
    """(step, reason) of the first diverged state of (T+1, ...) arrays, or (None, "")."""
    bad = ~np.all(np.isfinite(qpos), axis=1) | ~np.all(np.isfinite(qvel), axis=1)
    fast = np.max(np.abs(np.nan_to_num(qvel, nan=np.inf)), axis=1) > max_speed
    dano_of_pair = [p.a for p in scene.pairs]
    limit = 0.5 * np.asarray(scene.base_mass)[dano_of_pair] * np.asarray(params.alpha)[dano_of_pair]
    deep = np.any(np.nan_to_num(psi, nan=np.inf) > limit, axis=1) if psi.shape[1] else np.zeros(len(qpos), bool)
    if not (bad.any() or fast.any() or deep.any()):
        return None, ""
    k = int(np.argmax(bad | fast | deep))
    if bad[k]:
        return k, "non-finite state"
    if fast[k]:
        return k, f"speed {np.max(np.abs(qvel[k])):.3g} above {max_speed:g}"
    j = int(np.argmax(psi[k] / limit))
    return k, f"overlap of pair {scene.pair_names[j]} is {psi[k, j]:.3g}, more than half the object's mass"


def params_to_dict(scene: Scene, params: SimParams) -> dict:
    """JSON-able {"contact": {name: [per pair]}, "alpha": {dano: α}, "pairs": [...]}, and
    {name: {dano: [x, y, z]}} for the inertial parameters that are set."""
    out = {
        "pairs": list(scene.pair_names),
        "contact": {n: np.asarray(getattr(params.contact, n)).tolist() for n in params.contact.names()},
        "alpha": dict(zip(scene.dano_names, np.asarray(params.alpha).tolist())),
    }
    for name in ("com_offset", "second_moment_scale", "principal_axes"):
        if getattr(params, name) is not None:
            out[name] = dict(zip(scene.dano_names, np.asarray(getattr(params, name)).tolist()))
    return out

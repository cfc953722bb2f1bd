"""Stepping and rollouts on MuJoCo MJX with DANO contact.

One step (time step h):

1. ``mjx.fwd_position``: kinematics, mass matrix M, MuJoCo's own collisions and
   constraints, at the current configuration q.
2. DANO contact geometry (ψ, χ, n) and the point Jacobians at χ, at q
   (:mod:`dano.contact.geometry`).
3. The generalized contact force Q(v) = Jpᵀ… (:func:`~dano.contact.force.generalized_force`)
   and its velocity Jacobian D = ∂Q/∂qvel (forward-mode AD, nv × nv).
4. MJX's velocity, actuation and acceleration stages and constraint solver with Q
   added to ``qfrc_applied``.
5. A linearly implicit velocity update, as Dojo treats damping and friction
   implicitly: (M + h·diag(dof_damping) − h·D)·qacc = qfrc_smooth + qfrc_constraint.
6. ``mjx.euler`` (with the EULERDAMP flag disabled it takes this qacc as given):
   v' = v + h·qacc, then positions (quaternions included) with v'.

This keeps the paper's stiff defaults (spring 3e4, damper 3e5) stable at h = 0.01 s
and h = 0.0326 s.
"""

from __future__ import annotations

import functools
import json
from dataclasses import dataclass
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from .._files import atomic_write
from .._mjx import mjx

from ..contact import geometry
from ..contact.force import generalized_force
from ..errors import DanoError, FileFormatError
from .scene import Scene, SceneArrays, SceneStatic, SimParams


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class State:
    """qpos: (nq,) MuJoCo generalized positions (free joints: CoM position [m], wxyz
    quaternion); qvel: (nv,) generalized velocities (free joints: linear velocity,
    world frame [m/s], then angular velocity, body frame [rad/s])."""

    qpos: jax.Array
    qvel: jax.Array


class SimulationDiverged(DanoError):
    """The state became non-finite, too fast or too deeply interpenetrating; ``step`` and
    ``time`` [s] tell when."""

    def __init__(self, step: int, time: float, reason: str):
        self.step, self.time = step, time
        super().__init__(f"simulation diverged at step {step} (t = {time:.4g} s): {reason}; "
                         "reduce the time step or check the parameters")


def _model_with_alpha(static: SceneStatic, arrays: SceneArrays, alpha):
    m = arrays.model
    ids = jnp.asarray(static.dano_bodies, dtype=jnp.int32)
    if len(static.dano_bodies) == 0:
        return m
    mass = arrays.base_mass * alpha
    return m.replace(
        body_mass=m.body_mass.at[ids].set(mass),
        body_subtreemass=m.body_subtreemass.at[ids].set(mass),
        body_inertia=m.body_inertia.at[ids].set(arrays.base_inertia * alpha[:, None]),
    )


def contact_geometry(static: SceneStatic, arrays: SceneArrays, alpha, m, d):
    """Per-pair overlap ψ (P,), centroid χ (P, 3), normal (P, 3) and the relative point
    Jacobians jacp, jacr (P, nv, 3) of A minus B at χ, for Data ``d`` after
    ``fwd_position``."""
    psis, chis, normals, jps, jrs = [], [], [], [], []
    for p in static.pairs:
        da = arrays.danos[p.a]
        xa, Ra = d.xpos[p.body_a], d.xmat[p.body_a]
        if p.kind == "plane":
            psi, chi, n = geometry.plane(da.wp, da.points, da.sample_radius, alpha[p.a], xa, Ra,
                                         d.geom_xpos[p.geom], d.geom_xmat[p.geom][:, 2])
        elif p.kind == "dano":
            db = arrays.danos[p.b]
            psi, chi, n = geometry.dano_pair(da, db, alpha[p.a], alpha[p.b], xa, Ra, d.xpos[p.body_b],
                                             d.xmat[p.body_b])
        else:
            psi, chi, n = geometry.primitive(p.kind, da.wp, da.points, da.sample_radius, alpha[p.a], xa, Ra,
                                             d.geom_xpos[p.geom], d.geom_xmat[p.geom], m.geom_size[p.geom])
        jpa, jra = mjx.jac(m, d, chi, p.body_a)
        if p.body_b != 0:
            jpb, jrb = mjx.jac(m, d, chi, p.body_b)
            jpa, jra = jpa - jpb, jra - jrb
        psis.append(psi)
        chis.append(chi)
        normals.append(n)
        jps.append(jpa)
        jrs.append(jra)
    if not psis:
        nv = m.nv
        z = jnp.zeros((0,))
        return z, jnp.zeros((0, 3)), jnp.zeros((0, 3)), jnp.zeros((0, nv, 3)), jnp.zeros((0, nv, 3))
    return jnp.stack(psis), jnp.stack(chis), jnp.stack(normals), jnp.stack(jps), jnp.stack(jrs)


def _step(static: SceneStatic, arrays: SceneArrays, params: SimParams, m, d, ctrl, qfrc):
    """One step of Data ``d`` on model ``m`` (α already applied, :func:`_model_with_alpha`)."""
    d = d.replace(ctrl=ctrl)
    d = mjx.fwd_position(m, d)
    psi, _, normal, jacp, jacr = contact_geometry(static, arrays, params.alpha, m, d)
    h = static.dt

    def q_contact(qvel):
        return generalized_force(params.contact, psi, normal, jacp, jacr, qvel)

    Q, D = jax.linearize(q_contact, d.qvel)
    D = jax.vmap(D, out_axes=1)(jnp.eye(m.nv, dtype=d.qvel.dtype))  # ∂Q/∂qvel, (nv, nv)
    d = d.replace(qfrc_applied=qfrc + Q)
    d = mjx.fwd_velocity(m, d)
    d = mjx.fwd_actuation(m, d)
    d = mjx.fwd_acceleration(m, d)
    if d._impl.efc_J.size:
        d = mjx.solve(m, d)
        qfrc_total = d.qfrc_smooth + d.qfrc_constraint
    else:
        qfrc_total = d.qfrc_smooth
    A = mjx.full_m(m, d) + h * jnp.diag(m.dof_damping) - h * D
    qacc = jnp.linalg.solve(A, qfrc_total)
    d = mjx.euler(m, d.replace(qacc=qacc))
    return d, psi


@functools.partial(jax.jit, static_argnums=(0,))
def _rollout(static: SceneStatic, arrays: SceneArrays, params: SimParams, qpos0, qvel0, controls, qfrc):
    m = _model_with_alpha(static, arrays, params.alpha)
    d0 = mjx.make_data(m).replace(qpos=qpos0, qvel=qvel0)

    def body(d, inputs):
        ctrl, f = inputs
        d_next, psi = _step(static, arrays, params, m, d, ctrl, f)
        return d_next, (d_next.qpos, d_next.qvel, psi)

    d_last, (qpos, qvel, psi) = jax.lax.scan(body, d0, (controls, qfrc))
    d_last = mjx.fwd_position(m, d_last)
    psi_last = contact_geometry(static, arrays, params.alpha, m, d_last)[0]
    qpos = jnp.concatenate([qpos0[None], qpos])
    qvel = jnp.concatenate([qvel0[None], qvel])
    psi = jnp.concatenate([psi, psi_last[None]])
    return qpos, qvel, psi


@dataclass(frozen=True)
class Trajectory:
    """A simulated (or observed) trajectory of T+1 states.

    time (T+1,) [s]; qpos (T+1, nq); qvel (T+1, nv) (MuJoCo conventions, see
    :class:`State`); psi (T+1, P): overlap of each contact pair (mass units) at each
    state; body_names (nbody,); dano_names (D,) with qpos_adr/dof_adr (D,): where each
    DANO's free joint sits in qpos/qvel; pair_names (P,); metadata: JSON-able dict.
    """

    time: np.ndarray
    qpos: np.ndarray
    qvel: np.ndarray
    psi: np.ndarray
    body_names: tuple[str, ...]
    dano_names: tuple[str, ...]
    qpos_adr: tuple[int, ...]
    dof_adr: tuple[int, ...]
    pair_names: tuple[str, ...]
    metadata: dict

    def dano_pose(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """Position (T+1, 3) [m] and wxyz quaternion (T+1, 4) of a DANO's centre of mass."""
        i = self.dano_names.index(name)
        a = self.qpos_adr[i]
        return self.qpos[:, a : a + 3], self.qpos[:, a + 3 : a + 7]


def _as_jax(x, shape, what):
    arr = jnp.asarray(np.asarray(x, dtype=np.float64))
    if arr.shape != shape:
        raise DanoError(f"{what} must have shape {shape}, got {tuple(arr.shape)}")
    if not bool(jnp.all(jnp.isfinite(arr))):
        raise DanoError(f"{what} contains NaN or infinite values")
    return arr


def check_params(scene: Scene, params: SimParams) -> None:
    """Raises DanoError for non-finite or invalid parameters (concrete values only)."""
    leaves = jax.tree_util.tree_leaves(params)
    if any(isinstance(x, jax.core.Tracer) for x in leaves):
        return
    params.contact.validate()
    alpha = np.asarray(params.alpha)
    if alpha.shape != (len(scene.dano_names),) or not np.all(np.isfinite(alpha)) or np.any(alpha <= 0):
        raise DanoError(f"alpha must be {len(scene.dano_names)} finite positive mass scales, got {alpha.tolist()}")


def rollout_arrays(scene: Scene, state0: State, controls, params: SimParams, steps: int, qfrc=None):
    """The jitted, differentiable core of :func:`rollout`: returns (qpos (T+1, nq),
    qvel (T+1, nv), psi (T+1, P)) as JAX arrays. Use it inside ``jax.jacfwd``."""
    if controls is None:
        controls = jnp.zeros((steps, scene.nu))
    if qfrc is None:
        qfrc = jnp.zeros((steps, scene.nv))
    return _rollout(scene.static, scene.arrays, params, state0.qpos, state0.qvel, controls, qfrc)


def rollout(
    scene: Scene,
    state0: State,
    controls=None,
    params: SimParams | None = None,
    steps: int | None = None,
    *,
    qfrc=None,
    max_speed: float = 1e3,
    progress=None,
) -> Trajectory:
    """Simulate ``steps`` steps of ``scene.dt`` from ``state0`` inside ``jax.lax.scan``.

    controls: (T, nu) actuator controls per step (default zeros); qfrc: optional
    (T, nv) generalized forces per step [N, N·m]; params: :class:`SimParams`
    (default :meth:`Scene.default_params`); steps: T (default len(controls)).
    Returns a :class:`Trajectory`. Raises DanoError for bad shapes or parameters and
    :class:`SimulationDiverged` (with the step number) if the state becomes
    non-finite, a speed exceeds ``max_speed`` [m/s or rad/s] or an overlap exceeds half
    the DANO's mass (bodies passed through each other).
    For gradients use :func:`rollout_arrays` under ``jax.jacfwd``.
    progress: optional ``progress(done, total, description)``; the rollout then runs
    in 20 equal chunks (one compilation) so that it can report.
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
    qpos0 = _as_jax(state0.qpos, (scene.nq,), "initial qpos")
    qvel0 = _as_jax(state0.qvel, (scene.nv,), "initial qvel")
    ctrl = jnp.zeros((steps, scene.nu)) if controls is None else _as_jax(controls, (steps, scene.nu), "controls")
    f = None if qfrc is None else _as_jax(qfrc, (steps, scene.nv), "qfrc")
    if progress is None:
        qpos, qvel, psi = (np.asarray(x) for x in rollout_arrays(scene, State(qpos0, qvel0), ctrl, params, steps, f))
    else:
        qpos, qvel, psi = _chunked(scene, State(qpos0, qvel0), ctrl, params, steps, f, progress)
    time = np.arange(steps + 1) * scene.dt
    _check_divergence(scene, params, time, qpos, qvel, psi, max_speed)
    return Trajectory(
        time=time,
        qpos=qpos,
        qvel=qvel,
        psi=psi,
        body_names=scene.body_names,
        dano_names=scene.dano_names,
        qpos_adr=scene.qpos_adr,
        dof_adr=scene.dof_adr,
        pair_names=scene.pair_names,
        metadata={"scene": scene.name, "dt": scene.dt, "params": params_to_dict(scene, params)},
    )


def _check_divergence(scene, params, time, qpos, qvel, psi, max_speed):
    """Raise SimulationDiverged at the first step with a non-finite state, a speed above
    ``max_speed``, or an overlap above half the DANO's mass (bodies passed through each
    other: the time step is too large for the contact stiffness)."""
    bad = ~np.all(np.isfinite(qpos), axis=1) | ~np.all(np.isfinite(qvel), axis=1)
    fast = np.max(np.abs(np.nan_to_num(qvel, nan=np.inf)), axis=1) > max_speed
    dano_of_pair = [p.a for p in scene.static.pairs]
    limit = 0.5 * np.asarray(scene.arrays.base_mass)[dano_of_pair] * np.asarray(params.alpha)[dano_of_pair]
    deep = np.any(np.nan_to_num(psi, nan=np.inf) > limit, axis=1) if psi.shape[1] else np.zeros(len(time), bool)
    if bad.any() or fast.any() or deep.any():
        k = int(np.argmax(bad | fast | deep))
        if bad[k]:
            reason = "non-finite state"
        elif fast[k]:
            reason = f"speed {np.max(np.abs(qvel[k])):.3g} above {max_speed:g}"
        else:
            j = int(np.argmax(psi[k] / limit))
            reason = f"overlap of pair {scene.pair_names[j]} is {psi[k, j]:.3g}, more than half the object's mass"
        raise SimulationDiverged(k, float(time[k]), reason)


def _chunked(scene, state0, ctrl, params, steps, qfrc, progress, n_chunks: int = 20):
    size = -(-steps // n_chunks)
    pad = size * n_chunks - steps
    ctrl = jnp.concatenate([ctrl, jnp.repeat(ctrl[-1:], pad, axis=0)])
    qfrc = jnp.zeros((size * n_chunks, scene.nv)) if qfrc is None else jnp.concatenate([qfrc, jnp.zeros((pad, scene.nv))])
    parts, state = [], state0
    for k in range(n_chunks):
        sl = slice(k * size, (k + 1) * size)
        qpos, qvel, psi = rollout_arrays(scene, state, ctrl[sl], params, size, qfrc[sl])
        parts.append([np.asarray(x) for x in (qpos, qvel, psi)] if k == 0 else [np.asarray(x)[1:] for x in (qpos, qvel, psi)])
        state = State(qpos[-1], qvel[-1])
        progress(min((k + 1) * size, steps), steps, "simulating")
        if not (np.all(np.isfinite(parts[-1][0])) and np.all(np.isfinite(parts[-1][1]))):
            break  # diverged: the caller reports where
    qpos, qvel, psi = (np.concatenate([p[i] for p in parts]) for i in range(3))
    n = min(steps + 1, len(qpos))
    if n < steps + 1:  # stopped early; pad with NaN so the divergence check finds the step
        fill = lambda a: np.concatenate([a[:n], np.full((steps + 1 - n,) + a.shape[1:], np.nan)])  # noqa: E731
        return fill(qpos), fill(qvel), fill(psi)
    return qpos[:n], qvel[:n], psi[:n]


def params_to_dict(scene: Scene, params: SimParams) -> dict:
    """JSON-able {"contact": {name: [per pair]}, "alpha": {dano: α}, "pairs": [...]}."""
    return {
        "pairs": list(scene.pair_names),
        "contact": {n: np.asarray(getattr(params.contact, n)).tolist() for n in params.contact.names()},
        "alpha": dict(zip(scene.dano_names, np.asarray(params.alpha).tolist())),
    }


def save_trajectory(traj: Trajectory, path: str | Path) -> Path:
    """Write a trajectory to ``.npz``: arrays time (T+1,) [s], qpos (T+1, nq), qvel
    (T+1, nv), psi (T+1, P), body_names, dano_names, qpos_adr, dof_adr, pair_names and
    ``metadata`` (JSON string). Written atomically; refuses non-finite data."""

    for k in ("qpos", "qvel", "psi"):
        if not np.all(np.isfinite(getattr(traj, k))):
            raise DanoError(f"refusing to write a trajectory with non-finite {k}")
    arrays = {
        "time": traj.time, "qpos": traj.qpos, "qvel": traj.qvel, "psi": traj.psi,
        "body_names": np.asarray(traj.body_names, dtype=str), "dano_names": np.asarray(traj.dano_names, dtype=str),
        "qpos_adr": np.asarray(traj.qpos_adr, dtype=np.int64), "dof_adr": np.asarray(traj.dof_adr, dtype=np.int64),
        "pair_names": np.asarray(traj.pair_names, dtype=str),
        "metadata": np.asarray(json.dumps({"format": "dano-trajectory", "version": 1, **traj.metadata})),
    }
    path = Path(path)
    atomic_write(path, lambda f: np.savez_compressed(f, **arrays))
    return path


def load_trajectory(path: str | Path) -> Trajectory:
    """Read a trajectory written by :func:`save_trajectory`. Raises FileFormatError."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            a = {k: z[k] for k in z.files}
    except Exception as exc:
        raise FileFormatError(f"{path}: cannot read trajectory ({exc})") from exc
    missing = {"time", "qpos", "qvel"} - set(a)
    if missing:
        raise FileFormatError(f"{path}: missing arrays {sorted(missing)}")
    try:
        meta = json.loads(str(a["metadata"])) if "metadata" in a else {}
    except ValueError as exc:
        raise FileFormatError(f"{path}: corrupt metadata ({exc})") from exc
    T = len(a["time"])
    psi = a.get("psi", np.zeros((T, 0)))
    if a["qpos"].shape[0] != T or a["qvel"].shape[0] != T or psi.shape[0] != T:
        raise FileFormatError(f"{path}: time {a['time'].shape}, qpos {a['qpos'].shape}, qvel {a['qvel'].shape}, "
                              f"psi {psi.shape} disagree")
    tup = lambda k: tuple(a[k].tolist()) if k in a else ()  # noqa: E731
    return Trajectory(a["time"], a["qpos"], a["qvel"], psi, tup("body_names"),
                      tup("dano_names"), tup("qpos_adr"), tup("dof_adr"), tup("pair_names"), meta)

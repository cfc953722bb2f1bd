"""Built-in scenes users can run by name (``dano simulate NAME``).

Each builder returns a :class:`Setup`: the scene, the initial state, parameters, a
default duration and the controls. Lengths are in the units of the assets (the
paper's bunny is about one unit across; we treat units as metres, gravity −9.81).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from ..data import load_builtin
from ..errors import DanoError
from ..pose import quat_to_matrix
from .scene import DanoObject, Scene, SimParams, add_ground, compose
from .dynamics import State


@dataclass(frozen=True)
class Setup:
    """A runnable scene: ``controls(times (T,) [s]) -> (T, nu)`` gives the actuator
    controls at the start of each step (None: zeros); duration [s] is the default."""

    scene: Scene
    state0: State
    params: SimParams
    duration: float
    controls: Callable[[np.ndarray], np.ndarray] | None
    description: str


def _normalize(q) -> np.ndarray:
    q = np.asarray(q, dtype=np.float64)
    return q / np.linalg.norm(q)


def initial_state(scene: Scene, poses: dict, velocities: dict | None = None, start: State | None = None) -> State:
    """A :class:`State` from the model's qpos0 (or ``start``) with free bodies placed and launched.

    poses: {body name: (pos (3,) world [m], quat (4,) wxyz)}; velocities: {body name:
    (v (3,) world [m/s], ω (3,) body frame [rad/s])}; start: the configuration (nq,) and
    velocity (nv,) the other dofs keep (default: qpos0, at rest; e.g. a keyframe's,
    :func:`keyframe_start`); the named bodies' own velocities start at zero unless given.
    Bodies must have a free joint."""
    qpos = scene.qpos0 if start is None else np.array(start.qpos, dtype=np.float64)
    qvel = np.zeros(scene.nv) if start is None else np.array(start.qvel, dtype=np.float64)
    m = scene.mj_model

    def free_joint(name):
        b = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, name)
        if b < 0:
            raise DanoError(f"no body named {name!r} in scene {scene.name!r}")
        j = m.body_jntadr[b]
        if j < 0 or int(m.jnt_type[j]) != int(mujoco.mjtJoint.mjJNT_FREE):
            raise DanoError(f"body {name!r} has no free joint; set its joints through qpos instead")
        return j

    for name, (pos, quat) in poses.items():
        j = free_joint(name)
        a = m.jnt_qposadr[j]
        qpos[a : a + 7] = np.r_[pos, _normalize(quat)]
        qvel[m.jnt_dofadr[j] : m.jnt_dofadr[j] + 6] = 0.0
    for name, (v, w) in (velocities or {}).items():
        a = m.jnt_dofadr[free_joint(name)]
        qvel[a : a + 6] = np.r_[v, w]
    return State(jax.device_put(qpos), jax.device_put(qvel))


def resting_height(asset, quat=(1, 0, 0, 0)) -> float:
    """Centre-of-mass height at which the lowest sample touches z = 0."""
    R = quat_to_matrix(_normalize(quat))
    return float(-np.min((asset.points @ R.T)[:, 2]))


PAPER_DROP_QUAT = _normalize([1.0, 0.3, 0.0, 0.5])


def bunny_drop(dt: float | None = None, contact_model: str = "centroid") -> Setup:
    """The paper's bunny dropped at height 1.1, q ∝ (1, 0.3, 0, 0.5), v = (2, 2, 1),
    ω = (0.5, 1, 1) (body frame), sliding friction 0.1, h = 0.01 s: it tumbles to rest."""
    bunny = load_builtin("bunny")
    scene = compose([DanoObject("bunny", bunny, (0, 0, 1.1), PAPER_DROP_QUAT)], dt=dt or 0.01, name="bunny-drop",
                    contact_model=contact_model)
    state = initial_state(scene, {"bunny": ((0, 0, 1.1), PAPER_DROP_QUAT)}, {"bunny": ((2, 2, 1), (0.5, 1, 1))})
    return Setup(scene, state, scene.default_params(sliding_friction=0.1), 5.0, None, bunny_drop.__doc__)


def bunny_slide(dt: float | None = None, contact_model: str = "centroid") -> Setup:
    """The paper bunny, upright on the ground, thrown along +x at 2.5 m/s with the paper's
    default friction 0.2 and sliding drag 0.1 (Eq. 9): it slides to a stop after
    (v − (μ/β)·ln(1 + βv/μ))/(gβ) = 0.90 m (1.59 m without the drag)."""
    bunny = load_builtin("bunny")
    z = resting_height(bunny)
    scene = compose([DanoObject("bunny", bunny, (0, 0, z))], dt=dt or 0.01, name="bunny-slide",
                    contact_model=contact_model)
    state = initial_state(scene, {"bunny": ((0, 0, z), (1, 0, 0, 0))}, {"bunny": ((2.5, 0, 0), (0, 0, 0))})
    return Setup(scene, state, scene.default_params(), 2.5, None, bunny_slide.__doc__)


def _add_ball(spec: mujoco.MjSpec, name: str, pos, radius: float = 0.25, mass: float = 10.0) -> None:
    body = spec.worldbody.add_body(name=name, pos=list(pos))
    body.add_freejoint(name=f"{name}_free")
    body.add_geom(name=name, type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[radius, 0, 0], mass=mass,
                  rgba=[0.3, 0.5, 0.9, 1])


def sphere_hits_bunny(dt: float | None = None, contact_model: str = "centroid") -> Setup:
    """A sphere (radius 0.25, mass 10: the paper's pusher) rolls at 3 m/s into the paper
    bunny resting on the ground. Sphere-ground contact is MuJoCo's own; sphere-bunny and
    bunny-ground are DANO contacts."""
    bunny = load_builtin("bunny")
    z = resting_height(bunny)
    spec = mujoco.MjSpec()
    add_ground(spec)
    _add_ball(spec, "sphere", (-1.2, 0, 0.25))
    scene = compose([DanoObject("bunny", bunny, (0, 0, z))], spec, dt=dt or 0.01, name="sphere-hits-bunny",
                    contact_model=contact_model)
    state = initial_state(scene, {"bunny": ((0, 0, z), (1, 0, 0, 0)), "sphere": ((-1.2, 0, 0.25), (1, 0, 0, 0))},
                        {"sphere": ((3.0, 0, 0), (0, 12.0, 0))})
    return Setup(scene, state, scene.default_params(), 2.0, None, sphere_hits_bunny.__doc__)


def two_bunnies_sphere(dt: float | None = None, contact_model: str = "centroid") -> Setup:
    """The paper's Fig. 5: a sphere hits a bunny, which then hits a second bunny. The
    bunnies are queryable DANOs (signed-distance fields of the low-poly Stanford bunny),
    so their contact queries each other's field in both directions."""
    bunny = load_builtin("bunny_lowpoly")
    z = resting_height(bunny) + 0.005
    spec = mujoco.MjSpec()
    add_ground(spec)
    _add_ball(spec, "sphere", (-1.0, 0, 0.25))
    objs = [DanoObject("bunny_a", bunny, (0, 0, z)), DanoObject("bunny_b", bunny, (0.75, 0.05, z), rgba=(0.6, 0.75, 0.5, 1))]
    scene = compose(objs, spec, dt=dt or 0.01, name="two-bunnies-sphere", contact_model=contact_model)
    state = initial_state(scene, {"bunny_a": ((0, 0, z), (1, 0, 0, 0)), "bunny_b": ((0.75, 0.05, z), (1, 0, 0, 0)),
                                "sphere": ((-1.0, 0, 0.25), (1, 0, 0, 0))},
                        {"sphere": ((4.0, 0, 0), (0, 16.0, 0))})
    return Setup(scene, state, scene.default_params(), 2.5, None, two_bunnies_sphere.__doc__)


# Joint targets of the Panda (panda_nohand.xml) putting the pusher centre, 6 cm beyond
# the flange with the flange pointing down, at (0.30, 0, 0.30) and then at x = 0.30 ... 0.75
# (6 points) on the line y = 0, z = 0.075; solved offline with damped least-squares IK
# on MuJoCo's site Jacobian.
PANDA_WAYPOINTS = np.array([
    [0.0, -0.7255, 0.0, -2.9196, 0.0, 2.1941, 0.785],
    [0.0, 0.1874, 0.0, -2.9813, 0.0, 3.1687, 0.785],
    [0.0, 0.2919, 0.0, -2.7184, 0.0, 3.0103, 0.785],
    [0.0, 0.4228, 0.0, -2.4339, 0.0, 2.8567, 0.785],
    [0.0, 0.5777, 0.0, -2.1171, 0.0, 2.6948, 0.785],
    [0.0, 0.7671, 0.0, -1.743, 0.0, 2.5101, 0.785],
    [0.0, 1.0342, 0.0, -1.229, 0.0, 2.2632, 0.785],
])
PANDA_WAYPOINT_TIMES = np.array([0.0, 0.8, 1.2, 1.6, 2.0, 2.4, 2.8])


def menagerie_panda(who: str = "panda-push-bunny", hand: bool = False) -> Path:
    """Path of the Menagerie Panda (``panda_nohand.xml``, or ``panda.xml`` with its two-finger
    hand if ``hand``) under ``$MENAGERIE_ROOT``.

    Raises DanoError if it is not there: the Panda's meshes (33 MB, Apache-2.0) do not
    ship with dano and nothing is downloaded at run time.
    """
    root = os.environ.get("MENAGERIE_ROOT")
    name = "panda.xml" if hand else "panda_nohand.xml"
    path = Path(root) / "franka_emika_panda" / name if root else None
    if path is None or not path.is_file():
        raise DanoError(
            f"{who} needs the MuJoCo Menagerie Franka Panda: set MENAGERIE_ROOT to a folder holding "
            f"franka_emika_panda/{name} (a clone of mujoco_menagerie)"
            + (f"; not found at {path}" if path else "")
        )
    return path


def panda_push_bunny(dt: float | None = None, contact_model: str = "centroid") -> Setup:
    """The Menagerie Panda with a pusher bar (capsule) at its flange pushes the paper
    bunny, scaled to 15 cm and 0.25 kg, along the ground by following scripted joint
    targets. The Panda's own collisions are off; the pusher and the ground touch the
    bunny through DANO contact."""
    spec = mujoco.MjSpec.from_file(str(menagerie_panda()))
    for g in spec.geoms:  # the arm moves on position targets; only the pusher touches the bunny
        g.contype, g.conaffinity = 0, 0
    for b in spec.bodies:  # gravity compensation, as the real arm's controller does
        if b.name != "world":
            b.gravcomp = 1.0
    # a pusher bar (capsule, radius 3 cm, 12 cm long) across the push direction: a bar
    # carries the bunny ahead where a point pusher lets it slip off sideways
    probe = spec.copy().compile()
    probe_data = mujoco.MjData(probe)
    probe_data.qpos[:7] = PANDA_WAYPOINTS[1]
    mujoco.mj_kinematics(probe, probe_data)
    axis = probe_data.body("link7").xmat.reshape(3, 3).T @ np.array([0.0, 1.0, 0.0])  # world y in link7's frame
    quat = np.zeros(4)
    mujoco.mju_quatZ2Vec(quat, axis)
    spec.body("link7").add_geom(name="pusher", type=mujoco.mjtGeom.mjGEOM_CAPSULE, size=[0.03, 0.06, 0],
                                pos=[0, 0, 0.107 + 0.06], quat=quat, contype=2, conaffinity=2, mass=0.1,
                                rgba=[0.9, 0.2, 0.2, 1])
    add_ground(spec)
    bunny = load_builtin("bunny").scaled(0.15).with_mass(0.25)
    z = resting_height(bunny) + 0.001
    pos = (0.45, 0.0, z)
    scene = compose([DanoObject("bunny", bunny, pos)], spec, dt=dt or 0.005, name="panda-push-bunny",
                    contact_model=contact_model)
    free = initial_state(scene, {"bunny": (pos, (1, 0, 0, 0))})
    state = State(free.qpos.at[:7].set(PANDA_WAYPOINTS[0]), free.qvel)

    def controls(times: np.ndarray) -> np.ndarray:
        return np.stack([np.interp(times, PANDA_WAYPOINT_TIMES, PANDA_WAYPOINTS[:, k]) for k in range(7)], axis=1)

    return Setup(scene, state, scene.default_params(sliding_friction=0.3), 3.2, controls, panda_push_bunny.__doc__)


def keyframe_names(scene: Scene) -> list[str]:
    """The names of the scene's MuJoCo keyframes (``<keyframe><key name=...>``), in order
    ("" for an unnamed key)."""
    m = scene.mj_model
    return [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_KEY, k) or "" for k in range(m.nkey)]


@dataclass(frozen=True)
class KeyframeStart:
    """A MuJoCo keyframe of the scene's MJCF as a start: state: qpos (nq,) and qvel (nv,) of
    the key for the MJCF's own joints, each DANO at its placed pose (``qpos0``) and at rest;
    ctrl: (nu,) the key's actuator controls (MuJoCo holds them until changed); index and name
    of the key."""

    state: State
    ctrl: np.ndarray
    index: int
    name: str


def keyframe_start(scene: Scene, key: str | int, where: str = "the scene") -> KeyframeStart:
    """The start that MuJoCo's keyframe ``key`` (a name, or an index as an int or a string of
    digits; a name takes precedence) describes, for a scene composed from an MJCF that has
    ``<keyframe>`` keys. A key is written for the MJCF as it stands: its qpos/qvel cover the
    MJCF's own joints (MuJoCo fills the rest, the DANOs' free joints that :func:`compose`
    appends after them, with qpos0, i.e. their placed pose, and zero velocity); time is not
    used (a run starts at t = 0). where: how errors name the model (e.g. its file).

    Raises DanoError (one line, listing the keys) for an unknown key or a scene without keys,
    and for a key that dano cannot apply faithfully: one that sets mocap poses or actuator
    activations (only qpos, qvel and ctrl are applied), or whose qpos/qvel is longer than the
    MJCF's own joints (it would write into the DANOs' free joints, which their placed poses
    override)."""
    m = scene.mj_model
    names = keyframe_names(scene)
    label = f"--keyframe {str(key)!r}"
    if not names:
        raise DanoError(f"{label}: {where} has no keyframes (an MJCF <keyframe><key .../></keyframe>)")
    text = str(key)
    if text in names:
        k = names.index(text)
    elif text.isdigit() and int(text) < len(names):
        k = int(text)
    else:
        listed = ", ".join(f"{i} {n!r}" if n else f"{i} (unnamed)" for i, n in enumerate(names))
        raise DanoError(f"{label}: {where} has no key {text!r}; its keys (index, name): {listed}")
    qpos, qvel = np.array(m.key_qpos[k], dtype=np.float64), np.array(m.key_qvel[k], dtype=np.float64)
    for name, qa, va in zip(scene.dano_names, scene.qpos_adr, scene.dof_adr):
        if not (np.array_equal(qpos[qa : qa + 7], m.qpos0[qa : qa + 7]) and not np.any(qvel[va : va + 6])):
            raise DanoError(f"{label}: the key's qpos or qvel is longer than {where}'s own joints and reaches the "
                            f"free joint dano adds for DANO {name!r}; write the key for the MJCF alone (the DANOs' "
                            "start is --object's pose and --qvel)")
    unsupported = []
    if m.na and np.any(m.key_act[k] != 0):
        unsupported.append("act (actuator activations)")
    if m.nmocap:
        mocap = np.flatnonzero(m.body_mocapid >= 0)
        order = m.body_mocapid[mocap]
        if not (np.allclose(m.key_mpos[k].reshape(-1, 3)[order], m.body_pos[mocap])
                and np.allclose(m.key_mquat[k].reshape(-1, 4)[order], m.body_quat[mocap])):
            unsupported.append("mpos/mquat (mocap poses)")
    if unsupported:
        raise DanoError(f"{label}: the key sets {' and '.join(unsupported)}, which dano simulate does not apply "
                        "(it applies a key's qpos, qvel and ctrl)")
    return KeyframeStart(State(jnp.asarray(qpos), jnp.asarray(qvel)), np.array(m.key_ctrl[k], dtype=np.float64),
                         k, names[k])


def mjcf_setup(path: str | Path, objects: list[DanoObject], dt: float | None = None, duration: float = 2.0,
               contact_model: str = "centroid", keyframe: str | int | None = None) -> Setup:
    """A runnable :class:`Setup` from a user's MJCF/URDF file and DANOs placed at their
    ``pos``/``quat`` at rest (paper default contact parameters, zero controls). dt: the time
    step [s]; default: the one the MJCF states (:func:`~dano.sim.scene.stated_timestep`), else
    :data:`~dano.sim.scene.DEFAULT_DT`. keyframe: start the MJCF's own joints and actuators from this key of
    its ``<keyframe>`` (name or index; :func:`keyframe_start`): its qpos and qvel, and its
    ctrl held for the whole run; the DANOs keep their pose, at rest. Raises DanoError if the
    file is missing or does not compile, or for an unknown or unsupported key."""
    path = Path(path)
    scene = compose(objects, path, dt=dt, name=path.stem, contact_model=contact_model)
    start = keyframe_start(scene, keyframe, where=str(path)) if keyframe is not None else None
    state = initial_state(scene, {o.name: (o.pos, o.quat) for o in objects}, start=start.state if start else None)
    controls = None
    description = f"MJCF {path}"
    if start is not None and scene.nu:
        ctrl = start.ctrl

        def controls(times: np.ndarray) -> np.ndarray:
            return np.tile(ctrl, (len(times), 1))
    if start is not None:
        description += f", from its key {start.index}" + (f" {start.name!r}" if start.name else "")
    return Setup(scene, state, scene.default_params(), duration, controls, description)


BUILTIN_SCENES: dict[str, Callable[..., Setup]] = {
    "bunny-drop": bunny_drop,
    "bunny-slide": bunny_slide,
    "sphere-hits-bunny": sphere_hits_bunny,
    "two-bunnies-sphere": two_bunnies_sphere,
    "panda-push-bunny": panda_push_bunny,
}


def load_scene(name: str, dt: float | None = None, contact_model: str = "centroid") -> Setup:
    """A built-in scene by name, with time step ``dt`` [s] (default: the scene's) and
    ``contact_model`` ("centroid", "per_sample" or a contact model instance, e.g.
    ``PerSample(friction_steepness=30.0)``) for every pair. Raises DanoError
    (listing the names) for an unknown one."""
    if name not in BUILTIN_SCENES:
        raise DanoError(f"unknown scene {name!r}; built-in scenes: {', '.join(BUILTIN_SCENES)} (or an MJCF path)")
    if dt is not None and (not np.isfinite(dt) or dt <= 0):
        raise DanoError(f"time step dt must be positive, got {dt}")
    return BUILTIN_SCENES[name](dt, contact_model)

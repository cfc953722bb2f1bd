"""Built-in trajectory-optimisation tasks (``dano trajopt TASK``).

``push-sphere`` is the paper's push-and-slide (Fig. 7): a floating, fully actuated sphere
(mass 10, radius 0.25; a 3-D force, world frame, and a 3-D torque, body frame) pushes the
paper's bunny DANO over the ground (sliding friction 0.05, impact spring 3e4, damper 3e5)
so that the bunny ends 1.0 unit sideways (+y) of where a plain push leaves it, and the
sphere ends equally shifted; h = 0.02 s, T = 60 steps.

``push-panda`` goes beyond the paper (which replayed the sphere's path with the arm's
kinematics): the Menagerie Franka Panda's own dynamics are optimised, joint torques as
controls within the arm's torque limits (87 N m joints 1–4, 12 N m joints 5–7) and its
joint limits as stage inequalities, to push the paper bunny scaled to 15 cm (0.25 kg)
with a spherical pusher (radius 2.5 cm) on the flange to a goal 10 cm away, 30° off the
push's straight line; h = 0.01 s, T = 80. The arm is gravity-compensated (as its real
controller does), its own collisions are off; the initial guess is a PD controller
tracking a scripted straight push.

Decisions where the paper is silent: the sphere is gravity-compensated (it floats) and
touches only the bunny (DANO contact), not the ground; the plain push is 80 N along +x
for 0.5 s, then 80 N of braking for 0.5 s, and it is also the initial guess; the stage
cost is 0.1·½|qvel|² + 0.2·½|u/u_ref|² with u_ref the sphere's weight m·g [N] for the
forces and m·g·r [N m] for the torques (so the two weights compare quantities of order
one); the terminal equality constraints fix the bunny's centre of mass in x–y and the
sphere's centre in x, y and z.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from .._config import check_ranges
from ..data import load_asset, load_builtin
from ..errors import DanoError
from ..sim import DanoObject, compose
from ..sim.scene import add_ground
from ..sim.scenes import PANDA_WAYPOINTS, initial_state, menagerie_panda, resting_height
from ..trajopt.ilqr import ILQRConfig, Solution, rollout, solve
from ..trajopt.mpc import RecedingHorizonResult, receding_horizon
from ..trajopt.problem import Problem, mjx_dynamics, scene_dynamics

G = 9.81


checked = check_ranges  # old name, kept


@dataclass(frozen=True)
class PushConfig:
    """Settings shared by the push tasks (a ``dano trajopt`` TOML/JSON file: these keys at the
    top level). Raises DanoError naming the first setting out of range (``horizon out of
    range: 1``)."""

    task: str = "push-sphere"
    """The task's name (picks which task's settings apply): ``push-sphere``."""
    dt: float = 0.02
    """Time step h [s], > 0."""
    horizon: int = 60
    """Horizon T [steps], 2 to 10,000."""
    sliding_friction: float = 0.05
    """Sliding friction μ [-] of both contact pairs, >= 0."""
    impact_spring: float = 3e4
    """Impact spring k [N per unit overlap] of both contact pairs, > 0."""
    impact_damper: float = 3e5
    """Impact damper c [N·s/m per unit overlap] of both contact pairs, >= 0."""
    state_weight: float = 0.1
    """Weight of ½|qvel|² per stage [1/(unit of qvel)²], >= 0."""
    control_weight: float = 0.2
    """Weight of ½|u/u_ref|² per stage [-] (u_ref: the task's control scale), > 0."""
    max_iterations: int = 300
    """iLQR iterations in all, >= 1."""
    constraint_tolerance: float = 1e-3
    """Largest allowed constraint violation, of each constraint's coordinates apart (a goal's x and y each;
    the x–y distance ``object_final_error`` may so reach √2 times it) [m; N·m for torque bounds; rad for
    joint limits], > 0."""
    penalty_initial: float = 10.0
    """Initial augmented-Lagrangian penalty μ₀, in (0, 1e8) (large enough that the goal outweighs the control
    cost from the first iteration: with too small a μ₀ the first step drops the push and loses the contact
    gradient)."""
    model_error: float = 0.0
    """If > 0: also run the plan, open loop and with receding horizon, in a world whose sliding friction is
    (1 + model_error) times the model's; > -1."""
    replan_every: int = 5
    """Receding horizon: steps executed between re-plans, >= 1."""
    replan_iterations: int = 30
    """Receding horizon: iLQR iterations per re-plan, >= 1."""
    contact_model: str = "centroid"
    """DANO contact model: ``centroid`` (the paper's) or ``per_sample``."""

    def __post_init__(self):
        check_ranges(self, self._checks())

    def _checks(self) -> list:
        task = type(self).__dataclass_fields__["task"].default  # each task's class names its own task
        return [("task", self.task == task),
                ("dt", self.dt > 0 and np.isfinite(self.dt)), ("horizon", 2 <= self.horizon <= 10000),
                ("sliding_friction", 0 <= self.sliding_friction < np.inf),
                ("impact_spring", 0 < self.impact_spring < np.inf), ("impact_damper", 0 <= self.impact_damper < np.inf),
                ("state_weight", 0 <= self.state_weight < np.inf),
                ("control_weight", 0 < self.control_weight < np.inf), ("max_iterations", self.max_iterations >= 1),
                ("constraint_tolerance", 0 < self.constraint_tolerance < np.inf),
                ("penalty_initial", 0 < self.penalty_initial < 1e8),
                ("model_error", -1 < self.model_error < np.inf), ("replan_every", self.replan_every >= 1),
                ("replan_iterations", self.replan_iterations >= 1)]

    def validate(self):
        """Old API, kept: the settings are checked when the config is built; returns it."""
        return self


@dataclass(frozen=True)
class PushSphereConfig(PushConfig):
    """Settings of ``push-sphere`` (the defaults are the paper's task)."""

    sideways: float = 1.0
    """Bunny goal: this far (+y) from where the plain push leaves it [m], finite."""

    def _checks(self) -> list:
        return super()._checks() + [("sideways", np.isfinite(self.sideways))]


@dataclass(frozen=True)
class PushPandaConfig(PushConfig):
    """Settings of ``push-panda``."""

    task: str = "push-panda"
    """The task's name: ``push-panda``."""
    dt: float = 0.01
    """Time step h [s], > 0."""
    horizon: int = 80
    """Horizon T [steps], 2 to 10,000."""
    sliding_friction: float = 0.3
    """Sliding friction μ [-] of both contact pairs, >= 0."""
    penalty_initial: float = 1000.0
    """Initial augmented-Lagrangian penalty μ₀, in (0, 1e8)."""
    goal_distance: float = 0.10
    """Bunny goal: this far from its start [m], 0 to 0.3."""
    goal_angle: float = 30.0
    """... in this direction [deg] from the scripted push's line (+x) towards +y, finite."""

    def _checks(self) -> list:
        return super()._checks() + [("goal_distance", 0 <= self.goal_distance <= 0.3),
                                    ("goal_angle", np.isfinite(self.goal_angle))]


@dataclass(frozen=True)
class PushObjectConfig(PushConfig):
    """Settings of ``push``: a floating sphere pushes any DANO (``object``) resting on the
    ground at the origin so that its centre of mass ends at ``goal``. The pusher is sized
    to the object as the paper's sphere is to its bunny (L: the object's longest extent,
    m: its mass): radius L/4, mass 3.1 m, starting 0.8 L behind the object (opposite the
    goal), a plain push of 25 m·L N along the goal direction, then braking, as the first
    guess. The other settings but the horizon are push-sphere's."""

    task: str = "push"
    """The task's name: ``push``."""
    horizon: int = 100
    """Horizon T [steps], 2 to 10,000 (2 s at the default time step: room to push the object
    and let friction stop it at the goal; push-sphere's 60 steps reach at rest only 0.35 m
    away at the default friction, :func:`stopping_reach`)."""
    object: str = "builtin:bunny"
    """The DANO to push: ``FILE.dano`` or ``builtin:NAME``."""
    goal: tuple[float, float] | None = None
    """Where its centre of mass should end, x y, world frame [m] (it starts at 0 0, at rest on
    the ground); None: one longest extent L along +x and L/2 along +y, brought nearer where
    that is beyond a quarter of the distance friction can stop it from within the horizon
    (:func:`stopping_reach`, with ``at_rest``: 0.245 m at the defaults)."""
    at_rest: bool = True
    """The object must end at rest: at the last step its x–y speed must be one at which
    friction stops it within ``constraint_tolerance`` (τ·v = 0 within it, τ =
    √(tolerance/(2μg)): :func:`rest_time_scale`), so that it rests where the plan ends; false:
    only its position at the last step is constrained, and it may still be sliding there."""
    pusher: str = "sphere"
    """The pusher: ``sphere`` (a floating, fully actuated sphere; the arm pushes only the built-in
    15 cm bunny for now: the push-panda task)."""
    max_force: float = 2.0
    """Largest force on the pusher, in its weights (|F| ≤ this × its weight m·g, a stage
    inequality (|F|/(m·g))² − this² ≤ 0 whose tolerance is ``constraint_tolerance`` in
    weights²) [-], > 0; inf: unbounded."""

    def _checks(self) -> list:
        goal_ok = self.goal is None or (len(self.goal) == 2 and bool(np.all(np.isfinite(self.goal))))
        return super()._checks() + [("goal", goal_ok), ("pusher", self.pusher == "sphere"),
                                    ("max_force", self.max_force > 0)]


SPHERE_MASS, SPHERE_RADIUS = 10.0, 0.25
SPHERE_START = (-0.8, 0.0, 0.25)
PLAIN_FORCE = 80.0  # N


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class PushParams:
    """The parameters p of a sphere-pusher task's problems (``push-sphere``, ``push``): values
    of the solver's programs, not constants, so that one set of programs serves every goal and
    every object of the same structure (the same sample count and contact model; another
    object's size, mass and pusher: the same programs, loaded from disk). sim: the
    :class:`~dano.sim.SimParams`; goal: (2,) object goal x–y, then (3,) pusher goal where the
    task has one [m], or None (the plain push); scene: the task's :class:`~dano.sim.Scene`;
    u_ref: (6,) the control scale of the cost [N, N m]; floor: () the lowest height of the
    pusher's centre [m] (its radius: the sphere floats, without MuJoCo contact with the ground,
    and the solve keeps it above the floor by a stage inequality), or None (no such constraint:
    the plain push)."""

    sim: Any
    goal: Any
    scene: Any
    u_ref: Any
    floor: Any = None


@dataclass(frozen=True)
class PushTask:
    """A built task: scene, params (the model's SimParams), problem, x0 (nx,), the initial
    guess U_plain (T, nu) (the plain push) and its states X_plain (T + 1, nx), bunny_goal
    (2,) x–y [m], pusher_goal (3,) [m] or None, bunny_qpos (slice of qpos), apply ("ctrl"
    or "qfrc") and control_dofs (the qvel indices a "qfrc" control acts on), u_ref (nu,)
    the control scale of the cost, the config; goal_parameter: whether the problem reads the
    goals (bunny_goal, then pusher_goal where there is one) from its parameters
    (:meth:`problem_params`), so that one compiled solver serves every goal."""

    scene: object
    params: object
    problem: Problem
    x0: np.ndarray
    U_plain: np.ndarray
    X_plain: np.ndarray
    bunny_goal: np.ndarray
    pusher_goal: np.ndarray | None
    bunny_qpos: slice
    apply: str
    control_dofs: np.ndarray | None
    u_ref: np.ndarray
    config: PushConfig
    goal_parameter: bool = False
    scene_parameter: bool = False
    pusher_floor: float | None = None
    """The lowest height of a floating pusher's centre [m] (:attr:`PushParams.floor`), or None."""

    def problem_params(self, params=None):
        """The problem's parameters p for SimParams ``params`` (default: the task's): a
        :class:`PushParams` where the task passes its scene as a parameter
        (``scene_parameter``: the sphere-pusher tasks), else ``(params, goal)`` where the
        task has a goal parameter (goal (2,) or (5,) [m]: bunny_goal, then pusher_goal), else
        ``params``."""
        params = self.params if params is None else params
        goal = None
        if self.goal_parameter:
            goals = [self.bunny_goal] + ([] if self.pusher_goal is None else [self.pusher_goal])
            goal = jnp.asarray(np.concatenate(goals), dtype=float)
        if self.scene_parameter:
            floor = None if self.pusher_floor is None else jnp.asarray(self.pusher_floor, dtype=float)
            return PushParams(params, goal, self.scene, jnp.asarray(self.u_ref, dtype=float), floor)
        return params if goal is None else (params, goal)


def _stage_cost(config: PushConfig, nq: int, u_ref):
    wq, wu, u_ref = config.state_weight, config.control_weight, jnp.asarray(u_ref)

    def stage_cost(x, u, t, p):
        return 0.5 * wq * jnp.sum(x[nq:] ** 2) + 0.5 * wu * jnp.sum((u / u_ref) ** 2)

    return stage_cost


def _params(scene, config: PushConfig):
    return scene.default_params(sliding_friction=config.sliding_friction, impact_spring=config.impact_spring,
                                impact_damper=config.impact_damper)


#: the default goal of ``push`` lies within this fraction of :func:`stopping_reach`
DEFAULT_GOAL_REACH = 0.25


def stopping_reach(config: PushConfig) -> float:
    """The furthest [m] an object pushed from rest can be when it stops by friction alone at
    the horizon's end, ½μg(T·h)² (launched at once at μgT·h; inf for μ = 0): with ``at_rest``,
    a goal further away is reached at rest within the horizon only if the pusher brakes it."""
    mu_g = config.sliding_friction * G
    return np.inf if mu_g <= 0.0 else 0.5 * mu_g * (config.horizon * config.dt) ** 2


def reach_warnings(task: PushTask) -> list[str]:
    """A warning where a task whose object must end at rest (``at_rest``) has its goal beyond
    :func:`stopping_reach`; [] otherwise (and for tasks without ``at_rest``)."""
    cfg = task.config
    if not getattr(cfg, "at_rest", False):
        return []
    distance, reach = float(np.linalg.norm(task.bunny_goal)), stopping_reach(cfg)
    if distance <= reach:
        return []
    return [f"the goal is {distance:.3g} m away, beyond the {reach:.3g} m from which sliding friction "
            f"{cfg.sliding_friction:g} alone brings the object to rest within the horizon ({cfg.horizon} steps of "
            f"{cfg.dt:g} s): it can end there at rest only if the pusher brakes it; give a longer horizon or more "
            "friction (--horizon, --sliding-friction), a nearer goal, or at_rest = false (a TOML configuration)"]


def rest_time_scale(config: PushConfig) -> float:
    """τ [s] of the at-rest constraint τ·v = 0 on the pushed object's x–y velocity v [m/s]
    (``push``'s ``at_rest``): a violation of ``constraint_tolerance`` ε then means a speed at
    which friction stops the object within ε (v²/(2μg) = ε: τ = √(ε/(2μg))), so that it comes
    to rest within about ε of where the plan ends; at most the horizon's time T·h (μ = 0)."""
    mu_g = config.sliding_friction * G
    horizon_time = config.horizon * config.dt
    if mu_g <= 0.0:
        return horizon_time
    return float(min(np.sqrt(config.constraint_tolerance / (2.0 * mu_g)), horizon_time))


def _sphere_pusher_task(config: PushConfig, asset, name: str, radius: float, mass: float, start, force,
                        goal_of, settle: bool = False, at_rest: bool = False, max_force: float = np.inf) -> PushTask:
    """A floating sphere (``radius`` [m], ``mass`` [kg], gravity compensated, touching only
    the DANO) at ``start`` (3,) [m] behind the DANO ``name`` resting at the origin; the plain
    push: ``force`` (3,) [N] for 25 of every 60 steps, then the same braking. ``goal_of(X_plain,
    object_q, pusher_q)`` gives (object goal (2,), pusher goal (3,) or None). ``settle``: the
    object starts where it rests (its height and tilt after the horizon's steps untouched, x–y
    at 0 0, velocities 0), not 1 mm above its lowest sample's touch; ``at_rest``: without a
    pusher goal, the object's x–y velocity must also be 0 at the last step; ``max_force``: the
    largest force on the pusher in its weights (a stage inequality), inf for none. The goals, the
    scene and the control scale are the problems' parameters (:class:`PushParams`), not
    constants of their programs, and both problems have a key (:class:`~dano.trajopt.Problem`)
    that holds what their functions read besides: their solver programs are kept on disk and
    serve every goal and every object of the same structure."""
    z = resting_height(asset) + 0.001
    spec = mujoco.MjSpec()
    add_ground(spec)
    # the model does not hold the start (the state does: initial_state below), so that one scene,
    # and so one set of compiled programs, serves every goal
    body = spec.worldbody.add_body(name="pusher", pos=[0.0, 0.0, radius], gravcomp=1.0)
    body.add_freejoint(name="pusher_free")
    # contype 2: no MuJoCo contact with the ground (conaffinity 1); DANO contact with the object
    body.add_geom(name="pusher", type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[radius, 0, 0], mass=mass,
                  contype=2, conaffinity=2, rgba=[0.3, 0.5, 0.9, 1])
    scene = compose([DanoObject(name, asset, (0, 0, z))], spec, dt=config.dt, name=config.task,
                    contact_model=config.contact_model)
    params = _params(scene, config)
    s0 = initial_state(scene, {name: ((0, 0, z), (1, 0, 0, 0)), "pusher": (tuple(start), (1, 0, 0, 0))})
    x0 = np.r_[np.asarray(s0.qpos), np.asarray(s0.qvel)]
    T = config.horizon
    pa, ba = scene.mj_model.jnt_qposadr[0], scene.qpos_adr[0]
    pusher, object_q = slice(pa, pa + 3), slice(ba, ba + 3)
    dofs = np.arange(scene.mj_model.jnt_dofadr[0], scene.mj_model.jnt_dofadr[0] + 6)
    step = scene_dynamics("qfrc", dofs=dofs)
    u_ref = np.array([mass * G] * 3 + [mass * G * radius] * 3)
    half = T * 25 // 60  # 25 of 60 steps: 0.5 s at the paper's h
    U_plain = np.zeros((T, 6))
    U_plain[:half, :3] = force
    U_plain[half:2 * half, :3] = -np.asarray(force)
    nq, wq, wu = scene.nq, float(config.state_weight), float(config.control_weight)

    def dynamics(x, u, t, p: PushParams):
        return step(x, u, t, (p.scene, p.sim))

    def stage_cost(x, u, t, p: PushParams):
        return 0.5 * wq * jnp.sum(x[nq:] ** 2) + 0.5 * wu * jnp.sum((u / p.u_ref) ** 2)

    # what the problems' functions read besides p (whose structure, the scene's included, is
    # part of every program's key): their key (the solver's programs are kept on disk)
    key = ("dano.experiments.push.sphere_pusher", dofs, wq, wu)
    plain = Problem(dynamics, stage_cost, lambda x, p: 0.0, T, len(x0), 6, key=key)
    plain_p = PushParams(params, None, scene, jnp.asarray(u_ref))
    if settle:  # the horizon's steps untouched (the same program as the plain push): where it rests
        rest = np.asarray(rollout(plain, x0, np.zeros_like(U_plain), plain_p))[-1]
        x0 = x0.copy()
        x0[ba + 2:ba + 7] = rest[ba + 2:ba + 7]  # height and orientation; x–y stay 0 0
        x0[nq:] = 0.0
    X_plain = np.asarray(rollout(plain, x0, U_plain, plain_p))
    object_goal, pusher_goal = goal_of(X_plain, object_q, pusher)
    at_rest = at_rest and pusher_goal is None
    object_v = slice(nq + int(scene.dof_adr[0]), nq + int(scene.dof_adr[0]) + 2)  # x–y velocity [m/s], world
    stop_time = rest_time_scale(config)

    def terminal(x, p: PushParams):
        if pusher_goal is None:
            at_goal = x[object_q][:2] - p.goal
            return jnp.concatenate([at_goal, stop_time * x[object_v]]) if at_rest else at_goal
        return jnp.concatenate([x[object_q][:2] - p.goal[:2], x[pusher] - p.goal[2:]])

    def limits(x, u, t, p: PushParams):  # the sphere floats through the ground unless kept above it
        floor = (p.floor - x[pa + 2])[None]
        if not np.isfinite(max_force):
            return floor
        return jnp.concatenate([floor, (jnp.sum((u[:3] / p.u_ref[:3]) ** 2) - max_force ** 2)[None]])

    problem = Problem(dynamics, stage_cost, lambda x, p: 0.0, T, len(x0), 6, inequality=limits,
                      terminal_equality=terminal,
                      key=key + ("goal parameter", (int(ba), int(ba) + 3),
                                 None if pusher_goal is None else (int(pa), int(pa) + 3), "floor", int(pa) + 2)
                      + ((("at rest", object_v.start, stop_time),) if at_rest else ())
                      + ((("max force", float(max_force)),) if np.isfinite(max_force) else ()))
    return PushTask(scene, params, problem, x0, U_plain, X_plain, np.asarray(object_goal), pusher_goal, object_q,
                    "qfrc", dofs, u_ref, config, goal_parameter=True, scene_parameter=True, pusher_floor=radius)


def push_sphere_task(config: PushSphereConfig = PushSphereConfig()) -> PushTask:
    """Build the push-sphere task: the scene, the plain push and the constrained problem."""
    def goals(X_plain, bunny_q, pusher):
        side = np.array([0.0, config.sideways])
        return X_plain[-1, bunny_q][:2] + side, np.r_[X_plain[-1, pusher][:2] + side, SPHERE_START[2]]

    return _sphere_pusher_task(config, load_builtin("bunny"), "bunny", SPHERE_RADIUS, SPHERE_MASS, SPHERE_START,
                               (PLAIN_FORCE, 0.0, 0.0), goals)


# the paper's sphere and push relative to its bunny (longest extent 1.004, mass 3.22)
PUSHER_RADIUS_PER_LENGTH, PUSHER_MASS_PER_MASS, PUSHER_START_PER_LENGTH = 0.25, 3.1, 0.8
PUSH_FORCE_PER_MASS_LENGTH = 25.0  # N per (kg m)


def push_object_task(config: PushObjectConfig = PushObjectConfig()) -> PushTask:
    """Build the ``push`` task for ``config.object`` (see :class:`PushObjectConfig`).
    Raises DanoError / FileFormatError naming the object file."""
    asset = load_asset(config.object)
    L, m = float(np.max(asset.size()["extents"])), asset.mass
    reach = stopping_reach(config)
    if config.goal is None:  # L along +x, L/2 along +y; within a quarter of the reach where it must end at rest
        goal = np.array([L, 0.5 * L])
        goal *= min(1.0, DEFAULT_GOAL_REACH * reach / np.linalg.norm(goal)) if config.at_rest else 1.0
    else:
        goal = np.asarray(config.goal, dtype=float)
    if np.linalg.norm(goal) < 1e-3 * L:
        if config.goal is None:
            raise DanoError(f"horizon {config.horizon} steps of {config.dt:g} s at sliding friction "
                            f"{config.sliding_friction:g}: friction stops the object within {reach:.3g} m, too near "
                            "for a default goal; give a longer horizon, more friction, or a goal")
        raise DanoError(f"goal {goal.tolist()} is where the object starts: give a goal away from 0 0")
    direction = np.r_[goal / np.linalg.norm(goal), 0.0]
    r = PUSHER_RADIUS_PER_LENGTH * L
    start = -PUSHER_START_PER_LENGTH * L * direction + np.array([0.0, 0.0, r])
    name = asset.name or "object"
    return _sphere_pusher_task(config, asset, name, r, PUSHER_MASS_PER_MASS * m, start,
                               PUSH_FORCE_PER_MASS_LENGTH * m * L * direction, lambda *_: (goal, None),
                               settle=True, at_rest=config.at_rest, max_force=config.max_force)


PANDA_TORQUE = np.array([87.0, 87.0, 87.0, 87.0, 12.0, 12.0, 12.0])  # N m, Franka's joint torque limits
PANDA_PUSHER_RADIUS = 0.025


def torque_controlled_arm(spec: mujoco.MjSpec) -> list:
    """Make the Menagerie Panda in ``spec`` a torque-controlled arm, in place: its own
    collisions off, every body gravity compensated, its first 7 actuators joint motors
    (ctrl = torque [N m] within Franka's torque limits). Returns the spec's actuators.
    Raises DanoError if the arm's 7 actuators are missing."""
    for g in spec.geoms:
        g.contype, g.conaffinity = 0, 0
    for b in spec.bodies:
        if b.name != "world":
            b.gravcomp = 1.0
    actuators = list(spec.actuators)
    if len(actuators) < 7:
        raise DanoError(f"expected the Panda's 7 arm actuators, found {len(actuators)}")
    for a, limit in zip(actuators[:7], PANDA_TORQUE):
        a.gaintype = mujoco.mjtGain.mjGAIN_FIXED
        a.gainprm[0] = 1.0
        a.biastype = mujoco.mjtBias.mjBIAS_NONE
        a.biasprm[:] = 0.0
        a.ctrlrange = [-limit, limit]
        a.forcerange = [-limit, limit]
    return actuators


def panda_spec() -> mujoco.MjSpec:
    """The Menagerie Panda (``$MENAGERIE_ROOT``) as a torque-controlled arm
    (:func:`torque_controlled_arm`) with a spherical pusher (geom "pusher") 16.7 cm beyond
    link 7's frame. Raises DanoError if the Panda is not found."""
    spec = mujoco.MjSpec.from_file(str(menagerie_panda("push-panda")))
    if len(torque_controlled_arm(spec)) != 7:
        raise DanoError(f"expected the Panda's 7 actuators, found {len(spec.actuators)}")
    spec.body("link7").add_geom(name="pusher", type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[PANDA_PUSHER_RADIUS, 0, 0],
                                pos=[0, 0, 0.167], contype=2, conaffinity=2, mass=0.1, rgba=[0.9, 0.2, 0.2, 1])
    return spec


def push_panda_task(config: PushPandaConfig = PushPandaConfig()) -> PushTask:
    """Build the push-panda task: the Panda scene, the PD-tracked straight push (the
    initial guess) and the constrained problem."""
    spec = panda_spec()
    add_ground(spec)
    bunny = load_builtin("bunny").scaled(0.15).with_mass(0.25)
    start = np.array([0.45, 0.0, resting_height(bunny) + 0.0005])
    scene = compose([DanoObject("bunny", bunny, tuple(start))], spec, dt=config.dt, name="push-panda",
                    contact_model=config.contact_model)
    params = _params(scene, config)
    free = initial_state(scene, {"bunny": (tuple(start), (1, 0, 0, 0))})
    qpos = np.asarray(free.qpos).copy()
    qpos[:7] = PANDA_WAYPOINTS[1]  # pusher 30 cm out, 7.5 cm up, behind the bunny
    x0 = np.r_[qpos, np.zeros(scene.nv)]
    nq, T = scene.nq, config.horizon
    ba = scene.qpos_adr[0]
    bunny_q = slice(ba, ba + 3)
    dynamics = mjx_dynamics(scene, "ctrl")
    # initial guess: PD tracking of a straight push (waypoint 1 -> 3: the pusher from x = 0.30
    # to 0.48 at 7.5 cm height) over 90 % of the horizon
    times = np.arange(T) * config.dt
    q_ref = np.stack([np.interp(times, [0.0, 0.9 * T * config.dt], PANDA_WAYPOINTS[[1, 3], k]) for k in range(7)], 1)
    kp = np.array([300.0] * 4 + [50.0] * 3)
    kd = np.sqrt(kp)

    def pd(x, q_r):
        u = jnp.clip(kp * (q_r - x[:7]) - kd * x[nq:nq + 7], -PANDA_TORQUE, PANDA_TORQUE)
        return dynamics(x, u, 0, params), u

    def pd_rollout(x, q_r):
        xn, u = pd(x, q_r)
        return xn, (xn, u)

    _, (X, U_plain) = jax.jit(lambda x: jax.lax.scan(pd_rollout, x, jnp.asarray(q_ref)))(jnp.asarray(x0))
    X_plain = np.concatenate([x0[None], np.asarray(X)])
    U_plain = np.asarray(U_plain)
    angle = np.deg2rad(config.goal_angle)
    bunny_goal = start[:2] + config.goal_distance * np.array([np.cos(angle), np.sin(angle)])
    m = scene.mj_model
    lo, hi = jnp.asarray(m.jnt_range[:7, 0]), jnp.asarray(m.jnt_range[:7, 1])

    def goal_dynamics(x, u, t, pg):  # pg = (params, goal): the goal is a parameter, as in push-sphere
        return dynamics(x, u, t, pg[0])

    # what the problem's functions read (the joint limits are the scene's): its key, so that the
    # solver's programs are kept on disk and serve every goal
    key = ("dano.experiments.push.panda", scene, "ctrl", float(config.state_weight), float(config.control_weight),
           PANDA_TORQUE, (int(ba), int(ba) + 3))
    problem = Problem(goal_dynamics, _stage_cost(config, nq, PANDA_TORQUE), lambda x, p: 0.0, T, len(x0), 7,
                      inequality=lambda x, u, t, p: jnp.concatenate([x[:7] - hi, lo - x[:7]]),
                      terminal_equality=lambda x, pg: x[bunny_q][:2] - pg[1],
                      u_lower=-PANDA_TORQUE, u_upper=PANDA_TORQUE, key=key)
    return PushTask(scene, params, problem, x0, U_plain, X_plain, bunny_goal, None, bunny_q, "ctrl", None,
                    PANDA_TORQUE.copy(), config, goal_parameter=True)


def solver_options(config: PushConfig) -> ILQRConfig:
    """The solver settings of a task: its μ₀, tolerance and iteration budget."""
    return ILQRConfig(max_iterations=config.max_iterations, constraint_tolerance=config.constraint_tolerance,
                      penalty_initial=config.penalty_initial)


def pusher_positions(task: PushTask, X) -> np.ndarray:
    """World positions (T + 1, 3) [m] of the geom named "pusher" along states X."""
    m = task.scene.mj_model
    d = mujoco.MjData(m)
    g = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "pusher")
    out = []
    for x in np.asarray(X):
        d.qpos[:] = x[:m.nq]
        mujoco.mj_kinematics(m, d)
        out.append(d.geom_xpos[g].copy())
    return np.array(out)


def final_errors(task: PushTask, X) -> tuple[float, float | None]:
    """(bunny x–y distance to its goal, pusher distance to its goal or None) at the last
    state [m]."""
    X = np.asarray(X)
    eb = float(np.linalg.norm(X[-1, task.bunny_qpos][:2] - task.bunny_goal))
    if task.pusher_goal is None:
        return eb, None
    return eb, float(np.linalg.norm(pusher_positions(task, X[-1:])[0] - task.pusher_goal))


def limit_report(task: PushTask, X, U) -> dict:
    """How the controls and (for the arm) the joints sit against their limits:
    ``max_control_ratio`` max|u|/u_max over the task's bounded controls (≤ 1 within
    tolerance), ``joint_limit_violation`` the largest excursion beyond a joint limit
    [rad] (0 if none; arm tasks only), ``pusher_below_floor`` how far the floating sphere's
    centre dips below its floor (its radius) [m] (0 if not; sphere tasks only) and
    ``pusher_max_force`` its largest force in its weights [-] and ``pusher_max_force_n`` the
    same in newtons (sphere tasks only)."""
    out = {}
    if task.problem.u_upper is not None:
        out["max_control_ratio"] = float(np.max(np.abs(np.asarray(U)) / np.asarray(task.problem.u_upper)))
    if task.pusher_floor is not None:  # how far the floating pusher's centre dips below its floor [m]
        force = float(np.max(np.linalg.norm(np.asarray(U)[:, :3], axis=1)))  # [N]
        out["pusher_max_force"], out["pusher_max_force_n"] = force / float(task.u_ref[0]), force
        out["pusher_below_floor"] = float(max(0.0, task.pusher_floor - np.min(pusher_positions(task, np.asarray(X))[:, 2])))
    elif task.problem.inequality is not None:
        m = task.scene.mj_model
        q = np.asarray(X)[:, :7]
        out["joint_limit_violation"] = float(max(0.0, np.max(q - m.jnt_range[:7, 1]), np.max(m.jnt_range[:7, 0] - q)))
    return out


@dataclass(frozen=True)
class ModelErrorResult:
    """The plan run in a world with other sliding friction: open_loop_states (T + 1, nx)
    (the plan's controls replayed), receding (the receding-horizon run)."""

    friction: float
    open_loop_states: np.ndarray
    receding: RecedingHorizonResult


def model_error_run(task: PushTask, solution: Solution, callback=None) -> ModelErrorResult:
    """Replay ``solution``'s controls open loop, then run the receding-horizon controller,
    in a world whose sliding friction is (1 + model_error)× the model's."""
    cfg = task.config
    mu_world = cfg.sliding_friction * (1.0 + cfg.model_error)
    world_params = task.params.replace(contact=task.params.contact.replace(
        sliding_friction=jnp.full_like(task.params.contact.sliding_friction, mu_world)))
    world_p = task.problem_params(world_params)
    X_open = np.asarray(rollout(task.problem, task.x0, solution.controls, world_p))
    world = jax.jit(lambda x, u: task.problem.dynamics(x, u, 0, world_p))
    rh = receding_horizon(task.problem, task.x0, world, solution.controls, task.problem_params(),
                          every=cfg.replan_every,
                          options=dataclasses.replace(solver_options(cfg), max_iterations=cfg.replan_iterations),
                          first=solution, callback=callback)
    return ModelErrorResult(mu_world, X_open, rh)


TASKS = {"push-sphere": (push_sphere_task, PushSphereConfig), "push-panda": (push_panda_task, PushPandaConfig),
         "push": (push_object_task, PushObjectConfig)}


def task_names() -> tuple[str, ...]:
    return tuple(TASKS)


#: a sphere push that does not converge from its plain push is solved again from the plain
#: push scaled by each of these in turn (the first guess's forces halved, then quartered),
#: until one converges: from the full push the sphere can pass beside a light object and lose
#: it (docs/trajopt.md)
RESTART_GUESS_SCALES = (0.5, 0.25)


def guess_name(scale: float) -> str:
    """The name of the first guess ``scale`` × the plain push in a solution's ``restarts``
    and the report's ``first_guess``: ``plain push``, ``plain push x0.5``, ..."""
    return "plain push" if scale == 1.0 else f"plain push x{scale:g}"


def solve_task(task: PushTask, callback=None) -> Solution:
    """Solve a built task from its plain push. A sphere push (``apply == "qfrc"``) that does
    not converge is solved again from the plain push scaled by each of
    :data:`RESTART_GUESS_SCALES` in turn, until one converges; the solution kept is the
    first that converges, else the one that violates the constraints least. The solves not
    kept are recorded in the kept one's ``restarts`` (guess, status, iterations,
    max_violation); every solve's seconds count in its ``wall_time_s`` and
    ``compile_time_s``."""
    options, p = solver_options(task.config), task.problem_params()
    first = solve(task.problem, task.x0, task.U_plain, p, options, callback=callback)
    if first.converged or task.apply != "qfrc":
        return first
    tried = [(1.0, first)]
    for scale in RESTART_GUESS_SCALES:
        tried.append((scale, solve(task.problem, task.x0, scale * task.U_plain, p, options, callback=callback)))
        if tried[-1][1].converged:
            break
    kept = tried[-1][1] if tried[-1][1].converged else min((sol for _, sol in tried), key=lambda s: s.max_violation)
    records = tuple({"guess": guess_name(scale), "status": sol.status, "iterations": sol.iterations,
                     "max_violation": sol.max_violation} for scale, sol in tried if sol is not kept)
    return dataclasses.replace(kept, restarts=records, wall_time_s=sum(sol.wall_time_s for _, sol in tried),
                               compile_time_s=sum(sol.compile_time_s for _, sol in tried))


def first_guess(solution: Solution) -> str:
    """The first guess the solution was solved from (:func:`solve_task`): the first of the
    plain push and its :data:`RESTART_GUESS_SCALES` that its ``restarts`` do not name."""
    replaced = {r["guess"] for r in solution.restarts}
    return next(name for name in map(guess_name, (1.0,) + RESTART_GUESS_SCALES) if name not in replaced)

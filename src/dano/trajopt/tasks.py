"""Built-in trajectory-optimisation tasks (``dano trajopt TASK``).

``push-sphere`` is the paper's push-and-slide (Fig. 7): a floating, fully actuated sphere
(mass 10, radius 0.25; a 3-D force, world frame, and a 3-D torque, body frame) pushes the
paper's bunny DANO over the ground (sliding friction 0.05, impact spring 3e4, damper 3e5)
so that the bunny ends 1.0 unit sideways (+y) of where a plain push leaves it, and the
sphere ends equally shifted; h = 0.02 s, T = 60 steps.

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

import jax.numpy as jnp
import mujoco
import numpy as np

from ..errors import DanoError
from .ilqr import Options, Solution, solve
from .mpc import RecedingHorizonResult, receding_horizon
from .problem import Problem, mjx_dynamics

G = 9.81


@dataclass(frozen=True)
class PushSphereConfig:
    """Settings of ``push-sphere`` (the defaults are the paper's task)."""

    task: str = "push-sphere"
    """the task's name"""
    dt: float = 0.02
    """time step h [s]"""
    horizon: int = 60
    """T, steps"""
    sideways: float = 1.0
    """bunny goal: this far (+y) from where the plain push leaves it [m]"""
    sliding_friction: float = 0.05
    """sliding friction μ of both contact pairs"""
    impact_spring: float = 3e4
    """impact spring k [N per unit overlap]"""
    impact_damper: float = 3e5
    """impact damper c [N s/m per unit overlap]"""
    state_weight: float = 0.1
    """weight of ½|qvel|² per stage"""
    control_weight: float = 0.2
    """weight of ½|u/u_ref|² per stage"""
    max_iterations: int = 300
    """iLQR iterations in all"""
    constraint_tolerance: float = 1e-3
    """largest allowed terminal-constraint violation [m]"""
    model_error: float = 0.0
    """if > 0: also run the plan, open loop and with receding horizon, in a world whose sliding friction is
    (1 + model_error) times the model's"""
    replan_every: int = 5
    """receding horizon: steps executed between re-plans"""
    replan_iterations: int = 30
    """receding horizon: iLQR iterations per re-plan"""
    contact_model: str = "centroid"
    """DANO contact model: centroid (the paper's) or per_sample"""

    def validate(self) -> "PushSphereConfig":
        """Raises DanoError naming the first setting out of range."""
        checks = [("task", self.task == "push-sphere"), ("dt", self.dt > 0 and np.isfinite(self.dt)), ("horizon", 2 <= self.horizon <= 10000),
                  ("sideways", np.isfinite(self.sideways)),
                  ("sliding_friction", 0 <= self.sliding_friction < np.inf),
                  ("impact_spring", 0 < self.impact_spring < np.inf), ("impact_damper", 0 <= self.impact_damper < np.inf),
                  ("state_weight", 0 <= self.state_weight < np.inf),
                  ("control_weight", 0 < self.control_weight < np.inf), ("max_iterations", self.max_iterations >= 1),
                  ("constraint_tolerance", 0 < self.constraint_tolerance < np.inf),
                  ("model_error", -1 < self.model_error < np.inf), ("replan_every", self.replan_every >= 1),
                  ("replan_iterations", self.replan_iterations >= 1)]
        for name, ok in checks:
            if not ok:
                raise DanoError(f"{name} out of range: {getattr(self, name)}")
        return self


SPHERE_MASS, SPHERE_RADIUS = 10.0, 0.25
SPHERE_START = (-0.8, 0.0, 0.25)
PLAIN_FORCE = 80.0  # N


@dataclass(frozen=True)
class PushTask:
    """A built task: scene, params (model), problem, x0 (nx,), plain-push controls
    U_plain (T, nu), the plain push's states X_plain (T + 1, nx), goals {name: (k,)}
    and the body indices (``bunny_qpos``, ``pusher_qpos``: slices of qpos; control_dofs
    (nu,): the qvel indices the controls act on)."""

    scene: object
    params: object
    problem: Problem
    x0: np.ndarray
    U_plain: np.ndarray
    X_plain: np.ndarray
    bunny_goal: np.ndarray
    pusher_goal: np.ndarray
    bunny_qpos: slice
    pusher_qpos: slice
    control_dofs: np.ndarray
    config: PushSphereConfig


def push_sphere_task(config: PushSphereConfig = PushSphereConfig()) -> PushTask:
    """Build the push-sphere task: the scene, the plain push and the constrained problem."""
    from ..data import load_builtin
    from ..sim import DanoObject, compose
    from ..sim.scene import add_ground
    from ..sim.scenes import initial_state, resting_height
    from .ilqr import rollout

    config.validate()
    bunny = load_builtin("bunny")
    z = resting_height(bunny) + 0.001
    spec = mujoco.MjSpec()
    add_ground(spec)
    body = spec.worldbody.add_body(name="pusher", pos=list(SPHERE_START), gravcomp=1.0)
    body.add_freejoint(name="pusher_free")
    # contype 2: no MuJoCo contact with the ground (conaffinity 1); DANO contact with the bunny
    body.add_geom(name="pusher", type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[SPHERE_RADIUS, 0, 0], mass=SPHERE_MASS,
                  contype=2, conaffinity=2, rgba=[0.3, 0.5, 0.9, 1])
    scene = compose([DanoObject("bunny", bunny, (0, 0, z))], spec, dt=config.dt, name="push-sphere",
                    contact_model=config.contact_model)
    params = scene.default_params(sliding_friction=config.sliding_friction, impact_spring=config.impact_spring,
                                  impact_damper=config.impact_damper)
    s0 = initial_state(scene, {"bunny": ((0, 0, z), (1, 0, 0, 0)), "pusher": (SPHERE_START, (1, 0, 0, 0))})
    x0 = np.r_[np.asarray(s0.qpos), np.asarray(s0.qvel)]
    nq, T = scene.nq, config.horizon
    pa, ba = scene.mj_model.jnt_qposadr[0], scene.qpos_adr[0]
    pusher, bunny_q = slice(pa, pa + 3), slice(ba, ba + 3)
    dofs = np.arange(scene.mj_model.jnt_dofadr[0], scene.mj_model.jnt_dofadr[0] + 6)
    dynamics = mjx_dynamics(scene, "qfrc", dofs=dofs)
    u_ref = jnp.asarray([SPHERE_MASS * G] * 3 + [SPHERE_MASS * G * SPHERE_RADIUS] * 3)
    half = T * 25 // 60  # 25 of 60 steps: 0.5 s at the paper's h
    U_plain = np.zeros((T, 6))
    U_plain[:half, 0] = PLAIN_FORCE
    U_plain[half:2 * half, 0] = -PLAIN_FORCE
    wq, wu = config.state_weight, config.control_weight

    def stage_cost(x, u, t, p):
        return 0.5 * wq * jnp.sum(x[nq:] ** 2) + 0.5 * wu * jnp.sum((u / u_ref) ** 2)

    plain = Problem(dynamics, stage_cost, lambda x, p: 0.0, T, len(x0), 6)
    X_plain = np.asarray(rollout(plain, x0, U_plain, params))
    bunny_goal = X_plain[-1, bunny_q][:2] + np.array([0.0, config.sideways])
    pusher_goal = np.r_[X_plain[-1, pusher][:2] + np.array([0.0, config.sideways]), SPHERE_START[2]]
    bg, pg = jnp.asarray(bunny_goal), jnp.asarray(pusher_goal)

    def terminal(x, p):
        return jnp.concatenate([x[bunny_q][:2] - bg, x[pusher] - pg])

    problem = Problem(dynamics, stage_cost, lambda x, p: 0.0, T, len(x0), 6, terminal_equality=terminal)
    return PushTask(scene, params, problem, x0, U_plain, X_plain, bunny_goal, pusher_goal, bunny_q, pusher, dofs,
                    config)


def solver_options(config) -> Options:
    """The solver settings of a task: μ₀ = 10 (the terminal constraints matter from the
    first iteration, before the push could be optimised away), the task's tolerance."""
    return Options(max_iterations=config.max_iterations, constraint_tolerance=config.constraint_tolerance,
                   penalty_initial=10.0)


def final_errors(task: PushTask, X) -> tuple[float, float]:
    """(bunny x–y distance to its goal, sphere distance to its goal) at the last state [m]."""
    X = np.asarray(X)
    return (float(np.linalg.norm(X[-1, task.bunny_qpos][:2] - task.bunny_goal)),
            float(np.linalg.norm(X[-1, task.pusher_qpos] - task.pusher_goal)))


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
    import jax

    from .ilqr import rollout

    cfg = task.config
    mu_world = cfg.sliding_friction * (1.0 + cfg.model_error)
    world_params = task.params.replace(contact=task.params.contact.replace(
        sliding_friction=jnp.full_like(task.params.contact.sliding_friction, mu_world)))
    X_open = np.asarray(rollout(task.problem, task.x0, solution.controls, world_params))
    world = jax.jit(lambda x, u: task.problem.dynamics(x, u, 0, world_params))
    rh = receding_horizon(task.problem, task.x0, world, solution.controls, task.params, every=cfg.replan_every,
                          options=dataclasses.replace(solver_options(cfg), max_iterations=cfg.replan_iterations),
                          first=solution, callback=callback)
    return ModelErrorResult(mu_world, X_open, rh)


TASKS = {"push-sphere": (push_sphere_task, PushSphereConfig)}


def task_names() -> tuple[str, ...]:
    return tuple(TASKS)


def solve_task(task: PushTask, callback=None) -> Solution:
    """Solve a built task from its plain push."""
    return solve(task.problem, task.x0, task.U_plain, task.params, solver_options(task.config), callback=callback)


def unknown_task(name: str) -> DanoError:
    return DanoError(f"unknown task {name!r}; built-in tasks: {', '.join(TASKS)} (or a TOML/JSON config)")

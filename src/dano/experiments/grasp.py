"""``grasp-panda``: the Menagerie Panda's two-finger hand grasps the 15 cm bunny DANO from the
table, lifts it and holds it for a second (the paper's abstract: "optimize grasps").

The pipeline, every stage on the DANO's own contact samples and dano's simulator:

1. **Grasp pose**: a search over antipodal pairs of the DANO's contact samples (outward
   normals opposed within the friction cone's half-angle, the grip axis horizontal for a
   top-down approach, the width within the hand's opening less a margin) whose finger paths
   are free of samples (the open fingers descend and close without cutting the object); the
   pair with the least gravity lever about the grip and the best-aligned normals is chosen
   (:func:`antipodal_grasp`).
2. **Arm configurations** for the pre-grasp (12 cm above), grasp and lifted poses by inverse
   kinematics of the hand's grip site (SciPy's bounded least squares on MuJoCo's kinematics).
3. **Approach** (home → pre-grasp): optimised by the constrained iLQR through
   :func:`dano.sim.step` (joint torques within Franka's limits, joint limits, the hand kept
   above the pre-grasp height, arriving at rest: :func:`optimise_approach`).
4. **Motion**: joint-space PD tracking of the optimised approach (its torques fed forward),
   then descend → settle → close → lift → hold, with gravity compensation of the arm and a
   feedforward of the object's weight at the grip site during lift and hold, simulated with
   :func:`dano.sim.step` (DANO contact between the bunny, the two finger pads and the table).
5. **Closing force**: a scan of the grip force per finger; the smallest force that lifts the
   bunny by at least 90 % of the goal and holds it with less than ``slip_tolerance_mm`` of
   slip is chosen (all forces of the scan go through one compiled rollout).

The 12 cm descent and the lift stay joint interpolations between IK poses, and the grasp
pose and force are chosen by a search and a scan rather than through the simulator's
gradients (docs/trajopt.md says why).

Decisions where the issue is silent: the finger motor is a force motor on the hand's tendon
(ctrl = grip force per finger [N], −20 to 70 N: Franka's hand holds 70 N continuously),
the finger joints get 200 N s/m of damping (the hand's gearing: they close at ≈ 7 cm/s under
15 N instead of slamming into the object); only the two main fingertip pads (1.7 × 1.7 cm
faces) touch the bunny, each made 2 cm thick outwards with the inner face where Menagerie has
it (a thin box lets the centroid pass its mid-plane and the normal flip); the pads are stiff
(impact spring 1e6, damper 1e7 per unit overlap: the paper's 3e4 lets the 1.7 cm pad's
largest overlap carry only ≈ 5 N) and the table keeps the paper's values; sliding friction 0.8
on both (rubber pads, a wooden table), with the paper code's friction steepness, 30 s/m
(:data:`GRASP_FRICTION_STEEPNESS`: dano's default 100 is not robust with these pads at 10 ms);
h = 2 ms. At the push tasks' 10 ms, with one
constraint pass per step, this contact diverged (at 10 N the fingers were driven through
their limits and the state grew to 1e124 within two steps); the step's second constraint
pass (:class:`dano.sim.NewtonConfig`) keeps 10 ms bounded too, but 2 ms is what was
measured. A run whose velocities exceed 1e3 or are not finite is marked ``diverged`` and
never chosen.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from .._compiled import cached_jit, compile_seconds
from .._config import check_ranges
from .._mjx import mjx
from ..data import load_builtin
from ..errors import DanoError
from ..sim import DanoObject, NewtonConfig, compose, make_data, step
from ..sim.dynamics import tied
from ..sim.rollout import carried
from ..sim.scene import add_ground, contact_model_or_error
from ..sim.scenes import initial_state, menagerie_panda, resting_height
from ..trajopt.ilqr import ILQRConfig, solve
from ..trajopt.problem import Problem, mjx_dynamics
from .push import PANDA_TORQUE, torque_controlled_arm

PAD_INNER_HALF_THICKNESS = 0.01  # [m] pads thickened outwards to 2 cm
GRIP_SITE_OFFSET = 0.1034  # [m] hand frame: the main pads' centre below the hand's origin
OPEN_GAP = 0.083  # [m] between the pads' inner faces, fingers fully open (2 × 0.04 + 3 mm)
HOME = np.array([0.0, 0.0, 0.0, -1.57079, 0.0, 1.57079, -0.7853])  # Menagerie's "home" keyframe
PAIR_BLOCK = 256  # sample rows per block of the pair search
ANGLE_WEIGHT = 0.02  # [m] score of a normal at 90° from the grip axis, against the torque arm
ARM_KP = np.array([600.0] * 4 + [100.0] * 3)  # joint PD gains of the executed motion [N m/rad]
ARM_KD = 2.0 * np.sqrt(ARM_KP)  # [N m s/rad]
OPEN_FORCE = 10.0  # [N] per finger, holding the hand open
FINGERS_OPEN = 0.04  # [m] each finger joint, fully open
PHASES = (("approach", 1.0), ("descend", 0.8), ("settle", 0.4), ("close", 0.5), ("lift", 0.8), ("hold", 1.0))


@dataclass(frozen=True)
class GraspPandaConfig:
    """Settings of ``grasp-panda`` (a ``dano trajopt`` TOML/JSON file: these keys at the top
    level). Raises DanoError naming the first setting out of range."""

    task: str = "grasp-panda"
    """The task's name: ``grasp-panda``."""
    dt: float = 0.002
    """Time step h [s], in (0, 0.01] (the stiff pads' contact: see the module's notes)."""
    sliding_friction: float = 0.8
    """Sliding friction μ [-] of the pads and the table, in (0, 10)."""
    pad_spring: float = 1e6
    """Impact spring k of the two finger-pad pairs [N per unit overlap], in (0, 1e9)."""
    pad_damper: float = 1e7
    """Impact damper c of the finger-pad pairs [N·s/m per unit overlap], in [0, 1e10)."""
    lift_height: float = 0.10
    """Lift goal [m], in (0, 0.3]."""
    grip_forces: tuple[float, ...] = (10.0, 15.0, 20.0, 30.0, 40.0, 50.0)
    """Grip forces per finger scanned for the closing force [N], each in (0, 70]; at least one."""
    slip_tolerance_mm: float = 5.0
    """Largest accepted slip of the object in the hand over the hold [mm], > 0."""
    friction_cone_deg: float = 15.0
    """Antipodal test: largest angle between a sample's normal and the grip axis [deg], in (0, 60)."""
    contact_model: str = "centroid"
    """DANO contact model of the main run: ``centroid`` (the paper's) or ``per_sample``."""
    compare_models: bool = True
    """Also run the other contact model at the chosen grasp and force."""
    optimise_approach: bool = True
    """Optimise the approach (home to pre-grasp) with the constrained iLQR; false: PD tracking of a joint-space
    interpolation."""
    approach_iterations: int = 100
    """iLQR iteration budget of the approach, >= 1."""

    def validate(self):
        """Old API, kept: the settings are checked when the config is built; returns it."""
        return self

    def __post_init__(self):
        checks = [("task", self.task == "grasp-panda"), ("dt", 0 < self.dt <= 0.01),
                  ("sliding_friction", 0 < self.sliding_friction < 10), ("pad_spring", 0 < self.pad_spring < 1e9),
                  ("pad_damper", 0 <= self.pad_damper < 1e10), ("lift_height", 0 < self.lift_height <= 0.3),
                  ("grip_forces", len(self.grip_forces) > 0 and all(0 < f <= 70 for f in self.grip_forces)),
                  ("slip_tolerance_mm", self.slip_tolerance_mm > 0),
                  ("friction_cone_deg", 0 < self.friction_cone_deg < 60),
                  ("contact_model", self.contact_model in ("centroid", "per_sample")),
                  ("approach_iterations", isinstance(self.approach_iterations, int) and self.approach_iterations >= 1)]
        check_ranges(self, checks)


def hand_spec() -> mujoco.MjSpec:
    """The Menagerie Panda with its hand (``$MENAGERIE_ROOT``): a torque-controlled arm,
    the finger tendon driven by a grip-force motor (ctrl[7] = force per finger [N], > 0
    closes), damped finger joints, the two main fingertip pads as the only collision geoms
    ("left_finger_pad", "right_finger_pad") and a site "grip" between them. Raises
    DanoError if the Panda is not found."""
    spec = mujoco.MjSpec.from_file(str(menagerie_panda("grasp-panda", hand=True)))
    actuators = torque_controlled_arm(spec)
    if len(actuators) != 8:
        raise DanoError(f"expected the Panda's 8 actuators (7 joints and the hand), found {len(actuators)}")
    grip = actuators[7]  # on the tendon "split" (0.5 per finger joint): −2 makes ctrl the force per finger
    grip.gaintype = mujoco.mjtGain.mjGAIN_FIXED
    grip.gainprm[:] = 0.0
    grip.gainprm[0] = -2.0
    grip.biastype = mujoco.mjtBias.mjBIAS_NONE
    grip.biasprm[:] = 0.0
    grip.ctrlrange = [-20.0, 70.0]
    grip.forcerange = [-140.0, 140.0]
    for j in spec.joints:
        if j.name.startswith("finger_joint"):
            j.damping = [200.0, 0.0, 0.0]
    for finger in ("left_finger", "right_finger"):
        boxes = [g for g in spec.body(finger).geoms if g.type == mujoco.mjtGeom.mjGEOM_BOX]
        if not boxes:
            raise DanoError(f"the Panda's {finger} has no fingertip pad boxes")
        pad = max(boxes, key=lambda g: g.size[0] * g.size[2])
        inner = pad.pos[1] - pad.size[1]
        pad.size = [pad.size[0], PAD_INNER_HALF_THICKNESS, pad.size[2]]
        pad.pos = [pad.pos[0], inner + PAD_INNER_HALF_THICKNESS, pad.pos[2]]
        pad.contype, pad.conaffinity = 2, 2
        pad.name = f"{finger}_pad"
    spec.body("hand").add_site(name="grip", pos=[0.0, 0.0, GRIP_SITE_OFFSET])
    return spec


@dataclass(frozen=True)
class Grasp:
    """An antipodal grasp: centre (3,) world [m], axis (3,) horizontal unit grip axis
    (world), width [m] between the two contact samples, torque_arm [m] horizontal distance
    of the centre from the object's centre of mass, candidates: how many pairs passed."""

    center: np.ndarray
    axis: np.ndarray
    width: float
    torque_arm: float
    candidates: int


def antipodal_grasp(points, normals, com, max_width: float = OPEN_GAP - 0.018, min_width: float = 0.015,
                    cone_deg: float = 15.0, min_height: float = 0.025) -> Grasp:
    """The best antipodal grasp among the DANO's contact samples.

    points, normals: (N, 3) world frame [m] and outward unit normals; com: (3,) [m].
    A pair (i, j) qualifies if min_width < |p_j − p_i| < max_width, the axis is within 0.1
    of horizontal, n_i and n_j lie within ``cone_deg`` of −axis and +axis, the centre is
    ``min_height`` above the table, and no sample lies in the open fingers' columns or the
    pads' closing paths (pad faces 1.7 × 1.7 cm with 3 mm margins). The chosen pair has the
    least score: the horizontal distance of its centre from ``com`` [m] (the lever of the
    object's weight about the grip) + 0.02 m × sin of the larger angle between a normal and
    the grip axis (a margin inside the friction cone). Raises DanoError if no pair qualifies.
    """
    P, n = np.asarray(points, np.float64), np.asarray(normals, np.float64)
    cos = np.cos(np.deg2rad(cone_deg))
    pairs = []
    for start in range(0, len(P), PAIR_BLOCK):  # rows in blocks: memory O(block × N), not O(N²)
        rows = slice(start, start + PAIR_BLOCK)
        d = P[None] - P[rows, None]
        w = np.linalg.norm(d, axis=-1)
        u = d / np.maximum(w, 1e-12)[..., None]
        ok = (w > min_width) & (w < max_width) & (np.abs(u[..., 2]) < 0.1) & (u[..., 0] >= 0)  # each pair once
        ok &= (np.einsum("ik,ijk->ij", n[rows], u) < -cos) & (np.einsum("jk,ijk->ij", n, u) > cos)
        ok &= 0.5 * (P[rows, None, 2] + P[None, :, 2]) > min_height
        bi, bj = np.nonzero(ok)
        pairs.append((bi + start, bj, u[bi, bj], w[bi, bj]))
    i, j, axes, widths = (np.concatenate(x) for x in zip(*pairs))
    centers = 0.5 * (P[i] + P[j])
    worst = np.minimum(-np.einsum("kd,kd->k", n[i], axes), np.einsum("kd,kd->k", n[j], axes))
    arms = np.linalg.norm(centers[:, :2] - np.asarray(com)[:2], axis=1)
    score = arms + ANGLE_WEIGHT * np.sqrt(np.clip(1.0 - worst ** 2, 0.0, 1.0))
    half_open = OPEN_GAP / 2 + 0.005
    best, count = None, 0
    for k in np.argsort(score, kind="stable"):
        a = axes[k].copy()
        a[2] = 0.0
        a /= np.linalg.norm(a)
        v = np.cross([0.0, 0.0, 1.0], a)
        r = P - centers[k]
        along, side, up = r @ a, r @ v, r[:, 2]
        column = (np.abs(np.abs(along) - half_open) < 0.008) & (np.abs(side) < 0.0115) & (up > -0.0115) & (up < 0.09)
        path = ((np.abs(along) > widths[k] / 2 + 0.003) & (np.abs(along) < half_open) & (np.abs(side) < 0.0115)
                & (np.abs(up) < 0.0115))
        if not np.any(column | path):
            count += 1
            if best is None:
                best = Grasp(centers[k], a, float(widths[k]), float(arms[k]), 0)
    if best is None:
        raise DanoError(f"no antipodal grasp within the hand's opening ({max_width * 100:.1f} cm) is free of the "
                        f"object: {len(i)} pairs passed the width and friction-cone tests")
    return dataclasses.replace(best, candidates=count)


def grip_ik(model: mujoco.MjModel, site: int, target, axis, q0, rotation=None) -> tuple[np.ndarray, float]:
    """Joint angles (7,) placing ``site`` at ``target`` (3,) [m] with the hand's z axis down
    and its finger axis (y) along ``axis`` (or the site's orientation equal to ``rotation``
    (3, 3)), within the joint limits less 0.05 rad; bounded least squares (SciPy) from q0.
    Returns (q, largest residual [m or unit-vector components])."""
    from scipy.optimize import least_squares

    data = mujoco.MjData(model)
    lo, hi = model.jnt_range[:7, 0] + 0.05, model.jnt_range[:7, 1] - 0.05

    def residual(q):
        data.qpos[:7] = q
        mujoco.mj_kinematics(model, data)
        R = data.site_xmat[site].reshape(3, 3)
        orient = (R - rotation).ravel() if rotation is not None else np.r_[R[:, 2] - [0, 0, -1], R[:, 1] - axis]
        return np.r_[10.0 * (data.site_xpos[site] - target), orient, 1e-3 * (q - HOME)]

    sol = least_squares(residual, np.clip(q0, lo, hi), bounds=(lo, hi))
    return sol.x, float(np.abs(sol.fun[:-7]).max())


def arm_torque(q, qd, q_ref, qd_ref, tau_ff):
    """The executed arm law: joint PD (:data:`ARM_KP`, :data:`ARM_KD`) on the reference angles
    q_ref [rad] and speeds qd_ref [rad/s] plus the feedforward tau_ff [N m], clipped to
    Franka's torque limits; all (7,) (jnp or NumPy)."""
    return jnp.clip(ARM_KP * (q_ref - q) + ARM_KD * (qd_ref - qd) + tau_ff, -PANDA_TORQUE, PANDA_TORQUE)


def joint_reference(waypoints: np.ndarray, times: np.ndarray) -> np.ndarray:
    """(len(times), 7) joint angles [rad] interpolated linearly between ``waypoints``
    (len(PHASES) + 1, 7) at the phase boundaries (:data:`PHASES`); ``times`` [s]."""
    knots = np.cumsum([0.0] + [t for _, t in PHASES])[: len(waypoints)]
    return np.stack([np.interp(times, knots, waypoints[:, k]) for k in range(7)], axis=1)


APPROACH_DT = 0.01  # [s] stage of the approach's iLQR (free space: no stiff contact to resolve)
APPROACH_CLEARANCE = 0.01  # [m] the grip site stays at most this far below the pre-grasp height


@dataclass(frozen=True)
class ApproachPlan:
    """The approach optimised by the constrained iLQR (:func:`optimise_approach`): states
    (T + 1, 18) [qpos (9), qvel (9)] of the arm and hand and torques (T, 7) [N m] at
    ``dt`` = :data:`APPROACH_DT`; report: the solve's figures (iterations, status, cost,
    max_violation, final_error_rad, min_clearance_m, and the same for the scripted PD
    approach it starts from: scripted_final_error_rad, scripted_cost)."""

    states: np.ndarray
    controls: np.ndarray
    dt: float
    report: dict


def optimise_approach(task: GraspTask) -> ApproachPlan:
    """Optimise the arm's motion from Menagerie's home pose to the pre-grasp pose (the first
    phase, :data:`PHASES`) with the constrained iLQR (:func:`dano.trajopt.solve`) through
    :func:`dano.sim.step` of the arm and hand in free space (stage h = :data:`APPROACH_DT`):
    controls the 7 joint torques within Franka's limits (fingers not driven); stage cost
    ½‖q̇_arm‖² + ½‖τ/τ_max‖²; inequalities: joint limits and the grip site no lower than
    :data:`APPROACH_CLEARANCE` below the pre-grasp height (the hand comes from above, where
    the grasp search checked the fingers' descent columns); terminal equalities: the arm at
    the pre-grasp joint angles, at rest. Started from the scripted approach (PD tracking of
    the joint interpolation). The bunny is not in this problem: the constraint keeps the hand
    above it, and the executed grasp simulates everything together. This planning model has
    MuJoCo's constraints off (no constraint solve in its steps: the approach's solve took
    43 s instead of 59 s cold, same iterations and cost to 1e-6): the joint limits are the
    solver's inequalities, and the undriven fingers, held by their damping, stay within
    0.02 mm of open (against their limit, the full model's were pushed 3.4 mm into it)."""
    cfg = task.config
    # MuJoCo's constraints off in the planning model (see above); the executed grasp has them
    spec = hand_spec()
    spec.option.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONSTRAINT
    scene = compose([], spec, dt=APPROACH_DT, name="grasp-panda-approach", ground=False)
    params = scene.default_params()
    nq, nv = scene.nq, scene.nv
    T = int(round(PHASES[0][1] / APPROACH_DT))
    q_pre = np.asarray(task.waypoints[1])
    x0 = np.r_[HOME, FINGERS_OPEN, FINGERS_OPEN, np.zeros(nv)]
    step = mjx_dynamics(scene, "ctrl")
    open_grip = jnp.asarray([0.0])  # (no finger force: nothing would stop the fingers)

    def dynamics(x, u, t, p):
        return step(x, jnp.concatenate([u, open_grip.astype(u.dtype)]), t, p)

    def target_dynamics(x, u, t, pt):  # pt = (params, target): the target is a parameter
        return dynamics(x, u, t, pt[0])

    m, site = scene.model, mujoco.mj_name2id(scene.mj_model, mujoco.mjtObj.mjOBJ_SITE, "grip")

    def grip_height(x):
        return mjx.kinematics(m, make_data(scene, x[:nq])).site_xpos[site, 2]

    z_pre = float(grip_height(jnp.asarray(np.r_[q_pre, FINGERS_OPEN, FINGERS_OPEN, np.zeros(nv)])))
    tau = jnp.asarray(PANDA_TORQUE)
    lo, hi = (jnp.asarray(scene.mj_model.jnt_range[:7, k]) for k in (0, 1))

    def stage_cost(x, u, t, p):
        return 0.5 * jnp.sum(x[nq:nq + 7] ** 2) + 0.5 * jnp.sum((u / tau) ** 2)

    # the pre-grasp joint angles and height are the problem's parameters (target (8,) = q_pre,
    # z_pre), not constants of its programs, and the problem has a key naming what its
    # functions read (the joint limits are the scene's): the solver's programs are kept on
    # disk and serve every grasp
    target = jnp.asarray(np.r_[q_pre, z_pre])
    key = ("dano.experiments.grasp.approach", scene, "ctrl", int(site), float(APPROACH_CLEARANCE), PANDA_TORQUE,
           np.asarray(open_grip))
    problem = Problem(target_dynamics, stage_cost, lambda x, p: 0.0, T, len(x0), 7,
                      inequality=lambda x, u, t, pt: jnp.concatenate(
                          [x[:7] - hi, lo - x[:7], (pt[1][7] - APPROACH_CLEARANCE - grip_height(x))[None]]),
                      terminal_equality=lambda x, pt: jnp.concatenate([x[:7] - pt[1][:7], x[nq:nq + 7]]),
                      u_lower=-PANDA_TORQUE, u_upper=PANDA_TORQUE, key=key)
    # the initial guess: the scripted approach (PD tracking of the joint interpolation)
    q_ref = joint_reference(np.stack([HOME, q_pre]), np.arange(T) * APPROACH_DT)

    def pd(x, q_r):
        u = arm_torque(x[:7], x[nq:nq + 7], q_r, 0.0, 0.0)
        x = dynamics(x, u, 0, params)
        return x, (x, u)

    _, (X0, U0) = jax.jit(lambda x: jax.lax.scan(pd, x, jnp.asarray(q_ref)))(jnp.asarray(x0))
    X0, U0 = np.asarray(X0), np.asarray(U0)
    sol = solve(problem, x0, U0, (params, target), ILQRConfig(max_iterations=cfg.approach_iterations))
    X, U = np.asarray(sol.states), np.asarray(sol.controls)
    heights = np.asarray(jax.jit(jax.vmap(grip_height))(jnp.asarray(X)))
    starts = np.concatenate([x0[None], X0[:-1]])  # the stage costs' states x_0 … x_{T−1}
    scripted_cost = float(jnp.sum(jax.vmap(stage_cost, (0, 0, None, None))(starts, U0, 0, None)))
    report = {"optimised": True, "status": sol.status, "converged": bool(sol.converged),
              "iterations": int(sol.iterations), "cost": float(sol.cost), "max_violation": float(sol.max_violation),
              "final_error_rad": float(np.abs(X[-1, :7] - q_pre).max()),
              "final_speed_rad_s": float(np.abs(X[-1, nq:nq + 7]).max()),
              "min_clearance_m": float(heights.min() - (z_pre - APPROACH_CLEARANCE)),
              "scripted_cost": scripted_cost, "scripted_final_error_rad": float(np.abs(X0[-1, :7] - q_pre).max()),
              "dt": APPROACH_DT, "stages": T, "wall_time_s": float(sol.wall_time_s),
              "compile_time_s": float(sol.compile_time_s)}
    return ApproachPlan(X, U, APPROACH_DT, report)


@dataclass(frozen=True)
class GraspRun:
    """One simulated grasp: states (T + 1, nx), controls (T, nu), grip force per finger
    [N], lift_height [m] (the object's centre of mass above its start at the end of the
    hold), slip_mm (object motion relative to the hand over the hold [mm]), slip_deg (its
    rotation relative to the hand [deg]), hold_start_lift [m] (at the hold's start),
    diverged (non-finite or |qvel| > 1e3 somewhere: the other figures are then NaN)."""

    states: np.ndarray
    controls: np.ndarray
    grip_force: float
    lift_height: float
    hold_start_lift: float
    slip_mm: float
    slip_deg: float
    diverged: bool = False


@dataclass(frozen=True)
class GraspTask:
    """The built task: scene, params (pads stiffened), x0 (nx,) (arm at Menagerie's home,
    fingers open, bunny at rest), the grasp, waypoints (len(PHASES) + 1, 7): the arm's
    joint targets at the phase boundaries [rad], the config, and the optimised approach
    (:func:`optimise_approach`; None: the approach interpolates the waypoints)."""

    scene: object
    params: object
    x0: np.ndarray
    grasp: Grasp
    waypoints: np.ndarray
    config: GraspPandaConfig
    approach: ApproachPlan | None = None


#: the friction steepness [s/m] of every grasp-panda pair: the paper code's. With the default
#: (100) the stiff pads at h = 10 ms drove a finger 3.6 cm past its joint limit even with the
#: step's second constraint pass, and 200 or 300 dropped the bunny at 30 and 50 N (2026-11-27)
GRASP_FRICTION_STEEPNESS = 30.0


def grasp_scene(config: GraspPandaConfig, contact_model=None):
    """The scene (the hand, the 15 cm, 0.25 kg bunny at rest at (0.5, 0) on the table), its
    params (pads stiffened) and x0 = [qpos, qvel] (nx,): the arm at Menagerie's home, the
    fingers open. contact_model: None for the config's, a name ("centroid", "per_sample")
    with :data:`GRASP_FRICTION_STEEPNESS`, or a contact model instance used as it is."""
    spec = hand_spec()
    add_ground(spec)
    bunny = load_builtin("bunny").scaled(0.15).with_mass(0.25)
    start = np.array([0.5, 0.0, resting_height(bunny) + 0.0005])
    model = contact_model or config.contact_model
    if isinstance(model, str):
        model = contact_model_or_error(model, GRASP_FRICTION_STEEPNESS)
    scene = compose([DanoObject("bunny", bunny, tuple(start))], spec, dt=config.dt, name="grasp-panda",
                    contact_model=model)
    params = scene.default_params(sliding_friction=config.sliding_friction)
    for pair in scene.pair_names:
        if pair.endswith("_pad"):
            params = scene.set_param(params, "impact_spring", config.pad_spring, pair)
            params = scene.set_param(params, "impact_damper", config.pad_damper, pair)
    free = initial_state(scene, {"bunny": (tuple(start), (1, 0, 0, 0))})
    qpos = np.asarray(free.qpos, dtype=np.float64).copy()
    qpos[:7], qpos[7:9] = HOME, FINGERS_OPEN
    return scene, params, np.r_[qpos, np.zeros(scene.nv)]


def with_contact_model(task: GraspTask, contact_model) -> GraspTask:
    """The same task (grasp, waypoints, config) in a scene with another contact model (a name
    or an instance, as :func:`grasp_scene` takes it)."""
    scene, params, x0 = grasp_scene(task.config, contact_model)
    return dataclasses.replace(task, scene=scene, params=params, x0=x0)


def build(config: GraspPandaConfig = GraspPandaConfig()) -> GraspTask:
    """Build the scene, choose the grasp and solve the IK waypoints. Raises DanoError for
    settings out of range, a missing Panda, no grasp within the hand or an unreachable one."""
    scene, params, x0 = grasp_scene(config)
    ba = scene.qpos_adr[0]
    start = x0[ba:ba + 3]
    real = np.asarray(scene.samples.weights[0]) > 0  # (the scene pads the samples with zero weights)
    points = np.asarray(scene.samples.points[0], np.float64).T[real] + start  # identity orientation at rest
    normals = np.asarray(scene.samples.normals[0], np.float64).T[real]
    grasp = antipodal_grasp(points, normals, start, cone_deg=config.friction_cone_deg)
    m = scene.mj_model
    site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "grip")
    best = None
    for axis in (grasp.axis, -grasp.axis):  # the hand is symmetric: take the better-conditioned wrist
        q_grasp, e1 = grip_ik(m, site, grasp.center, axis, HOME)
        q_pre, e2 = grip_ik(m, site, grasp.center + [0, 0, 0.12], axis, q_grasp)
        if best is None or max(e1, e2) < best[2]:
            best = (q_grasp, q_pre, max(e1, e2))
    q_grasp, q_pre, err = best
    d = mujoco.MjData(m)
    d.qpos[:7] = q_grasp
    mujoco.mj_kinematics(m, d)
    q_lift, e3 = grip_ik(m, site, grasp.center + [0, 0, config.lift_height], None, q_grasp,
                         rotation=d.site_xmat[site].reshape(3, 3).copy())
    if max(err, e3) > 1e-3:
        raise DanoError(f"the Panda cannot reach the grasp at {np.round(grasp.center, 3).tolist()} "
                        f"(IK residual {max(err, e3):.3g})")
    waypoints = np.stack([HOME, q_pre, q_grasp, q_grasp, q_grasp, q_lift, q_lift])
    return GraspTask(scene, params, x0, grasp, waypoints, config)


def _schedules(task: GraspTask):
    dt = task.config.dt
    knots = np.cumsum([0.0] + [t for _, t in PHASES])
    steps = int(round(knots[-1] / dt))
    times = np.arange(steps) * dt
    q_ref = joint_reference(task.waypoints, times)
    # grip: open (−10 N) until the close phase, then ramp to the force over 0.3 s
    ramp = np.where(times < knots[3], -1.0, np.clip((times - knots[3]) / 0.3, 0.0, 1.0))
    # the object's weight at the grip site, fed forward from the lift on
    m = task.scene.mj_model
    d = mujoco.MjData(m)
    d.qpos[:7] = task.waypoints[-1]
    mujoco.mj_kinematics(m, d)
    mujoco.mj_comPos(m, d)
    jac = np.zeros((3, m.nv))
    mujoco.mj_jacSite(m, d, jac, None, mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "grip"))
    weight = float(task.scene.assets[0].mass) * 9.81
    tau_ff = jac[:, :7].T @ np.array([0.0, 0.0, weight])
    ff = np.where(times[:, None] >= knots[4], tau_ff[None], 0.0)
    qd_ref = np.zeros_like(q_ref)
    plan = task.approach
    if plan is not None:  # the approach tracks the optimised joint path and speeds, its torques fed forward
        first = times < knots[1]
        t_plan = np.arange(len(plan.states)) * plan.dt
        nq = plan.states.shape[1] // 2
        for k in range(7):
            q_ref[first, k] = np.interp(times[first], t_plan, plan.states[:, k])
            qd_ref[first, k] = np.interp(times[first], t_plan, plan.states[:, nq + k])
        stage = np.minimum((times[first] / plan.dt).astype(int), len(plan.controls) - 1)
        ff[first] = plan.controls[stage]
    return knots, q_ref, qd_ref, ramp, ff


def _grasp_rollouts(scene, params, x0, q_ref, qd_ref, ramp, ff, forces, newton: NewtonConfig):
    """States (F, T + 1, nx) and controls (F, T, nu) of the grasp with each grip force of
    ``forces`` (F,) [N] (the schedules: :func:`_schedules`)."""
    nq = scene.nq

    def one(force):
        grip = jnp.where(ramp < 0, -OPEN_FORCE, ramp * force)
        data = make_data(scene, x0[:nq], x0[nq:])

        def body(state, inp):  # MuJoCo's state carried: time and the constraint solver's warm start go on
            qr, qdr, g, tff = inp
            d = data.replace(**state)
            arm = arm_torque(d.qpos[:7], d.qvel[:7], qr, qdr, tff)
            u = jnp.concatenate([arm, g[None]]).astype(d.ctrl.dtype)
            d = step(scene, params, d.replace(ctrl=u), newton)
            return carried(d), (jnp.concatenate([d.qpos, d.qvel]), u)

        # the carry tied to the (batched) force: vmap's scan rule then batches the step once
        # instead of in rounds (tracing 7.4 -> 4.7 s for the grasp's 10 ms scene)
        _, (X, U) = jax.lax.scan(body, tied(carried(data), force), (q_ref, qd_ref, grip, ff))
        return jnp.concatenate([x0[None], X.astype(x0.dtype)]), U

    return jax.vmap(one)(forces)


# kept on disk per scene (dano._compiled): a later run loads the program instead of tracing it
_grasp_rollouts_compiled = cached_jit(_grasp_rollouts, static_argnums=(8,))


def simulate(task: GraspTask, forces, newton=None) -> tuple[list[GraspRun], float]:
    """Simulate the grasp with each grip force per finger in ``forces`` [N] (one compiled
    rollout, vmapped over the forces); newton: the step's NewtonConfig (default: the
    step's defaults). Returns (runs, compile time [s]: tracing, or loading the program
    from disk, and compiling)."""
    newton = newton or NewtonConfig()
    knots, q_ref, qd_ref, ramp, ff = _schedules(task)
    x0 = jnp.asarray(task.x0)
    f = jnp.asarray(forces, dtype=x0.dtype)
    since = time.time()
    X, U = _grasp_rollouts_compiled(task.scene, task.params, x0,
                                    *(jnp.asarray(a, x0.dtype) for a in (q_ref, qd_ref, ramp, ff)), f, newton)
    X, U = np.asarray(X), np.asarray(U)
    compile_s = compile_seconds(since)
    hold = int(round(knots[-2] / task.config.dt))
    return [_measure(task, X[k], U[k], float(v), hold) for k, v in enumerate(forces)], compile_s


def _measure(task: GraspTask, X, U, force: float, hold: int) -> GraspRun:
    m = task.scene.mj_model
    d = mujoco.MjData(m)
    hand = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "hand")
    bunny = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "bunny")
    ba = task.scene.qpos_adr[0]

    def in_hand(x):  # the bunny's position and orientation in the hand's frame
        d.qpos[:] = x[:m.nq]
        mujoco.mj_kinematics(m, d)
        R = d.xmat[hand].reshape(3, 3)
        return R.T @ (d.xpos[bunny] - d.xpos[hand]), R.T @ d.xmat[bunny].reshape(3, 3)

    z0 = task.x0[ba + 2]
    if not (np.all(np.isfinite(X)) and np.abs(X[:, m.nq:]).max() < 1e3):
        nan = float("nan")
        return GraspRun(X, U, force, nan, nan, nan, nan, diverged=True)
    p0, R0 = in_hand(X[hold])
    p1, R1 = in_hand(X[-1])
    cos = np.clip((np.trace(R0.T @ R1) - 1.0) / 2.0, -1.0, 1.0)
    return GraspRun(X, U, force, float(X[-1, ba + 2] - z0), float(X[hold, ba + 2] - z0),
                    float(1000.0 * np.linalg.norm(p1 - p0)), float(np.degrees(np.arccos(cos))))


def succeeded(run: GraspRun, config: GraspPandaConfig) -> bool:
    """Still lifted by ≥ 90 % of the goal at the end of the hold, slip within tolerance."""
    return bool(not run.diverged and run.lift_height >= 0.9 * config.lift_height
                and run.slip_mm <= config.slip_tolerance_mm)


def run_grasp(config: GraspPandaConfig, progress=None) -> tuple[GraspTask, GraspRun, dict]:
    """Build, choose the grasp, scan the grip forces (and compare the contact models).
    Returns (task, chosen run, report). The report has ``lift_height``, ``slip_mm``,
    ``slip_deg``, ``converged`` (a force in the scan lifted and held the object),
    ``grip_force``, ``wall_time_s``, ``compile_time_s``, the grasp and the scan,
    ``contact_models`` {model: {lift_height, hold_start_lift, slip_mm, slip_deg}} at the chosen
    force, and ``approach`` (:class:`ApproachPlan`'s report and executed_final_error_rad, or
    {"optimised": false})."""
    t0 = time.perf_counter()
    if progress is not None:
        progress(0, 4, "building the grasp task")
    task = build(config)
    approach = {"optimised": False}
    compile_s = 0.0
    if config.optimise_approach:
        if progress is not None:
            progress(1, 4, "optimising the approach (iLQR)")
        task = dataclasses.replace(task, approach=optimise_approach(task))
        approach = dict(task.approach.report)
        compile_s += approach["compile_time_s"]
    if progress is not None:
        progress(2, 4, "simulating the grip-force scan")
    t1 = time.perf_counter()
    runs, scan_compile_s = simulate(task, config.grip_forces)
    compile_s += scan_compile_s
    scan_s = time.perf_counter() - t1 - scan_compile_s
    ok = [r for r in runs if succeeded(r, config)]
    chosen = min(ok, key=lambda r: r.grip_force) if ok else max(
        runs, key=lambda r: (np.nan_to_num(r.lift_height, nan=-1.0), -np.nan_to_num(r.slip_mm, nan=1e9)))
    models = {config.contact_model: _summary(chosen)}
    if config.compare_models:
        if progress is not None:
            progress(3, 4, "the other contact model")
        other = "per_sample" if config.contact_model == "centroid" else "centroid"
        other_runs, other_compile_s = simulate(with_contact_model(task, other), [chosen.grip_force])
        models[other] = _summary(other_runs[0])
        compile_s += other_compile_s
    if progress is not None:
        progress(4, 4, "done")
    g = task.grasp
    if not chosen.diverged:  # the executed approach (2 ms steps, PD on the plan, bunny and table present)
        end = int(round(PHASES[0][1] / config.dt))
        approach["executed_final_error_rad"] = float(np.abs(chosen.states[end, :7] - task.waypoints[1]).max())
    report = {
        "task": config.task, "lift_height": chosen.lift_height, "hold_start_lift": chosen.hold_start_lift,
        "slip_mm": chosen.slip_mm, "slip_deg": chosen.slip_deg, "converged": bool(ok),
        "status": "lifted and held" if ok else "no force in the scan lifted and held the object",
        "grip_force": chosen.grip_force, "contact_model": config.contact_model,
        "grasp": {"center": g.center.tolist(), "axis": g.axis.tolist(), "width": g.width,
                  "torque_arm": g.torque_arm, "candidates": g.candidates},
        "scan": [{"grip_force": r.grip_force, **_summary(r), "success": succeeded(r, config)} for r in runs],
        "contact_models": models, "scan_time_s": scan_s, "wall_time_s": time.perf_counter() - t0,
        "compile_time_s": compile_s, "dt": config.dt, "hold_s": PHASES[-1][1],
        "optimised": "grasp pose (antipodal search), closing force (scan)" + (
            " and approach (constrained iLQR)" if config.optimise_approach else "; approach scripted (PD on IK poses)"),
        "approach": approach,
    }
    return task, chosen, report


def _summary(r: GraspRun) -> dict:
    return {"lift_height": r.lift_height, "hold_start_lift": r.hold_start_lift, "slip_mm": r.slip_mm,
            "slip_deg": r.slip_deg, "diverged": r.diverged}

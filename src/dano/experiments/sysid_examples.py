"""Built-in identification problems: the paper's real soap video, the bunny pushes, the
ContactNets cube tosses, and coverage studies of the defaults."""

from __future__ import annotations

import dataclasses
import functools
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from .._jax_setup import enable_float64
from ..asset import build
from ..contact import CONTACT_MODELS
from ..data import builtin_file, load_builtin
from ..errors import DanoError, FileFormatError
from ..fields import BoxField
from ..pose import normalize_quat, quat_error, quat_multiply, rotate, rotvec_to_quat
from ..sim import State, rollout, rollout_arrays
from ..sim.dynamics import model_with_params, moments_of_inertia, second_moments
from ..sim.scene import DanoObject, add_ground, compose
from ..sim.scenes import resting_height
from ..sysid.config import solver_options
from ..sysid.outputs import estimates_report
from ..sysid.problem import FitParameter, Observation, SEGMENT_NUISANCE_PREFIXES, SysIdProblem, Weights
from .._threads import side_by_side
from ..sysid.solve import identify, scan_costs
from ..sysid.uncertainty import cramer_rao

# ../shared/README.md: the soap video is 120 frames/s; the paper Froude-scaled time by
# sqrt(15.342) because its collider is 15.342x larger than the real soap.
SOAP_FPS = 120.0
SOAP_FROUDE = np.sqrt(15.342)
SOAP_FRAME_DT = SOAP_FROUDE / SOAP_FPS  # 0.03264 s of simulation per video frame
#: paper's mapping from the NeRF world frame to its simulation frame (a rotation vector [rad])
SOAP_MAP_ROTVEC = 0.39 * np.array([1.0, -1.0, 0.0]) / np.sqrt(2.0)
SOAP_MAP_OFFSET = np.array([0.0, 0.0, 1.2])
SOAP_MAP_SCALE = 1.0 / 3.0


def soap_poses(length_scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """The real soap trajectory in the paper's simulation frame: (time (33,) [s], poses (33, 7)).

    Positions: p_sim = R·(p − p₀ + [0, 0, 1.2])/3 with R a 0.39 rad rotation about
    (1, −1, 0)/√2 (the paper's mapping: the table becomes z = 0). ``length_scale`` scales
    the displacements (a different assumed real length per scene unit). Orientation: the
    tracked (constant) orientation composed with R. Time: frame k at k·√15.342/120 s.
    """
    data = np.loadtxt(builtin_file("soap_pose_traj.csv").open(), delimiter=",")
    p, q = data[:3].T, data[3:].T
    turn = rotvec_to_quat(SOAP_MAP_ROTVEC)
    pos = rotate(turn, p - p[0] + SOAP_MAP_OFFSET) * SOAP_MAP_SCALE
    pos = pos[0] + length_scale * (pos - pos[0])
    quat = quat_multiply(turn, normalize_quat(q))
    quat *= np.sign(quat[:, :1])
    return np.arange(len(pos)) * SOAP_FRAME_DT, np.concatenate([pos, quat], axis=1)


def _soap_scene(substeps: int):
    return _soap_scene_cached(substeps, bool(jax.config.jax_enable_x64))


@functools.lru_cache(maxsize=4)
def _soap_scene_cached(substeps: int, x64: bool):
    """The soap on the table (one scene per substep count: problems at other length scales
    share its compiled residual; each observation sets the initial pose)."""
    soap = load_builtin("bluesoap")
    _, poses = soap_poses(1.0)
    return compose([DanoObject("soap", soap, poses[0, :3], poses[0, 3:])], dt=SOAP_FRAME_DT / substeps, name="soap")


def soap_problem(length_scale: float = 1.0, substeps: int = 1, initial_friction: float = 0.3) -> SysIdProblem:
    """Identify the sliding friction of the real soap (paper §VI-A) from its video track.

    Unknowns: the sliding friction of the soap/ground pair (initial guess
    ``initial_friction``, bounds [0, 2]) and, as nuisance, the initial horizontal
    velocity. Residuals: horizontal positions only (weights x, y: 1, z: 0; orientation
    0): only translation was tracked, and the tracked height is noise around the resting
    height. The observed heights are shifted by a constant so that the soap starts resting
    on the table (its tracked point is not its centre of mass). The sliding drag is 0, as
    in the paper authors' own soap script (a Coulomb fit); the other contact parameters are
    the paper's defaults.
    """
    scene = _soap_scene(substeps)
    time, poses = soap_poses(length_scale)
    z_rest = resting_height(scene.assets[0], poses[0, 3:])
    poses = poses.copy()
    poses[:, 2] += z_rest - poses[0, 2]
    obs = Observation(time=time, poses={"soap": poses}, name="soap_pose_traj.csv")
    return SysIdProblem(scene, [obs], [FitParameter("sliding_friction", initial_friction, 0.0, 2.0)],
                        weights=Weights(position=(1.0, 1.0, 0.0), rotation=0.0), substeps=substeps,
                        fit_velocity="xy", base_params=scene.default_params(sliding_drag=0.0))


def pusher_scene(bunny=None, dt: float = 0.01, kp: float = 500.0, kv: float = 140.0):
    """The paper's interactive-perception set-up: the paper bunny on the ground and a
    floating sphere (radius 0.25, mass 10) on three slide joints ``pusher_x/y/z`` driven by
    position actuators (PD: F = kp·(target − x) − kv·ẋ, gravity compensated). The sphere
    touches only the bunny (DANO contact), not the ground."""
    bunny = bunny or load_builtin("bunny")
    spec = mujoco.MjSpec()
    add_ground(spec)
    body = spec.worldbody.add_body(name="pusher", pos=[0, 0, 0], gravcomp=1.0)
    for axis, vec in zip("xyz", np.eye(3)):
        body.add_joint(name=f"pusher_{axis}", type=mujoco.mjtJoint.mjJNT_SLIDE, axis=list(vec))
        spec.add_actuator(name=f"pusher_{axis}", target=f"pusher_{axis}", trntype=mujoco.mjtTrn.mjTRN_JOINT,
                          gaintype=mujoco.mjtGain.mjGAIN_FIXED, gainprm=[kp] + [0] * 9,
                          biastype=mujoco.mjtBias.mjBIAS_AFFINE, biasprm=[0, -kp, -kv] + [0] * 7)
    body.add_geom(name="pusher", type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[0.25, 0, 0], mass=10.0, contype=2,
                  conaffinity=2, rgba=[0.3, 0.5, 0.9, 1])
    z = resting_height(bunny)
    return compose([DanoObject("bunny", bunny, (0, 0, z))], spec, dt=dt, name="bunny-pushes"), z


def push_observations(scene, z_bunny: float, params, num_pushes: int = 10, duration: float = 2.0,
                      position_noise: float = 0.0, rotation_noise_deg: float = 0.0, seed: int = 0,
                      rest_frames: int = 20, push_height: float = 0.3):
    """Simulate ``num_pushes`` pushes of the bunny by the sphere under ``params`` (the hidden
    ground truth) and return them as :class:`Observation` s of the bunny's pose and the
    sphere's position, with optional Gaussian noise (position [m], rotation angle [deg]).

    Push k approaches from the direction 2πk/N with a lateral offset, along a straight
    target line through the bunny at the sphere-centre height ``push_height`` [m] over
    ``duration`` s. Bunny and sphere are at rest for the
    first ``rest_frames`` frames (the sphere reaches the bunny after about 0.35 s): the
    observations say so, and the initial state is averaged over them."""
    rng = np.random.default_rng(seed)
    dt = scene.dt
    steps = int(round(duration / dt))

    pj = [int(scene.mj_model.jnt_qposadr[mujoco.mj_name2id(scene.mj_model, mujoco.mjtObj.mjOBJ_JOINT, f"pusher_{a}")])
          for a in "xyz"]  # the sphere's slide joints (actuated in this order)
    b = scene.qpos_adr[scene.dano_index("bunny")]
    # let the bunny settle on the ground first (sphere parked far away)
    settle = scene.qpos0
    settle[pj] = [5.0, 5.0, 0.3]
    settle[b : b + 7] = [0, 0, z_bunny, 1, 0, 0, 0]
    hold = jnp.tile(jnp.asarray(settle[pj]), (200, 1))
    rest = np.asarray(rollout_arrays(scene, State(jnp.asarray(settle), jnp.zeros(scene.nv)), hold, params, 200)[0][-1])
    t = np.arange(steps + 1) * dt
    obs = []
    for k in range(num_pushes):
        ang = 2 * np.pi * k / num_pushes
        d = np.array([np.cos(ang), np.sin(ang), 0.0])
        side = np.array([-d[1], d[0], 0.0]) * 0.15 * np.sin(3 * ang + 0.5)
        start = -0.95 * d + side + [0, 0, push_height]
        end = 0.6 * d + side + [0, 0, push_height]
        s = np.clip(t[:-1] / (0.8 * duration), 0, 1)
        targets = start + (end - start) * (3 * s**2 - 2 * s**3)[:, None]
        qpos0 = rest.copy()
        qpos0[pj] = start
        qpos, _, _ = rollout_arrays(scene, State(jnp.asarray(qpos0), jnp.zeros(scene.nv)), jnp.asarray(targets),
                                    params, steps)
        qpos = np.asarray(qpos)
        bunny = qpos[:, b : b + 7].copy()
        pusher = qpos[:, pj].copy()
        if position_noise:
            bunny[:, :3] += rng.normal(0, position_noise, bunny[:, :3].shape)
            pusher += rng.normal(0, position_noise, pusher.shape)
        if rotation_noise_deg:
            noise = rotvec_to_quat(rng.normal(0, np.radians(rotation_noise_deg) / np.sqrt(3), (len(t), 3)))
            bunny[:, 3:] = quat_multiply(normalize_quat(bunny[:, 3:]), noise)
        obs.append(Observation(time=t, poses={"bunny": bunny},
                               joints={"pusher_x": pusher[:, 0], "pusher_y": pusher[:, 1], "pusher_z": pusher[:, 2]},
                               qvel0=np.zeros(scene.nv), controls=targets, name=f"push {k}", rest_frames=rest_frames,
                               settle_steps=50))
    return obs


#: hidden ground truth and the distant initial guess of the bunny experiment
PUSH_TRUTH = {"alpha": 0.13, "sliding_friction": 0.35}
PUSH_GUESS = {"alpha": 0.05, "sliding_friction": 0.8}


def push_problem(position_noise: float = 0.0, rotation_noise_deg: float = 0.0, num_pushes: int = 10,
                 seed: int = 0) -> SysIdProblem:
    """The paper's §VI-A bunny experiment: identify the bunny's mass scale α and its sliding
    friction on the ground from ``num_pushes`` pushes with known PD targets, observing only
    the bunny's pose and the sphere's position. Truth α = 0.13, μ = 0.35; guess α = 0.05,
    μ = 0.8. Residuals are weighted by the inverse noise levels (1 mm : 0.5°)."""
    scene, z = pusher_scene()
    pair = "bunny/ground"
    truth = scene.set_param(scene.default_params(), "sliding_friction", PUSH_TRUTH["sliding_friction"], pair)
    truth = scene.set_param(truth, "alpha", PUSH_TRUTH["alpha"], "bunny")
    obs = push_observations(scene, z, truth, num_pushes, position_noise=position_noise,
                            rotation_noise_deg=rotation_noise_deg, seed=seed)
    params = [FitParameter("alpha", PUSH_GUESS["alpha"], 0.01, 1.0, target="bunny"),
              FitParameter("sliding_friction", PUSH_GUESS["sliding_friction"], 0.0, 2.0, target=pair)]
    w_rot = (1e-3 / np.radians(0.5)) ** 2
    return SysIdProblem(scene, obs, params, weights=Weights((1.0, 1.0, 1.0), w_rot, 1.0),
                        base_params=scene.default_params())  # the data's world: the paper's drag


#: the dynamics-refinement variant: the bunny's centre of mass off by 5 % of its size and its
#: principal moments by 10 % (+, −, +) from the field's estimates
PUSH_COM_ERROR = 0.05
PUSH_MOMENT_ERROR = (0.10, -0.10, 0.10)


def second_moment_scale_for(base_inertia: np.ndarray, moment_factors) -> np.ndarray:
    """(3,) factors on the principal second moments Σ that turn principal moments
    ``base_inertia`` (3,) into ``base_inertia * moment_factors``. Raises ValueError if that
    inertia is not physical (a triangle inequality fails)."""
    target = second_moments(np.asarray(base_inertia) * np.asarray(moment_factors))
    if np.any(target < 0):
        raise ValueError(f"moments {np.asarray(base_inertia) * moment_factors} violate a triangle inequality")
    return target / second_moments(np.asarray(base_inertia))


def push_dynamics_problem(position_noise: float = 0.0, rotation_noise_deg: float = 0.0, num_pushes: int = 10,
                          seed: int = 0, push_height: float = 0.3):
    """The bunny pushes with the object's own dynamics unknown: the hidden truth has the
    bunny's centre of mass off the field's estimate by 5 % of its size (its largest extent)
    along (1, −1, 0.5)/1.5 and principal moments off by +10 %, −10 %, +10 %; α, friction, the
    centre-of-mass offset and the three second-moment scales are identified from α = 0.05,
    μ = 0.8, no offset and unit scales. Returns (problem, truth dict: alpha,
    sliding_friction, com_offset (3,) [m], second_moment_scale (3,), size [m],
    principal_moments (3,) [kg m²] of the truth, base_moments (3,) [kg m²] of the guess).
    ``push_height``: the sphere centre's height along the pushes [m] (0.3: the paper's, at the
    bunny's centre of mass; higher pushes tip it and excite the roll and pitch moments)."""
    scene, z = pusher_scene()
    pair = "bunny/ground"
    asset = scene.assets[scene.dano_index("bunny")]
    size = float(np.ptp(asset.points, axis=0).max())
    offset = PUSH_COM_ERROR * size * np.array([1.0, -1.0, 0.5]) / 1.5
    base = np.asarray(scene.base_inertia)[0]
    scale = second_moment_scale_for(base, 1 + np.asarray(PUSH_MOMENT_ERROR))
    truth = scene.set_param(scene.default_params(), "sliding_friction", PUSH_TRUTH["sliding_friction"], pair)
    truth = scene.set_param(truth, "alpha", PUSH_TRUTH["alpha"], "bunny")
    for a in range(3):
        truth = scene.set_param(truth, f"com_offset_{'xyz'[a]}", offset[a], "bunny")
        truth = scene.set_param(truth, f"second_moment_scale_{'xyz'[a]}", scale[a], "bunny")
    obs = push_observations(scene, z, truth, num_pushes, position_noise=position_noise,
                            rotation_noise_deg=rotation_noise_deg, seed=seed, push_height=push_height)
    bound = 0.2 * size
    params = [FitParameter("alpha", PUSH_GUESS["alpha"], 0.01, 1.0, target="bunny"),
              FitParameter("sliding_friction", PUSH_GUESS["sliding_friction"], 0.0, 2.0, target=pair)]
    params += [FitParameter(f"com_offset_{a}", 0.0, -bound, bound, target="bunny") for a in "xyz"]
    params += [FitParameter(f"second_moment_scale_{a}", 1.0, 0.25, 4.0, target="bunny") for a in "xyz"]
    w_rot = (1e-3 / np.radians(0.5)) ** 2
    # the start of each push is averaged over its noisy rest frames: its position and heading
    # are nuisance parameters (with them left out, the start's error biases the moments)
    problem = SysIdProblem(scene, obs, params, weights=Weights((1.0, 1.0, 1.0), w_rot, 1.0),
                           base_params=scene.default_params(), fit_position="xy" if position_noise else "",
                           fit_rotation="z" if rotation_noise_deg else "")
    body = scene.body_names.index("bunny")
    moments = np.asarray(model_with_params(scene, truth).body_inertia)[body] / PUSH_TRUTH["alpha"]
    return problem, {**PUSH_TRUTH, "com_offset": offset.tolist(), "second_moment_scale": scale.tolist(),
                     "size": size, "principal_moments": moments.tolist(), "base_moments": base.tolist()}


def dynamics_recovery(estimates: dict, truth: dict, covariance: np.ndarray | None = None) -> dict:
    """How well :func:`push_dynamics_problem`'s fit recovered the truth: centre-of-mass error
    as a fraction of the size (per axis and its norm), relative errors of the principal
    moments (3,), of α and of the friction. With ``covariance`` (n, n), of the parameters in
    ``estimates``' order (e.g. :func:`~dano.sysid.cramer_rao` at the truth), also their
    standard deviations on the same scales (``*_std``, the moments' by the delta method)."""
    labels = list(estimates)
    com_keys = [f"bunny:com_offset_{a}" for a in "xyz"]
    scale_keys = [f"bunny:second_moment_scale_{a}" for a in "xyz"]
    com = np.array([estimates[k] for k in com_keys])
    base = second_moments(np.asarray(truth["base_moments"]))
    moments = moments_of_inertia(base * np.array([estimates[k] for k in scale_keys]))
    com_err = (com - np.asarray(truth["com_offset"])) / truth["size"]
    truth_moments = np.asarray(truth["principal_moments"])
    out = {"com_error_of_size": com_err.tolist(), "com_error_norm_of_size": float(np.linalg.norm(com_err)),
           "moment_relative_error": (moments / truth_moments - 1).tolist(),
           "alpha_relative_error": estimates["bunny:alpha"] / truth["alpha"] - 1,
           "friction_relative_error": estimates["bunny/ground:sliding_friction"] / truth["sliding_friction"] - 1}
    if covariance is not None:
        cov = np.asarray(covariance)
        idx = lambda keys: [labels.index(k) for k in keys]  # noqa: E731
        G = np.stack([moments_of_inertia(base * e) for e in np.eye(3)], axis=1)  # the moments are linear in the scales
        s = idx(scale_keys)
        out["moment_relative_std"] = (np.sqrt(np.diag(G @ cov[np.ix_(s, s)] @ G.T)) / truth_moments).tolist()
        out["com_std_of_size"] = (np.sqrt(np.diag(cov)[idx(com_keys)]) / truth["size"]).tolist()
        a, f = idx(["bunny:alpha", "bunny/ground:sliding_friction"])
        out["alpha_relative_std"] = float(np.sqrt(cov[a, a]) / truth["alpha"])
        out["friction_relative_std"] = float(np.sqrt(cov[f, f]) / truth["sliding_friction"])
    return out


# ContactNets' acrylic cube (../shared/README.md): side 0.1048 m, 0.37 kg, 147 frames/s
CUBE_SIDE = 0.1048
CUBE_MASS = 0.37
CUBE_FRAME_DT = 0.0068


def contactnets_tosses(path, tosses: int) -> list[tuple[str, np.ndarray]]:
    """The first ``tosses`` tosses (sorted by number) of a ContactNets ``.npz``: arrays
    ``toss_<n>`` of shape (T, 13) per frame: orientation wxyz, position [m], angular
    velocity (body frame) [rad/s], linear velocity (world frame) [m/s].
    Raises FileFormatError for a file that is not such an archive, DanoError for too few tosses."""
    path = Path(path)
    try:
        with np.load(path) as z:
            names = sorted((k for k in z.files if k.startswith("toss_")), key=lambda k: int(k.split("_")[1]))
            arrays = [(k, np.asarray(z[k], dtype=np.float64)) for k in names[:tosses]]
    except FileNotFoundError:
        raise FileFormatError(f"{path}: no such file") from None
    except (OSError, ValueError) as exc:
        raise FileFormatError(f"{path}: not a ContactNets .npz archive ({exc})") from exc
    if len(names) < tosses:
        raise DanoError(f"{path}: {len(names)} tosses (arrays toss_<n>), {tosses} requested")
    for k, a in arrays:
        if a.ndim != 2 or a.shape[1] != 13 or len(a) < 3:
            raise FileFormatError(f"{path}: {k} must be (T >= 3, 13) per frame (quaternion, position, angular "
                                  f"and linear velocity), got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise FileFormatError(f"{path}: {k} holds non-finite values")
    return arrays


def cube_observation(name: str, a: np.ndarray) -> Observation:
    """A ContactNets toss (T, 13) as an :class:`Observation` of the DANO "cube" with its
    measured velocities (every frame: windows start from them; the first is qvel0)."""
    poses = np.column_stack([a[:, 4:7], a[:, 0:4]])
    velocities = np.column_stack([a[:, 10:13], a[:, 7:10]])  # linear (world), angular (body): MuJoCo's order
    return Observation(time=np.arange(len(a)) * CUBE_FRAME_DT, poses={"cube": poses}, qvel0=velocities[0],
                       velocities={"cube": velocities}, name=name)


def cube_scene(substeps: int = 2, contact_model: str = "centroid"):
    """An analytic-box DANO of the ContactNets cube (side 0.1048 m, 0.37 kg, 3000 samples)
    on the ground plane, h = frame interval / ``substeps``."""
    half = CUBE_SIDE / 2
    asset = build(BoxField((half, half, half), edge_width=0.002), mass=CUBE_MASS, num_samples=3000,
                  mesh_resolution=16, seed=0, name="contactnets_cube")
    return compose([DanoObject("cube", asset, (0, 0, half))], dt=CUBE_FRAME_DT / substeps, name="contactnets-cube",
                   contact_model=contact_model)


def contactnets_problem(path, tosses: int = 10, start: float = 0.3, substeps: int = 2,
                        contact_model: str = "centroid") -> tuple[SysIdProblem, list[Observation]]:
    """The ContactNets cube identification: sliding friction (from ``start``, in [0, 1.5]),
    impact spring (3e4, in [3e3, 3e5]) and damper (3e5, in [1e4, 3e6]) of the cube–ground
    pair and the table height, fitted on the even-numbered half of the first ``tosses``
    tosses (whole trajectories from their measured initial velocities); returns the problem
    and the held-out (odd) observations. Drag terms are off (the paper's default sliding drag
    0.1 would add a viscous law the data do not ask for); rotation residuals weigh 0.1 per
    rad² against 1 per m². Raises DanoError for fewer than 2 tosses or a bad start."""
    if tosses < 2:
        raise DanoError(f"--tosses must be at least 2 (half fitted, half held out), got {tosses}")
    if not 0.0 <= start <= 1.5:
        raise DanoError(f"--start must lie in the friction bounds [0, 1.5], got {start}")
    arrays = contactnets_tosses(path, tosses)
    obs = [cube_observation(k, a) for k, a in arrays]
    scene = cube_scene(substeps, contact_model)
    base = scene.default_params(sliding_drag=0.0)
    params = [FitParameter("sliding_friction", start, 0.0, 1.5), FitParameter("impact_spring", 3e4, 3e3, 3e5),
              FitParameter("impact_damper", 3e5, 1e4, 3e6)]
    problem = SysIdProblem(scene, obs[0::2], params, weights=Weights((1.0, 1.0, 1.0), 0.1), base_params=base,
                           substeps=substeps, fit_ground=True)
    return problem, obs[1::2]


def pose_errors(observations: list[Observation], simulated: list[np.ndarray]) -> dict:
    """Observed vs simulated poses of the DANO "cube": ``position_rms_mm`` (RMS of the
    centre-of-mass distance over all frames after the first), ``rotation_rms_deg`` (RMS of
    the rotation angle between observed and simulated orientation) and per trajectory.
    simulated: per observation, qpos (frames, nq) in the observations' frame."""
    pos_sq, rot_sq, per = [], [], []
    for obs, q in zip(observations, simulated):
        o = obs.poses["cube"]
        n = min(len(o), len(q))
        dp = np.linalg.norm(q[1:n, :3] - o[1:n, :3], axis=1)
        da = np.degrees(np.linalg.norm(quat_error(q[1:n, 3:7], o[1:n, 3:]), axis=1))
        pos_sq.append(dp**2)
        rot_sq.append(da**2)
        per.append({"name": obs.name, "position_rms_mm": 1e3 * float(np.sqrt(np.mean(dp**2))),
                    "rotation_rms_deg": float(np.sqrt(np.mean(da**2)))})
    return {"position_rms_mm": 1e3 * float(np.sqrt(np.mean(np.concatenate(pos_sq)))),
            "rotation_rms_deg": float(np.sqrt(np.mean(np.concatenate(rot_sq)))), "per_toss": per}


def prediction_errors(problem: SysIdProblem, observations: list[Observation], theta) -> dict:
    """:func:`pose_errors` of ``observations`` simulated from their measured initial states
    with the parameters θ of ``problem`` (same layout; ground height included)."""
    held = SysIdProblem(problem.scene, observations, problem.parameters, weights=problem.weights,
                        base_params=problem.base_params, substeps=problem.substeps, fit_ground=problem.fit_ground,
                        failure_substeps=problem.failure_substeps)
    return pose_errors(observations, held.simulate(np.asarray(theta)))


def contactnets_identify(path, tosses: int = 10, start: float = 0.3, scan: int = 6, starts: int = 2,
                         substeps: int = 2, contact_model: str = "centroid", bootstrap: int = 0):
    """Identify the ContactNets cube (:func:`contactnets_problem`) with a global start
    (``scan``: Sobol points over the three contact parameters' bounds, ``starts`` local
    solves), predict the held-out tosses, and compare with the best fixed friction on a
    grid (0.05, 0.10, …, 1.0; spring and damper at the paper's defaults, table at z = 0,
    chosen by the same fit cost). ``bootstrap`` > 0: also resample the fitted tosses this many
    times (:func:`dano.sysid.bootstrap`). Returns (problem, result, report) with ``report`` the
    JSON-able dict of ``dano sysid contactnets-cube --json``."""
    t0 = time.perf_counter()
    problem, held = contactnets_problem(path, tosses, start, substeps, contact_model)
    result = identify(problem, scan=scan, starts=starts, bootstrap_samples=bootstrap)
    problem = problem.as_identified(result)  # (the rollouts the answer came from)
    theta = np.asarray(result.estimates)
    fit_err = pose_errors(problem.observations, result.fitted)  # the fit's own rollouts, not simulated again
    held_err = prediction_errors(problem, held, theta)
    friction_only = SysIdProblem(problem.scene, problem.observations,
                                 [FitParameter("sliding_friction", start, 0.0, 1.5)], weights=problem.weights,
                                 base_params=problem.base_params, substeps=substeps)
    grid = np.round(np.arange(1, 21) * 0.05, 10)
    costs = scan_costs(friction_only, grid[:, None])
    best = float(grid[int(np.argmin(costs))])
    grid_err = prediction_errors(friction_only, held, [best])
    names = ("sliding_friction", "impact_spring", "impact_damper", "ground_height")
    report = {name: float(v) for name, v in zip(names, theta)}
    report.update({f"{name}_std": float(s) for name, s in zip(names, result.standard_errors)})
    if result.interval is not None:
        for name in names:
            if name in result.interval["lower"]:
                report[f"{name}_lower"], report[f"{name}_upper"] = (result.interval["lower"][name],
                                                                    result.interval["upper"][name])
    report.update({
        "interval": result.interval, "noise_estimate": result.noise, "identifiability": result.identifiability,
        "heldout_position_rms_mm": held_err["position_rms_mm"],
        "heldout_rotation_rms_deg": held_err["rotation_rms_deg"],
        "fit_position_rms_mm": fit_err["position_rms_mm"], "fit_rotation_rms_deg": fit_err["rotation_rms_deg"],
        "grid_best_friction": best,
        "grid_heldout_position_rms_mm": grid_err["position_rms_mm"],
        "grid_heldout_rotation_rms_deg": grid_err["rotation_rms_deg"],
        "grid": {"friction": grid.tolist(), "cost": [float(c) for c in costs]},
        "num_tosses": tosses, "fitted_tosses": [o.name for o in problem.observations],
        "heldout_tosses": [o.name for o in held], "start": start, "scan": scan, "starts": starts,
        "substeps": substeps, "contact_model": contact_model, "cost": result.final_cost,
        "wall_time_s": time.perf_counter() - t0, "compile_time_s": result.compile_time_s,
        "heldout_per_toss": held_err["per_toss"], "warnings": list(result.warnings),
        "notes": list(result.notes), "failure_substeps": result.failure_substeps, "bootstrap": result.bootstrap,
    })
    return problem, result, report


# ------------------------------------------------------------------ bootstrap coverage
G = 9.81


def analytic_slides(seed: int, box_half_height: float, trajectories: int = 8, frames: int = 20,
                    noise: float = 0.003, friction: float = 0.45, frame_dt: float = 0.01) -> list[Observation]:
    """Coulomb slides of a flat box on the ground, from the closed form s(t) = v₀t − ½μgt²
    (not simulated by dano): ``trajectories`` slides at speeds in [1.6, 2.4] m/s in random
    directions (seeded), x and y observed with Gaussian noise of ``noise`` [m] in every frame,
    the first included (so each trajectory's initial pose is off by its own noise, an error
    shared by all its frames). Initial velocities are given (qvel0)."""
    rng = np.random.default_rng(seed)
    t = np.arange(frames) * frame_dt
    out = []
    for k in range(trajectories):
        speed, heading = rng.uniform(1.6, 2.4), rng.uniform(0.0, 2 * np.pi)
        s = speed * t - 0.5 * friction * G * t**2
        poses = np.zeros((frames, 7))
        poses[:, 0], poses[:, 1] = s * np.cos(heading), s * np.sin(heading)
        poses[:, 2], poses[:, 3] = box_half_height, 1.0
        poses[:, :2] += rng.normal(0.0, noise, (frames, 2))
        qvel0 = np.r_[speed * np.cos(heading), speed * np.sin(heading), 0.0, 0.0, 0.0, 0.0]
        out.append(Observation(time=t, poses={"box": poses}, qvel0=qvel0, name=f"slide_{k}"))
    return out


def bootstrap_coverage(seeds: int = 20, samples: int = 100, trajectories: int = 8, noise: float = 0.003,
                       friction: float = 0.45, level: float = 0.95) -> dict:
    """How often intervals at ``level`` cover the true sliding friction over ``seeds`` noisy
    data sets of :func:`analytic_slides` (a 10 × 10 × 5 cm box DANO, 400 samples, 4 substeps
    per 10 ms frame): the bootstrap over trajectories (``samples`` refits) and the
    σ²(JᵀJ)⁻¹ interval. Returns {"seeds", "bootstrap_covers", "jacobian_covers", "per_seed":
    [{"seed", "estimate", "standard_error", "lower", "upper", "bootstrap_std"}], ...}."""
    from scipy.stats import norm

    enable_float64()
    asset = build(BoxField((0.1, 0.1, 0.05), edge_width=0.002), mass=1.0, num_samples=400, mesh_resolution=16,
                  name="box")
    scene = compose([DanoObject("box", asset, (0, 0, 0.05))], dt=0.0025)
    per_seed = []
    for seed in range(seeds):
        obs = analytic_slides(seed, 0.05, trajectories, noise=noise, friction=friction)
        problem = SysIdProblem(scene, obs, [FitParameter("sliding_friction", 0.3, 0.0, 2.0)],
                               weights=Weights((1.0, 1.0, 0.0), 0.0), substeps=4,
                               base_params=scene.default_params(sliding_drag=0.0))
        r = identify(problem, bootstrap_samples=samples, seed=seed)
        b = r.bootstrap
        per_seed.append({"seed": seed, "estimate": float(r.estimates[0]), "standard_error": float(r.standard_errors[0]),
                         "lower": b["lower"][0], "upper": b["upper"][0], "bootstrap_std": b["std"][0],
                         "percentile_lower": b["percentile_lower"][0], "percentile_upper": b["percentile_upper"][0]})
    z = norm.ppf(0.5 + level / 2)
    covers = lambda lo, hi: int(sum(s[lo] <= friction <= s[hi] for s in per_seed))  # noqa: E731
    return {"seeds": seeds, "samples": samples, "trajectories": trajectories, "noise_m": noise, "friction": friction,
            "level": level, "bootstrap_covers": covers("lower", "upper"),
            "percentile_covers": covers("percentile_lower", "percentile_upper"),
            "jacobian_covers": int(sum(abs(s["estimate"] - friction) <= z * s["standard_error"] for s in per_seed)),
            "per_seed": per_seed}


def interval_coverage(seeds: int = 100, trajectories: int = 4, noise: float = 0.002, friction: float = 0.45,
                      level: float = 0.95, frames: int = 20) -> dict:
    """Calibration of :func:`~dano.sysid.identify`'s default interval: how often it covers the
    true sliding friction over ``seeds`` noisy data sets made by dano itself (so the model is
    right and only the noise differs): a 10 × 10 × 5 cm box DANO (400 samples) sliding from
    ``trajectories`` known initial velocities (speeds in [1.6, 2.4] m/s, random directions,
    seeded as :func:`analytic_slides`), simulated at ``friction`` with 2 substeps per 10 ms
    frame, x and y observed with Gaussian noise of ``noise`` [m] in every frame (the first
    included: each trajectory's initial position is fitted as nuisance, ``fit_position="xy"``).
    Identification from μ = 0.3 in [0, 2] with every default. Returns {"seeds", "covers",
    "coverage", "per_seed": [{"seed", "estimate", "lower", "upper", "method"}], "warnings"
    (how many seeds warned), ...}."""
    enable_float64()
    asset = build(BoxField((0.1, 0.1, 0.05), edge_width=0.002), mass=1.0, num_samples=400, mesh_resolution=16,
                  name="box")
    scene = compose([DanoObject("box", asset, (0, 0, 0.05))], dt=0.005)
    truth = scene.default_params(sliding_friction=friction, sliding_drag=0.0)
    clean = []
    for o in analytic_slides(0, 0.05, trajectories, frames=frames, noise=0.0, friction=friction):
        traj = rollout(scene, State(jnp.asarray(o.poses["box"][0]), jnp.asarray(o.qvel0)), None, truth,
                       2 * (frames - 1))
        clean.append((o, np.asarray(traj.qpos)[::2]))
    per_seed, warned = [], 0
    for seed in range(seeds):
        rng = np.random.default_rng(1000 + seed)
        obs = []
        for o, q in clean:
            poses = q.copy()
            poses[:, :2] += rng.normal(0.0, noise, (frames, 2))
            obs.append(Observation(time=o.time, poses={"box": poses}, qvel0=o.qvel0, name=o.name))
        problem = SysIdProblem(scene, obs, [FitParameter("sliding_friction", 0.3, 0.0, 2.0)],
                               weights=Weights((1.0, 1.0, 0.0), 0.0), substeps=2, fit_position="xy")
        r = identify(problem, level=level, seed=seed)
        label = "sliding_friction"
        warned += bool(r.warnings)
        per_seed.append({"seed": seed, "estimate": float(r.estimates[0]), "lower": r.interval["lower"][label],
                         "upper": r.interval["upper"][label],
                         "profile": r.interval["profile_likelihood"][label],
                         "bootstrap": None if r.interval["bootstrap"] is None else
                         [r.interval["bootstrap"][label]["lower"], r.interval["bootstrap"][label]["upper"]]})
    covers = int(sum(s["lower"] <= friction <= s["upper"] for s in per_seed))
    prof = int(sum(s["profile"][0] <= friction <= s["profile"][1] for s in per_seed))
    boot = [s for s in per_seed if s["bootstrap"] is not None]
    return {"seeds": seeds, "trajectories": trajectories, "noise_m": noise, "friction": friction, "level": level,
            "covers": covers, "coverage": covers / seeds, "profile_covers": prof,
            "bootstrap_covers": int(sum(s["bootstrap"][0] <= friction <= s["bootstrap"][1] for s in boot)),
            "seeds_with_warnings": warned, "per_seed": per_seed}


# ------------------------------------------------------------------ the built-in identifications
def _push_dynamics_bound(problem: SysIdProblem, truth: dict) -> dict:
    """The Cramér–Rao standard deviations (:func:`~dano.sysid.cramer_rao`) of bunny-dynamics'
    estimates at the truth (nuisance offsets at zero) under the paper's noise, whatever noise
    the data carry; ``start_fitted`` says whether the pushes' starts are nuisance parameters
    (with the noise-free data they are not, and the bound is then the one for known starts).
    A bound that cannot be computed is reported as {"error": why}, not raised: the fit stands."""
    value = {"alpha": truth["alpha"], "sliding_friction": truth["sliding_friction"],
             **{f"com_offset_{a}": truth["com_offset"][k] for k, a in enumerate("xyz")},
             **{f"second_moment_scale_{a}": truth["second_moment_scale"][k] for k, a in enumerate("xyz")}}
    theta = np.array([value[p.name] for p in problem.parameters] + [0.0] * (problem.num_parameters
                                                                             - len(problem.parameters)))
    out = {"noise": {"position_m": 1e-3, "rotation_deg": 0.5, "pusher_m": 1e-3},
           "start_fitted": any(lab.startswith(SEGMENT_NUISANCE_PREFIXES) for lab in problem.labels)}
    try:
        cov = cramer_rao(problem, theta, problem.residual_noise(1e-3, 0.5, 1e-3))
    except DanoError as exc:
        return {**out, "error": str(exc)}
    bound = dynamics_recovery(dict(zip(problem.labels, theta)), truth, cov)
    return {**out, **{k: v for k, v in bound.items() if "_std" in k}}


def soap_sensitivity(friction: float) -> dict:
    """The soap's friction identified again with the assumed real length per scene unit
    scaled by 0.9 and 1.1, from ``friction`` (no scan, no profile: the sensitivity of the
    local answer), and the elasticity d ln μ / d ln L. The two fits stop when the cost changes
    by less than 1e-6 of itself (``ftol``, stricter than the main fit's statistical one,
    2e-3/(m − n) ≈ 3e-5 here, for a difference of two fits): that moves their friction by
    about 3e-6, 3000 times less than its standard error (0.0095), in half the evaluations of
    1e-8."""
    scales = (0.9, 1.1)  # the two identifications side by side (:func:`dano._threads.side_by_side`)
    fits = side_by_side([lambda s=s: identify(soap_problem(length_scale=s, substeps=4, initial_friction=friction),
                                              scan=0, profile_points=0, ftol=1e-6) for s in scales])
    for fit in fits:
        if isinstance(fit, DanoError):
            raise fit
    sens = {str(s): float(fit.estimates[0]) for s, fit in zip(scales, fits)}
    return {
        "sliding_friction_at_length_scale": {"0.9": sens["0.9"], "1.0": friction, "1.1": sens["1.1"]},
        "elasticity_dlnmu_dlnL": float((np.log(sens["1.1"]) - np.log(sens["0.9"])) / (np.log(1.1) - np.log(0.9))),
        "note": "friction is identified together with the assumed real length per scene unit; "
                "scaling all displacements by L scales the identified friction by about L^elasticity",
    }


def run_example(name: str, *, jacobian: str | None = None, noise: bool = True,
                sensitivity: bool = True, defer_studies: bool = False) -> tuple[SysIdProblem, object, dict]:
    """Run a built-in identification: ``soap`` (the paper's real soap video), ``bunny-pushes``
    (α and friction from 10 simulated pushes) or ``bunny-dynamics`` (the same with the centre
    of mass and inertia unknown). Returns (problem, result, {"report", "config"}) as
    :func:`dano.sysid.config.run`; the report adds, for the soap, ``length_scale_sensitivity``
    and ``paper_reference``; for the pushes, ``truth`` (and for bunny-dynamics ``recovery``).
    ``noise``: the paper's pose noise (1 mm, 0.5°) on the pushes' observations.
    ``sensitivity``: the soap's length-scale study (:func:`soap_sensitivity`: two more
    identifications beside the result; False leaves it and its key out).
    ``defer_studies``: the studies beside the result are not run but returned, as
    {"studies": {report key: function of no argument}} in the third element, for the caller
    to run (the command line runs them while it draws the fit) and add to the report.
    Raises DanoError for another name."""
    extra: dict = {}
    noise_levels = (1e-3, 0.5) if noise else (0.0, 0.0)
    if name == "soap":
        problem, solver = soap_problem(substeps=4), {"jacobian": "ad", "horizons": ()}  # default scan, profile
        resolved = {"example": "soap", "substeps": 4, "length_scale": 1.0,
                    "data": "soap_pose_traj.csv (real video, 120 fps) + bluesoap collider (paper)",
                    "time_scale": "Froude: sqrt(15.342) s of simulation per s of video",
                    "fit": ["sliding_friction (soap/ground)", "initial velocity x, y (nuisance)"],
                    "weights": {"position": [1, 1, 0], "rotation": 0}, "sensitivity": sensitivity}
    elif name == "bunny-dynamics":
        problem, truth = push_dynamics_problem(*noise_levels)
        # continuation from the distant guess, no scan; no profiles (8 parameters: minutes more; its
        # uncertainty is the Cramér–Rao bound reported beside it)
        solver = {"jacobian": "ad", "horizons": (0.4,), "max_iterations": 100, "scan": 0, "profile_points": 0}
        resolved = {"example": "bunny-dynamics", "truth": truth, "initial_guess": PUSH_GUESS,
                    "noise": {"position_m": noise_levels[0], "rotation_deg": noise_levels[1]}, "pushes": 10,
                    "horizons": [0.4]}
        extra["truth"] = truth
    elif name == "bunny-pushes":
        problem, solver = push_problem(*noise_levels), {"jacobian": "ad", "horizons": (0.4,), "scan": 0}
        resolved = {"example": "bunny-pushes", "truth": PUSH_TRUTH, "initial_guess": PUSH_GUESS,
                    "noise": {"position_m": noise_levels[0], "rotation_deg": noise_levels[1]}, "pushes": 10,
                    "horizons": [0.4]}
        extra["truth"] = PUSH_TRUTH
    else:
        raise DanoError(f"unknown identification example {name!r}: one of soap, bunny-pushes, bunny-dynamics")
    if jacobian is not None:
        solver["jacobian"] = jacobian
    resolved["solver"] = {**solver, "method": "scipy.optimize.least_squares (trf), bounds"}
    result = identify(problem, **solver_options(solver))
    problem = problem.as_identified(result)  # (the rollouts the answer came from)
    report = {**estimates_report(result), **extra}
    if name == "bunny-dynamics":
        report["recovery"] = dynamics_recovery(dict(zip(result.labels, result.estimates)), extra["truth"])
        report["recovery"]["cramer_rao"] = _push_dynamics_bound(problem, extra["truth"])
    studies = {}
    if name == "soap":
        if sensitivity:
            studies["length_scale_sensitivity"] = functools.partial(soap_sensitivity, report["sliding_friction"])
        report["paper_reference"] = {"video_identification": 0.61, "tilted_plane": 0.75}
    if defer_studies:
        return problem, result, {"report": report, "config": resolved, "studies": studies}
    report.update({key: study() for key, study in studies.items()})
    return problem, result, {"report": report, "config": resolved}


@dataclasses.dataclass(frozen=True)
class ContactNetsConfig:
    """``contactnets-cube``: real cube tosses (ContactNets), friction, impact spring and
    damper and the table height fitted on the even tosses, the odd ones predicted."""

    data: Path
    """The ContactNets tosses: a .npz of ``toss_<n>`` arrays, (T, 13) each (not shipped with
    dano, e.g. shared/data/real/contactnets_cube/tosses_100_299.npz)."""
    tosses: int = 10
    """Use the first this many tosses (even ones fitted, odd ones held out), 2 to 200."""
    start: float = 0.3
    """Initial guess of the sliding friction."""
    contact_model: str = "centroid"
    """centroid (the paper's) or per_sample."""
    bootstrap: int = 0
    """Also refit this many resamples of the fitted tosses (0 or 2 to 10,000) for a 95 % interval."""

    def __post_init__(self):
        if not 2 <= self.tosses <= 200:
            raise DanoError(f"--tosses must be 2 to 200, got {self.tosses}")
        if self.contact_model not in CONTACT_MODELS:
            raise DanoError(f"unknown --contact-model {self.contact_model!r}; available: {', '.join(CONTACT_MODELS)}")
        if self.bootstrap and not 2 <= self.bootstrap <= 10_000:
            raise DanoError(f"--bootstrap must be 0 or 2 to 10000 resamples, got {self.bootstrap}")


def run_contactnets(config: ContactNetsConfig):
    """Run ``contactnets-cube`` (:func:`contactnets_identify`). Returns (problem, result,
    {"report", "config"}); ``config`` reruns it (``dano sysid config.json``)."""
    problem, result, report = contactnets_identify(config.data, config.tosses, config.start,
                                                   contact_model=config.contact_model, bootstrap=config.bootstrap)
    resolved = {"example": "contactnets-cube", "data": str(Path(config.data).resolve()), "tosses": config.tosses,
                "start": config.start, "contact_model": config.contact_model, "bootstrap": config.bootstrap}
    return problem, result, {"report": report, "config": resolved}

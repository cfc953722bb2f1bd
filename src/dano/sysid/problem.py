"""Observed trajectories and the identification problem (paper §V-A, Eq. 13).

θ* = argmin_θ Σ_trajectories Σ_t ‖x̂_t − x_t(θ)‖²_W,  θ_min ≤ θ ≤ θ_max,

where x_t(θ) comes from an open-loop rollout from the observed initial state and x̂_t
are the observed poses. Residuals: position differences (per-axis weights) and
orientation differences on SO(3), log(q̂_t⁻¹ ⊗ q_t) (rotation vector; q and −q are the
same rotation, so sign flips between frames do not matter).
"""

from __future__ import annotations

import dataclasses
import functools
import threading
from dataclasses import dataclass, field
from typing import NamedTuple, Sequence

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from .. import _compiled, sharding
from .._compiled import cached_jit, shape_bucket
from ..contact.params import ContactParams
from ..errors import DanoError
from ..pose import (quat_error, quat_inverse, quat_mean, quat_multiply, rotate, rotvec_to_quat, slope_weights,
                    velocity_from_poses)
from ..sim.dynamics import State
from ..sim.implicit import NewtonConfig
from ..sim.rollout import rollout_arrays
from ..sim.scene import INERTIAL_PARAMETERS, Scene, SimParams


@dataclass(frozen=True)
class Observation:
    """One observed trajectory.

    time: (T,) strictly increasing frame times [s] at one frame rate, T >= 3: every interval a
    whole number of the smallest (frames may be missing, e.g. dropped by a camera; each run of
    consecutive frames is then rolled out from its own first frame, as windows are:
    :meth:`runs`); time stamps that jitter (intervals not whole numbers of one) are taken at
    the simulation's frame rate, dt x substeps, each frame within :data:`MAX_JITTER` of it
    and compared with the rollout at its own time (:func:`frame_shifts`);
    poses: {DANO name: (T, 7)} observed centre-of-mass position [m] (scene/world frame)
    and wxyz orientation of each tracked DANO;
    joints: {joint name: (T,)} observed positions of other one-dof (slide or hinge) joints,
    e.g. a pusher's slide joints [m or rad];
    qpos0 / qvel0: optional full initial state (nq,) / (nv,) (the tracked DANOs' poses and
    joints are still taken from the observation); by default qpos0 is the scene's qpos0
    with the observed first poses and joint values, and qvel0 is derived from the first
    frames (second-order one-sided differences), or zero with ``rest_frames`` > 1;
    controls: optional (T−1, nu) actuator controls per frame interval;
    qfrc: optional (T−1, nv) known generalized forces per frame interval [N, N·m];
    velocities: {DANO name: (T, 6)} optional measured velocities of tracked DANOs per frame,
    MuJoCo's free-joint convention: linear (world frame) [m/s], then angular (body frame)
    [rad/s]; every rollout segment (a trajectory, or each window) starts from them instead of
    finite differences of the poses (qvel0, or rest_frames > 1, still decide the first frame);
    units: length unit of the poses; must be "m" (scene units);
    rest_frames: if > 1, the tracked bodies are known to be at rest during the first
    ``rest_frames`` frames: the initial pose is their mean (rotations averaged with
    :func:`dano.pose.quat_mean`), which reduces tracking noise in the
    initial state by about √rest_frames;
    frame_interval: the frame interval Δ [s] where frames are missing in a pattern that hides it
    (every other one: the smallest interval is then 2Δ); None (default): the smallest interval;
    settle_steps: with rest_frames > 1, simulate this many steps from that initial state
    (controls held at their first value) before the rollout is compared with the frames,
    so that the bodies start in the model's own resting contact (a pose estimate off by a
    fraction of a millimetre otherwise starts with a spurious impact).
    """

    time: np.ndarray
    poses: dict = field(default_factory=dict)
    joints: dict = field(default_factory=dict)
    qpos0: np.ndarray | None = None
    qvel0: np.ndarray | None = None
    controls: np.ndarray | None = None
    qfrc: np.ndarray | None = None
    velocities: dict = field(default_factory=dict)
    units: str = "m"
    name: str = ""
    rest_frames: int = 1
    settle_steps: int = 0
    frame_interval: float | None = None

    @property
    def num_frames(self) -> int:
        return len(self.time)

    @property
    def frame_dt(self) -> float:
        """The frame interval Δ [s]: ``frame_interval`` where given, else the smallest interval
        between frames."""
        return float(self.frame_interval) if self.frame_interval is not None else float(np.min(np.diff(self.time)))

    def runs(self) -> tuple[tuple[int, int], ...]:
        """The runs of consecutive frames, split where frames are missing (an interval of two
        or more frame intervals): ((first frame, frames), ...), one run when none is missing."""
        gaps = np.flatnonzero(np.diff(np.asarray(self.time, dtype=np.float64)) > 1.5 * self.frame_dt) + 1
        edges = np.r_[0, gaps, self.num_frames]
        return tuple((int(a), int(b - a)) for a, b in zip(edges[:-1], edges[1:]))

    def frames(self, first: int, stop: int) -> "Observation":
        """The observation of frames ``first`` to ``stop`` − 1 (time, poses, joints, velocities,
        and the controls and forces of the intervals between them); the full initial state and
        the rest frames only where ``first`` is 0."""
        cut = lambda a, k=0: None if a is None else np.asarray(a)[first:stop - k]  # noqa: E731
        start = first == 0
        return dataclasses.replace(
            self, time=cut(self.time), poses={k: cut(v) for k, v in self.poses.items()},
            velocities={k: cut(v) for k, v in self.velocities.items()},
            joints={k: cut(v) for k, v in self.joints.items()}, controls=cut(self.controls, 1),
            qfrc=cut(self.qfrc, 1), qpos0=self.qpos0 if start else None, qvel0=self.qvel0 if start else None,
            rest_frames=self.rest_frames if start else 1, settle_steps=self.settle_steps if start else 0)


@dataclass(frozen=True)
class FitParameter:
    """A parameter to identify: name is a contact parameter (ContactParams field), "alpha"
    (the mass scale α [kg/m³ per unit density], mass = α∫φ dV: the asset's own is
    ``asset.alpha``, for a mesh built with a mass its mass over its volume; identifiable only
    where a body of known mass or a known force acts on the DANO) or one of the object's own
    dynamics (:data:`dano.sim.scene.INERTIAL_PARAMETERS`:
    ``com_offset_x|y|z`` [m, body frame], ``second_moment_scale_x|y|z`` [1, ≥ 0: a physical
    inertia], ``principal_axes_x|y|z`` [rad]); target: a pair name (contact) or DANO name
    (the others), None for all; initial guess and bounds [lower, upper]."""

    name: str
    initial: float
    lower: float = 0.0
    upper: float = np.inf
    target: str | None = None

    @property
    def label(self) -> str:
        return self.name if self.target is None else f"{self.target}:{self.name}"


@dataclass(frozen=True)
class Weights:
    """Residual weights: position (3,) per axis [1/m²]; rotation [1/rad²], or None (the
    default): each DANO's rotation vector [rad] is weighed by its size, times
    :func:`rotation_length` [m/rad], so that a rotation weighs like the displacement of the
    object's mass points it causes, whatever the object's size; joints [1/unit²]."""

    position: Sequence[float] = (1.0, 1.0, 1.0)
    rotation: float | None = None
    joints: float = 1.0


MAX_OBSERVED_SPEED = 100.0  # m/s: faster observed motion means the positions are not in metres
#: the most frames an observation may miss in a row (more points to a wrong time stamp)
MAX_MISSING_FRAMES = 1000
#: the fewest consecutive frames a rollout starts from (its start velocity is differenced from
#: three); shorter runs between missing frames are left out
MIN_RUN_FRAMES = 3
#: how far a frame's time stamp may stray from its run's frame-rate grid, as a fraction of the
#: frame interval (jitter: each such frame is compared with the simulation interpolated to its
#: own time, :func:`frame_shifts`); the most for which a dropped frame is still told apart from
#: late ones: two consecutive frames are then 0.5 to 1.5 frame intervals apart, a gap more
MAX_JITTER = 0.25


def check_units(obs: Observation) -> None:
    """Raise DanoError if a tracked DANO of ``obs`` moves faster than
    :data:`MAX_OBSERVED_SPEED` between frames: its positions are then not in metres (or its
    times not in seconds), e.g. millimetres."""
    t = np.asarray(obs.time, dtype=np.float64)
    if len(t) < 2 or not np.all(np.diff(t) > 0):
        return
    for name, poses in obs.poses.items():
        p = np.asarray(poses, dtype=np.float64)[:, :3]
        with np.errstate(all="ignore"):  # 1e300 positions: refused elsewhere, without a numpy warning
            speeds = np.linalg.norm(np.diff(p, axis=0), axis=1) / np.diff(t)
        k = int(np.argmax(speeds))
        if speeds[k] > MAX_OBSERVED_SPEED:
            # (one glitch makes two fast intervals, there and back; more point to the units)
            cause = ("positions must be in metres and times in seconds" if np.sum(speeds > MAX_OBSERVED_SPEED) > 2
                     else "a tracking outlier, or positions not in metres (times in seconds)")
            raise DanoError(f"{name} moves at up to {speeds[k]:.3g} m/s between frames (frames {k} and {k + 1}, "
                            f"t = {t[k]:.6g} s): {cause}")


def is_jittered(obs: Observation) -> bool:
    """Whether the observation's intervals are not all whole numbers of its frame interval
    (to 1e-6): time stamps that jitter (a recording's clock), to be compared with the
    simulation at their own times (:func:`frame_shifts`)."""
    dt = np.diff(np.asarray(obs.time, dtype=np.float64))
    if len(dt) == 0:
        return False
    step = obs.frame_dt
    with np.errstate(all="ignore"):  # (a bad frame_interval is refused by the checks)
        return bool(np.any(np.abs(dt - np.round(dt / step) * step) > 1e-6 * dt + 1e-9))


def grid_offsets(t: np.ndarray, step: float) -> np.ndarray:
    """(T,) each frame's time [s] less its place at one frame every ``step`` [s] from the first
    frame of its run of consecutive frames (runs split where an interval is 1.5 steps or more,
    as :meth:`Observation.runs`); 0 at every run's first frame."""
    t = np.asarray(t, dtype=np.float64)
    starts = np.r_[0, np.flatnonzero(np.diff(t) > 1.5 * step) + 1]
    first = np.repeat(starts, np.diff(np.r_[starts, len(t)]))
    return t - t[first] - (np.arange(len(t)) - first) * step


def frame_shifts(t: np.ndarray, step: float, substeps: int) -> np.ndarray:
    """(F,) where each of a segment's consecutive frames (times ``t`` (F,) [s]) falls in its
    rollout, less its place at one frame every ``step`` [s]: in simulation steps (each
    step/substeps); 0 for the first frame and for frames on the grid."""
    t = np.asarray(t, dtype=np.float64)
    return (t - t[0] - np.arange(len(t)) * step) * (substeps / step)


def _at_frames(qpos, first: int, substeps: int, frames: int, shift=None, quat_adr=()):
    """The rollout's qpos (steps + 1, nq) at ``frames`` frames from step ``first``, one every
    ``substeps`` steps; with ``shift`` (frames,) [steps] (jittered time stamps,
    :func:`frame_shifts`) interpolated to each frame's own time: linearly between the steps
    around it, the quaternions at ``quat_adr`` (wxyz) renormalised (their chord; the steps are
    short)."""
    if shift is None:
        return qpos[first : first + (frames - 1) * substeps + 1 : substeps]
    s = first + jnp.arange(frames) * substeps + shift
    i = jnp.clip(jnp.floor(s).astype(jnp.int32), 0, qpos.shape[0] - 2)
    w = (s - i)[:, None]
    out = qpos[i] * (1 - w) + qpos[i + 1] * w
    for a in quat_adr:
        q = out[:, a : a + 4]
        out = out.at[:, a : a + 4].set(q / jnp.linalg.norm(q, axis=1, keepdims=True))
    return out


def _check_observation(obs: Observation, scene: Scene, k: int) -> None:
    with np.errstate(all="ignore"):  # absurd values are reported by the checks, not by numpy warnings
        _check_observation_values(obs, scene, k)


def _check_observation_values(obs: Observation, scene: Scene, k: int) -> None:
    tag = obs.name or f"trajectory {k}"
    t = np.asarray(obs.time, dtype=np.float64)
    if t.ndim != 1 or len(t) < 3:
        raise DanoError(f"{tag}: time must be a 1-D array of at least 3 frames (velocities are estimated from the "
                        f"first three), got shape {t.shape}")
    if not np.all(np.isfinite(t)):
        raise DanoError(f"{tag}: time contains NaN or infinite values")
    dt = np.diff(t)
    if np.any(dt <= 0):
        i = int(np.argmax(dt <= 0))
        raise DanoError(f"{tag}: timestamps must increase; frame {i + 1} (t = {t[i + 1]:.6g}) is not after frame {i}")
    step = dt.min() if obs.frame_interval is None else obs.frame_interval
    if not (np.isfinite(step) and 0 < step):
        raise DanoError(f"{tag}: frame_interval must be positive, got {step!r}")
    # two frames that jitter towards each other may come closer than a frame interval, but not
    # to 1 - 2 x MAX_JITTER of it (half: then a frame interval longer than the frames' is given)
    if dt.min() <= step * (1 - 2 * MAX_JITTER) + 1e-9:
        i = int(np.argmin(dt))
        raise DanoError(f"{tag}: frames {i} and {i + 1} (t = {t[i]:.6g} s) are {dt[i]:.6g} s apart, no more than half "
                        f"the frame interval, {step:.6g} s (frame_interval, or dt x substeps where time stamps "
                        "jitter): a repeated frame, or a frame interval longer than the frames'")
    whole = np.round(dt / step)
    if is_jittered(obs):  # each frame within MAX_JITTER of its run's grid
        off = np.abs(grid_offsets(t, step)) > MAX_JITTER * step
        if np.any(off):
            i = int(np.argmax(off))
            raise DanoError(f"{tag}: frames must be at one frame rate (frames may be missing, and time stamps may "
                            f"jitter by up to {MAX_JITTER:.0%} of the frame interval, {step:.6g} s): frame {i} "
                            f"(t = {t[i]:.6g} s) is farther from its place at that rate (the frame rate differs from "
                            "1/(dt x substeps), or the time stamps jitter more)")
    if whole.max() > MAX_MISSING_FRAMES + 1:
        i = int(np.argmax(whole))
        raise DanoError(f"{tag}: frame {i + 1} (t = {t[i + 1]:.6g} s) comes {int(whole[i])} frame intervals after "
                        f"frame {i}: more than {MAX_MISSING_FRAMES} frames missing in a row (a wrong time stamp?); "
                        "give the parts as separate trajectories")
    if obs.units != "m":
        raise DanoError(f"{tag}: poses are in {obs.units!r}; convert them to the scene's units (m) first")
    if not obs.poses and not obs.joints:
        raise DanoError(f"{tag}: nothing observed (no poses and no joints)")
    for name, p in obs.poses.items():
        scene.dano_index(name)
        p = np.asarray(p, dtype=np.float64)
        if p.shape != (len(t), 7):
            raise DanoError(f"{tag}: poses of {name!r} must have shape ({len(t)}, 7) (x y z qw qx qy qz), got {p.shape}")
        if not np.all(np.isfinite(p)):
            bad = int(np.argmax(~np.all(np.isfinite(p), axis=1)))
            raise DanoError(f"{tag}: poses of {name!r} contain NaN or infinite values (first at frame {bad})")
        if np.any(np.abs(np.linalg.norm(p[:, 3:], axis=1) - 1) > 1e-3):
            raise DanoError(f"{tag}: quaternions of {name!r} are not unit length")
    try:
        check_units(obs)
    except DanoError as exc:
        raise DanoError(f"{tag}: {exc}") from None
    for name, v in obs.velocities.items():
        if name not in obs.poses:
            raise DanoError(f"{tag}: velocities of {name!r}, which the trajectory does not track (its poses are not "
                            "given)")
        v = np.asarray(v, dtype=np.float64)
        if v.shape != (len(t), 6) or not np.all(np.isfinite(v)):
            raise DanoError(f"{tag}: velocities of {name!r} must be finite with shape ({len(t)}, 6) (vx vy vz world, "
                            f"wx wy wz body), got {v.shape}")

    for name, v in obs.joints.items():
        j = mujoco.mj_name2id(scene.mj_model, mujoco.mjtObj.mjOBJ_JOINT, name)
        if j < 0:
            raise DanoError(f"{tag}: the scene has no joint named {name!r}")
        if int(scene.mj_model.jnt_type[j]) not in (int(mujoco.mjtJoint.mjJNT_SLIDE), int(mujoco.mjtJoint.mjJNT_HINGE)):
            raise DanoError(f"{tag}: joint {name!r} is not a slide or hinge joint; observe free bodies as poses")
        v = np.asarray(v, dtype=np.float64)
        if v.shape != (len(t),) or not np.all(np.isfinite(v)):
            raise DanoError(f"{tag}: joint {name!r} must be {len(t)} finite values, got shape {v.shape}")
    for what, arr, shape in (("qpos0", obs.qpos0, (scene.nq,)), ("qvel0", obs.qvel0, (scene.nv,))):
        if arr is not None and (np.shape(arr) != shape or not np.all(np.isfinite(arr))):
            raise DanoError(f"{tag}: {what} must be {shape[0]} finite values, got shape {np.shape(arr)}")
    for what, arr, width in (("controls", obs.controls, scene.nu), ("qfrc", obs.qfrc, scene.nv)):
        if arr is not None:
            a = np.asarray(arr)
            if a.shape != (len(t) - 1, width) or not np.all(np.isfinite(a)):
                raise DanoError(f"{tag}: {what} must be finite with shape ({len(t) - 1}, {width}), got {a.shape}")


def finite_difference_velocity(times: np.ndarray, poses: np.ndarray, step: float = 0.0) -> np.ndarray:
    """(6,) initial velocity of a free body from its first three poses (times (≥3,) [s],
    poses (≥3, 7) x y z qw qx qy qz): linear velocity (world frame) [m/s] by a second-order
    one-sided difference, angular velocity (body frame) [rad/s] from the relative rotations
    (:func:`dano.pose.velocity_from_poses` of degree 2), both taken ``step``/2 before the
    first pose.

    step: the simulation step h [s] that starts from this velocity, 0 for the velocity at the
    first pose. MuJoCo's Euler integrator, and dano's implicit step with it, is semi-implicit:
    x_{k+1} = x_k + h·v_{k+1}, so its velocities lag its positions by half a step, and a
    rollout started from the true velocity v(t₀) under a constant acceleration a falls behind
    by a·h·t/2 (a slide to a stop by v₀·h/2: 6 mm for 1.2 m/s at h = 10 ms, which moves an
    identified friction by several percent). Started from v(t₀ − h/2) = v − a·h/2 (exact for
    a parabola), its positions match the parabola's at every step. The stencil is
    (−(3 + ρ)x₀ + (4 + 2ρ)x₁ − (1 + ρ)x₂)/(2Δ), ρ = h/Δ: its noise gain is
    :func:`finite_difference_gain`."""
    times = np.asarray(times, dtype=np.float64)[:3]
    return velocity_from_poses(times, np.asarray(poses)[:3], degree=2, at=-0.5 * float(step))


def next_frames_start(times: np.ndarray, poses: np.ndarray, step: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """A free body's start that leaves its first frame's position out: (position (3,) [m,
    world frame], velocity (6,)) from the least-squares parabola through the next
    :data:`NEXT_FRAMES` frames (times (≥ 1 + NEXT_FRAMES,) [s], poses (≥ 1 + NEXT_FRAMES, 7)):
    its value at the first frame's time, and its slope half a step h = ``step`` [s] before it
    (the integrator's, as in :func:`finite_difference_velocity`); angular velocity [rad/s,
    body frame] as :func:`finite_difference_velocity` takes it, and the orientation stays the
    first frame's. Where a rollout starts from when the first frames disagree with the
    motion after them (a first frame that is off: :func:`start_velocity_disagreement`);
    exact for a constant acceleration. Raises DanoError with fewer frames."""
    t = np.asarray(times, dtype=np.float64)
    if len(t) < 1 + NEXT_FRAMES:
        raise DanoError(f"next_frames_start needs {1 + NEXT_FRAMES} frames, got {len(t)}")
    p = np.asarray(poses, dtype=np.float64)
    n = slice(1, 1 + NEXT_FRAMES)
    P = np.polynomial.polynomial
    coef = P.polyfit(t[n] - t[1], p[n, :3], 2)  # (3, 3): per axis, constant, slope, curvature
    first = t[0] - t[1]
    linear = P.polyval(first - 0.5 * float(step), P.polyder(coef))
    return P.polyval(first, coef), np.concatenate([linear, finite_difference_velocity(t, p, step)[3:]])


def finite_difference_gain(step_ratio: float = 0.0) -> float:
    """How many times a start velocity from :func:`finite_difference_velocity` amplifies the
    position noise σ of equally spaced frames, over the frame interval Δ (its noise is
    gain·σ/Δ): the norm of its stencil's weights (:func:`dano.pose.slope_weights`) at unit
    spacing, ‖(3 + ρ, 4 + 2ρ, 1 + ρ)‖/2 for ρ = step/Δ (√26/2 = 2.55 at ρ = 0, √14 = 3.74 at
    ρ = 1, one simulation step per frame)."""
    return float(np.linalg.norm(slope_weights(np.arange(3.0), 2, at=-0.5 * float(step_ratio))))


#: start velocities from finite differences uncertain by more than this fraction of the
#: typical start speed are fitted by ``fit_velocity="auto"`` (and warned of where not fitted)
START_VELOCITY_NOISE = 0.05

#: position noise below this [m] is rounding, not measurement: no start is fitted for it
NOISE_FLOOR = 1e-6


def _moving_starts(observations, segments, sigma_all, opening_only: bool = False):
    """(obs, segment, poses (n, 7)) of each segment start whose velocity comes from finite
    differences of its frames (no measured velocities, ``qvel0`` or ``rest_frames``; at least
    3 frames) and whose segment moves: its net displacement exceeds 3√2‖σ‖ (σ (3,) [m]; a
    still object's start velocity is noise that its contact damps at once). opening_only:
    only starts that open a recording's run of frames (:func:`_opens_a_run`)."""
    for seg in segments:
        obs = observations[seg.obs]
        if seg.start == 0 and (obs.qvel0 is not None or obs.rest_frames > 1):
            continue
        if opening_only and not _opens_a_run(obs, seg):
            continue
        for name, poses in obs.poses.items():
            if name in obs.velocities or seg.frames < 3:
                continue
            k, p = seg.start, np.asarray(poses, dtype=np.float64)
            if np.linalg.norm(p[k + seg.frames - 1, :3] - p[k, :3]) <= 3 * np.sqrt(2) * np.linalg.norm(sigma_all):
                continue  # still within the noise
            yield obs, seg, p


def start_velocity_uncertainty(observations, segments, position_noise, axes: str = "xyz", substeps: int = 1
                               ) -> tuple[float, float] | None:
    """How uncertain the rollouts' start velocities are where finite differences of the
    observed frames give them: (spread, typical) [m/s], spread = g·‖σ_axes‖/Δt (σ the
    position noise per axis (3,) [m], e.g. from :func:`dano.sysid.uncertainty.
    noise_of_observations`; Δt the median frame interval; g = :func:`finite_difference_gain`
    of 1/``substeps``, simulation steps per frame) and typical the median speed of the
    *moving* starts: those whose segment's net displacement exceeds 3√2‖σ‖ (a still object's
    start velocity is noise that its contact damps at once). Starts with measured
    velocities, a given ``qvel0`` or ``rest_frames`` are left out. None where no moving start
    comes from finite differences, or the noise is unknown or below :data:`NOISE_FLOOR`."""
    if position_noise is None or not axes:
        return None
    sigma_all = np.asarray(position_noise, dtype=np.float64)
    if not np.linalg.norm(sigma_all) > NOISE_FLOOR:
        return None
    speeds, dts = [], []
    for obs, seg, p in _moving_starts(observations, segments, sigma_all):
        k = seg.start
        v = finite_difference_velocity(np.asarray(obs.time)[k:k + 3], p[k:k + 3])
        speeds.append(float(np.linalg.norm(v[:3])))
        dts.append(obs.frame_dt)
    if not speeds:
        return None
    sigma = sigma_all[["xyz".index(a) for a in axes]]
    gain = finite_difference_gain(1.0 / substeps)
    return gain * float(np.linalg.norm(sigma)) / float(np.median(dts)), float(np.median(speeds))


#: frames after a start's first that :func:`start_velocity_disagreement` fits its second
#: velocity estimate to
NEXT_FRAMES = 4


def _opens_a_run(obs: Observation, seg: Segment) -> bool:
    """Whether ``seg`` starts at the first frame of a run of ``obs``'s frames (the recording's
    first, or the first after missing frames: where a tracker starts cold), not at a window's
    start inside one (:meth:`Observation.runs`)."""
    return seg.start == 0 or any(first == seg.start for first, _ in obs.runs())


def start_velocity_disagreement(observations, segments, position_noise, axes: str = "xyz", shift: int = 0
                                ) -> tuple[float, float, float] | None:
    """How far the start velocities that finite differences take from each start's first
    three frames (:func:`finite_difference_velocity`) stray from the motion that the frames
    after the first describe: at each moving start (as :func:`start_velocity_uncertainty`
    counts them) that opens a run of frames (the recording's first frame or the first after
    missing ones; windows inside a run start from ordinary frames, often just before an
    impact, where no parabola holds) with at least 1 + :data:`NEXT_FRAMES` frames, the
    difference along ``axes`` between that velocity and the slope, at the first frame, of the
    least-squares parabola through the next :data:`NEXT_FRAMES` frames (both exact for a
    constant acceleration: a slide, a flight). A first frame that is off (a tracker's cold start, a pose read a
    substep apart from the rest, a push between the first frames) makes them disagree.

    position_noise: (3,) per axis [m], or None (taken as none). ``shift``: the same
    comparison ``shift`` frames after each start (the second frame's, 1, is what the first
    frame's is weighed against: :func:`stray_start_velocities`), at the starts with
    ``shift`` frames more. Returns (disagreement, noise, typical) [m/s]: the median over
    those starts of the difference's norm, the median of what the noise alone makes it
    (‖w‖·‖σ_axes‖, w the two stencils' difference), and the median speed of those starts;
    None where there is no such start or no axis."""
    if not axes:
        return None
    sigma_all = np.zeros(3) if position_noise is None else np.asarray(position_noise, dtype=np.float64)
    cols = ["xyz".index(a) for a in axes]
    sigma = float(np.linalg.norm(sigma_all[cols]))
    gaps, noise, speeds = [], [], []
    for obs, seg, p in _moving_starts(observations, segments, sigma_all, opening_only=True):
        k, n = seg.start + shift, NEXT_FRAMES
        if seg.frames < 1 + n + shift:
            continue
        t = np.asarray(obs.time, dtype=np.float64)[k:k + 1 + n]
        first = slope_weights(t[:3], 2)  # (the stencil of finite_difference_velocity at its first frame)
        after = slope_weights(t[1:], 2, at=t[0] - t[1])
        w = np.concatenate([first, np.zeros(n - 2)]) - np.concatenate([[0.0], after])
        x = p[k:k + 1 + n, :3]
        gaps.append(float(np.linalg.norm((w @ x)[cols])))
        noise.append(float(np.linalg.norm(w)) * sigma)
        speeds.append(float(np.linalg.norm(first @ x[:3])))
    if not gaps:
        return None
    return float(np.median(gaps)), float(np.median(noise)), float(np.median(speeds))


def noisy_start_velocities(observations, segments, position_noise, axes: str, substeps: int = 1) -> str | None:
    """Where :func:`start_velocity_uncertainty` along ``axes`` exceeds
    :data:`START_VELOCITY_NOISE` of the typical moving start's speed, the phrase that says so
    (for the notes of ``fit_velocity="auto"`` and the warning where they are not fitted);
    None otherwise. position_noise: (3,) per axis [m], or None."""
    found = start_velocity_uncertainty(observations, segments, position_noise, axes, substeps)
    if found is None or found[1] <= 0 or found[0] <= START_VELOCITY_NOISE * found[1]:
        return None
    spread, typical = found
    per_axis = 1e3 * np.asarray(position_noise, dtype=np.float64)[["xyz".index(a) for a in axes]]
    sigma = ", ".join(f"{v:.3g}" for v in per_axis) + (" mm per axis" if len(axes) > 1 else " mm")
    return (f"finite differences of the observed frames, whose position noise along {axes} is {sigma}, "
            f"start the rollouts from velocities uncertain by about {spread:.3g} m/s, "
            f"{100 * spread / typical:.0f} % of the typical moving start's speed ({typical:.3g} m/s)")


#: where a rollout's start velocity comes from when no velocity is measured or given
#: (:attr:`SysIdProblem.start_velocity`)
START_VELOCITIES = ("auto", "first frames", "next frames")

#: a start velocity disagreement this many times what the noise alone makes is not noise
DISAGREEMENT_SIGNIFICANCE = 3.0

#: a first frame's disagreement above this fraction of the typical start speed is taken as
#: a first frame that is off on its own; below it, only where it is
#: :data:`FIRST_FRAME_CONTRAST` times the second frame's (:func:`stray_start_velocities`)
CLEAR_DISAGREEMENT = 0.15

#: how far a first frame's disagreement (of 5 to 15 % of the speed) must exceed the second
#: frame's for the first frame to be taken as off, not the motion as uneven
FIRST_FRAME_CONTRAST = 1.5


def stray_start_velocities(observations, segments, position_noise, axes: str) -> str | None:
    """Where the first frames disagree with the motion of the frames after them
    (:func:`start_velocity_disagreement`) by more than :data:`START_VELOCITY_NOISE` of the
    typical moving start's speed and more than :data:`DISAGREEMENT_SIGNIFICANCE` times what
    the noise alone would make (noise-free data too: another engine's), the phrase that says
    so; None otherwise. A disagreement of up to :data:`CLEAR_DISAGREEMENT` of the speed
    counts only where it exceeds :data:`FIRST_FRAME_CONTRAST` times the same comparison one
    frame later: a first frame that is off stands out from the frames after it, while a
    motion that is not a parabola over the first frames (a contact settling after a launch:
    four clean MuJoCo C slides of a bunny disagree by 6 % at their first frame and 8 % at
    their second) disagrees at both. position_noise: (3,) per axis [m], or None."""
    found = start_velocity_disagreement(observations, segments, position_noise, axes)
    if found is None:
        return None
    gap, noise, typical = found
    if typical <= 0 or gap <= START_VELOCITY_NOISE * typical or gap <= DISAGREEMENT_SIGNIFICANCE * noise:
        return None
    if gap <= CLEAR_DISAGREEMENT * typical:
        later = start_velocity_disagreement(observations, segments, position_noise, axes, shift=1)
        if later is not None and gap <= FIRST_FRAME_CONTRAST * later[0]:
            return None
    return (f"the start velocities that finite differences take from each start's first three frames disagree "
            f"with the motion of the next {NEXT_FRAMES} frames by {gap:.3g} m/s along {axes} (median over the "
            f"moving starts), {100 * gap / typical:.0f} % of the typical moving start's speed ({typical:.3g} m/s): "
            "a first frame may be off (a tracker's cold start, a pose read a substep apart from the rest)")


#: rotation vector of q_obs⁻¹ ⊗ q_sim, (..., 3) [rad]; sign-invariant and NaN-free
#: (:func:`dano.pose.quat_error`)
quat_log_error = quat_error


def impact_windows(obs: Observation, threshold_g: float = 3.0, span_s: float = 0.02,
                   min_intervals: int = 5) -> list[int]:
    """Window starts (frame indices, the first 0) for multiple shooting that begin just before
    each impact seen in the observation: where a tracked DANO's acceleration, from second
    differences over ``span_s`` (at least one frame; it averages tracking noise down),
    departs from free fall by more than ``threshold_g`` g. A run of such frames is one
    impact; its window starts one span before the run. Windows shorter than
    ``min_intervals`` frame intervals are merged into the previous one. Between impacts the
    motion is smooth (flight, sliding), so each window's rollout stays close to the data,
    while the chaotic part, which impact happens how, restarts from the observed state."""
    h = obs.frame_dt
    k = max(1, int(round(span_s / h)))
    T = obs.num_frames
    hot = np.zeros(T, dtype=bool)
    for p in obs.poses.values():
        x = np.asarray(p, dtype=np.float64)[:, :3]
        if T < 2 * k + 1:
            continue
        a = (x[2 * k :] - 2 * x[k:-k] + x[: -2 * k]) / (k * h) ** 2
        a[:, 2] += 9.81  # departure from free fall
        hot[k:-k] |= np.linalg.norm(a, axis=1) > threshold_g * 9.81
    starts = [0]
    rising = np.flatnonzero(hot[1:] & ~hot[:-1]) + 1
    for r in rising:
        s = max(0, int(r) - k)
        if s - starts[-1] >= min_intervals and T - 1 - s >= min_intervals:
            starts.append(s)
    return starts


@dataclass(frozen=True)
class Segment:
    """A rollout segment (a whole trajectory or a window of one): observation index,
    first frame, number of frames."""

    obs: int
    start: int
    frames: int


def _pad(a: np.ndarray, key: str, frames: int, steps: int) -> np.ndarray:
    """Pad one segment's array to a batch's longest segment: controls and forces by holding
    their last values (steps after the segment's end: only a jittered last frame, compared a
    fraction of a step after it, sees them), observed frames by repeating the last one,
    frame shifts with zeros."""
    if key in ("ctrl", "qfrc"):
        return np.concatenate([a, np.repeat(a[-1:], steps - len(a), axis=0)]) if len(a) else np.zeros(
            (steps,) + a.shape[1:])
    if key in ("obs_pose", "obs_joint") and a.shape[1] < frames:
        return np.concatenate([a, np.repeat(a[:, -1:], frames - a.shape[1], axis=1)], axis=1)
    if key == "shift":
        return np.concatenate([a, np.zeros(frames - len(a))])
    return a


def _valid_residuals(intervals: list[int], padded: int, cols: list[int]) -> np.ndarray:
    """Indices into the raveled (segments, residuals) array of a batch that belong to real
    frames: each segment's residuals are blocks of ``padded`` frames × ``cols[k]`` columns,
    of which the first ``intervals[s]`` frames are real."""
    per_segment = padded * sum(cols)
    keep = []
    for s, n in enumerate(intervals):
        start = s * per_segment
        for c in cols:
            keep.append(start + np.arange(n * c))
            start += padded * c
    return np.concatenate(keep) if keep else np.zeros(0, dtype=np.int64)


def _poses_to_table(poses, height, R):
    """(F, 7) world poses (x y z, wxyz) -> the frame of a table at height ``height`` tilted by
    R (world ← table, a quaternion (4,)): p ↦ R⁻¹(p − h·e_z), q ↦ R⁻¹ ⊗ q."""
    Ri = quat_inverse(R)
    p = rotate(Ri, poses[:, :3] - jnp.stack([0.0, 0.0, height]).astype(poses.dtype))
    return jnp.concatenate([p, quat_multiply(Ri, poses[:, 3:])], axis=1)


def _poses_from_table(poses, height, R):
    """The inverse of :func:`_poses_to_table`."""
    p = rotate(R, poses[:, :3]) + jnp.stack([0.0, 0.0, height]).astype(poses.dtype)
    return jnp.concatenate([p, quat_multiply(R, poses[:, 3:])], axis=1)


def _to_table(qpos0, qvel0, qadr, dadr, height, R):
    """Initial state of the tracked free bodies in the table's frame (linear velocities rotate;
    angular velocities are in the body frame and do not)."""
    for a, d in zip(qadr, dadr):
        qpos0 = qpos0.at[a : a + 7].set(_poses_to_table(qpos0[None, a : a + 7], height, R)[0])
        qvel0 = qvel0.at[d : d + 3].set(rotate(quat_inverse(R), qvel0[d : d + 3]))
    return qpos0, qvel0


#: label prefixes of the per-segment nuisance parameters (:attr:`SysIdProblem.labels`)
SEGMENT_NUISANCE_PREFIXES = ("v0[", "w0[", "p0[", "r0[")

def forward_only(failure_substeps: int = 1) -> NewtonConfig:
    """The residuals' rollouts' step settings: forward-mode derivatives only (their Jacobians
    are forward-mode; per-sample contact's fallback then costs nothing in the tangents of a
    batch's trajectories that do not overflow: :attr:`~dano.sim.implicit.NewtonConfig.reverse_mode`),
    a step whose Newton solve fails taken again in ``failure_substeps`` substeps (1: never)."""
    return NewtonConfig(reverse_mode=False, failure_substeps=failure_substeps)


def _with_offsets(qpos0, qvel0, block, qadr, dadr, axes):
    """Initial state of one segment with its nuisance offsets added: ``block`` (tracked DANOs,
    len(axes)), ``axes`` as :attr:`SysIdProblem.fit_axes`: 0–2 linear velocity [m/s, world],
    3–5 angular velocity [rad/s, body], 6–8 position [m, world], 9–11 a rotation vector
    [rad, world] applied to the orientation (q ← exp(r) ⊗ q)."""
    rot = [k for k, a in enumerate(axes) if a >= 9]
    rot_axes = jnp.asarray([axes[k] - 9 for k in rot], dtype=jnp.int32)
    for b, (qa, da) in enumerate(zip(qadr, dadr)):
        for k, a in enumerate(axes):
            if a < 6:
                qvel0 = qvel0.at[da + a].add(block[b, k])
            elif a < 9:
                qpos0 = qpos0.at[qa + a - 6].add(block[b, k])
        if rot:
            r = jnp.zeros(3, dtype=block.dtype).at[rot_axes].set(block[b, jnp.asarray(rot)])
            qpos0 = qpos0.at[qa + 3 : qa + 7].set(quat_multiply(rotvec_to_quat(r), qpos0[qa + 3 : qa + 7]))
    return qpos0, qvel0


def _check_ground_only(scene, observations) -> None:
    """fit_ground shifts the observed DANOs; that equals moving the ground only if the
    ground plane (at z = 0, horizontal) is the world's only collidable geometry, every
    other body is a DANO, and every observation tracks all DANOs."""
    m = scene.mj_model
    others = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, b) for b in range(1, m.nbody)]
    others = [b for b in others if b not in scene.dano_names]
    if others:
        raise DanoError(f"fit_ground needs a scene of DANOs on the ground only; it also has bodies {others}")
    for k, o in enumerate(observations):
        if set(o.poses) != set(scene.dano_names):
            raise DanoError(f"fit_ground: {o.name or f'trajectory {k}'} must track every DANO "
                            f"{list(scene.dano_names)}, it tracks {sorted(o.poses)}")
    world = [g for g in range(m.ngeom) if m.geom_bodyid[g] == 0 and (m.geom_contype[g] or m.geom_conaffinity[g])]
    planes = [g for g in world if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_PLANE]
    if len(world) != 1 or len(planes) != 1 or abs(m.geom_pos[planes[0], 2]) > 0 or not np.allclose(
            m.geom_quat[planes[0]], [1, 0, 0, 0]):
        raise DanoError("fit_ground needs a scene whose only world geometry is the horizontal ground plane at z = 0 "
                        f"(this one has {len(world)} collidable world geoms)")


def rotation_length(asset) -> float:
    """Characteristic length L [m/rad] of a DANO for rotation residuals: the rms distance a
    mass point moves per radian of rotation, averaged over rotation axes,
    L = √(tr J / (3 m)) (J: inertia about the centre of mass [kg m²], m: mass [kg]; α
    cancels). A rotation error of θ rad then weighs like a position error of L·θ m (a solid
    sphere of radius R: L = √(4/15)·R ≈ 0.52 R)."""
    J = np.asarray(asset.inertia, dtype=np.float64)
    return float(np.sqrt(max(np.trace(J), 0.0) / (3.0 * float(asset.mass))))


class StartPriorRows(NamedTuple):
    """The start prior's residual rows r_i = weight_i·θ[index_i] (:class:`SysIdProblem`'s
    ``start_prior``), k of them: index (k,) int into θ; weight (k,) [residual units per unit
    of the offset]; observation (k,) int, the trajectory of each row's segment; noise (k,) int,
    the observation noise each row carries (position axis x y z: 0–2; rotation: 3); unit (k,)
    the residual weight of that noise (√w of the axis [1/m], or the rotation weight [m/rad]),
    so that a row's noise is the frames' noise of its kind times unit."""

    index: np.ndarray
    weight: np.ndarray
    observation: np.ndarray
    noise: np.ndarray
    unit: np.ndarray


@dataclass(frozen=True)
class JacobianBlocks:
    """The residual r (m,) at θ (n,) and its Jacobian J (m, n) as the identification's structure
    holds it: a segment's residuals (its frames', and its start prior's rows) depend on θ's
    global entries (the parameters, then the ground's) and on its own nuisance block only, so
    J is kept per segment as a dense (rows, k) block over k = P + G + block size columns
    (:meth:`SysIdProblem.jacobian_blocks`). With S segments of R rows each, that is S·R·k
    numbers instead of m·n (m ≈ S·R, n ≈ S·block).

    residuals: (m,) the residual vector (:meth:`SysIdProblem.residuals`' order). Per batch
    of the residual's layout: rows (count, R) int, the row of r each block row is (−1: a
    padded segment or frame, or an entry without a start prior row); columns (count, k) int,
    θ's entries the block's columns are; values (count, R, k) float, ∂r/∂θ there.
    num_parameters: n."""

    residuals: np.ndarray
    rows: tuple[np.ndarray, ...]
    columns: tuple[np.ndarray, ...]
    values: tuple[np.ndarray, ...]
    num_parameters: int

    def dense(self) -> np.ndarray:
        """(m, n) the Jacobian as a dense matrix (zeros outside the blocks)."""
        J = np.zeros((len(self.residuals), self.num_parameters))
        for rows, cols, vals in zip(self.rows, self.columns, self.values):
            real = rows >= 0
            J[rows[real][:, None], cols[np.nonzero(real)[0]]] = vals[real]
        return J

    def compressed(self, residuals: np.ndarray, scale: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The least-squares problem in as few rows as the blocks allow: (r_c (K + 1,), J_c
        (K + 1, n)) with ‖r_c‖ = ‖r‖, J_cᵀ J_c = JᵀJ and J_cᵀ r_c = Jᵀr (so the Gauss–Newton
        model ‖r + J s‖² is the same for every step s), K = Σ segments × min(R, k). Each
        segment's block is factored J_s = Q_s R_s (thin QR); its rows become R_s and Q_sᵀ r_s,
        and what Q_s does not span, ‖r_s − Q_s Q_sᵀ r_s‖, is pooled in the last entry (whose
        Jacobian row is 0: r's part orthogonal to J's columns has no first-order change).
        A trust-region solver's SVD then costs K·n² instead of m·n² (m/K ≈ R/k: 16× for box
        slides of 20 frames with start velocities fitted), with the same iterates up to a
        rounding difference, which a jagged cost grows
        (:data:`~dano.sysid.uncertainty.COMPRESS_MIN_PARAMETERS`).

        residuals: (m,) the vector to factor against (e.g. the bounded and scaled residual a
        solver sees); scale: (m,) per-row factors applied to J's rows (None: 1); non-finite
        Jacobian entries count as 0. Raises ValueError if residuals or scale are not (m,) and
        finite."""
        m = len(self.residuals)
        r = np.asarray(residuals, dtype=np.float64)
        s = np.ones(m) if scale is None else np.asarray(scale, dtype=np.float64)
        for name, a in (("residuals", r), ("scale", s)):
            if a.shape != (m,) or not np.all(np.isfinite(a)):
                raise ValueError(f"JacobianBlocks.compressed: {name} must be {m} finite values, got shape {a.shape}"
                                 + ("" if a.shape != (m,) else " with non-finite entries"))
        out_r, out_J, perp = [], [], 0.0
        for rows, cols, vals in zip(self.rows, self.columns, self.values):
            real = rows >= 0
            at = np.where(real, rows, 0)
            rb = np.where(real, r[at], 0.0)
            Jb = np.where(real[..., None], np.where(np.isfinite(vals), vals, 0.0) * s[at][..., None], 0.0)
            Q, R = np.linalg.qr(Jb)  # (count, R, kk), (count, kk, k)
            qtr = np.einsum("crk,cr->ck", Q, rb)
            perp += float(np.sum((rb - np.einsum("crk,ck->cr", Q, qtr)) ** 2))
            count, kk, k = R.shape
            Jc = np.zeros((count * kk, self.num_parameters))
            Jc[np.arange(count * kk)[:, None], np.repeat(cols, kk, axis=0)] = R.reshape(count * kk, k)
            out_r.append(qtr.ravel())
            out_J.append(Jc)
        out_r.append(np.array([np.sqrt(perp)]))
        out_J.append(np.zeros((1, self.num_parameters)))
        return np.concatenate(out_r), np.concatenate(out_J)


@dataclass(frozen=True)
class BatchLayout:
    """Static structure of one batch of segments that share a layout (vmapped together):
    the number of segments (padded: :func:`segment_bucket`, then to a multiple of the
    devices), the tracked DANOs' qpos/qvel addresses, observed joints' qpos addresses,
    simulated steps (settling included; the longest segment's frame intervals padded:
    :data:`INTERVAL_BITS`) and settling steps."""

    count: int
    qadr: tuple[int, ...]
    dadr: tuple[int, ...]
    jadr: tuple[int, ...]
    steps: int
    settle: int


class _Structure(NamedTuple):
    """A problem's residual as its compiled functions take it (:meth:`SysIdProblem._build_structure`)."""

    layout: "ResidualLayout"
    data: dict
    keep: np.ndarray  # (m,) int: the real entries of padded_residuals' output
    members: tuple[tuple[int, ...], ...]  # per batch, the indices of its real segments
    global_index: np.ndarray  # (P + G,) int: θ's global entries (parameters, then the ground's)
    block_index: tuple[np.ndarray, ...]  # per batch (count, block) int: each segment's nuisance entries in θ
    segment_rows: tuple[int, ...]  # per batch, the residual entries of each of its segments (padded frames)
    block_rows: tuple[np.ndarray, ...]  # per batch (count, rows + block) int: JacobianBlocks.rows
    block_columns: tuple[np.ndarray, ...]  # per batch (count, P + G + block) int: JacobianBlocks.columns

    def slots(self) -> list:
        """(batch, row in the batch) of each segment, in the segments' order: where its outputs are."""
        where = {sid: (b, i) for b, m in enumerate(self.members) for i, sid in enumerate(m)}
        return [where[sid] for sid in range(len(where))]


@dataclass(frozen=True)
class ResidualLayout:
    """The static (hashable) structure of a problem's residual: what its compiled functions
    are keyed on. Problems of the same layout and scene, whatever their observed values,
    weights and parameter values, share one compilation (e.g. a bootstrap's resamples,
    continuation stages, and data sets whose segment counts and lengths fall in the same
    buckets: :func:`segment_bucket`, :data:`INTERVAL_BITS`). It holds no segment index or θ length:
    the compiled functions take θ's global entries and each batch's nuisance blocks apart
    (:func:`padded_residuals`)."""

    batches: tuple[BatchLayout, ...]
    parameters: tuple[tuple[str, int | None], ...]  # (name, index of its DANO or pair; None: every one)
    fit_axes: tuple[int, ...]
    pos_axes: tuple[int, ...]
    rotation: bool
    joints: bool
    substeps: int
    fit_ground: bool
    fit_tilt: bool
    #: devices (in all processes) the segments of each batch are split over
    #: (:mod:`dano.sharding`); every batch's segment count is then a multiple of it
    shards: int = 1
    #: whether some time stamps jitter: frames compared with the rollout interpolated to their
    #: own times (the data's ``shift``, :func:`frame_shifts`), rolled out ``substeps`` steps further
    jittered: bool = False
    #: whether each batch's segments are rolled out one after the other (a loop; padded copies
    #: skipped) instead of vmapped: where their Newton iteration counts differ much from step
    #: to step, a vmapped loop runs every segment for its slowest one's count
    #: (:func:`segments_in_turn`)
    in_turn: bool = False
    #: the substeps a rollout step whose Newton solve fails is taken again in
    #: (:attr:`SysIdProblem.failure_substeps`, :attr:`~dano.sim.NewtonConfig.failure_substeps`)
    failure_substeps: int = 1


def _layout_mesh(layout: ResidualLayout, *_):
    """The mesh a layout's segments are split over, or None (one device)."""
    return sharding.mesh_of_size(layout.shards)


def _table(theta, fit_tilt: bool):
    """(height, rotation world ← table (a quaternion (4,))) of the ground from θ's last entries."""
    if fit_tilt:
        return theta[-3], rotvec_to_quat(jnp.stack([theta[-2], theta[-1], jnp.zeros_like(theta[-1])]))
    return theta[-1], jnp.asarray([1.0, 0.0, 0.0, 0.0], dtype=theta.dtype)


def _tilted_scene(scene: Scene, R) -> Scene:
    """The scene with gravity seen from the table's frame: R⁻¹·g."""
    m = scene.model
    return scene.replace(model=m.replace(opt=m.opt.replace(gravity=rotate(quat_inverse(R), m.opt.gravity))))


def _with_parameters(scene: Scene, base_params: SimParams, parameters, theta) -> SimParams:
    for i, (name, target) in enumerate(parameters):
        base_params = scene.set_param(base_params, name, theta[i], target)
    return base_params


def padded_residuals(layout: ResidualLayout, scene: Scene, base_params: SimParams, data: dict, theta_g, blocks,
                     with_frames: bool = False, with_failures: bool = False):
    """The identification residual, a pure JAX function of its arguments: every batch's
    segments rolled out (vmapped, or one after the other: ``layout.in_turn``, where padded
    segments are skipped and their entries zero) for the batch's padded length, each segment's
    residuals frame by frame, padded frames and segments included (their entries are meaningless:
    :attr:`SysIdProblem.keep` selects the real ones). ``data``: :attr:`SysIdProblem.data`.
    theta_g: (P + G,) θ's global entries: the identified parameters, then the ground's (G = 0,
    1 or 3); blocks: per batch (count, tracked DANOs, len(fit_axes)), each segment's nuisance
    offsets (:meth:`SysIdProblem.split_theta`). Returns the residual (m_padded,), batches and
    segments in order. With ``layout.shards`` > 1 each batch's segments are split over that
    many devices (``shard_map``; every device rolls out its own segments, the residuals are
    gathered). with_frames (static): also return the simulated qpos at every frame, per batch
    (count, frames, nq), padded frames included, the tracked DANOs' poses in the observations'
    frame (the fitted trajectories the residual compares, :meth:`SysIdProblem.fitted`), and
    each step's Newton iterations and whether it failed, per batch ((count, steps) int,
    (count, steps) bool: :func:`segments_in_turn`, :meth:`SysIdProblem.failed_steps`).
    with_failures (static, without frames): (residual, each batch's failed steps per segment
    (count,) int)."""
    params = _with_parameters(scene, base_params, layout.parameters, theta_g)
    sim_scene = scene
    if layout.fit_ground:
        height, R = _table(theta_g, layout.fit_tilt)
        if layout.fit_tilt:
            sim_scene = _tilted_scene(scene, R)
    pos_axes = jnp.asarray(layout.pos_axes, dtype=jnp.int32)
    wpos, wjoint, axes, substeps = data["wpos"], data["wjoint"], layout.fit_axes, layout.substeps
    mesh = _layout_mesh(layout)
    out, fitted, iterations, failed_counts = [], [], [], []
    for b, batch in enumerate(layout.batches):
        qadr, dadr, jadr, settle = batch.qadr, batch.dadr, batch.jadr, batch.settle
        wrot = data["wrot"][b]

        def one(block, qpos0, qvel0, ctrl, qfrc, obs_pose, obs_joint, shift=None):
            if layout.fit_ground:  # observations in the frame of the table (at z = height, tilted by R)
                qpos0, qvel0 = _to_table(qpos0, qvel0, qadr, dadr, height, R)
                obs_pose = jax.vmap(lambda p: _poses_to_table(p, height, R))(obs_pose)
            qpos0, qvel0 = _with_offsets(qpos0, qvel0, block, qadr, dadr, axes)
            if layout.jittered:  # the last frames may fall after their place: a frame interval more
                ctrl = jnp.concatenate([ctrl, jnp.repeat(ctrl[-1:], substeps, axis=0)])
                qfrc = jnp.concatenate([qfrc, jnp.repeat(qfrc[-1:], substeps, axis=0)])
            qpos, _, _, its, failed = rollout_arrays(sim_scene, State(qpos0, qvel0), ctrl, params,
                                                     batch.steps + (substeps if layout.jittered else 0), qfrc,
                                                     overlaps=False, newton=forward_only(layout.failure_substeps),
                                                     iterations=True, failures=True)
            # states at frames 0..F-1
            states = _at_frames(qpos, settle, substeps, (batch.steps - settle) // substeps + 1, shift,
                                tuple(a + 3 for a in qadr))
            frames = states[1:]
            res = []  # components with zero weight are left out (they would dilute σ²)
            for k, a in enumerate(qadr):
                if len(layout.pos_axes):
                    err = frames[:, a : a + 3] - obs_pose[k, 1:, :3]
                    res.append((err[:, pos_axes] * wpos).ravel())
                if layout.rotation:
                    res.append((wrot[k] * quat_log_error(obs_pose[k, 1:, 3:], frames[:, a + 3 : a + 7])).ravel())
            if layout.joints:
                for k, a in enumerate(jadr):
                    res.append(wjoint * (frames[:, a] - obs_joint[k, 1:]))
            if with_failures:
                return jnp.concatenate(res), jnp.sum(failed[: batch.steps]).astype(jnp.int32)
            if not with_frames:
                return jnp.concatenate(res)
            if layout.fit_ground:  # back in the observations' frame
                for a in qadr:
                    states = states.at[:, a : a + 7].set(_poses_from_table(states[:, a : a + 7], height, R))
            return jnp.concatenate(res), states, (its[: batch.steps], failed[: batch.steps])

        d = data["batches"][b]
        args = [blocks[b], d["qpos0"], d["qvel0"], d["ctrl"], d["qfrc"], d["obs_pose"], d["obs_joint"]]
        args += [d["shift"]] if layout.jittered else []
        fn = one
        if layout.in_turn:  # a loop over the segments; a padded copy's entries are zeros
            args = [d["real"]] + args

            def fn(real, *row, one=one):
                return jax.lax.cond(real, lambda: one(*row), lambda: jax.tree_util.tree_map(
                    jnp.zeros_like, jax.eval_shape(one, *row)))
        r = sharding.split_rows(fn, mesh, (0,) * len(args), 1 if layout.in_turn else None)(*args)
        if with_frames:
            r, states, its = r
            fitted.append(states)
            iterations.append(its)
        elif with_failures:
            r, counts = r
            failed_counts.append(counts)
        out.append(r.ravel())
    if with_failures:
        return jnp.concatenate(out), tuple(failed_counts)
    return (jnp.concatenate(out), tuple(fitted), tuple(iterations)) if with_frames else jnp.concatenate(out)


def _run(fn, *args) -> np.ndarray:
    """``fn(*args)`` as NumPy arrays; the time of a call that traced, loaded or compiled
    counts in :data:`COMPILE_SECONDS`."""
    return jax.tree_util.tree_map(np.asarray, fn(*args))


#: seconds spent in calls that traced, loaded or compiled a program (process-wide, shared
#: by every compiled function of dano: :func:`~dano.sysid.identify` reports its own share)
COMPILE_SECONDS = _compiled.COMPILE_SECONDS


# compiled once per layout, scene structure and shapes, and traced once per structure across
# processes when the compilation cache is on (dano._compiled)
def _residuals_and_jacobian(layout, scene, base_params, data, theta_g, blocks):
    """(forward-mode Jacobian (m_padded, P + G + Σ block sizes), (residual, fitted frames per
    batch, Newton iterations per batch: :func:`segments_in_turn`)) of :func:`padded_residuals`,
    with respect to θ's global entries and one offset δ_b per batch added to every segment's
    block of that batch. A segment's residuals depend on no other segment's block, so its
    rows of the δ_b columns are its derivatives with respect to
    its own block (:meth:`SysIdProblem.jacobian_blocks` keeps them as its block's columns):
    the rollouts carry P + G + Σ block tangents, not all of θ's, whatever the segment count.
    One trace, the primal computed once with the tangents (tracing the rollout is most of a
    compilation's time); the frames give the fitted trajectories without a rollout program of
    their own."""
    sizes = [int(np.prod(b.shape[1:])) for b in blocks]
    starts = np.cumsum([theta_g.shape[0]] + sizes)

    def r(x):
        shifted = tuple(b + x[s : s + n].reshape(b.shape[1:]) for b, s, n in zip(blocks, starts, sizes))
        res, states, its = padded_residuals(layout, scene, base_params, data, x[: theta_g.shape[0]], shifted,
                                            with_frames=True)
        return res, (res, states, its)

    local = jnp.concatenate([theta_g, jnp.zeros(sum(sizes), theta_g.dtype)])
    return jax.jacfwd(r, has_aux=True)(local)


_residuals_and_jacobian_jit = cached_jit(_residuals_and_jacobian, static_argnums=(0,), mesh=_layout_mesh)
_residuals_only_jit = cached_jit(padded_residuals, static_argnums=(0,), mesh=_layout_mesh)  # finite differences


#: held while a problem decides whether its segments run in turn (one decision, whichever
#: thread asks first: :meth:`SysIdProblem._segments_in_turn`)
_DECIDING = threading.RLock()
#: the Jacobians whose failed steps a problem keeps (:meth:`SysIdProblem.failed_steps`), and its lock
FAILED_SEEN = 8
_SEEN = threading.Lock()

#: the least Newton-iteration waste (:func:`segments_in_turn`) at which, on a CPU, the
#: Jacobian rolls a problem's segments out one after the other instead of vmapped
IN_TURN_WASTE = 2.0
#: and the least Newton iterations its real segments need (Σ over segments and steps): below
#: it a Jacobian is short and the loop's own compilation would not pay for itself
IN_TURN_WORK = 5000


def segments_in_turn(iterations, members) -> bool:
    """Whether the Jacobian should roll the segments out one after the other, from the Newton
    iterations of a vmapped call: iterations, per batch (count, steps) int (the padded
    segments, copies of a real one, included); members, per batch, its real segments. The
    waste is what the vmapped loops run, every segment of a batch each step for its slowest
    segment's iterations, Σ_b count_b·Σ_t max_s it, over what the real segments need alone,
    Σ_b Σ_s Σ_t it: 1 for one segment, larger the more the counts differ from step to step.
    True on a CPU where the waste is at least :data:`IN_TURN_WASTE` and the real segments
    need at least :data:`IN_TURN_WORK` iterations (a vmap's lanes run in parallel elsewhere:
    False). Deterministic (iteration counts, not timings), so an identification's answer
    does not depend on the machine's load."""
    if jax.default_backend() != "cpu":
        return False
    ran = sum(it.shape[0] * it.max(axis=0).sum() for it in iterations)
    needed = sum(it[: len(m)].sum() for it, m in zip(iterations, members))
    return bool(needed >= IN_TURN_WORK and ran >= IN_TURN_WASTE * needed)


#: leading binary digits kept of a batch's longest segment's frame intervals (within 25 %,
#: e.g. 97 to 112 intervals run as 112): :func:`~dano._compiled.shape_bucket`
INTERVAL_BITS = 3


def segment_bucket(count: int) -> int:
    """A batch's segment count padded to a shared shape: 1, 2, 4, 6, 8, 12, 16, 24, 32, …
    (two leading binary digits, 3 run as 4, so that a fourth trajectory added to three
    reuses their compilation): at most 1.5× the segments simulated, 1.2× for 5."""
    return 4 if count == 3 else shape_bucket(count, 2)


#: parameter vectors per vmapped batch (:meth:`SysIdProblem.batch_residuals`): one compiled shape
#: (rounded up to a multiple of the devices in use when they split the batch)
BATCH = 16

#: on a CPU, the most segment rollouts (parameter vectors × a batch's padded segments) that
#: :meth:`SysIdProblem.batch_residuals` runs as one vmapped chunk (:func:`batch_chunk`)
CPU_ROLLOUTS_PER_CHUNK = 16


def batch_chunk(layout: "ResidualLayout", rows: int) -> int | None:
    """Parameter vectors per vmapped chunk of a batch of ``rows`` vectors (per device), or
    None for all of them at once (one vmap). On a GPU: None. On a CPU: enough vectors for
    :data:`CPU_ROLLOUTS_PER_CHUNK` segment rollouts of the layout's largest batch (at least
    one; one: a plain loop over the vectors), the chunks run one after the other
    (:func:`dano.sharding.map_rows`). A vmap over the vectors on top of the segments' own
    vmap made each vector's rollouts slower on a CPU than alone: measured on the 2-core VM
    (16 vectors, one XLA thread, float64), the bunny pushes (12 padded segments) 8.3–9.1 s
    one vector at a time against 13.6–15.5 s vmapped (one vector alone: 0.52–0.66 s); 40
    MuJoCo C slides of a mesh object (48) 1.2–1.6 s against 2.3–2.4 s; the soap (1 segment)
    keeps its vmap (0.06 s against 0.13 s a vector at a time); three slides (4) and five
    cube tosses (6) ran about as fast either way. Short, uniform rollouts lose a little: on
    32 vectors of the benchmark's box slides (20 frames, ``dano bench --suite sysid``:
    ``batch_by_segments``) the vmap was 1.21× and 1.07× faster with 4 and 16 slides (one XLA
    thread; 1.30× and 1.17× with XLA's threads), hundredths of a second, and 1.28× slower
    with 64 (1.08×)."""
    if jax.default_backend() != "cpu":
        return None
    chunk = max(1, CPU_ROLLOUTS_PER_CHUNK // max(b.count for b in layout.batches))
    return None if chunk >= rows else chunk


def _batch_residuals(layout, shards, chunk, scene, base_params, data, thetas_g, blocks):
    """Residuals (K, padded m) at K parameter vectors (their global entries (K, P + G) and
    nuisance blocks, per batch (K, count, ...)), the vectors split over ``shards`` devices
    and each device's evaluated ``chunk`` at a time (None: all at once; :func:`batch_chunk`),
    and each batch's failed steps per segment (K, count) int."""
    one = lambda th, bl: padded_residuals(layout, scene, base_params, data, th, bl, with_failures=True)  # noqa: E731
    return sharding.split_rows(one, sharding.mesh_of_size(shards), (0, 0), chunk)(thetas_g, blocks)


_batch_residuals_jit = cached_jit(_batch_residuals, static_argnums=(0, 1, 2),
                                  mesh=lambda layout, shards, chunk: sharding.mesh_of_size(shards))


#: contact parameters held at a neutral value when ``sliding_friction`` is identified and they
#: are neither identified nor given (``base_params``): the data cannot separate them from it
NEUTRAL_WITH_FRICTION = {"sliding_drag": 0.0}


def identification_params(scene: Scene, parameters: Sequence[FitParameter], given: dict | None = None
                          ) -> tuple[SimParams, tuple[str, ...]]:
    """The values of the parameters not identified: the paper's defaults with ``given``
    ({contact parameter: value}, e.g. a TOML's ``[contact]``) on top, except that the terms of
    :data:`NEUTRAL_WITH_FRICTION` are held neutral when ``sliding_friction`` is identified and
    they are neither identified nor given. Returns (SimParams, notes saying what was held).
    Raises TypeError for an unknown contact parameter (as ``scene.default_params``)."""
    given = dict(given or {})
    fitted = {p.name for p in parameters}
    neutral = {k: v for k, v in NEUTRAL_WITH_FRICTION.items()
               if "sliding_friction" in fitted and k not in fitted and k not in given}
    notes = tuple(f"{k} is held at {v} (a Coulomb world) while sliding_friction is identified: the data cannot "
                  "separate the two; identify it too, or give it (base_params, TOML [contact]), to change that"
                  for k, v in neutral.items())
    return scene.default_params(**{**neutral, **given}), notes


_AUTO_NOTE = "start velocities (fit_velocity auto):"
_STARTS_NOTE = "start velocities (start_velocity auto):"
_NEXT_FRAMES_TAKEN = 'start_velocity = "next frames"'  # (in the notes of starts taken so)
_GIVEN_NOTE = " (given: base_params or TOML [contact])"
_MISSING_NOTE = "rolled out from its own first frame, as windows are"  # (in every missing-frames note)


def _derived_anew(note: str, auto: bool) -> bool:
    """Whether ``note`` is one that SysIdProblem derives again on this construction: a given
    drag's (always), missing frames' (always), the start velocities' (when fit_velocity or
    start_velocity is "auto" again)."""
    return (_GIVEN_NOTE in note or _MISSING_NOTE in note or _JITTER_NOTE in note
            or auto and note.startswith((_AUTO_NOTE, _STARTS_NOTE)))


_JITTER_NOTE = "compared with the simulation interpolated to its own time"  # (in every jitter note)


def _well_formed_times(obs: Observation) -> bool:
    """Whether the time stamps are finite and increasing, at least 3 (what the checks refuse
    otherwise, naming the cause)."""
    t = np.asarray(obs.time, dtype=np.float64)
    return t.ndim == 1 and len(t) >= 3 and bool(np.all(np.isfinite(t))) and bool(np.all(np.diff(t) > 0))


def _check_jittered_rate(obs: Observation, scene: Scene, substeps: int, k: int) -> None:
    """Raises DanoError where time stamps that jitter are not at the simulation's frame rate
    (their median interval more than :data:`MAX_JITTER` from dt x substeps), naming the dt
    that would be."""
    step = scene.dt * substeps
    if not (_well_formed_times(obs) and is_jittered(obs) and abs(obs.frame_dt - step) <= 1e-9 * step):
        return  # (another frame interval given: the checks say where it fails)
    median = float(np.median(np.diff(np.asarray(obs.time, dtype=np.float64))))
    if abs(median / step - 1) > MAX_JITTER:
        raise DanoError(f"{obs.name or f'trajectory {k}'}: its time stamps jitter around a frame interval of about "
                        f"{median:.6g} s (the median; {1 / median:.4g} frames/s), which does not match the scene's "
                        f"time step {scene.dt:.6g} s x {substeps} substeps: set dt x substeps to the frame interval "
                        f"(for {substeps} substeps, dt about {median / substeps:.6g} s; the camera's nominal rate, "
                        "e.g. 1/30 s for 30 frames/s)")


def _jitter_note(obs: Observation, k: int) -> str | None:
    """What an observation whose time stamps jitter is fitted by (None where they do not)."""
    if not is_jittered(obs):
        return None
    step = obs.frame_dt
    worst = float(np.max(np.abs(grid_offsets(obs.time, step))))
    return (f"{obs.name or f'trajectory {k}'}: time stamps off the frame rate by up to {worst * 1e3:.3g} ms "
            f"({worst / step:.0%} of the frame interval dt x substeps = {step:.6g} s): each frame is {_JITTER_NOTE}")


def _missing_frames_note(obs: Observation, k: int) -> str | None:
    """What an observation that misses frames is fitted by (None where none is missing);
    raises DanoError where no run of :data:`MIN_RUN_FRAMES` consecutive frames is left, or its
    rest frames run past the first run."""
    runs = obs.runs()
    if len(runs) == 1:
        return None
    tag = obs.name or f"trajectory {k}"
    t = np.asarray(obs.time, dtype=np.float64)
    missing = int(round((t[-1] - t[0]) / obs.frame_dt)) + 1 - obs.num_frames
    short = [(a, n) for a, n in runs if n < MIN_RUN_FRAMES]
    if len(short) == len(runs):
        raise DanoError(f"{tag}: no {MIN_RUN_FRAMES} consecutive frames between its missing ones: a rollout starts "
                        f"from {MIN_RUN_FRAMES} (its start velocity is differenced from them)")
    if obs.rest_frames > runs[0][1]:
        raise DanoError(f"{tag}: rest_frames = {obs.rest_frames}, but frames are missing after frame {runs[0][1] - 1}")
    after = ", ".join(f"{t[a - 1]:.6g}" for a, _ in runs[1:][:5]) + (", ..." if len(runs) > 6 else "")
    left = (f"; runs of fewer than {MIN_RUN_FRAMES} frames are left out (frames "
            + ", ".join(f"{a}" if n == 1 else f"{a}-{a + n - 1}" for a, n in short[:5])
            + (", ..." if len(short) > 5 else "") + ")") if short else ""
    return (f"{tag}: {missing} frame{'s' if missing > 1 else ''} missing (after t = {after} s): each of its "
            f"{len(runs)} runs of consecutive frames is {_MISSING_NOTE}{left}")


def _given_drag_notes(params: SimParams, parameters: Sequence[FitParameter]) -> tuple[str, ...]:
    """A note where ``sliding_friction`` is identified with given parameters whose
    non-identified terms of :data:`NEUTRAL_WITH_FRICTION` are not neutral (e.g. the paper's
    drag of ``scene.default_params()``): such a term biases the friction on data from
    anywhere but a dano simulation with that value."""
    fitted = {p.name for p in parameters}
    if "sliding_friction" not in fitted:
        return ()
    notes = []
    for k, v in NEUTRAL_WITH_FRICTION.items():
        given = np.unique(np.asarray(getattr(params.contact, k), dtype=np.float64))
        if k not in fitted and np.any(given != v):
            notes.append(f"{k} is held at {', '.join(f'{x:g}' for x in given)}{_GIVEN_NOTE} "
                         f"while sliding_friction is identified: right for data simulated with it; on data from "
                         f"elsewhere (another engine, video) it biases the friction: give {k} = {v:g} or leave it "
                         f"out for a Coulomb world")
    return tuple(notes)


def _time_step_fix(frame_dt: float, dt: float, substeps: int) -> str:
    """What makes a frame interval ``frame_dt`` [s] and a time step ``dt`` [s] agree: the
    substeps (an identification TOML's ``[options] substeps``) where ``frame_dt`` is a whole
    multiple of ``dt`` (e.g. 100 frames/s on an MJCF's 5 ms step: 2), else the time step
    that ``substeps`` needs."""
    if frame_dt >= 1.0:  # frames a second or more apart: times in milliseconds, most likely
        return (f"frames {frame_dt:.6g} s apart are not a recording's rate: times must be in seconds (times in "
                f"milliseconds divided by 1000 give {frame_dt / 1000:.6g} s)")
    ratio = frame_dt / dt
    whole = round(ratio)
    if whole >= 1 and abs(ratio - whole) <= 1e-9 * ratio:
        return (f"set substeps = {whole} (the frame interval over the time step; TOML [options]), or the scene's "
                f"time step to {frame_dt / substeps:.6g} s")
    return f"for {substeps} substeps the scene's time step must be {frame_dt / substeps:.6g} s"


@dataclass(frozen=True, eq=False)
class SysIdProblem:
    """Identification of ``parameters`` from ``observations`` of ``scene``: a frozen
    specification. Its residual is a pure function of (layout, scene, base params, data, θ)
    (:func:`padded_residuals`); the compiled residual and Jacobian are cached by JAX on the
    static :class:`ResidualLayout` (and the scene's structure and the arrays' shapes), never
    stored on the problem, so problems of the same structure share them.

    weights: residual weights (:class:`Weights`); by default rotations are weighed by each
    DANO's size (:func:`rotation_length`), positions by 1/m². base_params: the values of the
    parameters not identified; by default the paper's, except that when ``sliding_friction``
    is identified the sliding drag (which the data cannot separate from it) is held at 0, a
    Coulomb world (:data:`NEUTRAL_WITH_FRICTION`; said in :attr:`notes`).
    substeps: simulation steps per frame interval (scene.dt must equal frame_dt/substeps);
    fit_velocity: axes ("x", "y", "z" letters) of each tracked DANO's initial linear
    velocity to fit as nuisance parameters, per segment (e.g. "xy"), "" for none, or "auto"
    (the default): the weighed axes where the start velocities come from finite differences
    of frames noisy enough to make them uncertain by more than :data:`START_VELOCITY_NOISE`
    of their typical speed, or of first frames that disagree by that much with the motion
    after them (:func:`stray_start_velocities`), else "" (resolved here; said in
    :attr:`notes`); window: split
    trajectories into windows of this many frame intervals, each rolled out from its
    observed state (multiple shooting for long or chaotic motions), or "auto": a window
    starting just before each impact the observation shows (:func:`impact_windows`);
    None: whole trajectories. Windows start from the observed pose and the measured
    velocities when given (``Observation.velocities``), else finite differences.
    fit_angular_velocity: axes of the initial angular velocity (body frame) to fit likewise.
    fit_position / fit_rotation: axes of an offset of each segment's initial position (world
    frame) and of a rotation vector (world frame) applied to its initial orientation, fitted
    likewise: an observed start carries the tracking noise of its frame(s).
    fit_ground: fit the height [m] of the ground plane (a real table is never exactly at
    z = 0) as one more nuisance parameter, ``ground_height``, the last entry of θ. It is
    applied by shifting the observed heights (exact, since a vertical shift leaves gravity
    unchanged, for scenes of DANOs on the ground plane only, all tracked: checked).
    fit_tilt: with fit_ground, also the ground's tilt, ``ground_tilt_x`` and
    ``ground_tilt_y`` [rad] (the rotation vector (t_x, t_y, 0) that takes the simulation's
    horizontal ground to the observed table), after ``ground_height`` at the end of θ. The
    observations are taken into the table's frame and gravity is tilted the other way
    (exact; residuals are compared in the table's frame, which equals the world's for
    isotropic position weights).
    start_prior: every fitted start-state offset also gets a pseudo-observation, one residual
    row saying what the observed frames say of it (:attr:`start_prior_rows`): a position offset
    is the start frame's error (√w·δp, like a frame's residual), a rotation offset likewise
    (L·δr), and a velocity offset the error of the finite-difference velocity, whose noise is
    g·σ/Δt for frames of position noise σ (g = :func:`finite_difference_gain` of
    1/``substeps``: √14 at one step per frame, √26/2 for many): Δt/g·√w·δv (angular:
    Δt/g·L·δω), in the residuals' own units, so that no noise level is needed. A pose
    offset's row counts as one frame more (N/(N + 1) of a start frame's own error is
    corrected); a velocity offset's row, where the frames determine it (a moving start: frame
    k moves by k·Δt·δv), weighs (1/g²)/Σk² of them, 0.02 % for a window of 10 intervals at
    one step per frame; where they do not (the velocity
    of a resting object into the floor, which its contact absorbs) the row holds the offset
    near the frames' value instead of letting the solver wander along a flat direction. The
    finite difference reuses frames 1 and 2, which are residuals too: counted twice, a
    negligible amount for moving starts, a little optimistic for the offsets' own standard
    errors. False: plain least squares over the frames.
    start_velocity: where a start that is neither measured nor given comes from: "first
    frames", its pose and the finite differences of its first three frames
    (:func:`finite_difference_velocity`); "next frames", at the starts that open a run of
    frames (a recording's first frame, the first after missing ones; not windows inside a
    run), the parabola through the :data:`NEXT_FRAMES` frames after the first
    (:func:`next_frames_start`: position and velocity); "auto" (the default): "next frames"
    where the first frames disagree with the motion after them along the weighed axes
    (:func:`stray_start_velocities`; said in :attr:`notes`, and then ``fit_velocity="auto"``
    fits the start velocities too), else "first frames" (resolved here; :func:`~dano.sysid.identify`
    takes :meth:`started_from_first_frames` where its scan fits better so).
    failure_substeps: the substeps a rollout step whose Newton solve fails is taken again in
    (:attr:`~dano.sim.NewtonConfig.failure_substeps`); 1 (the default): never, a program
    without the substeps' loop. :func:`~dano.sysid.identify` identifies again with
    :data:`~dano.sim.implicit.DEFAULT_FAILURE_SUBSTEPS` where its scan's rollouts diverge
    (:meth:`with_failure_substeps`).
    Raises DanoError for inconsistent input (see :func:`_check_observation`), unknown
    parameters, bounds that exclude the initial guess, or fewer residuals than parameters.
    """

    scene: Scene
    observations: Sequence[Observation]
    parameters: Sequence[FitParameter]
    weights: Weights = Weights()
    base_params: SimParams | None = None
    substeps: int = 1
    fit_velocity: str = "auto"
    window: int | str | None = None
    fit_ground: bool = False
    fit_angular_velocity: str = ""
    fit_tilt: bool = False
    fit_position: str = ""
    fit_rotation: str = ""
    notes: tuple[str, ...] = ()
    start_prior: bool = True
    start_velocity: str = "auto"
    failure_substeps: int = 1

    def __post_init__(self):
        def put(name, value):  # normalised fields of the frozen specification
            object.__setattr__(self, name, value)

        scene = self.scene
        put("observations", tuple(self.observations))
        put("parameters", tuple(self.parameters))
        put("fit_ground", bool(self.fit_ground))
        put("fit_tilt", bool(self.fit_tilt))
        put("substeps", int(self.substeps))
        put("start_prior", bool(self.start_prior))
        # time stamps that jitter (no frame interval given): at the simulation's frame interval,
        # each frame compared at its own time
        put("observations", tuple(dataclasses.replace(o, frame_interval=scene.dt * self.substeps)
                                  if o.frame_interval is None and _well_formed_times(o) and is_jittered(o) else o
                                  for o in self.observations))
        if self.fit_tilt and not self.fit_ground:
            raise DanoError("fit_tilt needs fit_ground: the tilt is the ground plane's, fitted with its height")
        if isinstance(self.failure_substeps, bool) or not isinstance(self.failure_substeps, (int, np.integer)) \
                or self.failure_substeps < 1:
            raise DanoError(f"failure_substeps must be an integer >= 1, got {self.failure_substeps!r}")
        put("failure_substeps", int(self.failure_substeps))
        if not self.observations:
            raise DanoError("no observed trajectories given")
        if self.fit_ground:
            _check_ground_only(scene, self.observations)
        kinds = (("fit_velocity", self.fit_velocity), ("fit_angular_velocity", self.fit_angular_velocity),
                 ("fit_position", self.fit_position), ("fit_rotation", self.fit_rotation))
        if not self.parameters and not any(axes for _, axes in kinds):
            raise DanoError("no parameters to identify")
        missing = []
        for k, obs in enumerate(self.observations):
            _check_jittered_rate(obs, scene, self.substeps, k)
            _check_observation(obs, scene, k)
            missing.append(_missing_frames_note(obs, k))
            missing.append(_jitter_note(obs, k))
            expected = obs.frame_dt / self.substeps
            if abs(expected - scene.dt) > 1e-9 * max(scene.dt, 1e-12) + 1e-12:
                raise DanoError(
                    f"{obs.name or f'trajectory {k}'}: frame interval {obs.frame_dt:.6g} s "
                    f"({1 / obs.frame_dt:.4g} frames/s) does not match the scene's time step {scene.dt:.6g} s x "
                    f"{self.substeps} substeps: {_time_step_fix(obs.frame_dt, scene.dt, self.substeps)}")
        w = self.weights
        wp = np.asarray(w.position, dtype=np.float64)
        if wp.shape != (3,) or not np.all(np.isfinite(wp)) or np.any(wp < 0) or not all(
                v is None or (np.isfinite(v) and v >= 0) for v in (w.rotation, w.joints)) or w.joints is None:
            raise DanoError(f"weights must be finite and non-negative with 3 position weights, got {w}")
        labels = [p.label for p in self.parameters]
        if len(set(labels)) != len(labels):
            raise DanoError(f"parameters are listed twice: {sorted({x for x in labels if labels.count(x) > 1})}")
        for name, axes in kinds:
            if name == "fit_velocity" and axes == "auto":
                continue
            if not isinstance(axes, str) or set(axes) - set("xyz") or len(set(axes)) != len(axes):
                raise DanoError(f"{name} must be made of the letters x, y, z, each at most once"
                                + (', or "auto"' if name == "fit_velocity" else "") + f", got {axes!r}")
        if self.start_velocity not in START_VELOCITIES:
            raise DanoError(f"start_velocity must be one of {', '.join(map(repr, START_VELOCITIES))}, "
                            f"got {self.start_velocity!r}")
        for p in self.parameters:
            if p.name not in ("alpha",) + INERTIAL_PARAMETERS + ContactParams.names():
                raise DanoError(f"unknown parameter {p.name!r}; known: alpha, {', '.join(INERTIAL_PARAMETERS)}, "
                                f"{', '.join(ContactParams.names())}")
            if p.target is not None and p.name in ("alpha",) + INERTIAL_PARAMETERS:
                scene.dano_index(p.target)
            elif p.target is not None and p.target not in scene.pair_names:
                raise DanoError(f"no contact pair {p.target!r}; pairs: {list(scene.pair_names)}")
            if not p.lower < p.upper:
                raise DanoError(f"bounds [{p.lower}, {p.upper}] of {p.label} are empty: lower must be below upper")
            if not (p.lower <= p.initial <= p.upper) or not np.isfinite(p.initial):
                raise DanoError(f"bounds [{p.lower}, {p.upper}] of {p.label} exclude the initial guess {p.initial}")
        # notes this method derives are made anew (dataclasses.replace passes the old ones on)
        put("notes", tuple(n for n in self.notes if not _derived_anew(n, "auto" in (self.fit_velocity,
                                                                                     self.start_velocity)))
            + tuple(n for n in missing if n))
        if self.base_params is None:
            params, notes = identification_params(scene, self.parameters)
            put("base_params", params)
            put("notes", self.notes + notes)
        else:
            put("notes", self.notes + _given_drag_notes(self.base_params, self.parameters))
        if "auto" in (self.fit_velocity, self.start_velocity):
            auto_fit = self.fit_velocity == "auto"
            put("notes", self.notes + self._auto_starts(put))
            if auto_fit and not self.parameters and not (self.fit_velocity or any(a for _, a in kinds[1:])):
                raise DanoError("no parameters to identify")
        n_res = self.num_observed_residuals  # also checks the window
        if n_res < self.num_parameters:
            raise DanoError(f"{n_res} residuals for {self.num_parameters} parameters: observe more frames "
                            "or fit fewer parameters")

    def _auto_starts(self, put) -> tuple[str, ...]:
        """Resolves ``start_velocity="auto"`` and ``fit_velocity="auto"`` (with ``put``,
        __post_init__'s setter) and returns the note saying why. Along the axes whose positions
        are weighed: where the first frames disagree with the motion after them
        (:func:`stray_start_velocities`), each start is taken from the next frames ("next
        frames", else "first frames"); the start velocities are fitted where finite
        differences of noisy frames make them uncertain by more than
        :data:`START_VELOCITY_NOISE` of their typical speed (:func:`noisy_start_velocities`) or
        the first frames disagree so, "" otherwise (no note), and not where those parameters
        would outnumber the residuals."""
        from .uncertainty import noise_of_observations  # (it imports this module)

        axes = self._weighed_axes()
        noise = noise_of_observations(self.observations)["position_m"]
        stray = stray_start_velocities(self.observations, self.segments, noise, axes)
        moved = ""
        if self.start_velocity == "auto":
            put("start_velocity", "next frames" if stray else "first frames")
            moved = (f"each rollout starts from the parabola through the {NEXT_FRAMES} frames after its first "
                     f"({_NEXT_FRAMES_TAKEN})") if stray else ""
        if self.fit_velocity != "auto":
            return (f"{_STARTS_NOTE} {stray}; {moved}",) if moved else ()
        why = noisy_start_velocities(self.observations, self.segments, noise, axes, self.substeps) or stray
        return self._fitted_start_velocities(put, why + (f"; {moved}" if moved else "") if why else None)

    def _weighed_axes(self) -> str:
        return "".join(a for a, w in zip("xyz", self.weights.position) if w > 0)

    def _fitted_start_velocities(self, put, why: str | None) -> tuple[str, ...]:
        """Sets ``fit_velocity`` as "auto" resolves it for the reason ``why`` (None: no
        reason, ""): the weighed axes, unless their offsets would outnumber the residuals;
        returns the note saying so."""

        def fit(axes):  # (and the layout derived from it made anew)
            put("fit_velocity", axes)
            for derived in ("fit_axes", "start_prior_rows"):
                self.__dict__.pop(derived, None)

        fit("")
        if why is None:
            return ()
        axes, without = self._weighed_axes(), self.num_parameters
        fit(axes)
        if self.num_observed_residuals < self.num_parameters:
            added = self.num_parameters - without
            fit("")
            return (f'{_AUTO_NOTE} not fitted: {why}, but {added} nuisance parameters would outnumber the residuals '
                    '(fewer or longer windows would allow them)',)
        return (f'{_AUTO_NOTE} fit_velocity = "{axes}": {why}; each segment start\'s velocity is fitted as a '
                'nuisance parameter (fit_velocity = "" turns this off)',)

    def started_from_first_frames(self) -> "SysIdProblem":
        """Where ``start_velocity="auto"`` took each start from the next frames (the first
        frames disagreed with the motion after them: :func:`stray_start_velocities`), the
        problem as "auto" resolves it where they agree: each rollout started from its first
        three frames (``start_velocity="first frames"``), and, where ``fit_velocity`` was
        "auto" too, the start velocities fitted only for the frames' noise
        (:func:`noisy_start_velocities`); their notes made anew. Otherwise the problem itself.
        :func:`~dano.sysid.identify` takes it where its scan fits better (a first frame that
        is right, and a motion that is no parabola after it: an engine's contact that hops)."""
        from .uncertainty import noise_of_observations  # (it imports this module)

        taken = [n for n in self.notes if n.startswith((_AUTO_NOTE, _STARTS_NOTE)) and _NEXT_FRAMES_TAKEN in n]
        if self.start_velocity != "next frames" or not taken:
            return self
        auto_fit = any(n.startswith(_AUTO_NOTE) for n in taken)
        plain = dataclasses.replace(self, start_velocity="first frames", fit_velocity="" if auto_fit else self.fit_velocity,
                                    notes=tuple(n for n in self.notes if n not in taken))
        if auto_fit:
            noise = noise_of_observations(plain.observations)["position_m"]
            why = noisy_start_velocities(plain.observations, plain.segments, noise, plain._weighed_axes(),
                                         plain.substeps)
            put = lambda name, value: object.__setattr__(plain, name, value)  # noqa: E731 (a new problem's own)
            put("notes", plain.notes + plain._fitted_start_velocities(put, why))
        return plain

    def as_identified(self, result) -> "SysIdProblem":
        """The problem :func:`~dano.sysid.identify`'s ``result`` came from (its estimates are
        that problem's θ): started from the first frames where the identification took them
        (``result.start_velocity``, :meth:`started_from_first_frames`), with the failed steps'
        substeps it took (:meth:`with_failure_substeps`); itself where neither changed."""
        problem = self
        if result.start_velocity == "first frames" and self.start_velocity == "next frames":
            problem = self.started_from_first_frames()
        return problem.with_failure_substeps(result.failure_substeps)

    def truncated(self, fraction: float) -> "SysIdProblem":
        """The same problem on the first ``fraction`` of every trajectory (at least 3 frames)."""
        obs = [o.frames(0, max(3, int(np.ceil(fraction * o.num_frames)))) for o in self.observations]
        return dataclasses.replace(self, observations=tuple(obs))

    def with_failure_substeps(self, n: int) -> "SysIdProblem":
        """The same problem whose rollouts take a step whose Newton solve fails again in ``n``
        substeps (a layout of its own: compiled anew); itself where it already does (e.g.
        ``problem.as_identified(result)`` after :func:`identify`)."""
        return self if n == self.failure_substeps else dataclasses.replace(self, failure_substeps=n)

    def with_initial(self, theta) -> "SysIdProblem":
        """The same problem with the global parameters' initial guesses set from θ (its
        compiled residual is the same: the layout does not change)."""
        params = [dataclasses.replace(p, initial=float(np.clip(v, p.lower, p.upper)))
                  for p, v in zip(self.parameters, theta)]
        return dataclasses.replace(self, parameters=tuple(params))

    # -- layout
    @functools.cached_property
    def fit_axes(self) -> tuple[int, ...]:
        """Nuisance offsets of each segment's initial state, per tracked DANO: 0–2 linear
        velocity x y z (world), 3–5 angular velocity (body), 6–8 position (world), 9–11
        rotation vector (world) (:func:`_with_offsets`)."""
        kinds = (self.fit_velocity, self.fit_angular_velocity, self.fit_position, self.fit_rotation)
        return tuple(3 * k + "xyz".index(c) for k, axes in enumerate(kinds) for c in axes)

    @functools.cached_property
    def segments(self) -> tuple[Segment, ...]:
        """The rollout segments: whole trajectories, or their windows; a trajectory that misses
        frames is split where it does (:meth:`Observation.runs`; runs of fewer than
        :data:`MIN_RUN_FRAMES` frames are left out)."""
        segs, window = [], self.window
        if window is not None and window != "auto" and (
                not isinstance(window, (int, np.integer)) or isinstance(window, bool) or window < 2):
            raise DanoError(f"window must be an integer of at least 2 frame intervals or 'auto', got {window!r}")
        for k, o in enumerate(self.observations):
            for first, T in o.runs():
                if T < MIN_RUN_FRAMES:
                    continue
                if window is None:
                    starts = [0]
                elif window == "auto":
                    starts = impact_windows(o.frames(first, first + T))
                else:
                    starts = list(range(0, T - 1, window))
                if len(starts) > 1 and T - 1 - starts[-1] < 2:
                    starts.pop()  # fold a 1-interval remainder into the previous window
                for i, s in enumerate(starts):
                    end = starts[i + 1] if i + 1 < len(starts) else T - 1
                    segs.append(Segment(k, first + s, end - s + 1))
        return tuple(segs)

    @functools.cached_property
    def _tracked(self) -> list[list[str]]:
        return [sorted(o.poses) for o in self.observations]

    @property
    def labels(self) -> list[str]:
        """Names of θ's entries: the global parameters (``name`` or ``target:name``) first,
        then for each segment, each tracked DANO (sorted by name) and each fitted axis, the
        initial linear velocity offset [m/s, world frame] added to the measured or
        finite-difference estimate, ``v0[segment]:dano:axis``, the angular ones [rad/s, body
        frame], ``w0[segment]:dano:axis``, the initial position offsets [m, world frame],
        ``p0[segment]:dano:axis``, and the components of a rotation vector [rad, world frame]
        applied to the initial orientation, ``r0[segment]:dano:axis`` (with ``fit_ground``, the
        world-frame offsets are in the table's frame); the ground's parameters last."""
        names = [p.label for p in self.parameters]
        for i, s in enumerate(self.segments):
            for d in self._tracked[s.obs]:
                names += [f"{'vwpr'[a // 3]}0[{i}]:{d}:{'xyz'[a % 3]}" for a in self.fit_axes]
        return names + self.ground_labels

    @property
    def ground_labels(self) -> list[str]:
        """The ground's nuisance parameters at the end of θ: ground_height [m], then with
        fit_tilt ground_tilt_x, ground_tilt_y [rad]."""
        return (["ground_height"] if self.fit_ground else []) + (
            ["ground_tilt_x", "ground_tilt_y"] if self.fit_tilt else [])

    def _table(self, theta):
        return _table(theta, self.fit_tilt)

    def _tilted_scene(self, R):
        return _tilted_scene(self.scene, R)

    @property
    def num_parameters(self) -> int:
        return len(self.labels)

    @property
    def num_residuals(self) -> int:
        """Residual count m: the frames' (:attr:`num_observed_residuals`) and the start
        prior's rows (:attr:`start_prior_rows`) after them."""
        return self.num_observed_residuals + len(self.start_prior_rows.index)

    @property
    def num_observed_residuals(self) -> int:
        """Residuals of the observed frames; components with zero weight are left out."""
        per_pose = len(self._pos_axes()) + (3 if self.weighs_rotations() else 0)
        n = 0
        for seg in self.segments:
            o = self.observations[seg.obs]
            n += (seg.frames - 1) * (per_pose * len(o.poses) + (len(o.joints) if self.weights.joints > 0 else 0))
        return n

    def _pos_axes(self) -> tuple[int, ...]:
        return tuple(k for k in range(3) if self.weights.position[k] > 0)

    def weighs_rotations(self) -> bool:
        """Whether the residual holds rotation terms (3 per observed pose, a rotation vector
        [rad] times :meth:`rotation_weights`): ``weights.rotation`` None (by size) or above 0."""
        return self.weights.rotation is None or self.weights.rotation > 0

    def rotation_weights(self) -> np.ndarray:
        """(D,) the square root of each DANO's rotation weight [m/rad with the default, by
        size: :func:`rotation_length`; else √weights.rotation]: its rotation residuals are
        rotation vectors [rad] times this."""
        if self.weights.rotation is None:
            return np.array([rotation_length(a) for a in self.scene.assets])
        return np.full(len(self.scene.dano_names), np.sqrt(float(self.weights.rotation)))

    @functools.cached_property
    def start_prior_rows(self) -> StartPriorRows:
        """The start prior's residual rows (see the class docstring), after the frames'
        residuals; empty without ``start_prior`` or fitted offsets. Rows of zero weight (an axis
        weighed 0) are left out, and so are the velocity offsets of starts whose velocity is not
        a finite difference (``qvel0``, measured ``velocities``, ``rest_frames``); a start pose
        averaged over k ``rest_frames`` weighs √k times a frame."""
        rows: list[tuple[int, float, int, int, float]] = []
        if self.start_prior and self.fit_axes:
            wpos = np.sqrt(np.asarray(self.weights.position, dtype=np.float64))
            wrot = self.rotation_weights() if self.weighs_rotations() else np.zeros(len(self.scene.dano_names))
            offsets, n_axes = self._nuisance_offsets(), len(self.fit_axes)
            gain = finite_difference_gain(1.0 / self.substeps)
            for s, seg in enumerate(self.segments):
                o = self.observations[seg.obs]
                first = seg.start == 0
                # a start pose averaged over k rest frames carries σ/√k; a start velocity that is
                # given (qvel0, measured velocities, or 0 for rest frames) has no finite difference
                # to stand for: its offsets get no row
                frames = min(o.rest_frames, seg.frames) if first and o.rest_frames > 1 else 1
                for b, name in enumerate(self._tracked[seg.obs]):
                    d = self.scene.dano_index(name)
                    differenced = name not in o.velocities and not (first and (o.qvel0 is not None or frames > 1))
                    for k, a in enumerate(self.fit_axes):
                        kind, axis = divmod(a, 3)  # velocity, angular velocity, position, rotation
                        unit = wrot[d] if kind in (1, 3) else wpos[axis]
                        if unit > 0 and (kind >= 2 or differenced):
                            scale = o.frame_dt / gain if kind < 2 else np.sqrt(frames)
                            rows.append((offsets[s] + b * n_axes + k, unit * scale, seg.obs,
                                         3 if kind in (1, 3) else axis, unit))
        index, weight, owner, noise, unit = zip(*rows) if rows else ((),) * 5
        return StartPriorRows(np.asarray(index, dtype=np.int64), np.asarray(weight, dtype=np.float64),
                              np.asarray(owner, dtype=np.int64), np.asarray(noise, dtype=np.int64),
                              np.asarray(unit, dtype=np.float64))

    def _prior_residuals(self, theta) -> np.ndarray:
        """(..., k) the start prior's rows at θ (..., n)."""
        prior = self.start_prior_rows
        return np.asarray(theta, dtype=np.float64)[..., prior.index] * prior.weight

    def _nuisance_offsets(self) -> np.ndarray:
        """Start of each segment's block of nuisance offsets (velocities, pose) in θ (after the global ones)."""
        counts = [len(self._tracked[s.obs]) * len(self.fit_axes) for s in self.segments]
        return len(self.parameters) + np.cumsum([0] + counts)

    def initial(self) -> np.ndarray:
        return np.array([p.initial for p in self.parameters] + [0.0] * (self.num_parameters - len(self.parameters)))

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        n_extra = self.num_parameters - len(self.parameters)
        lo = np.array([p.lower for p in self.parameters] + [-np.inf] * n_extra)
        hi = np.array([p.upper for p in self.parameters] + [np.inf] * n_extra)
        return lo, hi

    def sim_params(self, theta) -> SimParams:
        """SimParams with the identified parameters from θ (the rest from base_params)."""
        return _with_parameters(self.scene, self.base_params, [(p.name, p.target) for p in self.parameters], theta)

    # -- data per segment
    def _segment_data(self, seg: Segment):
        o, sc = self.observations[seg.obs], self.scene
        sl = slice(seg.start, seg.start + seg.frames)
        t = np.asarray(o.time, dtype=np.float64)[sl]
        qpos = np.array(o.qpos0, dtype=np.float64) if (o.qpos0 is not None and seg.start == 0) else sc.qpos0
        qvel = np.zeros(sc.nv)
        step = sc.dt  # differenced velocities are the integrator's: half a step early (also where stamps jitter)
        if o.qvel0 is not None and seg.start == 0:
            qvel = np.array(o.qvel0, dtype=np.float64)
        moving = seg.start > 0 or (o.qvel0 is None and o.rest_frames <= 1)  # velocity from the frames, not given
        for name, p in o.poses.items():
            p = np.asarray(p, dtype=np.float64)[sl]
            i = sc.dano_index(name)
            qpos[sc.qpos_adr[i] : sc.qpos_adr[i] + 7] = p[0]
            if (moving and name not in o.velocities and self.start_velocity == "next frames"
                    and len(t) > NEXT_FRAMES and _opens_a_run(o, seg)):
                position, velocity = next_frames_start(t, p, step)
                qpos[sc.qpos_adr[i] : sc.qpos_adr[i] + 3] = position
                qvel[sc.dof_adr[i] : sc.dof_adr[i] + 6] = velocity
                continue
            if seg.start == 0 and o.rest_frames > 1:
                k = min(o.rest_frames, len(p))
                mean_q = quat_mean(p[:k, 3:])
                qpos[sc.qpos_adr[i] : sc.qpos_adr[i] + 7] = np.r_[p[:k, :3].mean(0), mean_q]
            if moving:
                qvel[sc.dof_adr[i] : sc.dof_adr[i] + 6] = (
                    np.asarray(o.velocities[name], dtype=np.float64)[seg.start] if name in o.velocities
                    else finite_difference_velocity(t, p, step))
            elif o.qvel0 is None:  # known to be at rest
                qvel[sc.dof_adr[i] : sc.dof_adr[i] + 6] = 0.0
        jadr = []
        for name, v in o.joints.items():
            j = mujoco.mj_name2id(sc.mj_model, mujoco.mjtObj.mjOBJ_JOINT, name)
            qa, da = int(sc.mj_model.jnt_qposadr[j]), int(sc.mj_model.jnt_dofadr[j])
            v = np.asarray(v, dtype=np.float64)[sl]
            qpos[qa] = v[:min(o.rest_frames, len(v))].mean() if seg.start == 0 else v[0]
            if moving:
                qvel[da] = slope_weights(t[:3], 2, at=-0.5 * step) @ v[:3]  # as finite_difference_velocity's
            elif o.qvel0 is None:
                qvel[da] = 0.0
            jadr.append(qa)
        steps = (seg.frames - 1) * self.substeps
        ctrl = np.zeros((steps, sc.nu))
        if o.controls is not None:
            ctrl = np.repeat(np.asarray(o.controls, dtype=np.float64)[seg.start : seg.start + seg.frames - 1],
                             self.substeps, axis=0)
        qfrc = np.zeros((steps, sc.nv))
        if o.qfrc is not None:
            qfrc = np.repeat(np.asarray(o.qfrc, dtype=np.float64)[seg.start : seg.start + seg.frames - 1],
                             self.substeps, axis=0)
        settle = o.settle_steps if (seg.start == 0 and o.rest_frames > 1) else 0
        if settle:
            ctrl = np.concatenate([np.repeat(ctrl[:1], settle, axis=0), ctrl])
            qfrc = np.concatenate([np.zeros((settle, sc.nv)), qfrc])
        obs_pose = np.stack([np.asarray(o.poses[n], dtype=np.float64)[sl] for n in self._tracked[seg.obs]]) \
            if o.poses else np.zeros((0, seg.frames, 7))
        obs_joint = np.stack([np.asarray(v, dtype=np.float64)[sl] for v in o.joints.values()]) \
            if o.joints else np.zeros((0, seg.frames))
        didx = [sc.dano_index(n) for n in self._tracked[seg.obs]]
        data = dict(qpos0=qpos, qvel0=qvel, ctrl=ctrl, qfrc=qfrc, obs_pose=obs_pose, obs_joint=obs_joint)
        if self._jittered:
            data["shift"] = frame_shifts(t, o.frame_dt, self.substeps)
        return data, \
            (tuple(sc.qpos_adr[i] for i in didx), tuple(sc.dof_adr[i] for i in didx), tuple(jadr), steps, settle)

    @functools.cached_property
    def _jittered(self) -> bool:
        """Whether some observation's time stamps jitter (:func:`is_jittered`)."""
        return any(is_jittered(o) for o in self.observations)

    def _groups(self) -> dict:
        """Segments batched by layout (tracked bodies, joints, settling): {layout: [(segment
        index, its data, its steps)]}, the order in which the residual vector is built."""
        groups: dict = {}
        for i, seg in enumerate(self.segments):
            data, (qadr, dadr, jadr, steps, settle) = self._segment_data(seg)
            groups.setdefault((qadr, dadr, jadr, settle), []).append((i, data, steps))
        return groups

    @functools.cached_property
    def _structure(self) -> "_Structure":
        """The residual's static structure, its arrays, the indices of the real (not padded)
        entries of :func:`padded_residuals`' output, and where each batch's segments and
        nuisance blocks come from. Segments of the same layout are batched whatever their
        lengths: shorter ones are padded to the longest (extra steps simulated, their frames
        dropped by ``keep``)."""
        return self._build_structure(1)

    def _build_structure(self, shards: int) -> "_Structure":
        """:attr:`_structure` with each batch's segments split over ``shards`` devices. Each
        batch's segment count and frame intervals are padded to buckets (:func:`segment_bucket`,
        :data:`INTERVAL_BITS`), so that data sets of other counts and lengths in the same
        buckets share the compiled functions, the count then to a multiple of ``shards``:
        padded segments are copies of the batch's last one, padded frames repeat the last
        frame (their residuals are dropped by ``keep``)."""
        batches, arrays, wrot, keep, members, block_index, segment_rows, offset = [], [], [], [], [], [], [], 0
        rot_w = self.rotation_weights()
        nuisance = self._nuisance_offsets()
        for (qadr, dadr, jadr, settle), items in self._groups().items():
            real = len(items)
            items = items + [items[-1]] * (sharding.padded_size(segment_bucket(real), shards) - real)
            steps = shape_bucket(max(st for _, _, st in items) // self.substeps, INTERVAL_BITS) * self.substeps
            frames = steps // self.substeps + 1
            # (host arrays put on the device: jnp.asarray compiled a small program per shape)
            arrays.append({k: jax.device_put(np.stack([_pad(d[k], k, frames, settle + steps) for _, d, _ in items]))
                           for k in items[0][1]} | {"real": jax.device_put(np.arange(len(items)) < real)})
            cols = self._columns(qadr, jadr)
            intervals = [st // self.substeps for _, _, st in items[:real]] + [0] * (len(items) - real)
            keep.append(offset + _valid_residuals(intervals, frames - 1, cols))
            offset += len(items) * (frames - 1) * sum(cols)
            segment_rows.append((frames - 1) * sum(cols))
            batches.append(BatchLayout(len(items), qadr, dadr, jadr, settle + steps, settle))
            members.append(tuple(i for i, _, _ in items[:real]))
            block_index.append(np.stack([np.arange(nuisance[i], nuisance[i + 1]) for i, _, _ in items]))
            wrot.append(jax.device_put(np.asarray([rot_w[self.scene.qpos_adr.index(a)] for a in qadr],
                                                  dtype=np.float64)))
        layout = ResidualLayout(
            batches=tuple(batches), parameters=tuple((p.name, self.scene.target_index(p.name, p.target))
                                                     for p in self.parameters),
            fit_axes=self.fit_axes, pos_axes=self._pos_axes(), rotation=self.weighs_rotations(),
            joints=self.weights.joints > 0, substeps=self.substeps, fit_ground=self.fit_ground,
            fit_tilt=self.fit_tilt, shards=shards, jittered=self._jittered, failure_substeps=self.failure_substeps)
        data = {"batches": tuple(arrays), "wrot": tuple(wrot),
                "wpos": jax.device_put(np.sqrt(np.asarray(self.weights.position, dtype=np.float64))[
                    np.asarray(layout.pos_axes, dtype=int)]),
                "wjoint": jax.device_put(np.asarray(np.sqrt(self.weights.joints), dtype=np.float64))}
        n = self.num_parameters
        global_index = np.r_[np.arange(len(self.parameters)), np.arange(n - len(self.ground_labels), n)]
        keep = np.concatenate(keep) if keep else np.zeros(0, dtype=np.int64)
        block_rows, block_columns = self._block_rows(keep, offset, members, block_index, segment_rows, global_index)
        return _Structure(layout, data, keep, tuple(members), global_index.astype(np.int64), tuple(block_index),
                          tuple(segment_rows), block_rows, block_columns)

    def _block_rows(self, keep, padded, members, block_index, segment_rows, global_index):
        """Per batch, each segment's rows of the residual vector (its frames', then its start
        prior's, one per block entry; −1 where padded or without a prior row) and its θ
        columns (global, then its block): :class:`JacobianBlocks`' rows and columns."""
        where = np.full(padded, -1, dtype=np.int64)
        where[keep] = np.arange(len(keep))
        prior = self.start_prior_rows
        prior_row = np.full(self.num_parameters, -1, dtype=np.int64)
        prior_row[prior.index] = len(keep) + np.arange(len(prior.index))
        rows, cols, offset = [], [], 0
        for real, idx, per in zip(members, block_index, segment_rows):
            count = len(idx)
            own = prior_row[idx]
            own[len(real):] = -1  # (padded segments repeat the last real one's block)
            rows.append(np.concatenate([where[offset : offset + count * per].reshape(count, per), own], axis=1))
            cols.append(np.concatenate([np.broadcast_to(global_index, (count, len(global_index))), idx], axis=1))
            offset += count * per
        return tuple(rows), tuple(c.astype(np.int64) for c in cols)

    def segment_entries(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per segment (:attr:`segments`' order): (rows (R_s,) int, the residual entries that
        depend on its nuisance block: its frames' and its start prior's; block (b_s,) int, θ's
        entries of that block). The cost is separable in the blocks: with the global entries
        held, a segment's block changes its own rows only."""
        st = self._structure
        g = len(st.global_index)
        out = [None] * len(self.segments)
        for members, rows, cols in zip(st.members, st.block_rows, st.block_columns):
            for i, sid in enumerate(members):
                out[sid] = (rows[i][rows[i] >= 0], cols[i][g:])
        return out

    @property
    def layout(self) -> ResidualLayout:
        """The residual's static structure (what its compilation is keyed on)."""
        return self._structure.layout

    @property
    def data(self) -> dict:
        """The residual's arrays (a pytree): per batch the stacked initial states (qpos0,
        qvel0), controls, forces and observed poses/joints, and the weights' square roots."""
        return self._structure.data

    @property
    def keep(self) -> np.ndarray:
        """(m,) int: the entries of :func:`padded_residuals`' output that are residuals."""
        return self._structure.keep

    def split_theta(self, theta, structure: _Structure | None = None):
        """θ (..., n) as :func:`padded_residuals` takes it: its global entries (..., P + G) (the
        identified parameters, then the ground's) and per batch of :attr:`layout` (or of
        ``structure``'s, e.g. segments split over devices) the segments' nuisance blocks (...,
        count, tracked DANOs, len(fit_axes)) (padded segments repeat their batch's last block).
        NumPy or JAX arrays (the same kind back). Raises DanoError if θ's last axis is not n
        (:attr:`num_parameters`, in the order of :attr:`labels`)."""
        if theta.shape[-1:] != (self.num_parameters,):
            raise DanoError(f"theta must have {self.num_parameters} entries (SysIdProblem.labels: "
                            f"{', '.join(self.labels[:3])}{', ...' if self.num_parameters > 3 else ''}), "
                            f"got shape {tuple(theta.shape)}")
        st = self._structure if structure is None else structure
        xp = np if isinstance(theta, np.ndarray) else jnp
        blocks = tuple(theta[..., idx].reshape(theta.shape[:-1] + (b.count, len(b.qadr), len(self.fit_axes)))
                       for idx, b in zip(st.block_index, st.layout.batches))
        return xp.take(theta, st.global_index, axis=-1), blocks

    @functools.cached_property
    def _split(self) -> dict:
        """Structures for segments split over devices, built on first use: {shards: _Structure}."""
        return {}

    def _shards(self) -> int:
        """The devices the segments are split over with the devices in use (:mod:`dano.sharding`)."""
        return sharding.shards_for(max(len(m) for m in self._structure.members))

    def _split_segments(self) -> "_Structure":
        """The structure for the devices in use (:mod:`dano.sharding`): the segments of each
        batch split over as many devices as the largest batch can use; one device: the plain
        :attr:`_structure`."""
        shards = self._shards()
        if shards == 1:
            return self._structure
        if shards not in self._split:
            self._split[shards] = self._build_structure(shards)
        return self._split[shards]

    def residuals_and_jacobian(self, theta) -> tuple[np.ndarray, np.ndarray]:
        """(m,) residual vector and (m, n) its forward-mode Jacobian at θ (n,), compiled once
        per structure (:class:`ResidualLayout`, scene, shapes). The segments are split over the
        devices in use (:mod:`dano.sharding`; the same values as on one device)."""
        blocks = self.jacobian_blocks(theta)
        return blocks.residuals, blocks.dense()

    def jacobian_blocks(self, theta) -> JacobianBlocks:
        """The residual (m,) at θ (n,) and its Jacobian per segment (:class:`JacobianBlocks`:
        the same values as :meth:`residuals_and_jacobian`, without the zeros of an (m, n)
        matrix): what solvers of many segments factor block by block."""
        return self._blocks_and_frames(theta)[0]

    @functools.cached_property
    def _in_turn(self) -> dict:
        """{shards: whether the Jacobian rolls the segments out one after the other}
        (:meth:`_segments_in_turn`)."""
        return {}

    def _segments_in_turn(self, st: "_Structure") -> bool:
        """Whether this problem's Jacobian rolls its segments out one after the other
        (:func:`segments_in_turn`), decided once per device split from the iterations of the
        vmapped Jacobian at the initial θ: the same decision whichever of the threads that
        run local starts side by side asks first. No batch of two segments or more, or not
        a CPU: vmapped, without that call."""
        decided = self._in_turn.get(st.layout.shards)
        if decided is not None:  # (without the lock: another problem may hold it while it decides)
            return decided
        with _DECIDING:
            if st.layout.shards not in self._in_turn:
                turn = False
                if jax.default_backend() == "cpu" and any(len(m) > 1 for m in st.members):
                    theta = np.asarray(self.initial(), dtype=np.float64)
                    out = _run(_residuals_and_jacobian_jit, st.layout, self.scene, self.base_params, st.data,
                               *jax.device_put(self.split_theta(theta, st)))
                    turn = segments_in_turn([its for its, _ in out[1][2]], st.members)
                    if not turn:  # the first Jacobian asked for is usually the initial θ's (a local start's)
                        self._in_turn_probe[st.layout.shards] = (theta.tobytes(), out)
                self._in_turn[st.layout.shards] = turn
            return self._in_turn[st.layout.shards]

    @functools.cached_property
    def _in_turn_probe(self) -> dict:
        """{shards: (θ's bytes, the vmapped program's output there)} of the call that decided
        :meth:`_segments_in_turn`, kept for the next Jacobian if it asks for the same θ."""
        return {}

    def _blocks_and_frames(self, theta):
        theta = np.asarray(theta, dtype=np.float64)
        # (keyed by the devices' split too: the same θ on other devices is evaluated there)
        key = (theta.tobytes(), self._shards())
        with _SEEN:
            last = self._last_blocks.get(key)
        if last is None:
            last = self._evaluate_blocks(theta)
            with _SEEN:  # (one: the answer's residual, fitted rollouts and failed steps ask for the same θ)
                self._last_blocks.clear()
                self._last_blocks[key] = last
        return last

    @functools.cached_property
    def _last_blocks(self) -> dict:
        """{(θ's bytes, the segments' split over devices): :meth:`_blocks_and_frames` there} of
        the last evaluation."""
        return {}

    def _evaluate_blocks(self, theta: np.ndarray):
        st = self._split_segments()
        theta_g, blocks = self.split_theta(theta, st)
        layout = dataclasses.replace(st.layout, in_turn=True) if self._segments_in_turn(st) else st.layout
        probe = self._in_turn_probe.pop(st.layout.shards, None)
        if probe is not None and probe[0] == theta.tobytes():
            Jl, (r, states, steps) = probe[1]
        else:
            Jl, (r, states, steps) = _run(_residuals_and_jacobian_jit, layout, self.scene, self.base_params, st.data,
                                          *jax.device_put((theta_g, blocks)))
        failed = tuple(f for _, f in steps)
        with _SEEN:  # (local starts run side by side in threads)
            self._failed_seen[theta.tobytes()] = failed
            while len(self._failed_seen) > FAILED_SEEN:
                self._failed_seen.pop(next(iter(self._failed_seen)))
        # each segment's rows: the global columns as they are, its batch's δ columns for its block,
        # then its start prior's rows (r_i = w_i·θ[index_i]: w_i in the entry's column)
        prior = self.start_prior_rows
        weight = np.zeros(len(theta))
        weight[prior.index] = prior.weight
        values, row, col, g = [], 0, len(theta_g), len(theta_g)
        for idx, rows in zip(st.block_index, st.segment_rows):
            count, size = idx.shape
            Lb = Jl[row : row + count * rows].reshape(count, rows, -1)
            own = np.zeros((count, size, g + size))
            own[:, np.arange(size), g + np.arange(size)] = weight[idx]
            values.append(np.concatenate([np.concatenate([Lb[:, :, :g], Lb[:, :, col : col + size]], axis=2), own],
                                         axis=1))
            row, col = row + count * rows, col + size
        residuals = np.concatenate([r[st.keep], self._prior_residuals(theta)])
        return (JacobianBlocks(residuals, st.block_rows, st.block_columns, tuple(values), len(theta)), st, states,
                failed)

    @functools.cached_property
    def _failed_seen(self) -> dict:
        """{θ's bytes: each batch's (count, steps) bool failed steps} of the last
        :data:`FAILED_SEEN` Jacobians (:meth:`failed_steps` at a local solve's answer: its last
        Jacobian's, no evaluation of its own)."""
        return {}

    def fitted(self, theta) -> list[np.ndarray]:
        """Fitted qpos (frames, nq) of every segment at θ (n,), as :meth:`simulate` gives them
        (MuJoCo generalized positions; the tracked DANOs' poses [m, wxyz] in the observations'
        frame, also when the ground is fitted), from the residual's own rollouts: the
        Jacobian's compiled program, so no rollout program of its own to compile; the same
        steps, batched as the residual batches them (equal to :meth:`simulate` to rounding)."""
        _, st, states, _ = self._blocks_and_frames(theta)
        return [np.array(states[b][i, : seg.frames]) for seg, (b, i) in zip(self.segments, st.slots())]

    def failed_steps(self, theta) -> np.ndarray:
        """(segments,) int: how many steps of each segment's rollout at θ (n,) failed (their
        Newton solve did not converge, or a contact pair turned by more than
        :data:`~dano.sim.implicit.MAX_TURN_CHANGE` over the step:
        :attr:`~dano.sim.dynamics.StepInfo.failed`; taken again in substeps where
        :attr:`failure_substeps` > 1, kept as they are otherwise). From the Jacobian's compiled
        program, as :meth:`fitted`: no evaluation where one of the last Jacobians was at θ (a
        local solve's last is at its answer), else one."""
        theta = np.asarray(theta, dtype=np.float64)
        with _SEEN:
            failed = self._failed_seen.get(theta.tobytes())
        if failed is None:
            _, _, _, failed = self._blocks_and_frames(theta)
        return np.array([int(np.sum(failed[b][i])) for b, i in self._split_segments().slots()])

    def residuals(self, theta) -> np.ndarray:
        """(m,) residual vector at θ (n,) (see :meth:`residuals_and_jacobian`: the same compiled
        function, so no second compilation in an AD solve)."""
        return self.residuals_and_jacobian(theta)[0]

    def residuals_only(self, theta) -> np.ndarray:
        """(m,) residual vector at θ (n,) without the Jacobian's tangents: a compilation of its
        own, worth it where residuals are evaluated many times without Jacobians
        (finite-difference solves)."""
        st = self._split_segments()
        theta = np.asarray(theta, dtype=np.float64)
        r = _run(_residuals_only_jit, st.layout, self.scene, self.base_params, st.data,
                 *jax.device_put(self.split_theta(theta, st)))
        return np.concatenate([r[st.keep], self._prior_residuals(theta)])

    def jacobian(self, theta) -> np.ndarray:
        """(m, n) forward-mode Jacobian of the residual at θ (see :meth:`residuals_and_jacobian`)."""
        return self.residuals_and_jacobian(theta)[1]

    def batch_residuals(self, thetas, *, failures: bool = False):
        """(K, m) residual vectors at K parameter vectors (K, n), vmapped in batches of
        :data:`BATCH` (the last one padded: compiled once per structure); each batch's vectors
        are split over the devices in use (:mod:`dano.sharding`) and, on a CPU, run a chunk at a
        time (:func:`batch_chunk`). Each vector's residuals are what it gives alone.
        failures=True: also (K, segments) int, each segment's failed steps
        (:meth:`failed_steps`) at each vector (the same program)."""
        thetas = np.asarray(thetas, dtype=np.float64)
        shards = sharding.shards_for(BATCH)
        size = sharding.padded_size(BATCH, shards)
        slots = self._structure.slots()
        out, failed = [], np.zeros((len(thetas), len(self.segments)), dtype=int)
        for start in range(0, len(thetas), size):
            chunk = thetas[start : start + size]
            padded = np.concatenate([chunk, np.repeat(chunk[-1:], size - len(chunk), axis=0)])
            r, counts = _run(_batch_residuals_jit, self.layout, shards, batch_chunk(self.layout, size // shards),
                             self.scene, self.base_params, self.data,
                             *jax.device_put(self.split_theta(padded)))
            out.append(np.concatenate([r[: len(chunk)][:, self.keep], self._prior_residuals(chunk)], axis=1))
            for sid, (b, i) in enumerate(slots):
                failed[start : start + len(chunk), sid] = counts[b][: len(chunk), i]
        residuals = np.concatenate(out) if out else np.zeros((0, self.num_residuals))
        return (residuals, failed) if failures else residuals

    def _column_kinds(self, qadr, jadr) -> list[tuple[str, int, int]]:
        """Residual blocks of a segment as (kind, columns per frame, DANO index in the scene
        or joint slot): per tracked DANO the weighted position axes ("position") and the
        rotation vector ("rotation"), then one per joint ("joint"); zero weights left out."""
        npos, wrot, wjoint = len(self._pos_axes()), self.weighs_rotations(), self.weights.joints > 0
        out = []
        for a in qadr:
            d = self.scene.qpos_adr.index(a)
            out += ([("position", npos, d)] if npos else []) + ([("rotation", 3, d)] if wrot else [])
        return out + ([("joint", 1, j) for j in range(len(jadr))] if wjoint else [])

    def _columns(self, qadr, jadr) -> list[int]:
        """Residual columns per frame of each block of a segment (:meth:`_column_kinds`)."""
        return [c for _, c, _ in self._column_kinds(qadr, jadr)]

    def _residual_blocks(self):
        """(observation index, kind, columns, frames, DANO index) of each block of the residual
        vector, in the order of :meth:`residual_function`'s output; kind: "position",
        "rotation", "joint"."""
        for (qadr, _, jadr, _), items in self._groups().items():
            for i, _, steps in items:
                for kind, cols, d in self._column_kinds(qadr, jadr):
                    yield self.segments[i].obs, kind, cols, steps // self.substeps, d

    def residual_observations(self) -> np.ndarray:
        """(m,) int: the observation (trajectory index) each residual belongs to, in the order
        of :meth:`residual_function`'s output (used to resample whole trajectories), the start
        prior's rows included."""
        return self._per_residual(lambda obs, kind: obs, self.start_prior_rows.observation).astype(np.int64)

    def residual_kinds(self) -> np.ndarray:
        """(m,) str: what each residual measures, in the order of :meth:`residual_function`'s
        output: "position", "rotation", "joint", or "start prior" (the start prior's rows)."""
        prior = self.start_prior_rows.observation
        return self._per_residual(lambda obs, kind: kind, np.full(len(prior), "start prior")).astype(str)

    def _per_residual(self, value, prior) -> np.ndarray:
        """(m,) ``value(observation index, kind)`` of each block's residuals, then ``prior`` (the
        start prior's rows), in the order of :meth:`residual_function`'s output."""
        return np.concatenate([np.full(cols * frames, value(obs, kind))
                               for obs, kind, cols, frames, _ in self._residual_blocks()] + [prior])

    def residual_series(self) -> list[np.ndarray]:
        """Index arrays into the residual vector, one per residual column of each block: the
        time series (frame by frame) of one component, for autocorrelation estimates (the
        start prior's rows, which are no time series, in none)."""
        out, start = [], 0
        for _, _, cols, frames, _ in self._residual_blocks():
            block = start + np.arange(cols * frames).reshape(frames, cols)
            out += [block[:, c] for c in range(cols)]
            start += cols * frames
        return out

    def residual_noise(self, position, rotation_deg, joints: float = 0.0) -> np.ndarray:
        """(m,) standard deviation of each residual [residual units] when the observed poses
        carry independent Gaussian noise: ``position`` [m] per axis (a number, or (3,) per
        axis x y z), ``rotation_deg`` [deg] the rms rotation angle (a rotation vector with
        ``rotation_deg``/√3 per axis, as :func:`~dano.experiments.sysid_examples.push_observations` draws
        it) and ``joints`` [joint units]; scaled by the weights' square roots like the
        residuals. Raises DanoError if a level is negative or not finite, or if a weighted
        component would have no noise."""
        pos = np.broadcast_to(np.asarray(position, dtype=np.float64), (3,))
        for name, v in (("position", pos), ("rotation_deg", rotation_deg), ("joints", joints)):
            if not np.all(np.isfinite(v) & (np.asarray(v) >= 0)):
                raise DanoError(f"noise level {name} must be a finite number >= 0, got {v}")
        axes = list(self._pos_axes())
        wpos = np.sqrt(np.asarray(self.weights.position, dtype=np.float64))[axes]
        rot_w = self.rotation_weights()
        out = []
        for _, kind, cols, frames, d in self._residual_blocks():
            if kind == "position":
                sd = pos[axes] * wpos
            elif kind == "rotation":
                sd = np.full(3, np.radians(rotation_deg) / np.sqrt(3) * rot_w[d])
            else:
                sd = np.full(1, joints * np.sqrt(self.weights.joints))
            if np.any(sd[:cols] <= 0):
                raise DanoError(f"the residuals include {kind} observations but their noise level is zero")
            out.append(np.tile(sd[:cols], frames))  # frame by frame, columns inside
        # a start prior row's noise: its frame's, in the frame residuals' units (zero levels of
        # the kinds it weighs were refused above: it weighs only axes the frames' residuals weigh)
        prior = self.start_prior_rows
        return np.concatenate(out + [np.r_[pos, np.radians(rotation_deg) / np.sqrt(3)][prior.noise] * prior.unit])

    def residual_function(self):
        """(θ) -> residual vector (m,), a pure JAX function (jit/jacfwd it; forward mode only
        with per-sample contact, :func:`forward_only`): :func:`padded_residuals`
        on this problem's layout and data, padded entries dropped. Residuals are ordered by
        batch, then segment, then block (per tracked DANO its position axes with non-zero weight
        [m·√w] and its rotation vector [rad·√w], then each joint), each block frame by frame
        (:meth:`_column_kinds`), then the start prior's rows (:attr:`start_prior_rows`)."""
        layout, data = self.layout, self.data
        scene, base, keep = self.scene, self.base_params, jnp.asarray(self.keep)
        index, weight = jnp.asarray(self.start_prior_rows.index), jnp.asarray(self.start_prior_rows.weight)
        return lambda theta: jnp.concatenate([
            padded_residuals(layout, scene, base, data, *self.split_theta(jnp.asarray(theta)))[keep],
            theta[index] * weight])

    def simulate(self, theta) -> list[np.ndarray]:
        """Fitted qpos (frames, nq) of every segment at θ (for plots and reports)."""
        params = self.sim_params(jnp.asarray(theta))
        axes, offsets = self.fit_axes, self._nuisance_offsets()
        out = []
        segments = [self._segment_data(seg) for seg in self.segments]
        # every segment rolled out for the longest one's steps (controls and forces padded with
        # zeros, states cut afterwards): one compilation instead of one per distinct length
        longest = max(settle + steps for _, (_, _, _, steps, settle) in segments)
        for sid, (data, (qadr, dadr, jadr, steps, settle)) in enumerate(segments):
            qpos0, qvel0, sim_scene = jnp.asarray(data["qpos0"]), jnp.asarray(data["qvel0"]), self.scene
            if self.fit_ground:
                height, R = self._table(jnp.asarray(theta))
                qpos0, qvel0 = _to_table(qpos0, qvel0, qadr, dadr, height, R)
                sim_scene = self._tilted_scene(R) if self.fit_tilt else self.scene
            block = jnp.asarray(theta)[offsets[sid] : offsets[sid + 1]].reshape(len(qadr), len(axes))
            qpos0, qvel0 = _with_offsets(qpos0, qvel0, block, qadr, dadr, axes)
            extra = self.substeps if self._jittered else 0  # (as padded_residuals rolls out)
            ctrl, qfrc = (jnp.asarray(_pad(np.asarray(data[k]), k, 0, longest + extra)) for k in ("ctrl", "qfrc"))
            qpos, _, _ = rollout_arrays(sim_scene, State(qpos0, qvel0), ctrl, params, longest + extra, qfrc,
                                        overlaps=False, newton=forward_only(self.failure_substeps))
            shift = jnp.asarray(data["shift"]) if self._jittered else None
            qpos = _at_frames(jnp.asarray(qpos), settle, self.substeps, steps // self.substeps + 1, shift,
                              tuple(a + 3 for a in qadr))
            if self.fit_ground:  # back in the observations' frame
                for a in qadr:
                    back = _poses_from_table(qpos[:, a : a + 7], height, R)
                    qpos = qpos.at[:, a : a + 7].set(back)
            out.append(np.array(qpos))
        return out

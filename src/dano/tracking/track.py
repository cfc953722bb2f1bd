"""Pose tracking in video: silhouettes (the paper, §VI-A) and colour (its limitation iii).

Per frame k the object's body pose p = (position [m], wxyz quaternion; a DANO's qpos) minimises

    L(p) = mean_px (α(p) − M)²  +  w_B·‖B(α(p)) − B(M)‖²  [+ w_C·mean_px ρ((C(p) − I)/s)]  [+ w_S·‖δ‖²]

with α the rendered silhouette coverage (:func:`dano.render.silhouette.silhouette_rays`), M the
mask averaged over the same pixel blocks, B the barycentre in image coordinates (divided by
the image diagonal), C the colour volume-rendered from a radiance field over the background
frame (:func:`dano.render.render_rays`), I the frame, ρ(x) = x²/√(1 + x²) a robust loss
(mean over colour channels) and δ = (translation / object
size, rotation vector [rad]) the step from the prediction. Adam (optax) runs a fixed number
of iterations per frame from a constant-velocity prediction of the previous two poses
(the previous pose after a frame flagged poor), with the learning rate decaying
log-linearly; the lowest-loss iterate is kept. The loss is a sum of squares; the colour
residual is x/(1 + x²)^¼ with x = (C − I)/s, so its square is quadratic near 0 and grows
linearly: robust to shading the field did not see.

To keep frames cheap only rays near the object are rendered: the mask's pixels and the
previous frame's silhouette, dilated by ``margin`` of the object's size in pixels; the
rest count as α = 0 = M. Ray sets are padded to multiples of 512, so a video compiles a
few times at most. The colour term, a volume render of the radiance field, is evaluated
on ``colour_rays`` of those rays drawn at random for each frame (its sum scaled by the
ratio, an unbiased estimate), and with the field's occupancy grid only the samples in
occupied cells are evaluated (``colour_samples`` per ray on average; rays that do not fit
are left out): on the synthetic slide all rays densely took > 55 s per frame.

A frame is flagged **poor** when the intersection over union of α and M is below
``poor_iou``: tracking loss is reported, not silently kept.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax

from ..errors import DanoError
from ..pose import (normalize_quat, quat_error, quat_inverse, quat_multiply, quat_to_matrix, rotvec_to_quat,
                    velocity_from_poses)
from ..render.cameras import pixel_rays, project_points
from ..render.silhouette import silhouette_rays
from ..render.volume import RenderConfig, render_rays
from .inputs import VideoInput

_BUCKET = 512


@dataclass(frozen=True)
class TrackConfig:
    """Settings of :func:`track`. Raises DanoError naming the first bad setting. (A
    Levenberg–Marquardt polish after Adam was tried and dropped: on the synthetic slide 5
    steps per frame took 4.3 s per frame instead of 2.3 s and left the RMS error at 10.9 mm
    instead of 11.0.)"""

    iterations: int = 60
    """Adam steps per frame, >= 1."""
    learning_rate: float = 0.01
    """Adam's initial step per frame [δ units: object sizes and radians], > 0."""
    final_learning_rate: float = 0.001
    """Adam's step at the frame's last iteration (log-linear decay) [δ units], > 0."""
    stride: int = 2
    """Pixels per block along each image axis (one ray per block, masks averaged over it), >= 1."""
    barycentre_weight: float = 1.0
    """Weight w_B of the silhouette barycentre term [-], >= 0."""
    colour_weight: float = 0.0
    """Weight w_C of the colour term [-], >= 0; 0: silhouette only; > 0 needs a radiance field."""
    colour_scale: float = 0.05
    """Scale s of the colour residual's robust loss [colour units in 0–1], > 0."""
    smoothness_weight: float = 0.0
    """Weight w_S of a prior toward the constant-velocity prediction [-], >= 0."""
    samples_across: int = 96
    """Render samples across the field box's diagonal, >= 1."""
    margin: float = 0.25
    """Ray-set dilation around the mask and the previous silhouette [fraction of the object's size], >= 0."""
    poor_iou: float = 0.8
    """Frames whose silhouette intersection over union is below this are flagged poor, in [0, 1]."""
    cold_start_passes: int = 5
    """Adam runs (of ``iterations`` steps each) at most on a frame that starts from no constant-velocity prediction
    (the first two frames, and the two after a poor one), each from the last run's pose, until the loss falls by
    less than 1 %, >= 1."""
    colour_rays: int = 1024
    """Rays of the colour term per frame, drawn at random from the ray set; 0: every ray of it."""
    colour_samples: int = 32
    """Field evaluations per colour ray on average when the radiance field has an occupancy grid (the render's
    budget), >= 1."""

    def check(self) -> "TrackConfig":
        """Old API, kept: the settings are checked when the config is built; returns it."""
        return self

    def __post_init__(self):
        for name in ("iterations", "stride", "samples_across", "colour_samples", "cold_start_passes"):
            if int(getattr(self, name)) < 1:
                raise DanoError(f"{name} must be at least 1, got {getattr(self, name)}")
        for name in ("learning_rate", "final_learning_rate", "colour_scale"):
            v = float(getattr(self, name))
            if not np.isfinite(v) or v <= 0:
                raise DanoError(f"{name} must be positive, got {v}")
        for name in ("barycentre_weight", "colour_weight", "smoothness_weight", "margin"):
            v = float(getattr(self, name))
            if not np.isfinite(v) or v < 0:
                raise DanoError(f"{name} must be non-negative, got {v}")
        if int(self.colour_rays) < 0:
            raise DanoError(f"colour_rays must be non-negative, got {self.colour_rays}")
        if not 0 <= self.poor_iou <= 1:
            raise DanoError(f"poor_iou must be in [0, 1], got {self.poor_iou}")


@dataclass(frozen=True)
class TrackedObject:
    """What is tracked: ``field`` (a DensityField, object frame [m]; ideally with
    ``signed_distance``); ``center_of_mass`` (3,) object frame [m] (poses are of the body
    frame: origin there, object axes); ``size`` [m] (its box diagonal: the unit of
    translation steps and errors); ``radiance``: a radiance field in the same object frame
    (``radiance(points, dirs) -> (σ, rgb)``, e.g. a trained :class:`~dano.nerf.HashGridField`)
    for the colour term, or None; ``radiance_occupancy``: its
    :class:`~dano.render.OccupancyGrid` (from :func:`~dano.nerf.load_field`; the colour term
    then evaluates only occupied samples), or None."""

    field: Any
    center_of_mass: np.ndarray
    size: float
    radiance: Any = None
    name: str = "object"
    radiance_occupancy: Any = None

    @classmethod
    def from_asset(cls, asset, radiance=None, radiance_occupancy=None) -> "TrackedObject":
        """From a DanoAsset that stores its field. Raises DanoError if it does not."""
        if asset.field is None:
            raise DanoError(f"{asset.name}: the DANO does not store its density field; tracking renders the field "
                            "(build it from a field, mesh or voxel grid so that it is kept)")
        b = np.asarray(asset.field.bounds(), dtype=np.float64)
        return cls(asset.field, np.asarray(asset.center_of_mass, dtype=np.float64),
                   float(np.linalg.norm(b[1] - b[0])), radiance, asset.name, radiance_occupancy)


@dataclass(frozen=True)
class TrackResult:
    """time (T,) [s]; poses (T, 7) body pose per frame: position [m], wxyz quaternion;
    loss (T,); iou (T,) silhouette intersection over union; poor (T,) bool; per-frame wall
    time [s]; config; alpha: (T, H/s, W/s) the final silhouettes (for overlays); stride;
    cold_start_passes: the Adam runs of each frame that started from no prediction."""

    time: np.ndarray
    poses: np.ndarray
    loss: np.ndarray
    iou: np.ndarray
    poor: np.ndarray
    frame_time_s: np.ndarray
    config: TrackConfig
    alpha: np.ndarray
    stride: int
    cold_start_passes: tuple = ()
    """Adam runs each frame that started from no prediction took, in order (TrackConfig.cold_start_passes)."""

    def summary(self) -> dict:
        return {"frames": int(len(self.time)), "poor_frames": int(self.poor.sum()),
                "cold_start_passes": [int(n) for n in self.cold_start_passes],
                "mean_iou": float(self.iou.mean()), "min_iou": float(self.iou.min()),
                "time_per_frame_s": float(np.median(self.frame_time_s)), "config": asdict(self.config)}


def block_average(images: np.ndarray, stride: int) -> np.ndarray:
    """(T, H, W, …) -> (T, H//s, W//s, …): means over s × s pixel blocks (the remainder cropped)."""
    t, h, w = images.shape[:3]
    hb, wb = h // stride, w // stride
    x = images[:, : hb * stride, : wb * stride]
    return x.reshape(t, hb, stride, wb, stride, *images.shape[3:]).mean(axis=(2, 4))


def compose_pose(position, quaternion, delta, size):
    """The body pose after a step δ = (translation / size, rotation vector [rad], body frame)."""
    q = quat_multiply(quaternion, rotvec_to_quat(delta[3:]))
    return position + size * delta[:3], q


def field_pose(position, quaternion, center_of_mass):
    """World-from-object pose of the field for a body pose (the body origin is the CoM)."""
    R = quat_to_matrix(quaternion)  # normalises
    return position - R @ center_of_mass, quaternion


def cold_start(poses: list, poor: list) -> bool:
    """Whether the next frame starts from no constant-velocity prediction (:func:`predict`
    falls back to the last pose, or there is none: the user's initial pose)."""
    return len(poses) < 2 or poor[-1] or poor[-2]


def predict(poses: list[np.ndarray], poor: list[bool]) -> np.ndarray:
    """Constant-velocity prediction of the next body pose from the last two (the last pose
    alone after a poor frame or with fewer than two)."""
    if cold_start(poses, poor):
        return poses[-1].copy()
    a, b = poses[-2], poses[-1]
    qa, qb = normalize_quat(a[3:]), normalize_quat(b[3:])
    q = quat_multiply(qb, quat_multiply(quat_inverse(qa), qb))
    return np.concatenate([2 * b[:3] - a[:3], q])


class _Problem:
    """The per-frame solve, jitted once per ray-set bucket."""

    def __init__(self, obj: TrackedObject, video: VideoInput, config: TrackConfig):
        self.obj, self.config = obj, config
        s = config.stride
        self.cam = video.camera
        h, w = video.frames.shape[1:3]
        self.hb, self.wb = h // s, w // s
        v, u = np.meshgrid((np.arange(self.hb) + 0.5) * s, (np.arange(self.wb) + 0.5) * s, indexing="ij")
        self.uv = np.stack([u.ravel(), v.ravel()], axis=-1)  # block centres [px]
        o, d = pixel_rays(self.cam, jnp.zeros(len(self.uv), jnp.int32), jnp.asarray(self.uv[:, 0]),
                          jnp.asarray(self.uv[:, 1]))
        self.origins, self.directions = np.asarray(o), np.asarray(d)
        f = np.asarray(self.cam.focal[0], dtype=np.float64)
        self.pixel_angle = s / float(np.sqrt(f[0] * f[1]))
        self.diag_px = float(np.hypot(h, w))
        b = np.asarray(obj.field.bounds(), dtype=np.float64)
        self.step = float(np.linalg.norm(b[1] - b[0])) / config.samples_across
        self.num_samples = int(config.samples_across) + 2
        self.masks = None if video.masks is None else block_average(video.masks, s).reshape(len(video.masks), -1)
        self.colours = block_average(video.frames, s).reshape(len(video.frames), -1, 3)
        bg = video.background if video.background is not None else np.ones((h, w, 3), np.float32)
        self.background = block_average(bg[None], s).reshape(-1, 3)
        if config.colour_weight > 0 and obj.radiance is None:
            raise DanoError("the colour term (photometric tracking) needs a radiance field of the object (a trained "
                            "field directory)")
        if self.masks is None and config.colour_weight == 0:
            raise DanoError("no masks: give mask images or a background frame, or track photometrically")
        if config.colour_weight > 0:
            rays = config.colour_rays or None
            budget = None if obj.radiance_occupancy is None or rays is None else rays * config.colour_samples
            self.colour_options = RenderConfig.for_bounds(obj.radiance.bounds(), config.samples_across, budget)
        self._solve = jax.jit(self._solve_frame)
        self._alpha_all = jax.jit(self._alpha)

    # --- pure pieces
    def _alpha(self, pose, origins, directions):
        p, q = field_pose(pose[:3], pose[3:], jnp.asarray(self.obj.center_of_mass, pose.dtype))
        return silhouette_rays(self.obj.field, origins, directions, pose=(p, q), step=self.step,
                               num_samples=self.num_samples, pixel_angle=self.pixel_angle).alpha

    def _residuals(self, delta, base, rays, target):
        """Residual vector r(δ) with L = Σ r² (see the module doc), and α."""
        origins, directions, uv, valid, colour_index = rays
        mask, colour, background, mask_bary, colour_factor = target
        cfg = self.config
        p, q = compose_pose(base[:3], base[3:], delta, self.obj.size)
        alpha = self._alpha(jnp.concatenate([p, q]), origins, directions) * valid
        n_all = self.hb * self.wb
        parts = [np.sqrt(cfg.smoothness_weight) * delta]
        if self.masks is not None:
            bary = jnp.sum(alpha[:, None] * uv, axis=0) / jnp.maximum(jnp.sum(alpha), 1e-6)
            parts += [(alpha - mask) / np.sqrt(n_all),
                      np.sqrt(cfg.barycentre_weight) * (bary - mask_bary) / self.diag_px]
        if cfg.colour_weight > 0:
            fp = field_pose(p, q, jnp.asarray(self.obj.center_of_mass, p.dtype))
            out = render_rays(self.obj.radiance, origins[colour_index], directions[colour_index],
                              self.colour_options, pose=fp, occupancy=self.obj.radiance_occupancy,
                              background=background[colour_index])
            x = (out.rgb - colour[colour_index]) / cfg.colour_scale
            robust = x / (1.0 + x * x) ** 0.25  # r² = x²/√(1 + x²): quadratic near 0, linear far out
            used = valid[colour_index] * out.complete  # rays beyond the render budget left out
            parts.append(colour_factor * np.sqrt(cfg.colour_weight / (3 * n_all)) * (used[:, None] * robust).ravel())
        return jnp.concatenate(parts), alpha

    def _loss(self, delta, base, rays, target):
        r, alpha = self._residuals(delta, base, rays, target)
        return jnp.sum(r * r), alpha

    def _solve_frame(self, base, rays, target):
        cfg = self.config
        schedule = optax.exponential_decay(cfg.learning_rate, cfg.iterations,
                                           cfg.final_learning_rate / cfg.learning_rate)
        opt = optax.adam(schedule)
        grad = jax.value_and_grad(self._loss, has_aux=True)
        delta0 = jnp.zeros(6, base.dtype)

        def body(_, carry):
            delta, state, best, best_loss = carry
            (loss, _), g = grad(delta, base, rays, target)
            better = loss < best_loss
            best, best_loss = jnp.where(better, delta, best), jnp.where(better, loss, best_loss)
            updates, state = opt.update(g, state, delta)
            return optax.apply_updates(delta, updates), state, best, best_loss

        carry = (delta0, opt.init(delta0), delta0, jnp.asarray(jnp.inf, base.dtype))
        delta, _, best, best_loss = jax.lax.fori_loop(0, cfg.iterations, body, carry)
        last, _ = self._loss(delta, base, rays, target)
        best = jnp.where(last < best_loss, delta, best)
        loss, alpha = self._loss(best, base, rays, target)
        p, q = compose_pose(base[:3], base[3:], best, self.obj.size)
        return jnp.concatenate([p, q / jnp.linalg.norm(q)]), loss, alpha

    # --- host side
    def _dilate(self, region: np.ndarray, pixels: float) -> np.ndarray:
        from scipy.ndimage import binary_dilation

        r = max(1, int(np.ceil(pixels / self.config.stride)))
        return binary_dilation(region.reshape(self.hb, self.wb), iterations=r).ravel()

    def silhouette(self, pose: np.ndarray) -> np.ndarray:
        """α at ``pose`` on every pixel block, (hb·wb,)."""
        return np.asarray(self._alpha_all(jnp.asarray(pose), jnp.asarray(self.origins), jnp.asarray(self.directions)))

    def check_in_view(self, pose: np.ndarray, alpha: np.ndarray) -> None:
        """Raise DanoError where the object at ``pose`` covers no pixel block of the image."""
        if (alpha > 0.01).any():
            return
        (u, v), depth = (x[0] for x in project_points(self.cam, 0, pose[None, :3]))
        w, h = self.cam.width, self.cam.height
        if depth <= 0:
            where = f"{-depth:.3g} m behind the camera"
        else:
            where = f"{depth:.3g} m in front of the camera, at pixel ({u:.0f}, {v:.0f}) of the {w}x{h} image"
        raise DanoError(f"the object is not in view in the first frame tracked: at the initial pose its centre of mass "
                        f"{np.round(pose[:3], 4).tolist()} is {where}, and it covers no pixel. Give the pose in "
                        f"the camera's world frame (centre of mass [m], then the wxyz quaternion), and check "
                        f"camera.json's \"convention\" (now {self.cam.convention!r}: \"blender\" looks along -z "
                        f"with +y up, \"opencv\" along +z with +y down)")

    def ray_set(self, k: int, previous_alpha: np.ndarray) -> np.ndarray:
        """Indices of the rays rendered for frame k: near the mask and near ``previous_alpha``
        (the previous frame's silhouette, or the initial pose's on every block)."""
        region = np.zeros(self.hb * self.wb, bool)
        if self.masks is not None:
            region |= self.masks[k] > 0
        region |= previous_alpha > 0.01
        if not region.any():
            region[:] = True
        extent = np.sqrt(region.sum()) * self.config.stride  # rough object size in pixels
        return np.flatnonzero(self._dilate(region, self.config.margin * extent + 2 * self.config.stride))

    def solve(self, k: int, base: np.ndarray, index: np.ndarray):
        n = len(index)
        size = int(np.ceil(n / _BUCKET) * _BUCKET)
        idx = np.concatenate([index, np.repeat(index[-1:], size - n)])
        valid = (np.arange(size) < n).astype(np.float64)
        k_colour = self.config.colour_rays
        if self.config.colour_weight > 0 and 0 < k_colour:
            # a fresh random subset for each frame (fixed by the frame index), scaled to the whole set
            colour_index = np.random.default_rng(k).choice(n, k_colour, replace=n < k_colour)
            colour_factor = np.sqrt(n / k_colour)
        else:
            colour_index, colour_factor = np.arange(size), 1.0
        rays = (jnp.asarray(self.origins[idx]), jnp.asarray(self.directions[idx]), jnp.asarray(self.uv[idx]),
                jnp.asarray(valid), jnp.asarray(colour_index, jnp.int32))
        if self.masks is not None:
            m = self.masks[k]
            mask = m[idx] * valid
            bary = (m[:, None] * self.uv).sum(axis=0) / max(float(m.sum()), 1e-6)
        else:
            mask, bary = np.zeros(size), np.zeros(2)
        target = (jnp.asarray(mask), jnp.asarray(self.colours[k][idx]), jnp.asarray(self.background[idx]),
                  jnp.asarray(bary), jnp.asarray(colour_factor, float))
        pose, loss, alpha = self._solve(jnp.asarray(base, float), rays, target)  # (float64 where enabled)
        full = np.zeros(self.hb * self.wb)
        full[index] = np.asarray(alpha)[:n]
        return np.asarray(pose), float(loss), full


def track(video: VideoInput, obj: TrackedObject, initial_pose, config: TrackConfig = TrackConfig(),
          frames: slice | None = None, progress=None) -> TrackResult:
    """Track ``obj`` through ``video`` from ``initial_pose`` (7,) (body pose of the first
    frame: CoM position [m], wxyz quaternion, world frame).

    Returns a :class:`TrackResult`. Raises DanoError for a bad config, a non-finite or zero
    initial pose, an object out of view at the initial pose (it covers no pixel of the first
    frame), an empty frame selection, no masks and no colour term, or the colour term without
    a radiance field.
    """
    pose = np.asarray(initial_pose, dtype=np.float64).reshape(-1)
    if pose.shape != (7,) or not np.all(np.isfinite(pose)) or np.linalg.norm(pose[3:]) < 1e-9:
        raise DanoError(f"initial pose must be 7 finite numbers (x, y, z, qw, qx, qy, qz) with a non-zero "
                        f"quaternion, got {pose.tolist()}")
    pose[3:] /= np.linalg.norm(pose[3:])
    problem = _Problem(obj, video, config)
    ks = range(video.num_frames)[frames or slice(None)]
    if len(ks) == 0:
        raise DanoError(f"no frames to track ({video.num_frames} frames in the video, selection {frames})")
    previous_alpha = problem.silhouette(pose)
    problem.check_in_view(pose, previous_alpha)
    poses, losses, ious, poor, times, alphas, passes = [], [], [], [], [], [], []
    for i, k in enumerate(ks):
        t0 = time.perf_counter()
        base = pose if i == 0 else predict(poses, poor)
        index = problem.ray_set(k, previous_alpha)
        p, loss, alpha = problem.solve(k, base, index)
        if cold_start(poses, poor) and np.all(np.isfinite(p)):
            p, loss, alpha, runs = _refine(problem, k, p, loss, alpha)
            passes.append(runs)
        if problem.masks is not None:
            m = problem.masks[k]
            iou = float(np.minimum(alpha, m).sum() / max(np.maximum(alpha, m).sum(), 1e-9))
        else:
            iou = float("nan")
        bad = not np.all(np.isfinite(p)) or (problem.masks is not None and iou < config.poor_iou)
        if not np.all(np.isfinite(p)):
            p = base
        poses.append(p)
        losses.append(loss)
        ious.append(iou)
        poor.append(bad)
        alphas.append(alpha.reshape(problem.hb, problem.wb).astype(np.float32))
        previous_alpha = alpha
        times.append(time.perf_counter() - t0)
        if progress is not None:
            progress(i + 1, len(ks), f"loss {loss:.2e}, IoU {iou:.3f}")
    return TrackResult(video.time[list(ks)], np.stack(poses), np.asarray(losses), np.asarray(ious),
                       np.asarray(poor), np.asarray(times), config, np.stack(alphas), config.stride, tuple(passes))


#: a cold start's Adam runs stop once one lowers the loss by less than this fraction
COLD_START_GAIN = 0.01


def _refine(problem, k: int, pose, loss: float, alpha):
    """Frame k solved again from its own result (a new ray set around its silhouette) while
    the loss falls by more than :data:`COLD_START_GAIN`, up to ``cold_start_passes`` runs in
    all: (pose, loss, silhouette, runs). For a frame that starts from no prediction: the
    first from the user's pose, which may be centimetres and tens of degrees off, the second
    from the first's pose, a frame's motion away. Their errors start every finite-difference
    velocity: one run of 60 steps left the own-object review's Spot 12° off in the first
    frame from a 20° start, and 5.7 mm off in the second."""
    passes = 1
    while passes < problem.config.cold_start_passes:
        p, l2, a = problem.solve(k, pose, problem.ray_set(k, alpha))
        passes += 1
        if not (np.all(np.isfinite(p)) and np.isfinite(l2) and l2 < loss):
            break
        gain = (loss - l2) / max(loss, 1e-300)
        pose, loss, alpha = p, l2, a
        if gain < COLD_START_GAIN:
            break
    return pose, loss, alpha, passes


def pose_errors(poses: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame translation error [m] and rotation error [deg] of (T, 7) poses against (T, 7)."""
    dp = np.linalg.norm(poses[:, :3] - truth[:, :3], axis=1)
    return dp, np.degrees(np.linalg.norm(quat_error(truth[:, 3:], poses[:, 3:]), axis=1))


def initial_velocity(time: np.ndarray, poses: np.ndarray, frames: int = 3) -> np.ndarray:
    """(6,) initial velocity of a free body from its first ``frames`` poses (T, 7) by least
    squares: linear velocity (world frame) [m/s] from a straight-line fit of the positions,
    angular velocity (body frame) [rad/s] from a fit through zero of the rotation vectors
    log(R₀ᵀR_k). Steadier than differences of two tracked poses; few frames, so that a
    contact soon after the first frame does not bias it (on the synthetic slide, which lands
    after 3 frames: ω from 3 frames (2.16, −0.90, 5.69) rad/s, from 5 (1.36, 0.39, 5.25); the
    truth (2, −1, 6)); :func:`dano.pose.velocity_from_poses` of degree 1."""
    n = int(min(max(frames, 2), len(time)))
    return velocity_from_poses(np.asarray(time)[:n], np.asarray(poses)[:n], degree=1)

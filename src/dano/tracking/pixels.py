"""Physics from pixels ("torques to pixels", the paper's limitation iv): identify contact
parameters by comparing rendered silhouettes of the *simulated* motion with the video's masks,
differentiating through the simulator and the renderer together.

θ = (parameters…, initial position offset (3) [m], initial linear velocity (3) [m/s, world],
initial angular velocity (3) [rad/s, body]): the rollout starts from the first frame's pose
(as tracked) shifted by the offset, so a tracked position error (mostly in depth) does not
bias the parameters. (The orientation is kept: tracked to a fraction of a degree, and
freeing it as well let the fit wander into wrong local minima in our tests.) Residuals, per frame k ≥ 1
and per pixel block of the frame's ray set: (α_k(θ) − M_k)/√N (N: blocks per image), and
√w_B·(B(α_k) − B(M_k))/diagonal for the barycentres — the tracking loss of
:mod:`dano.tracking.track` summed over the video. Gauss–Newton (SciPy's trust-region
least squares) with forward-mode Jacobians (``jax.jacfwd``, one column per unknown),
started from the best point of a scan over the first parameter's bounds (the cost through
contact is jagged: a local method alone stops early). The scan's grid and the local solve are
identification's (:func:`dano.sysid.solve.scan_points`, :func:`dano.sysid.solve.solve_least_squares`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import DanoError
from ..render.cameras import pixel_rays
from ..render.silhouette import silhouette_rays
from ..sim.dynamics import State
from ..sim.rollout import rollout_arrays
from ..sysid.solve import scan_points, solve_least_squares
from .inputs import VideoInput
from .track import block_average, field_pose


@dataclass(frozen=True)
class PixelFitResult:
    """labels; estimates (n,) (parameters, then the initial position offset (3) [m], v0 (3), ω0 (3));
    cost (final ½‖r‖²);
    scan: {"values": (S,), "costs": (S,)} along the first parameter; nfev/njev; wall and
    compile time [s]; success and the solver's message."""

    labels: list
    estimates: np.ndarray
    cost: float
    scan: dict
    nfev: int
    njev: int
    wall_time_s: float
    compile_time_s: float
    success: bool
    message: str

    def as_dict(self) -> dict:
        return {"parameters": {k: float(v) for k, v in zip(self.labels, self.estimates)}, "cost": self.cost,
                "scan": {k: np.asarray(v).tolist() for k, v in self.scan.items()}, "nfev": self.nfev,
                "njev": self.njev, "wall_time_s": self.wall_time_s, "compile_time_s": self.compile_time_s,
                "success": self.success, "message": self.message}


def _ray_sets(masks: np.ndarray, stride: int, margin_px: float) -> tuple[np.ndarray, np.ndarray]:
    """Per frame, the block indices of the dilated mask, padded to one length: (F, R) int and
    (F, R) float validity."""
    from scipy.ndimage import binary_dilation

    sets = []
    for m in masks:
        region = m > 0
        extent = np.sqrt(max(region.sum(), 1)) * stride
        r = max(1, int(np.ceil((margin_px * extent + 2 * stride) / stride)))
        sets.append(np.flatnonzero(binary_dilation(region, iterations=r)))
    size = max(len(s) for s in sets)
    index = np.stack([np.concatenate([s, np.repeat(s[-1:], size - len(s))]) for s in sets])
    valid = np.stack([(np.arange(size) < len(s)).astype(np.float64) for s in sets])
    return index, valid


def pixel_residual_function(scene, base_params, parameters: list[str], video: VideoInput, obj, qpos0: np.ndarray,
                            substeps: int, stride: int = 4, barycentre_weight: float = 1.0,
                            samples_across: int = 96, margin: float = 0.5):
    """(θ) -> residuals, a pure JAX function (jit/jacfwd it). ``parameters``: contact
    parameter names set on every pair (e.g. ["sliding_friction"]); qpos0: (nq,) the first
    frame's state; substeps: simulation steps per frame interval. Raises DanoError without
    masks or if the frame interval is not ``substeps`` × the scene's step."""
    if video.masks is None:
        raise DanoError("identification from pixels needs masks (mask images or a background frame)")
    frame_dt = float(np.median(np.diff(video.time)))
    if abs(frame_dt - substeps * scene.dt) > 1e-9:
        raise DanoError(f"frame interval {frame_dt:.6g} s is not {substeps} x the scene's step {scene.dt:.6g} s")
    h, w = video.frames.shape[1:3]
    hb, wb = h // stride, w // stride
    masks = block_average(video.masks, stride).reshape(video.num_frames, -1)[1:]
    index, valid = _ray_sets(masks.reshape(-1, hb, wb), stride, margin)
    v, u = np.meshgrid((np.arange(hb) + 0.5) * stride, (np.arange(wb) + 0.5) * stride, indexing="ij")
    uv_all = np.stack([u.ravel(), v.ravel()], axis=-1)
    o, d = pixel_rays(video.camera, jnp.zeros(len(uv_all), jnp.int32), jnp.asarray(uv_all[:, 0]),
                      jnp.asarray(uv_all[:, 1]))
    origins, directions = np.asarray(o)[index], np.asarray(d)[index]  # (F, R, 3)
    uv = uv_all[index]
    target = np.take_along_axis(masks, index, axis=1) * valid
    totals = masks.sum(axis=1)
    bary = (masks[..., None] * uv_all[None]).sum(axis=1) / np.maximum(totals, 1e-6)[:, None]
    f = np.asarray(video.camera.focal[0], dtype=np.float64)
    pixel_angle = stride / float(np.sqrt(f[0] * f[1]))
    b = np.asarray(obj.field.bounds(), dtype=np.float64)
    step = float(np.linalg.norm(b[1] - b[0])) / samples_across
    diag = float(np.hypot(h, w))
    n_all = hb * wb
    frames = video.num_frames
    steps = (frames - 1) * substeps
    dof = scene.dof_adr[0]
    adr = scene.qpos_adr[0]
    com = jnp.asarray(obj.center_of_mass)
    wb_ = float(np.sqrt(barycentre_weight))
    arrays = [jnp.asarray(a) for a in (origins, directions, uv, valid, target, bary)]

    def residuals(theta):
        params = base_params
        for i, name in enumerate(parameters):
            params = scene.set_param(params, name, theta[i])
        n = len(parameters)
        start = jnp.asarray(qpos0).at[adr : adr + 3].add(theta[n : n + 3])
        qvel0 = jnp.zeros(scene.nv, theta.dtype).at[dof : dof + 6].set(theta[n + 3 : n + 9])
        qpos, _, _ = rollout_arrays(scene, State(start, qvel0), None, params, steps)
        poses = qpos[substeps::substeps, adr : adr + 7]  # frames 1..F-1

        def frame(pose, origins_k, directions_k, uv_k, valid_k, target_k, bary_k):
            p, q = field_pose(pose[:3], pose[3:], com)
            alpha = silhouette_rays(obj.field, origins_k, directions_k, pose=(p, q), step=step,
                                    num_samples=samples_across + 2, pixel_angle=pixel_angle).alpha * valid_k
            centre = jnp.sum(alpha[:, None] * uv_k, axis=0) / jnp.maximum(jnp.sum(alpha), 1e-6)
            return jnp.concatenate([(alpha - target_k) / np.sqrt(n_all), wb_ * (centre - bary_k) / diag])

        return jax.vmap(frame)(poses, *arrays).ravel()

    return residuals


def identify_from_pixels(scene, base_params, video: VideoInput, obj, qpos0: np.ndarray, qvel0: np.ndarray,
                         substeps: int, parameter: str = "sliding_friction", bounds=(0.0, 1.5), scan: int = 16,
                         stride: int = 4, max_iterations: int = 60,
                         progress=None) -> PixelFitResult:
    """Identify ``parameter`` (and the first frame's state, as nuisance) from the video's masks.

    A scan of ``scan`` values of the parameter over ``bounds`` on the whole video from the
    given state, a second of ``scan`` values within one spacing of the best, then Gauss–Newton
    on everything from the best point. (The fine scan matters: from the synthetic slide's
    coarse best, 0.3 or 0.4, Gauss–Newton adjusted the initial spin to the wrong friction and
    stopped in another minimum, at 0.325 or 0.373.)
    qpos0: (nq,) the first frame's state (e.g. tracked); qvel0: (nv,) a guess of the initial
    velocity (e.g. from the tracked poses: :func:`~dano.tracking.initial_velocity`, or a
    two-stage fit's — the cost over the initial angular velocity has local minima).
    Raises DanoError (float32 scene, no masks, frame rate mismatch, too few frames)."""
    if scene.dtype != jnp.float64:
        raise DanoError("identification from pixels needs a float64 scene: call dano.enable_float64() first")
    if video.num_frames < 3:
        raise DanoError(f"identification from pixels needs at least 3 frames, got {video.num_frames}")
    t_start = time.perf_counter()
    compile_s = 0.0
    dof = scene.dof_adr[0]
    total = 2 * scan + max_iterations
    done = {"n": 0}

    def tick(what):
        done["n"] += 1
        if progress is not None:
            progress(min(done["n"], total), total, what)

    def solve(res, jac, x0, what):
        nonlocal compile_s
        t0 = time.perf_counter()
        jac(jnp.asarray(x0)).block_until_ready()
        compile_s += time.perf_counter() - t0

        def f(x):
            tick(what)
            return np.asarray(res(jnp.asarray(x)))

        lower, upper = np.r_[bounds[0], np.full(9, -np.inf)], np.r_[bounds[1], np.full(9, np.inf)]
        return solve_least_squares(f, np.clip(x0, lower, upper), lower, upper,
                                   jacobian=lambda x: np.asarray(jac(jnp.asarray(x))), max_iterations=max_iterations,
                                   xtol=1e-10, ftol=1e-10)

    x = np.r_[0.5 * (bounds[0] + bounds[1]), np.zeros(3), np.asarray(qvel0, dtype=np.float64)[dof : dof + 6]]
    fn = pixel_residual_function(scene, base_params, [parameter], video, obj, qpos0, substeps, stride)
    res, jac = jax.jit(fn), jax.jit(jax.jacfwd(fn))
    values, costs = [], []
    coarse = scan_points(np.array([bounds[0]], dtype=np.float64), np.array([bounds[1]], dtype=np.float64), scan)[:, 0]
    for level in (coarse, None):
        if level is None:  # a fine scan around the coarse minimum (one coarse spacing either side)
            best, spacing = values[int(np.argmin(costs))], coarse[1] - coarse[0]
            level = np.linspace(max(bounds[0], best - spacing), min(bounds[1], best + spacing), scan)
        for mu in level:
            t0 = time.perf_counter()
            r = np.asarray(res(jnp.asarray(np.r_[mu, x[1:]])))
            if not costs:
                compile_s += time.perf_counter() - t0
            values.append(float(mu))
            costs.append(0.5 * float(r @ r) if np.all(np.isfinite(r)) else np.inf)
            tick(f"scan {parameter} {mu:.3f}")
    values, costs = np.asarray(values), np.asarray(costs)
    sol = solve(res, jac, np.r_[values[int(np.argmin(costs))], x[1:]], "Gauss-Newton")
    labels = [parameter, "dx", "dy", "dz", "vx", "vy", "vz", "wx", "wy", "wz"]
    return PixelFitResult(labels, sol.x, sol.cost, {"values": values, "costs": costs}, sol.nfev, sol.njev,
                          time.perf_counter() - t_start, compile_s, sol.success, sol.message)

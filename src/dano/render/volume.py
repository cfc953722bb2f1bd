"""Differentiable volume rendering of a density (and colour) field placed at a pose.

The emission–absorption model of NeRF (Mildenhall et al. 2020, Eq. 3) with uniform steps:
along a ray x(t) = o + t·d, samples t_k = (k + ξ)·δ; opacity α_k = 1 − exp(−σ_k δ);
transmittance T_k = exp(−Σ_{j<k} σ_j δ); weights w_k = T_k α_k; colour Σ w_k c_k + (1 − Σ w_k)·b
for a background b; alpha Σ w_k; depth Σ w_k t_k / Σ w_k.

Samples sit on a grid anchored at the ray's origin (t = (k + ξ)·δ, not at the box entry), so a
moving object changes *which* samples fall in its box but never where they are: the render is
smooth in the object pose wherever the field is zero at its box's faces.

Empty space is skipped with an :class:`OccupancyGrid`: candidates in unoccupied cells are
dropped, the rest are packed into a fixed ``budget`` of field evaluations (static shapes, one
compilation). Rays whose samples did not all fit are reported ``complete = False``;
:func:`render_image` renders them again, training leaves them out of the loss.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import DanoError
from ..pose import quat_to_matrix
from .cameras import image_rays


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class RenderConfig:
    """How rays are sampled (all static: a change recompiles)."""

    step: float = field(metadata=dict(static=True))
    """Sample spacing δ along the ray [m]."""
    num_samples: int = field(metadata=dict(static=True))
    """Candidate samples per ray (the ray's chord through the field's box must be ≤ num_samples·δ, or its far
    end is not sampled)."""
    budget: int | None = field(default=None, metadata=dict(static=True))
    """Field evaluations per call (the occupied samples of all rays, packed ray by ray); None: room for every
    candidate (R·num_samples)."""
    near: float = field(default=0.0, metadata=dict(static=True))
    """No samples closer than this to the ray's origin [m]."""

    @classmethod
    def for_bounds(cls, bounds, samples_across: int = 256, budget: int | None = None,
                   near: float = 0.0) -> "RenderConfig":
        """Settings whose step is the box diagonal / ``samples_across``; every chord fits."""
        b = np.asarray(bounds, dtype=np.float64)
        diagonal = float(np.linalg.norm(b[1] - b[0]))
        return cls(diagonal / samples_across, int(samples_across) + 1, budget, near)


RenderOptions = RenderConfig  # old name, kept


class RenderOutput(NamedTuple):
    """Per ray: rgb (R, 3) in [0, 1] with the background; alpha (R,) = 1 − final
    transmittance; depth (R,) [m] along the ray (expected termination, 0 where alpha = 0);
    complete (R,) bool, False where the budget cut the ray's samples short; samples (R,)
    int, the ray's samples in occupied space (evaluated where complete)."""

    rgb: jax.Array
    alpha: jax.Array
    depth: jax.Array
    complete: jax.Array
    samples: jax.Array | None = None


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class OccupancyGrid:
    """A coarse grid over a field's box marking cells that may hold density.

    density: (n, n, n) float, a running maximum of σ in each cell [1/m];
    lower, upper: (3,) the box, object frame [m]; cutoff: () σ [1/m] above which a cell
    counts as occupied: min(threshold, mean cell density), so that a young field with
    σ everywhere still skips its emptiest cells (as instant-ngp does); threshold: (static).
    """

    density: jax.Array
    lower: jax.Array
    upper: jax.Array
    cutoff: jax.Array
    threshold: float = field(metadata=dict(static=True))

    @classmethod
    def create(cls, bounds, resolution: int = 64, threshold: float = 0.01, dtype=jnp.float32) -> "OccupancyGrid":
        """A grid with every cell occupied (density +inf until the first :func:`update`)."""
        b = np.asarray(bounds, dtype=np.float64)
        return cls(jnp.full((resolution,) * 3, jnp.inf, dtype), jnp.asarray(b[0], dtype), jnp.asarray(b[1], dtype),
                   jnp.asarray(threshold, dtype), float(threshold))

    @property
    def resolution(self) -> int:
        return int(self.density.shape[0])

    def occupied(self, points: jax.Array) -> jax.Array:
        """(…, 3) object-frame points -> (…,) bool, False outside the box."""
        n = self.density.shape[0]
        x = (points - self.lower) / (self.upper - self.lower)
        inside = jnp.all((x >= 0) & (x < 1), axis=-1)
        idx = jnp.clip((x * n).astype(jnp.int32), 0, n - 1)
        return inside & (self.density[idx[..., 0], idx[..., 1], idx[..., 2]] > self.cutoff)

    def cell_centres(self) -> jax.Array:
        n = self.density.shape[0]
        axis = (jnp.arange(n, dtype=self.lower.dtype) + 0.5) / n
        g = jnp.stack(jnp.meshgrid(axis, axis, axis, indexing="ij"), axis=-1).reshape(-1, 3)
        return self.lower + g * (self.upper - self.lower)

    def fraction_occupied(self) -> float:
        return float(jnp.mean(self.density > self.cutoff))


def update_occupancy(grid: OccupancyGrid, density_fn, key: jax.Array, decay: float = 0.95,
                     keep: jax.Array | None = None) -> OccupancyGrid:
    """One update: σ at a random point in every cell (``density_fn``: (N, 3) -> (N,)),
    kept as max(decay·old, new) so that cells empty for a while are dropped. ``keep``:
    (n, n, n) bool, cells that may be occupied at all (e.g. not carved away by images)."""
    n = grid.density.shape[0]
    cell = (grid.upper - grid.lower) / n
    pts = grid.cell_centres() + (jax.random.uniform(key, (n ** 3, 3), grid.lower.dtype) - 0.5) * cell
    sigma = jax.lax.stop_gradient(density_fn(pts)).reshape(grid.density.shape)
    if keep is not None:
        sigma = jnp.where(keep, sigma, 0.0)
    old = jnp.where(jnp.isfinite(grid.density), grid.density, 0.0)
    density = jnp.maximum(decay * old, sigma)
    cutoff = jnp.minimum(grid.threshold, jnp.mean(density))
    return OccupancyGrid(density, grid.lower, grid.upper, cutoff.astype(density.dtype), grid.threshold)


def _radiance(field, points, directions):
    """(σ (N,), rgb (N, 3)) of a radiance field, or of a density field drawn white."""
    if hasattr(field, "radiance"):
        return field.radiance(points, directions)
    sigma = field.density(points)
    return sigma, jnp.ones(points.shape[:-1] + (3,), points.dtype)


def _to_object_frame(origins, directions, pose):
    if pose is None:
        return origins, directions
    position, quaternion = pose
    rotation = quat_to_matrix(quaternion)  # normalises
    # x_object = Rᵀ (x_world − p): row vectors times R
    return (origins - position) @ rotation, directions @ rotation


def _box_interval(origins, directions, lower, upper, near):
    safe = jnp.where(jnp.abs(directions) < 1e-12, jnp.where(directions < 0, -1e-12, 1e-12), directions)
    t0 = (lower - origins) / safe
    t1 = (upper - origins) / safe
    enter = jnp.maximum(jnp.max(jnp.minimum(t0, t1), axis=-1), near)
    leave = jnp.min(jnp.maximum(t0, t1), axis=-1)
    return enter, leave


def render_rays(field, origins: jax.Array, directions: jax.Array, options: RenderConfig, *,
                pose: tuple[jax.Array, jax.Array] | None = None, occupancy: OccupancyGrid | None = None,
                background: Any = 1.0, key: jax.Array | None = None) -> RenderOutput:
    """Render R rays through ``field`` placed at ``pose``.

    field: a pytree with ``radiance(points, directions) -> (σ (N,) [1/m], rgb (N, 3))`` or a
    :class:`~dano.fields.DensityField` (σ = its density, drawn white), and ``bounds()``
    (2, 3), object frame [m]; origins, directions: (R, 3) world frame [m], directions unit;
    pose: (position (3,) [m], quaternion (4,) wxyz), world from object; None = identity;
    occupancy: skips empty cells (None: every sample in the box is evaluated);
    background: scalar, (3,) or (R, 3) colour behind the object; key: a PRNG key to jitter
    the samples along each ray (training), None = cell centres (evaluation).

    Differentiable (forward and reverse mode) in the field's parameters, the pose, the rays
    and the background. Returns a :class:`RenderOutput`.
    """
    dtype = origins.dtype
    o, d = _to_object_frame(origins, directions, pose)
    bounds = np.asarray(field.bounds(), dtype=np.float64)
    lower, upper = jnp.asarray(bounds[0], dtype), jnp.asarray(bounds[1], dtype)
    num_rays, num = o.shape[0], options.num_samples
    step = options.step
    budget = num_rays * num if options.budget is None else options.budget
    # candidates (R, S): which samples fall in the box and in occupied cells; no gradient
    o_c, d_c = jax.lax.stop_gradient(o), jax.lax.stop_gradient(d)
    enter, leave = _box_interval(o_c, d_c, lower, upper, options.near)
    jitter = 0.5 if key is None else jax.random.uniform(key, (num_rays, 1), dtype)
    t = (jnp.floor(enter / step)[:, None] + jnp.arange(num, dtype=dtype)[None, :] + jitter) * step
    valid = (t >= enter[:, None]) & (t <= leave[:, None])
    if occupancy is not None:
        valid = valid & occupancy.occupied(o_c[:, None, :] + t[..., None] * d_c[:, None, :])
    # pack the valid samples, ray by ray, into the budget
    (idx,) = jnp.nonzero(valid.reshape(-1), size=budget, fill_value=valid.size)
    used = idx < valid.size
    ray = jnp.where(used, idx // num, num_rays)  # num_rays: an unused slot
    safe_ray = jnp.minimum(ray, num_rays - 1)
    t_packed = t.reshape(-1)[jnp.where(used, idx, 0)]
    points = o[safe_ray] + t_packed[:, None] * d[safe_ray]  # differentiable in the pose and the rays
    sigma, rgb = _radiance(field, points, d[safe_ray])
    optical = jnp.where(used, sigma, 0.0) * step
    # transmittance: exclusive optical depth within each ray (a segmented scan: exact per ray)
    start = jnp.concatenate([jnp.ones(1, bool), ray[1:] != ray[:-1]])
    inclusive = _segmented_cumsum(optical, start)
    weights = jnp.exp(-(inclusive - optical)) * (1.0 - jnp.exp(-optical))
    alpha = jax.ops.segment_sum(weights, ray, num_segments=num_rays)
    colour = jax.ops.segment_sum(weights[:, None] * rgb, ray, num_segments=num_rays)
    depth_sum = jax.ops.segment_sum(weights * t_packed, ray, num_segments=num_rays)
    per_ray = valid.sum(axis=1)
    complete = jnp.cumsum(per_ray) <= budget  # every valid sample of the ray fitted
    bg = jnp.broadcast_to(jnp.asarray(background, dtype), (num_rays, 3))
    colour = colour + (1.0 - alpha)[:, None] * bg
    positive = alpha > 1e-10
    depth = jnp.where(positive, depth_sum / jnp.where(positive, alpha, 1.0), 0.0)
    return RenderOutput(colour, alpha, depth, complete, per_ray)


def _segmented_cumsum(x: jax.Array, start: jax.Array) -> jax.Array:
    """Inclusive cumulative sum of ``x`` restarting where ``start`` is True (exact per segment,
    unlike differences of one global cumulative sum in float32)."""

    def combine(a, b):
        xa, fa = a
        xb, fb = b
        return jnp.where(fb, xb, xa + xb), fa | fb

    return jax.lax.associative_scan(combine, (x, start))[0]


_RENDER_JIT = jax.jit(render_rays, static_argnames=("options",))


def render_image(field, cameras, camera: int, options: RenderConfig, *, pose=None,
                 occupancy: OccupancyGrid | None = None, background: Any = 1.0,
                 chunk: int = 4096) -> RenderOutput:
    """Render one whole image of ``cameras`` (a :class:`~dano.render.Cameras`): every ray in
    chunks of ``chunk`` rays (one compilation), rays the budget cut short rendered again.

    Returns a :class:`RenderOutput` of numpy arrays shaped (H, W, 3) / (H, W).
    Raises DanoError if ``options.budget`` cannot hold one ray's samples.
    """
    if options.budget is not None and options.budget < options.num_samples:
        raise DanoError(f"render budget {options.budget} is smaller than one ray's {options.num_samples} samples")
    origins, directions = (np.asarray(a) for a in image_rays(cameras, camera))
    n = len(origins)
    out = {k: np.zeros((n, 3) if k == "rgb" else (n,), np.float64) for k in ("rgb", "alpha", "depth")}
    todo = np.arange(n)
    while len(todo):
        take = todo[:chunk]
        pad = chunk - len(take)
        idx = np.concatenate([take, np.repeat(take[-1:], pad)]) if pad else take
        res = _RENDER_JIT(field, jnp.asarray(origins[idx]), jnp.asarray(directions[idx]), options, pose=pose,
                          occupancy=occupancy, background=background)
        done = np.asarray(res.complete)[: len(take)]  # the first ray always fits: budget >= num_samples
        for k in out:
            out[k][take[done]] = np.asarray(getattr(res, k))[: len(take)][done]
        todo = np.concatenate([take[~done], todo[chunk:]])
    h, w = cameras.height, cameras.width
    return RenderOutput(out["rgb"].reshape(h, w, 3), out["alpha"].reshape(h, w), out["depth"].reshape(h, w),
                        np.ones((h, w), bool), None)


def psnr(image: Any, reference: Any) -> float:
    """Peak signal-to-noise ratio [dB] of images in [0, 1]: −10·log10(mean squared error)."""
    mse = float(np.mean((np.asarray(image, np.float64) - np.asarray(reference, np.float64)) ** 2))
    return float("inf") if mse == 0 else -10.0 * np.log10(mse)

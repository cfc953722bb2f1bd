"""From a trained field's σ to the density a DANO integrates.

A NeRF's σ [1/m] is an extinction coefficient, not a mass density, and images never see
an object's inside: σ is large where the surface was seen and arbitrary within. Three
rules, evaluated on a grid of nodes over the field's box (``resolution`` nodes along its
longest side):

* ``"sigma"``: σ itself, as the paper integrated it (mass ∝ ∫σ: interior guesses and
  surface sharpness both change the mass);
* ``"occupancy"``: o = 1 − exp(−σ·δ), the opacity of one sample step δ (what training
  constrained), in [0, 1]; a hollow interior stays hollow;
* ``"solid"``: the points hidden from outside along all six axis directions (accumulated
  opacity ≥ 0.5 from each face of the box, :func:`hidden_from_outside`), the largest connected
  piece, as a ramp one node wide of its signed distance (:func:`signed_distance_nodes`):
  uniform density inside the seen surface, the mesh-like answer. Its surface is then moved
  along its normal by the offset that makes its silhouettes cover as many pixels as the
  field's own renders (:func:`silhouette_offset`): a soft field's median-depth surface lies
  inside the object, its silhouettes do not.

docs/fields-from-images.md reports which one gives the right mass properties.
"""

from __future__ import annotations

from dataclasses import dataclass
from dataclasses import field as dataclass_field
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from scipy import ndimage, special

from ..errors import DanoError
from ..fields import VoxelField, evaluate
from ..render import Cameras, RenderConfig, image_rays, render_image
from ..render.silhouette import silhouette_rays
from .synthetic import fibonacci_directions

DENSITY_RULES = ("solid", "occupancy", "sigma")


def node_grid(bounds: np.ndarray, resolution: int) -> tuple[np.ndarray, tuple[int, int, int]]:
    """Nodes over ``bounds`` (2, 3) with ``resolution`` along the longest side: (points (M, 3), shape)."""
    size = bounds[1] - bounds[0]
    spacing = float(size.max()) / (resolution - 1)
    shape = tuple(int(max(2, np.ceil(s / spacing) + 1)) for s in size)
    axes = [np.linspace(bounds[0, k], bounds[0, k] + spacing * (shape[k] - 1), shape[k]) for k in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    return grid, shape


def hidden_from_outside(sigma: np.ndarray, spacing: float, opacity: float = 0.5) -> np.ndarray:
    """Nodes (nx, ny, nz) bool that are hidden from all six axis directions: the opacity
    accumulated from each face of the box up to the node, 1 − exp(−∫σ), is at least
    ``opacity`` along +x, −x, +y, −y, +z and −z. A NeRF's surface is a thin shell of high σ
    over an unobserved, low-σ inside; this fills the shell solid without needing it closed
    at the grid's resolution (a threshold on σ followed by hole filling leaked through gaps)."""
    depth = sigma * spacing
    need = -np.log1p(-opacity)
    hidden = np.ones(sigma.shape, bool)
    for axis in range(3):
        # midpoint rule: half of the node's own cell counts, so the surface sits where the
        # accumulated opacity crosses ``opacity`` (a render's median depth), not a node inside
        before = np.cumsum(depth, axis=axis) - 0.5 * depth
        after = np.flip(np.cumsum(np.flip(depth, axis), axis=axis), axis) - 0.5 * depth
        hidden &= (before >= need) & (after >= need)
    return hidden


#: smoothing of the solid's signed distance [node spacings]: enough to take the voxel steps
#: out of the normals, little enough to keep thin parts (1 node shrank the bunny's silhouettes
#: 6 % more than its volume; docs/fields-from-images.md)
DISTANCE_SMOOTHING = 0.5


def signed_distance_nodes(solid: np.ndarray, smoothing: float = DISTANCE_SMOOTHING) -> np.ndarray:
    """Signed distance (nx, ny, nz) [node spacings, positive outside] to the boundary of a
    boolean node set, the boundary taken halfway between inside and outside nodes
    (SciPy's Euclidean distance transform), smoothed by a Gaussian of ``smoothing`` nodes."""
    inside = ndimage.distance_transform_edt(solid) - 0.5
    outside = ndimage.distance_transform_edt(~solid) - 0.5
    distance = np.where(solid, -inside, outside)
    return ndimage.gaussian_filter(distance, smoothing) if smoothing > 0 else distance


class _DistanceSurface:
    """A signed distance on nodes as a surface for :func:`silhouette_rays` [field units];
    its box is the node box (trilinear inside)."""

    def __init__(self, distance_nodes: np.ndarray, node_bounds: np.ndarray, spacing: float):
        self.grid = VoxelField(jnp.asarray(distance_nodes * spacing, jnp.float32),
                               jnp.asarray(node_bounds[0], jnp.float32), jnp.asarray(node_bounds[1], jnp.float32))
        self.box = np.asarray(node_bounds, dtype=np.float64)

    def bounds(self) -> np.ndarray:
        return self.box

    def signed_distance(self, points):
        return self.grid.density(points)


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class _Opacity:
    """A field's σ in a box fixed as static data (renders under ``jax.jit`` even for fields
    whose ``bounds()`` reads their own leaves); no colour: only the opacity is needed."""

    field: Any
    box: tuple = dataclass_field(metadata=dict(static=True))

    def bounds(self) -> np.ndarray:
        return np.asarray(self.box, dtype=np.float64)

    def density(self, points):
        return self.field.density(points)


def _calibration_cameras(centre: np.ndarray, radius: float, views: int, size: int):
    """``views`` cameras (Blender convention) evenly around a sphere of ``radius`` at
    ``centre``, 3 radii away, each image just holding the sphere."""
    distance = 3.0 * radius
    tan_half = 1.05 * radius / np.sqrt(distance**2 - radius**2)
    poses = []
    for u in fibonacci_directions(views):
        up = np.array([0.0, 0.0, 1.0]) if abs(u[2]) < 0.99 else np.array([0.0, 1.0, 0.0])
        x = np.cross(up, u)
        x /= np.linalg.norm(x)
        pose = np.eye(4)
        pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = x, np.cross(u, x), u, centre + distance * u
        poses.append(pose)
    return Cameras.create(np.stack(poses), size, size, 0.5 * size / tan_half)


class SilhouetteCalibration(NamedTuple):
    """What :func:`silhouette_offset` found: offset [field units] the surface moves outward;
    area_ratio_before / area_ratio_after: the solid's silhouette area over the field's
    rendered one (alpha summed over all views' pixels) before and after; views, size [px]."""

    offset: float
    area_ratio_before: float
    area_ratio_after: float
    views: int
    size: int


def silhouette_offset(field, distance: np.ndarray, node_bounds: np.ndarray, step: float, occupancy=None,
                      views: int = 12, size: int = 64, max_offset: float = 3.0) -> SilhouetteCalibration:
    """The outward offset of a solid's surface that makes its silhouettes cover as many
    pixels as the trained field's own renders (from ``views`` cameras evenly around it).

    Training fits the field's rendered opacity to the images, so its silhouettes are right,
    but a soft field's median-depth surface (the ``solid`` rule's) lies inside the object:
    on 100-px views of the bunny the uncalibrated solid lost 10 % of the volume. The solid's
    silhouettes come from :func:`dano.render.silhouette.silhouette_rays` of its signed
    distance, the field's from :func:`dano.render.render_image` (accumulated opacity), both
    at the same pixel centres; the offset δ solves Σ coverage(d − δ) = Σ α (SciPy's
    ``brentq``), |δ| ≤ ``max_offset`` node spacings (the bound is returned when the root lies
    beyond it).

    field: the trained field (``radiance`` or ``density``, ``bounds()``); distance: (nx, ny,
    nz) the solid's signed distance [node spacings, positive outside]
    (:func:`signed_distance_nodes`); node_bounds: (2, 3) first and last node [field units];
    step: the field's render sample step [field units]; occupancy: its
    :class:`~dano.render.OccupancyGrid` (faster) or None. Raises DanoError if the field
    renders no opacity in any view.
    """
    from scipy.optimize import brentq

    spacing = float((node_bounds[1, 0] - node_bounds[0, 0]) / (distance.shape[0] - 1))
    solid = _DistanceSurface(distance, node_bounds, spacing)
    inside = np.argwhere(distance <= 0)
    lo = node_bounds[0] + spacing * inside.min(axis=0)
    hi = node_bounds[0] + spacing * inside.max(axis=0)
    cameras = _calibration_cameras((lo + hi) / 2, 0.55 * float(np.linalg.norm(hi - lo)) + 2 * spacing, views, size)
    box = np.asarray(field.bounds(), dtype=np.float64)
    opacity = _Opacity(field, tuple(map(tuple, box.tolist())))
    options = RenderConfig.for_bounds(box, int(np.ceil(np.linalg.norm(box[1] - box[0]) / step)),
                                       budget=None if occupancy is None else 4096 * 64)
    silhouette_step = 0.5 * spacing
    sil_samples = int(np.ceil(np.linalg.norm(solid.bounds()[1] - solid.bounds()[0]) / silhouette_step)) + 2
    pixel_angle = 1.0 / float(cameras.focal[0, 0])
    closest = jax.jit(lambda o, d: silhouette_rays(solid, o, d, step=silhouette_step, num_samples=sil_samples,
                                                   pixel_angle=pixel_angle))
    alpha_field, ray_distance, footprint = [], [], []
    for c in range(views):
        render = render_image(opacity, cameras, c, options, occupancy=occupancy, background=0.0)
        alpha_field.append(render.alpha.ravel())
        out = closest(*image_rays(cameras, c))
        ray_distance.append(np.asarray(out.distance, np.float64))
        footprint.append(np.maximum(np.asarray(out.depth, np.float64), silhouette_step) * pixel_angle)
    target = float(np.sum(alpha_field))
    if not target > 0:
        raise DanoError("the field renders no opacity from any side; cannot calibrate the solid's surface")
    ray_distance, footprint = np.concatenate(ray_distance), np.concatenate(footprint)

    def area(offset_nodes: float) -> float:
        # each ray's coverage as silhouette_rays gives it, with the surface moved out by the offset
        x = np.clip(-4.0 * (ray_distance - offset_nodes * spacing) / footprint, -60.0, 60.0)
        return float(np.sum(special.expit(x)))

    before = area(0.0)
    lo_f, hi_f = area(-max_offset) - target, area(max_offset) - target
    if lo_f >= 0:
        offset = -max_offset
    elif hi_f <= 0:
        offset = max_offset
    else:
        offset = brentq(lambda x: area(x) - target, -max_offset, max_offset, xtol=1e-4)
    return SilhouetteCalibration(offset * spacing, before / target, area(offset) / target, views, size)


def density_grid(field, rule: str = "solid", resolution: int = 128, step: float | None = None,
                 scale: float = 1.0, surface_opacity: float = 0.5, occupancy=None, calibrate: bool = True,
                 details: bool = False):
    """The DANO density of a trained field as a :class:`~dano.fields.VoxelField`.

    field: anything with ``density(points) -> σ`` and ``bounds()`` (a
    :class:`~dano.nerf.HashGridField`); rule: one of :data:`DENSITY_RULES`; resolution:
    nodes along the box's longest side; step: δ [field units] of the ``occupancy`` and
    ``solid`` rules (default the box diagonal / 256, training's default); scale: metres per
    field unit (the grid's bounds are multiplied by it; densities keep their values);
    surface_opacity: the ``solid`` rule's surface, where the opacity accumulated from outside
    reaches this (0.5: a render's median depth); calibrate: the ``solid`` rule then moves
    that surface so its silhouettes match the field's renders (:func:`silhouette_offset`;
    ``occupancy``, the field's grid, makes its renders faster); details: also return a dict
    with the calibration (``surface_offset`` [field units], ``silhouette_area_ratio_before``
    and ``_after``; empty for the other rules or without calibration).

    Returns the :class:`~dano.fields.VoxelField` (bounds [field units × scale]), or
    ``(grid, details)``. Raises DanoError for an unknown rule, a bad resolution or scale,
    non-finite σ, or a field that is empty under the rule.
    """
    if rule not in DENSITY_RULES:
        raise DanoError(f"--density-rule must be one of {DENSITY_RULES}, got {rule!r}")
    if not 8 <= resolution <= 512:
        raise DanoError(f"--resolution must be 8 to 512, got {resolution}")
    if not (np.isfinite(scale) and scale > 0):
        raise DanoError(f"--field-scale must be a positive number, got {scale}")
    if not 0 < surface_opacity < 1:
        raise DanoError(f"--surface-opacity must be between 0 and 1, got {surface_opacity}")
    bounds = np.asarray(field.bounds(), dtype=np.float64)
    if step is None:
        step = float(np.linalg.norm(bounds[1] - bounds[0])) / 256
    points, shape = node_grid(bounds, resolution)
    spacing = float(points[1, 2] - points[0, 2])
    sigma = evaluate(field, points).reshape(shape)
    if not np.all(np.isfinite(sigma)):
        raise DanoError(f"the field's density is not finite at {int(np.sum(~np.isfinite(sigma)))} grid nodes")
    sigma = np.maximum(sigma, 0.0)
    node_bounds = np.stack([points.min(0), points.max(0)])
    info = {}
    if rule == "sigma":
        values = sigma
    elif rule == "occupancy":
        values = -np.expm1(-sigma * step)
    else:
        solid = hidden_from_outside(sigma, spacing=spacing, opacity=surface_opacity)
        if not solid.any():
            raise DanoError("the field is empty under the 'solid' rule (no node hidden from outside; an untrained "
                            "field?)")
        labels, count = ndimage.label(solid)
        if count > 1:
            sizes = ndimage.sum(solid, labels, index=np.arange(1, count + 1))
            solid = labels == (1 + int(np.argmax(sizes)))
        distance = signed_distance_nodes(solid)
        offset_nodes = 0.0
        if calibrate:
            cal = silhouette_offset(field, distance, node_bounds, step, occupancy)
            offset_nodes = cal.offset / spacing
            info = {"surface_offset": cal.offset * scale, "surface_offset_nodes": offset_nodes,
                    "silhouette_area_ratio_before": cal.area_ratio_before,
                    "silhouette_area_ratio_after": cal.area_ratio_after, "calibration_views": cal.views,
                    "calibration_size_px": cal.size}
        values = np.clip(0.5 - (distance - offset_nodes), 0.0, 1.0)  # a ramp one node wide about the surface
    if not np.any(values > 1e-6):
        raise DanoError(f"the field is empty under the {rule!r} rule (no node with density; an untrained field?)")
    grid = VoxelField.create(values, node_bounds * scale)
    return (grid, info) if details else grid

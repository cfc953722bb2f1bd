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
  piece, smoothed over one node spacing: uniform density inside the seen surface, the
  mesh-like answer.

docs/fields-from-images.md reports which one gives the right mass properties.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from ..errors import DanoError
from ..fields import VoxelField, evaluate

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


def density_grid(field, rule: str = "solid", resolution: int = 128, step: float | None = None,
                 scale: float = 1.0, surface_opacity: float = 0.5) -> VoxelField:
    """The DANO density of a trained field as a :class:`~dano.fields.VoxelField`.

    field: anything with ``density(points) -> σ`` and ``bounds()`` (a
    :class:`~dano.nerf.HashGridField`); rule: one of :data:`DENSITY_RULES`; resolution:
    nodes along the box's longest side; step: δ [field units] of the ``occupancy`` and
    ``solid`` rules (default the box diagonal / 256, training's default); scale: metres per
    field unit (the grid's bounds are multiplied by it; densities keep their values);
    surface_opacity: the ``solid`` rule's surface, where the opacity accumulated from outside
    reaches this (0.5: a render's median depth).

    Raises DanoError for an unknown rule, a bad resolution or scale, non-finite σ, or a
    field that is empty under the rule.
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
    sigma = evaluate(field, points).reshape(shape)
    if not np.all(np.isfinite(sigma)):
        raise DanoError(f"the field's density is not finite at {int(np.sum(~np.isfinite(sigma)))} grid nodes")
    sigma = np.maximum(sigma, 0.0)
    occupancy = -np.expm1(-sigma * step)
    if rule == "sigma":
        values = sigma
    elif rule == "occupancy":
        values = occupancy
    else:
        solid = hidden_from_outside(sigma, spacing=float(points[1, 2] - points[0, 2]), opacity=surface_opacity)
        labels, count = ndimage.label(solid)
        if count > 1:
            sizes = ndimage.sum(solid, labels, index=np.arange(1, count + 1))
            solid = labels == (1 + int(np.argmax(sizes)))
        values = np.clip(ndimage.gaussian_filter(solid.astype(np.float64), 1.0), 0.0, 1.0)
    if not np.any(values > 1e-6):
        raise DanoError(f"the field is empty under the {rule!r} rule (no node with density; an untrained field?)")
    node_bounds = np.stack([points.min(0), points.max(0)]) * scale
    return VoxelField.create(values, node_bounds)

"""Anti-aliased silhouettes of a solid placed at a pose, differentiable in the pose.

The accumulated opacity of :func:`~dano.render.render_rays` is the silhouette of an opaque
object only in the limit of a sharp, dense field sampled finely, and a point sample per
pixel then aliases: its derivative in the pose is non-zero only where the surface passes
within a sample of a ray. Tracking needs the opposite — the *fraction of each pixel the object
covers*, smooth in the pose — so this renders the limit directly from the surface distance:

* along each ray, samples t_k on a grid fixed to the ray (as in :func:`render_rays`) inside
  the field's box; the surface distance d_k at each (the field's ``signed_distance`` when it
  has one, else −w·logit(φ/φ_interior), exact for φ = ρ·σ(−d/w));
* d_min = min_k d_k, refined to the vertex of the parabola through the smallest sample and
  its two neighbours, is the ray's distance to the surface (for the grazing rays that make
  the silhouette's edge; without the refinement it ripples with the step as the object moves
  along the rays); a ray that misses the box has α = 0;
* coverage α = σ(−d_min / (ℓ/4)), with ℓ = t*·θ the pixel's footprint at the depth t* of the
  closest approach (θ: the pixel's angular size). A straight edge at distance e from a
  pixel's centre covers clip(½ − e/ℓ, 0, 1) of it; the logistic with width ℓ/4 has the same
  value and slope at e = 0.

So the edge of α sits exactly on the surface (no outward bias from an extinction scale) and
α is a box-filtered mask's counterpart: compare it with masks averaged over the same pixels.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..fields.base import interior_density
from .volume import _box_interval, _to_object_frame

_FAR = 1.0e3  # [m] the distance given to rays that miss the field's box


class SilhouetteOutput(NamedTuple):
    """Per ray: alpha (R,) covered fraction of the pixel in [0, 1]; distance (R,) the ray's
    closest sampled surface distance [m] (positive outside; 1e3 for a ray missing the box);
    depth (R,) the distance along the ray of that closest approach [m]."""

    alpha: jax.Array
    distance: jax.Array
    depth: jax.Array


def surface_distance(field, points: jax.Array, edge_width: float) -> jax.Array:
    """Signed distance to the surface [m], (N,), negative inside: ``field.signed_distance``
    when the field has one, else −w·logit(φ/φ_interior) (φ clipped to (1e-6, 1 − 1e-6) of
    full occupancy; 1e3 m where it is below 1e-6) with w = the field's ``edge_width`` or
    ``edge_width`` [m]. Without ``signed_distance`` the distance reaches only 13.8·w outside
    the surface: give fields whose edge width is at least a tenth of a pixel's footprint."""
    if hasattr(field, "signed_distance"):
        return field.signed_distance(points)
    w = float(getattr(field, "edge_width", edge_width))
    occupancy = field.density(points) / interior_density(field)  # a host value: fields are static here
    inside = jnp.clip(occupancy, 1e-6, 1.0 - 1e-6)
    # beyond the resolvable tail (occupancy < 1e-6) the point counts as far outside
    return jnp.where(occupancy < 1e-6, _FAR, -w * jnp.log(inside / (1.0 - inside)))


def silhouette_rays(field, origins: jax.Array, directions: jax.Array, *, pose=None, step: float,
                    num_samples: int, pixel_angle, edge_width: float | None = None) -> SilhouetteOutput:
    """Render the silhouette coverage of R rays through the solid ``field`` at ``pose``.

    field: a :class:`~dano.fields.DensityField` (object frame [m]), ideally with
    ``signed_distance``; origins, directions: (R, 3) world frame [m], directions unit;
    pose: (position (3,) [m], quaternion (4,) wxyz) world from object, None = identity;
    step: sample spacing along the ray [m] (static); num_samples: samples per ray (static;
    chords through the box longer than num_samples·step are cut); pixel_angle: scalar or
    (R,) angular size of each ray's pixel [rad] (pixel width / focal length);
    edge_width: w [m] for fields without ``signed_distance`` (default ``step``).

    Differentiable in the pose and the rays (forward and reverse mode). Returns a
    :class:`SilhouetteOutput`.
    """
    dtype = origins.dtype
    o, d = _to_object_frame(origins, directions, pose)
    bounds = np.asarray(field.bounds(), dtype=np.float64)
    lower, upper = jnp.asarray(bounds[0], dtype), jnp.asarray(bounds[1], dtype)
    enter, leave = _box_interval(jax.lax.stop_gradient(o), jax.lax.stop_gradient(d), lower, upper, 0.0)
    t = (jnp.floor(enter / step)[:, None] + jnp.arange(num_samples, dtype=dtype)[None, :] + 0.5) * step
    valid = (t >= enter[:, None]) & (t <= leave[:, None])
    points = o[:, None, :] + t[..., None] * d[:, None, :]
    dist = surface_distance(field, points.reshape(-1, 3), step if edge_width is None else edge_width)
    dist = jnp.where(valid, dist.reshape(t.shape), _FAR)
    k = jnp.argmin(dist, axis=1)
    take = lambda a, i: jnp.take_along_axis(a, jnp.clip(i, 0, num_samples - 1)[:, None], axis=1)[:, 0]  # noqa: E731
    d_k, t_k = take(dist, k), take(t, k)
    # the minimum between samples: the vertex of the parabola through the argmin and its
    # neighbours (without it, d_min ripples with period `step` as the object moves along the
    # rays, and a tracker settles in those ripples)
    d_lo, d_hi = take(dist, k - 1), take(dist, k + 1)
    usable = (k > 0) & (k < num_samples - 1) & (d_lo < 0.5 * _FAR) & (d_hi < 0.5 * _FAR)
    curvature = jnp.where(usable, d_hi - 2.0 * d_k + d_lo, 1.0)
    usable = usable & (curvature > 1e-12)
    shift = jnp.where(usable, jnp.clip(0.5 * (d_lo - d_hi) / jnp.where(usable, curvature, 1.0), -0.5, 0.5), 0.0)
    d_min = d_k - jnp.where(usable, 0.5 * curvature * shift * shift, 0.0)
    t_min = t_k + shift * step
    footprint = jnp.maximum(t_min, step) * jnp.asarray(pixel_angle, dtype)
    # a ray that misses the box covers nothing (its grid starts at the box's far-off slab
    # crossing: a ray almost parallel to a face had a footprint of km and α up to ~0.4)
    alpha = jnp.where(jnp.any(valid, axis=1), jax.nn.sigmoid(-4.0 * d_min / footprint), 0.0)
    return SilhouetteOutput(alpha, d_min, t_min)

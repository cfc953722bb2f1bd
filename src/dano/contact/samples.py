"""Device-side contact data of a scene's DANOs, stacked over DANOs."""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
from scipy.spatial import ConvexHull, QhullError, cKDTree

#: samples come in blocks of this many neighbours (:meth:`Samples.stack`): a contact model
#: can then find the few blocks near a contact instead of testing every sample
#: (:class:`~dano.contact.per_sample.PerSample`)
SAMPLE_BLOCK = 8


def spatial_order(points: np.ndarray, block: int = SAMPLE_BLOCK) -> np.ndarray:
    """A permutation (N,) of points (N, 3) that puts near points next to each other: the
    leaf order of a median-split k-d tree with leaves of at most ``block`` points (SciPy's
    cKDTree), so that consecutive runs of ``block`` samples are spatially compact."""
    if len(points) <= block:
        return np.arange(len(points))
    return np.asarray(cKDTree(points, leafsize=block, balanced_tree=True).indices)


#: a supporting plane holds the samples within this many sample radii of it: the per-sample
#: model's reach at rest (:data:`~dano.contact.per_sample.REACH_MARGIN`, 0.25) with room for
#: the overlap that holds the object up
FACE_BAND = 0.5
#: the convex hull's facets, largest first, whose planes :func:`face_sample_count` tries
FACE_CANDIDATES = 64


def face_sample_count(points, radius: float) -> int:
    """The most samples that one flat face of an object can rest on a plane with: of
    ``points`` (N, 3) [m] (one DANO's contact points, any frame), the largest number within
    :data:`FACE_BAND` sample radii (``radius`` [m]) of the plane of one of the
    :data:`FACE_CANDIDATES` largest facets of their convex hull (SciPy's Qhull), the planes
    a rigid object can rest on. Measured (5000 samples, default builds): a 76 × 25 mm puck
    1531 and a 10 × 6 × 3 cm box 1462 (their largest faces); the paper's bunny 111, Spot 146,
    the low-poly bunny 167, the blue soap 21. N where the points are too few or too flat for a
    hull (every sample may then touch at once)."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(pts) < 5:
        return len(pts)
    try:
        hull = ConvexHull(pts)
    except (QhullError, ValueError):
        return len(pts)
    corners = pts[hull.simplices]  # (F, 3, 3): Qhull's facets are triangles
    area = np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    planes = hull.equations[np.argsort(-area)[:FACE_CANDIDATES]]  # (F', 4): n·x + d <= 0 inside, |n| = 1
    return int(np.max(np.sum(pts @ planes[:, :3].T + planes[:, 3] > -FACE_BAND * float(radius), axis=0)))


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class Samples:
    """Contact samples of D DANOs, padded to a common count N (a multiple of
    :data:`SAMPLE_BLOCK`) with zero weights, each DANO's in :func:`spatial_order` (every
    contact quantity is a sum over samples: the order changes results only by roundoff).

    points: (D, 3, N) contact points, body frame (object axes, origin at the centre of
    mass) [m]; normals: (D, 3, N) outward unit normals, body frame; weights: (D, N) w_i per
    unit mass scale [kg/α] (paper: φ_i/Σφ·m); wp: (D, 4, N) [w·p; w] and wpp: (D, 6, N)
    [w·p_x², w·p_y², w·p_z², w·p_x·p_y, w·p_x·p_z, w·p_y·p_z], the weighted moments whose
    sums give the overlap, its centroid and their rates in matrix–vector products (two
    arrays, not one of ten rows: a product with the first four rows of one array copied
    them in every step, 2 µs of the bunny drop's 10); radius: (D,) sample radius r [m], the depth over which a sample's
    occupancy rises from 0 to 1; com: (D, 3) centre of mass, object frame [m];
    rho_ref: (D,) interior (full-occupancy) density of each DANO's field, 1 without one;
    extent: (D,) the largest distance of a sample from the body origin [m] (0 without
    samples): every sample lies in the ball of that radius about the body's position, which
    lets a pair kind tell cheaply that no sample can touch the other body
    (:func:`~dano.contact.base.skip_separated`); field_box: (D, 2, 3) the lower and upper
    corners of the box, object frame [m], outside of which each DANO's density field is zero
    (its ``bounds()``; ±inf without a field), which lets a DANO–DANO pair tell the same.
    """

    points: jax.Array
    normals: jax.Array
    weights: jax.Array
    wp: jax.Array
    wpp: jax.Array
    radius: jax.Array
    com: jax.Array
    rho_ref: jax.Array
    extent: jax.Array
    field_box: jax.Array

    def take(self, idx) -> "Samples":
        """The samples of DANOs ``idx`` (a static sequence of indices), leading axis len(idx)."""
        idx = np.asarray(idx, dtype=np.int32)
        if np.array_equal(idx, np.arange(self.radius.shape[0])):
            return self  # every DANO in order: no gather
        return jax.tree_util.tree_map(lambda x: x[idx], self)

    @staticmethod
    def stack(points, normals, weights, radius, com, rho_ref, field_box=None) -> "Samples":
        """From per-DANO lists of (N_k, 3) points and normals and (N_k,) weights (NumPy):
        each DANO's put in :func:`spatial_order`, all padded to the largest N_k rounded up
        to a multiple of :data:`SAMPLE_BLOCK`. field_box: per DANO its field's (2, 3)
        ``bounds()`` or None (no field: an unbounded box), or None for all."""
        orders = [spatial_order(np.asarray(p)) for p in points]
        points = [np.asarray(p)[o] for p, o in zip(points, orders)]
        normals = [np.asarray(v)[o] for v, o in zip(normals, orders)]
        weights = [np.asarray(w)[o] for w, o in zip(weights, orders)]
        n = max((len(p) for p in points), default=0)
        n += -n % SAMPLE_BLOCK

        def pad(a, width):
            out = np.zeros((n,) + a.shape[1:])
            out[: len(a)] = a
            return out

        P = np.stack([pad(p, 3).T for p in points]) if points else np.zeros((0, 3, 0))
        Nn = np.stack([pad(v, 3).T for v in normals]) if normals else np.zeros((0, 3, 0))
        W = np.stack([pad(w, 1) for w in weights]) if weights else np.zeros((0, 0))
        x, y, z = P[:, 0], P[:, 1], P[:, 2]
        WP = np.concatenate([P * W[:, None, :], W[:, None, :]], axis=1)
        WPP = np.stack([x * x, y * y, z * z, x * y, x * z, y * z], axis=1) * W[:, None, :]
        extent = np.array([np.max(np.linalg.norm(p, axis=1), initial=0.0) for p in points])
        unbounded = np.array([[-np.inf] * 3, [np.inf] * 3])
        boxes = [None] * len(points) if field_box is None else list(field_box)
        box = np.array([unbounded if b is None else np.asarray(b, dtype=np.float64).reshape(2, 3) for b in boxes])
        f = jax.device_put  # (as jnp.asarray, without compiling a small program per shape)
        return Samples(f(P), f(Nn), f(W), f(WP), f(WPP), f(np.asarray(radius, dtype=np.float64)),
                       f(np.asarray(com, dtype=np.float64).reshape(-1, 3)), f(np.asarray(rho_ref, dtype=np.float64)),
                       f(extent.reshape(len(points))), f(box.reshape(len(points), 2, 3)))

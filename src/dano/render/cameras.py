"""Pinhole cameras and their rays.

Conventions (both are in use; say which one a pose follows):

* **Blender/NeRF** (``transforms.json``, the NeRF datasets, nerfstudio): the camera looks
  along its −z axis, +y is up in the image, +x to the right.
* **OpenCV** (COLMAP, most robotics calibration): the camera looks along +z, +y is down in
  the image, +x to the right.

A camera-to-world pose is a (4, 4) rigid transform (rotation orthonormal, det +1) from the
camera frame to the world frame [m]; pixel (u, v) has its centre at (u + 0.5, v + 0.5),
u along the image width, v down the image height.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import DanoError

CONVENTIONS = ("blender", "opencv")

# Blender/NeRF camera axes in OpenCV's: flip y and z
_FLIP_YZ = np.diag([1.0, -1.0, -1.0, 1.0])


def opencv_from_blender(camera_to_world) -> np.ndarray:
    """Camera-to-world poses (…, 4, 4) in the Blender/NeRF convention -> OpenCV convention."""
    return np.asarray(camera_to_world, dtype=np.float64) @ _FLIP_YZ


def blender_from_opencv(camera_to_world) -> np.ndarray:
    """Camera-to-world poses (…, 4, 4) in the OpenCV convention -> Blender/NeRF convention."""
    return np.asarray(camera_to_world, dtype=np.float64) @ _FLIP_YZ


def check_poses(camera_to_world, what: str = "camera poses", tolerance: float = 1e-3) -> np.ndarray:
    """Validate camera-to-world poses: shape (C, 4, 4) (or (C, 3, 4)), finite, rotation
    orthonormal with determinant +1 within ``tolerance``, last row [0, 0, 0, 1].

    Returns (C, 4, 4) float64. Raises DanoError naming ``what`` and the first bad pose.
    """
    try:
        p = np.asarray(camera_to_world, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise DanoError(f"{what}: not an array of numbers ({exc})") from exc
    if p.ndim == 3 and p.shape[1:] == (3, 4):
        p = np.concatenate([p, np.broadcast_to([[[0.0, 0.0, 0.0, 1.0]]], (len(p), 1, 4))], axis=1)
    if p.ndim != 3 or p.shape[1:] != (4, 4) or len(p) == 0:
        raise DanoError(f"{what}: expected shape (C, 4, 4) camera-to-world matrices, got {p.shape}")
    bad = ~np.all(np.isfinite(p), axis=(1, 2))
    if bad.any():
        raise DanoError(f"{what}: pose {int(np.argmax(bad))} contains NaN or inf ({int(bad.sum())} bad poses)")
    rot = p[:, :3, :3]
    err = np.abs(np.einsum("cij,cik->cjk", rot, rot) - np.eye(3)).max(axis=(1, 2))
    det = np.linalg.det(rot)
    bad = (err > tolerance) | (np.abs(det - 1.0) > tolerance) | (np.abs(p[:, 3] - [0, 0, 0, 1]).max(axis=1) > tolerance)
    if bad.any():
        k = int(np.argmax(bad))
        raise DanoError(f"{what}: pose {k} is not a rigid transform (|RᵀR − I| = {err[k]:.3g}, det R = {det[k]:.4g}, "
                        f"last row {p[k, 3].tolist()}); scaled or sheared poses are not supported")
    return p


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class Cameras:
    """C pinhole cameras of one image size.

    camera_to_world: (C, 4, 4) float, world frame [m], in ``convention``;
    focal: (C, 2) float, (fx, fy) [px]; principal: (C, 2) float, (cx, cy) [px];
    width, height: image size [px] (static); convention: ``"blender"`` or ``"opencv"`` (static).
    Build with :meth:`create`, which validates.
    """

    camera_to_world: jax.Array
    focal: jax.Array
    principal: jax.Array
    width: int = field(metadata=dict(static=True))
    height: int = field(metadata=dict(static=True))
    convention: str = field(default="blender", metadata=dict(static=True))

    @classmethod
    def create(cls, camera_to_world, width: int, height: int, focal, principal=None,
               convention: str = "blender", dtype=jnp.float32) -> "Cameras":
        """``focal``: scalar, (2,), (C,) or (C, 2) [px]; ``principal`` default the image centre.

        Raises DanoError on bad poses (see :func:`check_poses`), non-positive sizes or
        focal lengths, or an unknown convention.
        """
        if convention not in CONVENTIONS:
            raise DanoError(f"camera convention must be one of {CONVENTIONS}, got {convention!r}")
        if int(width) <= 0 or int(height) <= 0:
            raise DanoError(f"image size must be positive, got {width}x{height}")
        pose = check_poses(camera_to_world)
        n = len(pose)
        f = np.asarray(focal, dtype=np.float64)
        f = np.broadcast_to(f[:, None] if f.ndim == 1 and f.shape[0] == n and n != 2 else f, (n, 2))
        if not np.all(np.isfinite(f)) or np.any(f <= 0):
            raise DanoError(f"focal lengths must be finite and positive, got {np.unique(f)[:4].tolist()}")
        c = np.broadcast_to(np.asarray([width / 2.0, height / 2.0] if principal is None else principal,
                                       dtype=np.float64), (n, 2))
        if not np.all(np.isfinite(c)):
            raise DanoError("principal points must be finite")
        return cls(jnp.asarray(pose, dtype), jnp.asarray(f, dtype), jnp.asarray(c, dtype),
                   int(width), int(height), convention)

    @property
    def num_cameras(self) -> int:
        return int(self.camera_to_world.shape[0])

    def __getitem__(self, index) -> "Cameras":
        index = np.atleast_1d(np.asarray(index))
        return Cameras(self.camera_to_world[index], self.focal[index], self.principal[index],
                       self.width, self.height, self.convention)


def pixel_rays(cameras: Cameras, camera: jax.Array, u: jax.Array, v: jax.Array) -> tuple[jax.Array, jax.Array]:
    """World-frame rays through pixel centres.

    camera: (R,) int camera index; u, v: (R,) float pixel coordinates (the pixel's centre
    is at integer + 0.5). Returns ``(origins (R, 3) [m], directions (R, 3) unit)``.
    """
    f = cameras.focal[camera]
    c = cameras.principal[camera]
    x = (u - c[:, 0]) / f[:, 0]
    y = (v - c[:, 1]) / f[:, 1]
    one = jnp.ones_like(x)
    if cameras.convention == "blender":
        d_cam = jnp.stack([x, -y, -one], axis=-1)
    else:
        d_cam = jnp.stack([x, y, one], axis=-1)
    pose = cameras.camera_to_world[camera]
    d = jnp.einsum("rij,rj->ri", pose[:, :3, :3], d_cam)
    d = d / jnp.linalg.norm(d, axis=-1, keepdims=True)
    return pose[:, :3, 3], d


def project_points(cameras: Cameras, camera: int, points) -> tuple[np.ndarray, np.ndarray]:
    """Where world points fall in one camera's image: the inverse of :func:`pixel_rays`.

    points: (N, 3) float, world frame [m]. Returns ``(uv (N, 2) [px], depth (N,) [m])``: pixel
    coordinates (a pixel's centre at integer + 0.5) and the distance in front of the camera
    along its optical axis (negative behind it, where ``uv`` is meaningless).
    """
    pose = np.asarray(cameras.camera_to_world[camera], dtype=np.float64)
    f = np.asarray(cameras.focal[camera], dtype=np.float64)
    c = np.asarray(cameras.principal[camera], dtype=np.float64)
    x = (np.asarray(points, dtype=np.float64).reshape(-1, 3) - pose[:3, 3]) @ pose[:3, :3]  # camera frame
    if cameras.convention == "blender":  # looks along −z, image y down = camera −y
        depth, right, down = -x[:, 2], x[:, 0], -x[:, 1]
    else:  # opencv: looks along +z, image y down = camera +y
        depth, right, down = x[:, 2], x[:, 0], x[:, 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = np.stack([c[0] + f[0] * right / depth, c[1] + f[1] * down / depth], axis=-1)
    return uv, depth


def image_rays(cameras: Cameras, camera: int) -> tuple[jax.Array, jax.Array]:
    """All rays of one image, row by row: ``(origins, directions)`` each (H·W, 3)."""
    v, u = np.meshgrid(np.arange(cameras.height), np.arange(cameras.width), indexing="ij")
    dt = cameras.focal.dtype
    idx = jnp.full(u.size, camera, dtype=jnp.int32)
    return pixel_rays(cameras, idx, jnp.asarray(u.ravel() + 0.5, dt), jnp.asarray(v.ravel() + 0.5, dt))

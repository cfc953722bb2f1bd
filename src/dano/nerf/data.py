"""Posed image sets: the Blender/nerfstudio ``transforms.json`` format and NPZ arrays.

``transforms.json`` (Blender/NeRF synthetic, instant-ngp, nerfstudio): camera-to-world
``transform_matrix`` per frame in the Blender/NeRF convention (camera looks along −z);
intrinsics shared at the top level or per frame — ``fl_x``/``fl_y``/``cx``/``cy``/``w``/``h``
[px], or ``camera_angle_x`` [rad] (horizontal field of view) — and ``file_path`` relative to
the JSON file (Blender omits the ``.png``). RGBA images give an alpha mask. dano adds
``"dano_bounds"`` ((2, 3) object box [m]) when it writes one; without it the box is
``"aabb"`` if present, else [−1.5, 1.5]³ (the Blender scenes' box).

NPZ (like ``lego_100px.npz``): ``images`` (C, H, W, 3|4) float in [0, 1] or uint8, ``poses``
(C, 4, 4) camera-to-world (Blender convention), ``focal`` [px] scalar or (C,), optional
``bounds`` (2, 3).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._files import read_npz
from ..errors import DanoError, FileFormatError
from ..fields.base import check_bounds
from ..render.cameras import Cameras

DEFAULT_BOUNDS = np.array([[-1.5, -1.5, -1.5], [1.5, 1.5, 1.5]])


@dataclass(frozen=True)
class Dataset:
    """Posed images of one object (host arrays).

    images: (C, H, W, 3) float32 RGB in [0, 1] (straight, not premultiplied);
    alpha: (C, H, W) float32 in [0, 1] or None (no mask: images already on their background);
    cameras: :class:`~dano.render.Cameras`; bounds: (2, 3) object box [m]; source: where it
    was read from; names: one name per image.
    """

    images: np.ndarray
    alpha: np.ndarray | None
    cameras: Cameras
    bounds: np.ndarray
    source: str
    names: tuple[str, ...]

    @property
    def num_images(self) -> int:
        return int(self.images.shape[0])

    def subset(self, index) -> "Dataset":
        index = np.asarray(index, dtype=int)
        return Dataset(self.images[index], None if self.alpha is None else self.alpha[index], self.cameras[index],
                       self.bounds, self.source, tuple(self.names[i] for i in index))

    def split(self, holdout: int) -> tuple["Dataset", "Dataset"]:
        """(train, held out): ``holdout`` views evenly spread over the set are held out.

        Raises DanoError unless 0 < holdout < number of images.
        """
        n = self.num_images
        if not 0 < holdout < n:
            raise DanoError(f"--holdout must be between 1 and {n - 1} for {n} images, got {holdout}")
        held = np.unique(np.round(np.linspace(0, n - 1, holdout)).astype(int))
        train = np.setdiff1d(np.arange(n), held)
        return self.subset(train), self.subset(held)


def load_dataset(path: str | Path, bounds=None) -> Dataset:
    """Read a posed image set from an ``.npz`` file, a ``transforms.json`` file or a folder
    holding one. ``bounds`` (2, 3) [m] overrides the box stated in the data.

    Raises FileFormatError naming the file for a missing or unreadable file or image,
    images of different sizes, poses that are not rigid or hold NaN, and bad bounds.
    """
    path = Path(path)
    if path.is_dir():
        path = path / "transforms.json"
    if not path.exists():
        raise FileFormatError(f"{path}: no such file (expected an .npz image set or a transforms.json)")
    try:
        if path.suffix == ".npz":
            data = _from_npz(path)
        else:
            data = _from_transforms(path)
        if bounds is not None:
            data = Dataset(data.images, data.alpha, data.cameras, check_bounds(bounds, "--bounds"), data.source,
                           data.names)
        return data
    except FileFormatError:
        raise
    except DanoError as exc:
        raise FileFormatError(f"{path}: {exc}") from exc


def as_float_images(images: np.ndarray, where: str) -> np.ndarray:
    """uint8/uint16/float images -> float32 in [0, 1]. Raises DanoError naming ``where`` for
    float images that are not finite or not in [0, 1]."""
    if images.dtype == np.uint8:
        return images.astype(np.float32) / 255.0
    if images.dtype == np.uint16:
        return images.astype(np.float32) / 65535.0
    out = images.astype(np.float32)
    if not np.all(np.isfinite(out)) or out.min() < 0.0 or out.max() > 1.0:
        raise DanoError(f"{where}: float images must be finite and in [0, 1]")
    return out


def _split_alpha(images: np.ndarray):
    if images.shape[-1] == 4:
        return np.ascontiguousarray(images[..., :3]), np.ascontiguousarray(images[..., 3])
    if images.shape[-1] == 3:
        return images, None
    raise DanoError(f"images must have 3 (RGB) or 4 (RGBA) channels, got {images.shape[-1]}")


def _from_npz(path: Path) -> Dataset:
    arrays = read_npz(path, ("images", "poses", "focal"), "image set")
    images = arrays["images"]
    if images.ndim != 4:
        raise DanoError(f"images must have shape (C, H, W, 3|4), got {images.shape}")
    rgb, alpha = _split_alpha(as_float_images(images, "images"))
    c, h, w = rgb.shape[:3]
    poses = arrays["poses"]
    if len(poses) != c:
        raise DanoError(f"{len(poses)} poses for {c} images")
    cameras = Cameras.create(poses, w, h, arrays["focal"], convention="blender")
    b = check_bounds(arrays.get("bounds", DEFAULT_BOUNDS), "bounds")
    return Dataset(rgb, alpha, cameras, b, str(path), tuple(f"{path.name}[{i}]" for i in range(c)))


def _intrinsics(frame: dict, top: dict, width: int, height: int) -> tuple[float, float, float, float]:
    def get(key):
        return frame.get(key, top.get(key))

    fx, fy = get("fl_x"), get("fl_y")
    if fx is None:
        angle = get("camera_angle_x")
        if angle is None:
            raise DanoError("no focal length: give fl_x (and fl_y) [px] or camera_angle_x [rad]")
        fx = 0.5 * width / np.tan(0.5 * float(angle))
    if fy is None:
        angle_y = get("camera_angle_y")
        fy = 0.5 * height / np.tan(0.5 * float(angle_y)) if angle_y is not None else fx
    cx, cy = get("cx"), get("cy")
    return float(fx), float(fy), float(width / 2 if cx is None else cx), float(height / 2 if cy is None else cy)


def _read_image(path: Path) -> np.ndarray:
    import imageio.v3 as iio

    if not path.exists() and not path.suffix:
        path = path.with_suffix(".png")
    if not path.exists():
        raise FileFormatError(f"{path}: image file not found")
    try:
        image = iio.imread(path)
    except Exception as exc:
        raise FileFormatError(f"{path}: cannot read image ({exc})") from exc
    if image.ndim == 2:
        image = np.repeat(image[..., None], 3, axis=-1)
    return as_float_images(image, str(path))


def _from_transforms(path: Path) -> Dataset:
    try:
        meta = json.loads(path.read_text())
    except Exception as exc:
        raise FileFormatError(f"{path}: cannot read JSON ({exc})") from exc
    frames = meta.get("frames") if isinstance(meta, dict) else None
    if not isinstance(frames, list):
        raise DanoError("no \"frames\" list")
    if not frames:
        raise DanoError("the \"frames\" list is empty: no views")
    images, alphas, poses, focal, principal, names = [], [], [], [], [], []
    size = None
    for i, frame in enumerate(frames):
        if not isinstance(frame, dict) or "file_path" not in frame or "transform_matrix" not in frame:
            raise DanoError(f"frame {i}: needs \"file_path\" and \"transform_matrix\"")
        image_path = (path.parent / frame["file_path"]).resolve()
        image = _read_image(image_path)
        rgb, alpha = _split_alpha(image)
        if size is None:
            size = rgb.shape[:2]
        elif rgb.shape[:2] != size:
            raise DanoError(f"frame {i} ({image_path.name}) is {rgb.shape[1]}x{rgb.shape[0]} px, the first image "
                            f"{size[1]}x{size[0]}; all images must have one size")
        if alphas and (alpha is None) != (alphas[0] is None):
            raise DanoError(f"frame {i} ({image_path.name}): mixes RGB and RGBA images")
        images.append(rgb)
        alphas.append(alpha)
        poses.append(frame["transform_matrix"])
        fx, fy, cx, cy = _intrinsics(frame, meta, size[1], size[0])
        focal.append((fx, fy))
        principal.append((cx, cy))
        names.append(str(frame["file_path"]))
    h, w = size
    for key, expected in (("w", w), ("h", h)):
        stated = meta.get(key)
        if stated is not None and int(stated) != expected:
            raise DanoError(f"\"{key}\" is {stated} but the images are {w}x{h} px")
    cameras = Cameras.create(np.asarray(poses, dtype=np.float64), w, h, np.asarray(focal), np.asarray(principal),
                             convention="blender")
    if "dano_bounds" in meta:
        b = check_bounds(meta["dano_bounds"], "dano_bounds")
    elif "aabb" in meta:
        b = check_bounds(meta["aabb"], "aabb")
    else:
        b = DEFAULT_BOUNDS.copy()
    alpha = None if alphas[0] is None else np.stack(alphas)
    return Dataset(np.stack(images), alpha, cameras, b, str(path), tuple(names))

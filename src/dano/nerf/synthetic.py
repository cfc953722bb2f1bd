"""Synthetic training data with exact ground truth: RGBA views of a mesh rendered by MuJoCo.

The mesh (its own frame and units, taken as metres) is drawn with a uniform diffuse
material under three fixed directional lights (no headlight, so shading is fixed to the
object and views agree), from cameras on a Fibonacci sphere looking at the centre of its
bounding box. Alpha comes from MuJoCo's segmentation render; both are rendered at
``supersample``× the size and averaged down, so edges are anti-aliased. Written as a
Blender/NeRF ``transforms.json`` with ``"dano_bounds"`` (the mesh box grown by 10 %).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import numpy as np
import tyro

from .._files import atomic_dir
from ..errors import DanoError
from ..io import load_mesh

_MARGIN = 0.10


def fibonacci_directions(n: int) -> np.ndarray:
    """(n, 3) unit vectors spread evenly over the sphere (golden-angle spiral)."""
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = k * np.pi * (3.0 - np.sqrt(5.0))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)


def add_lights(spec, centre, radius: float) -> None:
    """Three fixed directional lights (diffuse 0.6, ambient 0.12, no specular, no shadows)
    aimed at ``centre`` [m] from 4·``radius`` away: the lighting of dano's synthetic renders."""
    import mujoco

    for direction in ((0.5, 0.3, -1.0), (-0.7, 0.4, 0.3), (0.2, -0.8, 0.2)):
        light = spec.worldbody.add_light()
        light.type = mujoco.mjtLightType.mjLIGHT_DIRECTIONAL
        light.dir = np.asarray(direction) / np.linalg.norm(direction)
        light.diffuse = (0.6, 0.6, 0.6)
        light.ambient = (0.12, 0.12, 0.12)
        light.specular = (0.0, 0.0, 0.0)
        light.castshadow = False
        light.pos = np.asarray(centre) - 4 * radius * light.dir


def _model(mesh, size: int, fovy: float, colour):
    import mujoco

    spec = mujoco.MjSpec()
    spec.visual.global_.offwidth = size
    spec.visual.global_.offheight = size
    spec.visual.global_.fovy = fovy
    spec.visual.headlight.active = 0
    spec.visual.quality.shadowsize = 0
    add_lights(spec, mesh.bounds.mean(axis=0), float(np.linalg.norm(mesh.bounds[1] - mesh.bounds[0])) / 2)
    spec.add_mesh(name="object", uservert=np.asarray(mesh.vertices, dtype=np.float64).ravel(),
                  userface=np.asarray(mesh.faces, dtype=np.int32).ravel())
    geom = spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_MESH, meshname="object", name="object")
    geom.rgba = (*colour, 1.0)
    geom.contype = geom.conaffinity = 0
    # MuJoCo recentres a mesh's vertices on their centroid and principal axes and moves the
    # geom to compensate: in the world frame the mesh sits exactly where its file has it
    return spec.compile()


def rendered_camera(renderer) -> tuple[np.ndarray, float]:
    """The camera a ``mujoco.Renderer`` just set up by ``update_scene`` renders from:
    (camera-to-world (4, 4), Blender convention [m], tan of half the vertical field of view).
    MuJoCo renders the mean of its two eyes' cameras (each is ipd/2 aside)."""
    import mujoco

    gl = mujoco.mjv_averageCamera(renderer.scene.camera[0], renderer.scene.camera[1])
    forward, up = np.asarray(gl.forward, np.float64), np.asarray(gl.up, np.float64)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2] = np.cross(forward, up), up, -forward
    pose[:3, 3] = gl.pos
    return pose, float(gl.frustum_top) / float(gl.frustum_near)


def render_views(mesh, views: int, size: int, distance_factor: float = 2.0, fovy: float = 40.0,
                 supersample: int = 2, colour=(0.72, 0.55, 0.38), progress=None):
    """Render ``views`` RGBA images (views, size, size, 4) uint8 of a trimesh ``mesh``.

    Returns ``(images, camera_to_world (views, 4, 4) Blender convention, focal [px],
    bounds (2, 3) [m])``. Raises DanoError if no OpenGL context can be made.
    """
    import mujoco

    if views < 1 or size < 8:
        raise DanoError(f"--views must be >= 1 and --size >= 8, got {views} and {size}")
    big = size * supersample
    model = _model(mesh, big, fovy, colour)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    lo, hi = mesh.bounds
    centre = (lo + hi) / 2
    radius = float(np.linalg.norm(hi - lo)) / 2
    distance = distance_factor * radius / np.sin(np.radians(fovy) / 2) / 2
    try:
        renderer = mujoco.Renderer(model, big, big)
    except Exception as exc:
        raise DanoError(f"cannot create an OpenGL context for rendering (MUJOCO_GL={os.environ.get('MUJOCO_GL')}): "
                        f"{exc}") from exc
    images, poses = [], []
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    cam.lookat[:] = centre
    cam.distance = distance
    try:
        for i, direction in enumerate(fibonacci_directions(views)):
            # a free camera at this direction from the centre (elevation within ±89°: MuJoCo keeps z up)
            cam.azimuth = float(np.degrees(np.arctan2(direction[1], direction[0])))
            cam.elevation = float(-np.clip(np.degrees(np.arcsin(direction[2])), -89.0, 89.0))
            renderer.update_scene(data, cam)
            pose, tan_half = rendered_camera(renderer)
            rgb = renderer.render().astype(np.float64)
            renderer.enable_segmentation_rendering()
            seg = renderer.render()
            renderer.disable_segmentation_rendering()
            mask = ((seg[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM)) & (seg[..., 0] == 0)).astype(np.float64)
            rgba = np.concatenate([rgb * mask[..., None], mask[..., None] * 255.0], axis=-1)
            rgba = rgba.reshape(size, supersample, size, supersample, 4).mean(axis=(1, 3))
            a = rgba[..., 3:4]
            rgba[..., :3] = np.where(a > 0, rgba[..., :3] * 255.0 / np.maximum(a, 1e-9), 0.0)  # straight alpha
            images.append(np.clip(np.round(rgba), 0, 255).astype(np.uint8))
            poses.append(pose)
            if progress is not None:
                progress(i + 1, views, "rendering views")
    finally:
        renderer.close()
    focal = 0.5 * size / tan_half
    grow = _MARGIN * (hi - lo) + 1e-6
    return np.stack(images), np.stack(poses), focal, np.stack([lo - grow, hi + grow])


def render_dataset(mesh_path: str | Path, out_dir: str | Path, views: int = 100, size: int = 100,
                   progress=None) -> Path:
    """Render a mesh's views into ``out_dir`` (``transforms.json`` and ``images/r_NNN.png``).

    The folder appears complete or not at all (written beside it, then renamed). Raises
    DanoError if ``out_dir`` exists and is not empty, FileFormatError for a bad mesh.
    """
    import imageio.v3 as iio

    out_dir = Path(out_dir)
    if out_dir.exists() and (not out_dir.is_dir() or any(out_dir.iterdir())):
        raise DanoError(f"{out_dir}: exists and is not an empty folder; choose a new output folder")
    mesh = load_mesh(mesh_path, require_watertight=False)
    images, poses, focal, bounds = render_views(mesh, views, size, progress=progress)
    with atomic_dir(out_dir) as tmp:
        (tmp / "images").mkdir()
        frames = []
        for i, (image, pose) in enumerate(zip(images, poses)):
            name = f"images/r_{i:03d}.png"
            iio.imwrite(tmp / name, image)
            frames.append({"file_path": name, "transform_matrix": pose.tolist()})
        meta = {"camera_angle_x": float(2 * np.arctan(0.5 * size / focal)), "fl_x": focal, "fl_y": focal,
                "cx": size / 2, "cy": size / 2, "w": size, "h": size, "dano_bounds": bounds.tolist(),
                "dano_source": Path(mesh_path).name, "dano_units": "m",
                "dano_note": "RGBA views of the mesh rendered by MuJoCo (dano render-dataset); frame: the mesh file's; "
                             "lengths: the mesh file's, read as metres (a mesh in mm: dano build DIR --scale 0.001)",
                "frames": frames}
        (tmp / "transforms.json").write_text(json.dumps(meta, indent=1) + "\n")
    return out_dir


@dataclass(frozen=True)
class RenderDatasetConfig:
    """Render RGBA views of a mesh at known cameras with MuJoCo's renderer (headless) as a
    transforms.json image set: training data with exact ground truth."""

    mesh: Annotated[Path, tyro.conf.Positional, tyro.conf.arg(metavar="MESH")]
    """a mesh file (.obj/.stl/.ply/...; its frame and units, taken as metres)."""
    out: Annotated[Path, tyro.conf.arg(aliases=("-o",))]
    """the folder to write (transforms.json, images/r_NNN.png); must not exist or be empty."""
    views: int = 100
    """number of views (cameras on a Fibonacci sphere around the mesh)."""
    size: int = 100
    """image width and height [px]."""
    quiet: bool = False
    """no progress bar."""

    def __post_init__(self):
        if not 1 <= self.views <= 10_000 or not 8 <= self.size <= 4096:
            raise DanoError(f"--views must be 1 to 10000 and --size 8 to 4096, got {self.views} and {self.size}")

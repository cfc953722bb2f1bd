"""Videos with exact ground truth: a DANO's motion rendered by MuJoCo from its mesh.

The object's triangle mesh (its ``mesh_vertices``/``mesh_faces``, body frame) is drawn by
MuJoCo's OpenGL renderer — a rasteriser that dano's tracker does not use — on a textured
ground plane from a fixed camera, under the three directional lights of
:mod:`dano.nerf.synthetic` (no shadows, no headlight). Each frame is rendered at
``supersample``× the size and averaged down; the true mask comes from MuJoCo's
segmentation render, averaged the same way (fractional at the edges). A background frame
(the scene without the object) is rendered too, for background subtraction.

Written as a video folder (:mod:`dano.tracking.inputs`): ``frames/NNNN.png``,
``masks/NNNN.png``, ``background.png``, ``camera.json`` and ``truth.npz`` (the simulated
trajectory, dano's trajectory format).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from .._files import atomic_dir
from ..asset import visual_mesh
from ..data import load_builtin
from ..errors import DanoError
from ..nerf.synthetic import add_lights, rendered_camera
from ..sim import rollout
from ..sim.scene import DanoObject, compose
from ..sim.scenes import initial_state, resting_height
from ..trajectory import Trajectory, save_trajectory

#: the synthetic slide: the built-in low-poly bunny (1.29 m across) thrown across the ground
SLIDE_FRICTION = 0.35
SLIDE_VELOCITY = (3.0, 0.6, 0.0)  # world frame [m/s]
SLIDE_SPIN = (2.0, -1.0, 6.0)  # body frame [rad/s]
SLIDE_LIFT = 0.02  # start this high above resting contact [m]


@dataclass(frozen=True)
class VideoCamera:
    """A fixed camera of a synthetic video: ``lookat`` (3,) world [m], ``distance`` [m],
    ``azimuth``/``elevation`` [deg] (MuJoCo's free-camera angles), vertical field of view
    ``fovy`` [deg], image ``width`` × ``height`` [px]."""

    lookat: tuple = (0.5, 0.15, 0.2)
    distance: float = 2.6
    azimuth: float = -90.0
    elevation: float = -30.0
    fovy: float = 45.0
    width: int = 320
    height: int = 240


def _video_model(vertices, faces, camera: VideoCamera, supersample: int, colour=(0.72, 0.55, 0.38),
                 flat: bool = False):
    spec = mujoco.MjSpec()
    spec.visual.global_.offwidth = camera.width * supersample
    spec.visual.global_.offheight = camera.height * supersample
    spec.visual.global_.fovy = camera.fovy
    spec.visual.headlight.active = 0
    spec.visual.quality.shadowsize = 0
    if flat:  # ambient light only: every surface shows its own colour
        light = spec.worldbody.add_light(type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL, dir=[0, 0, -1])
        light.diffuse, light.ambient, light.specular, light.castshadow = (0, 0, 0), (1, 1, 1), (0, 0, 0), False
    else:
        add_lights(spec, np.asarray(camera.lookat, dtype=np.float64), 2.0)
    spec.add_texture(name="grid", type=mujoco.mjtTexture.mjTEXTURE_2D,
                           builtin=mujoco.mjtBuiltin.mjBUILTIN_CHECKER, width=256, height=256,
                           rgb1=[0.32, 0.36, 0.42], rgb2=[0.22, 0.25, 0.30])
    spec.add_material(name="grid", textures=["", "grid"], texrepeat=[4, 4], reflectance=0.0)
    ground = spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_PLANE, size=[6, 6, 0.1], material="grid",
                                     name="ground")
    ground.contype = ground.conaffinity = 0
    body = spec.worldbody.add_body(name="object", mocap=True)
    spec.add_mesh(name="object", uservert=np.asarray(vertices, dtype=np.float64).ravel(),
                  userface=np.asarray(faces, dtype=np.int32).ravel())
    geom = body.add_geom(type=mujoco.mjtGeom.mjGEOM_MESH, meshname="object", name="object")
    geom.rgba = (*colour, 1.0)
    geom.contype = geom.conaffinity = 0
    return spec.compile()


def render_video(asset, poses: np.ndarray, camera: VideoCamera = VideoCamera(), supersample: int = 2,
                 flat: bool = False, mesh=None, progress=None):
    """Render frames of ``asset`` (a DanoAsset with a visual mesh) at body poses ``poses``
    (T, 7): centre-of-mass position [m] and wxyz quaternion (MuJoCo's qpos of its free joint).
    flat: ambient light only (no shading: the object shows one colour); mesh: optional
    (vertices (V, 3) body frame [m], faces (F, 3)) to render instead of the asset's visual mesh.

    Returns ``(frames (T, H, W, 3) uint8, masks (T, H, W) float32 in [0, 1], background
    (H, W, 3) uint8, camera_to_world (4, 4) Blender convention, focal [px])``.
    Raises DanoError if the asset has no mesh or no OpenGL context can be made.
    """
    vertices, faces = (asset.mesh_vertices, asset.mesh_faces) if mesh is None else mesh
    if len(faces) == 0:
        raise DanoError(f"{asset.name}: has no visual mesh to render")
    model = _video_model(vertices, faces, camera, supersample, flat=flat)
    data = mujoco.MjData(model)
    w, h, s = camera.width, camera.height, supersample
    try:
        renderer = mujoco.Renderer(model, h * s, w * s)
    except Exception as exc:
        raise DanoError(f"cannot create an OpenGL context for rendering (MUJOCO_GL={os.environ.get('MUJOCO_GL')}): "
                        f"{exc}") from exc
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    cam.lookat[:] = camera.lookat
    cam.distance, cam.azimuth, cam.elevation = camera.distance, camera.azimuth, camera.elevation
    geom_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "object")

    def shrink(image):
        return image.reshape(h, s, w, s, -1).mean(axis=(1, 3))

    frames, masks = [], []
    try:
        data.mocap_pos[0] = (0.0, 0.0, -100.0)  # out of sight: the background
        mujoco.mj_forward(model, data)
        renderer.update_scene(data, cam)
        pose, tan_half = rendered_camera(renderer)
        background = np.round(shrink(renderer.render().astype(np.float64))).astype(np.uint8)
        for k, qpos in enumerate(np.asarray(poses, dtype=np.float64)):
            data.mocap_pos[0], data.mocap_quat[0] = qpos[:3], qpos[3:] / np.linalg.norm(qpos[3:])
            mujoco.mj_forward(model, data)
            renderer.update_scene(data, cam)
            frames.append(np.round(shrink(renderer.render().astype(np.float64))).astype(np.uint8))
            renderer.enable_segmentation_rendering()
            seg = renderer.render()
            renderer.disable_segmentation_rendering()
            hit = (seg[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM)) & (seg[..., 0] == geom_id)
            masks.append(shrink(hit[..., None].astype(np.float64))[..., 0].astype(np.float32))
            if progress is not None:
                progress(k + 1, len(poses), "rendering frames")
    finally:
        renderer.close()
    focal = 0.5 * h / tan_half
    return np.stack(frames), np.stack(masks), background, pose, focal


def slide_scene(dt: float = 0.01):
    """The synthetic slide's scene and initial state: the built-in ``bunny_lowpoly`` DANO
    (3.2 kg, 1.29 m across, paper contact defaults) 2 cm above resting contact, thrown at
    3 m/s with a spin. Returns ``(scene, state)``."""
    asset = load_builtin("bunny_lowpoly")
    z = resting_height(asset) + SLIDE_LIFT
    scene = compose([DanoObject("bunny", asset, (0, 0, z))], dt=dt, name="synthetic-slide")
    state = initial_state(scene, {"bunny": ((0, 0, z), (1, 0, 0, 0))}, {"bunny": (SLIDE_VELOCITY, SLIDE_SPIN)})
    return scene, state


def slide_trajectory(friction: float = SLIDE_FRICTION, duration: float = 1.2, fps: float = 50.0,
                     dt: float = 0.01):
    """The synthetic slide's ground truth (:func:`slide_scene` with sliding ``friction``): it
    slides about a metre, tips onto its side and spins down. Returns ``(scene, trajectory)``
    with a frame every 1/``fps`` s."""
    substeps = int(round(1.0 / (fps * dt)))
    if substeps < 1 or abs(substeps * dt * fps - 1.0) > 1e-9:
        raise DanoError(f"the frame interval 1/{fps} s must be a whole number of {dt} s steps")
    scene, state = slide_scene(dt)
    steps = int(round(duration * fps)) * substeps
    traj = rollout(scene, state, params=scene.default_params(sliding_friction=friction), steps=steps)
    keep = np.arange(0, steps + 1, substeps)
    frames = Trajectory(traj.time[keep], traj.qpos[keep], traj.qvel[keep], traj.psi[keep], traj.body_names,
                        traj.dano_names, traj.qpos_adr, traj.dof_adr, traj.pair_names,
                        {**traj.metadata, "sliding_friction": friction, "fps": fps})
    return scene, frames


def write_video_folder(out_dir: str | Path, frames, masks, background, camera_to_world, focal: float,
                       fps: float, extra: dict | None = None, truth=None) -> Path:
    """Write a video folder (frames, masks, background, camera.json, truth.npz) atomically:
    it appears complete or not at all. Raises DanoError if ``out_dir`` exists and is not an
    empty folder."""
    import imageio.v3 as iio

    out_dir = Path(out_dir)
    with atomic_dir(out_dir) as tmp:
        (tmp / "frames").mkdir()
        (tmp / "masks").mkdir()
        for k, (frame, mask) in enumerate(zip(frames, masks)):
            iio.imwrite(tmp / "frames" / f"{k:04d}.png", frame)
            iio.imwrite(tmp / "masks" / f"{k:04d}.png", np.round(np.clip(mask, 0, 1) * 255).astype(np.uint8))
        iio.imwrite(tmp / "background.png", background)
        h, w = frames.shape[1:3]
        meta = {"fl_x": float(focal), "fl_y": float(focal), "cx": w / 2, "cy": h / 2, "w": int(w), "h": int(h),
                "transform_matrix": np.asarray(camera_to_world).tolist(), "convention": "blender", "fps": float(fps),
                **(extra or {})}
        (tmp / "camera.json").write_text(json.dumps(meta, indent=1) + "\n")
        if truth is not None:
            save_trajectory(truth, tmp / "truth.npz")
    return out_dir


def surface_mesh(asset, resolution: int = 192):
    """The surface of an asset's signed-distance field, d = 0, by marching cubes
    (scikit-image) on a grid of ``resolution`` nodes along the longest axis: (vertices
    (V, 3) body frame [m], faces (F, 3)). The synthetic videos render this rather than the
    asset's visual mesh: that mesh is extracted on a coarse grid and cuts the convex
    features the silhouette is made of by a few mm, which made the tracked bunny's
    silhouette fit sit ~1 cm too far from the camera (measured: the field's silhouette
    covered 1.3–2.0 % more pixels than masks of the coarse mesh at the true poses).
    Raises DanoError if the asset's field has no signed distance."""
    field = asset.field
    if field is None or not hasattr(field, "signed_distance"):
        raise DanoError(f"{asset.name}: a synthetic video needs a DANO whose field has a signed distance")
    verts, faces = visual_mesh(field, 0.0, resolution, signed_distance=True)
    return verts - np.asarray(asset.center_of_mass, dtype=np.float64), faces


def synthetic_slide(out_dir: str | Path, friction: float = SLIDE_FRICTION, camera: VideoCamera = VideoCamera(),
                    duration: float = 1.2, fps: float = 50.0, progress=None) -> Path:
    """Simulate :func:`slide_trajectory` and render it (:func:`render_video`) into a video
    folder ``out_dir``; returns its path."""
    scene, truth = slide_trajectory(friction, duration, fps)
    asset = scene.assets[0]
    frames, masks, background, pose, focal = render_video(asset, truth.qpos[:, :7], camera, mesh=surface_mesh(asset),
                                                          progress=progress)
    extra = {"dano_source": "dano synthetic-slide: bunny_lowpoly rendered by MuJoCo",
             "dano_object": "bunny_lowpoly", "dano_sliding_friction": friction}
    return write_video_folder(out_dir, frames, masks, background, pose, focal, fps, extra, truth)

"""Videos of trajectories with MuJoCo's renderer (headless via EGL) and imageio-ffmpeg."""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np

from .._files import atomic_path
from ..errors import DanoError


def camera_id(model, name: str) -> int:
    """The id of the camera ``name`` of a ``mujoco.MjModel``. Raises DanoError naming the
    model's cameras when there is none of that name."""
    import mujoco

    cam = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, name)
    if cam < 0:
        names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_CAMERA, i) for i in range(model.ncam)]
        raise DanoError(f"--camera {name!r}: the scene has no such camera; its cameras: "
                        f"{', '.join(n for n in names if n) or 'none (leave --camera out: a free camera follows)'}")
    return cam


def render_frames(scene, traj, fps: float = 30.0, width: int = 640, height: int = 480, progress=None,
                  camera: str | None = None):
    """Yield RGB frames (height, width, 3) uint8 of ``traj`` (a :class:`~dano.Trajectory` of
    ``scene``) at ``fps``. camera: the name of a camera of the scene's MJCF; None: a free
    camera following the DANOs' mean position. ``progress(done, total, description)`` is
    called per frame.

    Raises DanoError for an unknown camera name (listing the scene's) or if no OpenGL context
    can be created (set MUJOCO_GL=egl or osmesa).
    """
    import mujoco

    m = scene.mj_model
    fixed = None if camera is None else camera_id(m, camera)
    d = mujoco.MjData(m)
    try:
        renderer = mujoco.Renderer(m, height, width)
    except Exception as exc:
        raise DanoError(f"cannot create an OpenGL context for rendering (MUJOCO_GL={os.environ.get('MUJOCO_GL')}): {exc}") from exc
    n_frames = max(1, int(np.floor(traj.time[-1] * fps)) + 1)
    idx = np.minimum(np.round(np.arange(n_frames) / fps / scene.dt).astype(int), len(traj.time) - 1)
    centres = np.stack([traj.dano_pose(n)[0] for n in traj.dano_names]).mean(0) if traj.dano_names else np.zeros(
        (len(traj.time), 3))
    extent = float(np.ptp(centres[:, :2], axis=0).max()) if len(centres) else 0.0
    size = max((a.points.max(0) - a.points.min(0)).max() for a in scene.assets) if scene.assets else 1.0
    cam = mujoco.MjvCamera()
    # far enough for the path and three object sizes (a 10 cm object pushed 12 cm: 0.3 m; the
    # distance was at least 1.3 m, where such an object was a few pixels across)
    cam.distance = max(1.3 * extent, 3.0 * size)
    cam.azimuth, cam.elevation = 135.0, -25.0
    opt = mujoco.MjvOption()
    try:
        for k, t in enumerate(idx):
            d.qpos[:] = traj.qpos[t]
            mujoco.mj_forward(m, d)
            # smooth camera: follow a moving average of the centre
            lo, hi = max(0, t - 25), min(len(centres), t + 25)
            cam.lookat[:] = centres[lo:hi].mean(0)
            renderer.update_scene(d, cam if fixed is None else fixed, opt)
            yield renderer.render().copy()
            if progress is not None:
                progress(k + 1, n_frames, "rendering")
    finally:
        renderer.close()


def write_video(scene, traj, path: str | Path, fps: float = 30.0, width: int = 640, height: int = 480,
                progress=None, camera: str | None = None) -> Path:
    """Render ``traj`` of ``scene`` to an H.264 ``.mp4`` (or ``.gif``) file at ``fps``, from the
    MJCF's camera named ``camera`` or (None) a free camera following the DANOs
    (:func:`render_frames`), ``width`` × ``height`` pixels.

    Written atomically: frames go to a temporary file in the same folder, renamed at the
    end; on any error nothing is left. Raises DanoError for an unsupported suffix or
    when rendering is impossible.
    """
    return write_frames(render_frames(scene, traj, fps, width, height, progress, camera), path, fps)


def check_video_writer(path: str | Path, what: str | None = None) -> None:
    """Raises DanoError (naming ``what``, default the path) unless ``path`` ends in .mp4 or
    .gif and, for .mp4, an ffmpeg executable is found (imageio-ffmpeg's own, or
    ``IMAGEIO_FFMPEG_EXE``). Cheap: callers check before a run, so that a missing encoder
    does not show only after the simulation (it was an "internal error" then)."""
    what = what or str(path)
    suffix = Path(path).suffix.lower()
    if suffix not in (".mp4", ".gif"):
        raise DanoError(f"{what}: must be .mp4 or .gif")
    if suffix == ".mp4":
        try:
            import imageio_ffmpeg

            imageio_ffmpeg.get_ffmpeg_exe()
        except (ImportError, RuntimeError) as exc:
            raise DanoError(f"{what}: writing .mp4 needs ffmpeg, which was not found ({exc}); install imageio-ffmpeg "
                            "or set IMAGEIO_FFMPEG_EXE to an ffmpeg executable, or write a .gif") from exc


#: the values of MUJOCO_GL with which MuJoCo loads no OpenGL back-end (MuJoCo's own list)
GL_DISABLED = ("disable", "disabled", "off", "false", "0")


def check_mujoco_video(path: str | Path, what: str | None = None) -> None:
    """:func:`check_video_writer`, and raises DanoError (naming ``what``) if MuJoCo's OpenGL
    is off (``MUJOCO_GL`` one of :data:`GL_DISABLED`, which dano sets on a machine without
    libEGL or libOSMesa), so that :func:`write_video` could not render. Called by the verbs
    that film with MuJoCo before their work (a simulation, a trajectory optimisation)."""
    what = what or str(path)
    check_video_writer(path, what)
    gl = os.environ.get("MUJOCO_GL", "")
    if gl.lower().strip() in GL_DISABLED:
        raise DanoError(f"{what}: cannot render: MuJoCo's OpenGL is off (MUJOCO_GL={gl}: this machine has no "
                        "libEGL or libOSMesa, or it was set so); install one (e.g. libegl1, libosmesa6) or leave out "
                        "the video")


def write_frames(frames, path: str | Path, fps: float = 30.0) -> Path:
    """Write RGB frames (an iterable of (H, W, 3) uint8) to an H.264 ``.mp4`` or a ``.gif``,
    atomically (nothing is left on error). Raises DanoError for another suffix or for an .mp4
    without ffmpeg (:func:`check_video_writer`)."""
    import imageio.v2 as imageio

    path = Path(path)
    suffix = path.suffix.lower()
    check_video_writer(path, f"{path}: video")
    kwargs = {"fps": fps}
    if suffix == ".mp4":
        kwargs.update(format="FFMPEG", codec="libx264", quality=7, macro_block_size=8, ffmpeg_log_level="error")
    else:
        kwargs.update(format="GIF", duration=1.0 / fps)
        del kwargs["fps"]
    with atomic_path(path) as tmp, warnings.catch_warnings():
        # imageio-ffmpeg starts ffmpeg with fork+exec; the child execs at once, so
        # Python's "fork with threads" warning does not apply
        warnings.filterwarnings("ignore", message="os.fork", category=RuntimeWarning)
        with imageio.get_writer(tmp, **kwargs) as writer:
            for frame in frames:
                writer.append_data(frame)
    return path

"""What tracking writes: the poses as a dano trajectory (ready for ``dano sysid``), a per-frame
table, an overlay video and a report."""

from __future__ import annotations

import csv
import io
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import numpy as np
import tyro

from .._files import atomic_write, check_new_folder
from ..data import load_asset
from ..errors import DanoError
from ..nerf import load_field
from ..pose import velocity_from_poses
from ..trajectory import Trajectory, save_trajectory
from ..viz.video import write_frames
from .inputs import VideoInput, load_video
from .track import TrackConfig, TrackedObject, TrackResult, track


def tracked_trajectory(result: TrackResult, name: str, metadata: dict | None = None) -> Trajectory:
    """The tracked poses as a one-DANO :class:`~dano.trajectory.Trajectory`: qpos (T, 7) body
    pose, qvel (T, 6) by central differences (linear: world frame [m/s]; angular: body frame
    [rad/s]); frames flagged poor are listed in the metadata (``poor_frames``)."""
    t, q = np.asarray(result.time, dtype=np.float64), np.asarray(result.poses, dtype=np.float64)
    vel = np.zeros((len(t), 6))
    if len(t) > 1:
        # frame k from frames a, b = k ± 1 (one-sided at the ends): the difference quotient of the
        # positions and log(q_a⁻¹ ⊗ q_b)/Δt, the body-frame rate (in frame a's axes; k's to first order)
        k = np.arange(len(t))
        ab = np.stack([np.maximum(k - 1, 0), np.minimum(k + 1, len(t) - 1)], axis=1)
        vel = velocity_from_poses(t[ab], q[ab], degree=1)
    meta = {"source": "dano track", "poor_frames": np.flatnonzero(result.poor).tolist(), **(metadata or {})}
    return Trajectory(t, q, vel, np.zeros((len(t), 0)), (name,), (name,), (0,), (0,),
                      (), meta)


def overlay_frames(video: VideoInput, result: TrackResult, frames=None):
    """Yield RGB uint8 frames: the video with the rendered silhouette's outline (green;
    red in frames flagged poor) and the tracked silhouette tinted over it."""
    from scipy.ndimage import binary_erosion

    ks = range(len(result.time)) if frames is None else frames
    h, w = video.frames.shape[1:3]
    s = result.stride
    for i in ks:
        image = video.frames[i].copy()
        a = np.repeat(np.repeat(result.alpha[i], s, axis=0), s, axis=1)
        full = np.zeros((h, w), np.float32)
        full[: a.shape[0], : a.shape[1]] = a
        inside = full > 0.5
        edge = inside & ~binary_erosion(inside, iterations=1)
        colour = np.array([0.9, 0.1, 0.1] if result.poor[i] else [0.1, 0.9, 0.2], np.float32)
        image = np.where(inside[..., None], 0.75 * image + 0.25 * colour, image)
        image[edge] = colour
        yield np.round(np.clip(image, 0, 1) * 255).astype(np.uint8)


def write_track_outputs(out_dir: str | Path, video: VideoInput, result: TrackResult, name: str,
                        report: dict, fps: float, video_file: bool = True) -> list[str]:
    """Write ``poses.npz`` (dano trajectory), ``track.csv`` (time, pose, loss, IoU, poor per
    frame), ``overlay.mp4`` and ``report.json`` into ``out_dir`` (each atomically).
    Returns the file names written."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    save_trajectory(tracked_trajectory(result, name), out / "poses.npz")
    buffer = io.StringIO()
    writer = csv.writer(buffer)
    writer.writerow(["frame", "time", "x", "y", "z", "qw", "qx", "qy", "qz", "loss", "iou", "poor", "wall_time_s"])
    for k in range(len(result.time)):
        writer.writerow([k, f"{result.time[k]:.6f}", *(f"{x:.7g}" for x in result.poses[k]), f"{result.loss[k]:.6g}",
                         f"{result.iou[k]:.5f}", int(result.poor[k]), f"{result.frame_time_s[k]:.3f}"])
    atomic_write(out / "track.csv", lambda f: f.write(buffer.getvalue().encode()))
    files = ["poses.npz", "track.csv"]
    if video_file:
        write_frames(overlay_frames(video, result), out / "overlay.mp4", fps)
        files.append("overlay.mp4")
    atomic_write(out / "report.json", lambda f: f.write((json.dumps(report, indent=2) + "\n").encode()))
    return files + ["report.json"]


@dataclass(frozen=True)
class TrackCommandConfig:
    """Track a DANO's pose through a video by fitting rendered silhouettes to masks (and colours)."""

    video: Annotated[Path, tyro.conf.Positional, tyro.conf.arg(metavar="VIDEO")]
    """a video folder (camera.json, frames/, optional masks/ and background.png), a folder of frames or a video
    file (then give --camera)."""
    object: Annotated[str, tyro.conf.arg(metavar="FILE.dano|builtin:NAME")]
    """the DANO tracked (a .dano file that stores its field, or builtin:NAME)."""
    pose: Annotated[tuple[float, float, float, float, float, float, float], tyro.conf.arg(metavar="X Y Z QW QX QY QZ")]
    """its body pose in the first frame (centre of mass [m], wxyz quaternion; world frame)."""
    out: Annotated[Path, tyro.conf.arg(aliases=("-o",))]
    """folder to write poses.npz (a dano trajectory, ready for `dano sysid`), track.csv, overlay.mp4,
    report.json."""
    camera: Path | None = None
    """camera.json (intrinsics, transform_matrix camera-to-world, convention, fps)."""
    masks: Path | None = None
    """folder of mask images (one per frame; white = object)."""
    background: Path | None = None
    """the background frame (no object) for background subtraction."""
    subtract_background: bool = False
    """make masks from the background even where mask images exist."""
    threshold: float = 0.08
    """background subtraction's colour difference (0-1)."""
    fps: float | None = None
    """frames per second (default: camera.json's)."""
    field: Path | None = None
    """a trained field directory (dano train-field) in the DANO's object frame, for the colour term."""
    colour_weight: float = 0.0
    """weight of the colour (photometric) term; needs --field."""
    colour_rays: int = 1024
    """rays of the colour term per frame, drawn at random among those rendered (0: all)."""
    iterations: int = 60
    """Adam steps per frame."""
    stride: int = 2
    """pixels per ray along each axis."""
    smoothness_weight: float = 0.0
    """weight of a prior toward the constant-velocity prediction."""
    no_video: bool = False
    """skip overlay.mp4."""
    identify: bool = False
    """then identify the sliding friction from the tracked poses (the two stages of docs/tracking.md): writes
    problem.toml (edit and rerun it: dano sysid problem.toml) and sysid/ (result.json, config.json, fit.png); the
    ground is z = 0 of camera.json's world frame (its small offset is fitted). The tracking's outputs stay if the
    identification fails."""
    json_: Annotated[bool, tyro.conf.arg(name="json")] = False
    """print one JSON object (frames, poor_frames, mean_iou, time_per_frame_s, ...; with --identify, the
    identification's report under "identification")."""
    quiet: bool = False
    """no progress bar."""

    def __post_init__(self):
        check_new_folder(self.out)

    def track_config(self) -> TrackConfig:
        """The per-frame fit's :class:`~dano.tracking.TrackConfig` of these options."""
        return TrackConfig(iterations=self.iterations, stride=self.stride, colour_weight=self.colour_weight,
                           smoothness_weight=self.smoothness_weight, colour_rays=self.colour_rays)


def track_command(config: TrackCommandConfig, progress=None) -> tuple[dict, list[str]]:
    """``dano track``: read the video (:func:`~dano.tracking.load_video`), track the object
    from ``pose`` (:func:`~dano.tracking.track`, with the field's colours if ``field``) and
    write the outputs (:func:`write_track_outputs`). Returns (report, file names written)."""

    fit = config.track_config()
    radiance = radiance_occupancy = None
    if config.field is not None:
        radiance, radiance_occupancy, _ = load_field(config.field)
    obj = TrackedObject.from_asset(load_asset(config.object), radiance, radiance_occupancy)
    data = load_video(config.video, camera=config.camera, masks=config.masks, background=config.background,
                      fps=config.fps, threshold=config.threshold, subtract_background=config.subtract_background)
    if config.identify and data.num_frames < MIN_IDENTIFY_FRAMES:
        raise DanoError(f"{config.video}: --identify needs at least {MIN_IDENTIFY_FRAMES} frames (fewer leave the "
                        "tracking noise unestimated, so nothing would check the fit against it), the video has "
                        f"{data.num_frames}")
    result = track(data, obj, config.pose, fit, progress=progress)
    rate = 1.0 / float(data.time[1] - data.time[0]) if data.num_frames > 1 else 1.0
    report = {**result.summary(), "video": str(config.video), "object": config.object,
              "initial_pose": list(config.pose), "frame_interval_s": 1.0 / rate if data.num_frames > 1 else None}
    files = write_track_outputs(config.out, data, result, obj.name, report, rate, video_file=not config.no_video)
    return report, files


#: the fewest frames ``dano track --identify`` identifies from: the noise estimate of the
#: tracked poses needs 5 third differences (:func:`~dano.sysid.uncertainty.noise_of_observations`),
#: without which no misfit is warned of; a new user's 4-frame video (a MuJoCo slide, μ = 0.4)
#: gave 0.371 [0.349, 0.393] with no warning
MIN_IDENTIFY_FRAMES = 8


def poor_frames_warning(report: dict) -> list[str]:
    """The warning (a list of none or one line) that a track ``report`` has frames flagged
    poor, which the identification leaves out as missing frames (``problem.toml``'s
    ``skip_poor_frames``)."""
    n = int(report.get("poor_frames", 0))
    return [f"{n} of the {report['frames']} tracked frames are flagged poor (silhouette IoU below the poor_iou cut): "
            "the identification leaves them out as missing frames (skip_poor_frames = false in problem.toml keeps "
            "them); check overlay.mp4 and track.csv"] if n else []


def write_tracked_problem(out_dir: str | Path, object_spec: str, frame_interval: float) -> Path:
    """``problem.toml`` in ``out_dir`` beside its ``poses.npz``: a ``dano sysid`` problem for
    the tracked object (its asset's absolute path, or ``builtin:NAME``) with the two-stage
    route's options (:func:`dano.sysid.config.template` with ``tracked``). Returns its path."""
    from ..sysid.config import template

    spec = object_spec if object_spec.startswith("builtin:") else str(Path(object_spec).resolve())
    path = Path(out_dir) / "problem.toml"
    text = template([spec], tracked="poses.npz", frame_interval=frame_interval)
    atomic_write(path, lambda f: f.write(text.encode()))
    return path

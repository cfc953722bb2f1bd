"""What tracking writes: the poses as a dano trajectory (ready for ``dano sysid``), a per-frame
table, an overlay video and a report."""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

import numpy as np

from .._files import atomic_write
from ..pose import velocity_from_poses
from ..trajectory import Trajectory, save_trajectory
from ..viz.video import write_frames
from .inputs import VideoInput
from .track import TrackResult


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

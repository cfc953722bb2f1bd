"""``dano real2sim synthetic-slide``: video → poses → friction (two stages) and video → friction
(end to end, through the renderer and the simulator), on a video with a known answer.

The video is :func:`dano.experiments.slide.synthetic_slide` (MuJoCo's rasteriser draws the
bunny's mesh; dano's tracker renders its density field). Masks come from background
subtraction. Tracking starts from the first frame's true pose perturbed by ``start_error``
(3 cm and 3° by default: a user's rough initial guess).
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
import tyro

from .._files import check_new_folder
from ..errors import DanoError
from ..pose import normalize_quat, quat_multiply, rotvec_to_quat
from ..sysid import FitParameter, Observation, SysIdProblem, Weights, identify
from ..trajectory import load_trajectory
from ..tracking.inputs import load_video
from ..tracking.outputs import write_track_outputs
from ..tracking.pixels import identify_from_pixels
from .slide import SLIDE_FRICTION, slide_scene, synthetic_slide
from ..tracking.track import TrackConfig, TrackedObject, initial_velocity, pose_errors, track

FRICTION_BOUNDS = (0.0, 1.5)


def perturb(pose: np.ndarray, translation: float, degrees: float, seed: int = 0) -> np.ndarray:
    """``pose`` (7,) moved by ``translation`` [m] and turned by ``degrees`` about random
    (seeded) directions."""
    rng = np.random.default_rng(seed)
    a, b = rng.normal(size=3), rng.normal(size=3)
    out = np.asarray(pose, dtype=np.float64).copy()
    out[:3] += translation * a / np.linalg.norm(a)
    turn = rotvec_to_quat(np.radians(degrees) * b / np.linalg.norm(b))
    out[3:] = quat_multiply(normalize_quat(out[3:]), turn)
    return out


def two_stage(scene, tracked_time, tracked_poses, substeps: int, scan: int = 16, window: int = 10):
    """Friction from tracked poses with dano's identification: multiple shooting over windows
    of ``window`` frame intervals (each rolled out from its tracked pose, its initial linear
    and angular velocity fitted as nuisance from a fit to its first frames), the ground's
    height fitted too (tracking errors are largest along the camera's axis, which is not
    horizontal), a global scan of the friction, then Gauss–Newton from the best points.
    Returns the :class:`~dano.sysid.SysIdResult`.

    Why windows: the slide ends in a tumble, and a rollout of the whole 1.2 s has many local
    minima in the initial angular velocity. Measured on one tracked video of the synthetic
    slide (friction 0.35; cost ½‖r‖²): whole trajectory, scan of 16: 0.326 (0.0214); scan of
    8 with continuation over 10/25/50 % of the length: 0.346 (0.0079) in one run and 0.372
    (0.0089) in another with a better initial velocity; windows of 10 intervals: 0.353
    (0.0053), of 20: 0.366, of 30: 0.319."""
    qvel0 = np.zeros(scene.nv)
    dof = scene.dof_adr[0]
    qvel0[dof : dof + 6] = initial_velocity(tracked_time, tracked_poses)
    name = scene.dano_names[0]
    obs = Observation(time=tracked_time, poses={name: tracked_poses}, qvel0=qvel0, name="tracked poses")
    problem = SysIdProblem(scene, [obs], [FitParameter("sliding_friction", 0.3, *FRICTION_BOUNDS)],
                           weights=Weights(position=(1.0, 1.0, 1.0), rotation=1.0), substeps=substeps,
                           fit_velocity="xyz", fit_angular_velocity="xyz", fit_ground=True, window=window,
                           base_params=scene.default_params())  # the synthetic slide's world: the paper's drag
    return identify(problem, scan=scan)


def first_window_velocity(scene, stage, tracked_time, tracked_poses) -> np.ndarray:
    """(nv,) the initial velocity the two-stage fit found for its first window."""
    qvel0 = np.zeros(scene.nv)
    dof = scene.dof_adr[0]
    qvel0[dof : dof + 6] = initial_velocity(tracked_time, tracked_poses)
    name = scene.dano_names[0]
    for k, axis in enumerate("xyz"):
        for kind, offset in (("v0", 0), ("w0", 3)):
            label = f"{kind}[0]:{name}:{axis}"
            if label in stage.labels:
                qvel0[dof + offset + k] += stage.estimates[stage.labels.index(label)]
    return qvel0


def synthetic_slide_real2sim(out_dir: str | Path, friction: float = SLIDE_FRICTION,
                             start_error: tuple[float, float] = (0.03, 3.0), config: TrackConfig = TrackConfig(),
                             scan: int = 16, video_file: bool = True, progress=None) -> dict:
    """Run the whole pipeline into ``out_dir`` (``video/`` the synthetic video, ``track/``
    the tracking outputs) and return the report (JSON-able)."""
    t_start = time.perf_counter()
    out = Path(out_dir)
    folder = synthetic_slide(out / "video", friction, progress=progress)
    truth = load_trajectory(folder / "truth.npz")
    video = load_video(folder, subtract_background=True)
    true_masks = load_video(folder).masks
    mask_iou = float(np.minimum(video.masks, true_masks).sum() / np.maximum(video.masks, true_masks).sum())
    scene, _ = slide_scene()
    asset = scene.assets[0]
    obj = TrackedObject.from_asset(asset)
    size = float(np.linalg.norm(np.ptp(asset.mesh_vertices, axis=0)))
    start = perturb(truth.qpos[0, :7], *start_error)
    t0 = time.perf_counter()
    result = track(video, obj, start, config, progress=progress)
    track_s = time.perf_counter() - t0
    dp, dr = pose_errors(result.poses, truth.qpos[:, :7])
    substeps = int(round((video.time[1] - video.time[0]) / scene.dt))
    stage = two_stage(scene, result.time, result.poses, substeps)
    # the pixels fit starts from the tracked first pose and the initial velocity the two-stage
    # fit found for its first window (its friction is not used: the pixels fit scans its own)
    qvel0 = first_window_velocity(scene, stage, result.time, result.poses)
    pixels = identify_from_pixels(scene, scene.default_params(), video, obj, result.poses[0], qvel0, substeps,
                                  bounds=FRICTION_BOUNDS, scan=scan, progress=progress)
    mu_two, mu_pix = float(stage.estimates[0]), float(pixels.estimates[0])
    report = {
        "mu_true": friction,
        "mu_two_stage": mu_two,
        "mu_two_stage_std": float(stage.standard_errors[0]),
        "mu_pixels": mu_pix,
        "mu_two_stage_error": mu_two / friction - 1.0,
        "mu_pixels_error": mu_pix / friction - 1.0,
        "track_rms_mm": float(np.sqrt(np.mean(dp ** 2)) * 1000),
        "track_rms_deg": float(np.sqrt(np.mean(dr ** 2))),
        "track_max_mm": float(dp.max() * 1000),
        "track_max_deg": float(dr.max()),
        "track_rms_percent_of_size": float(np.sqrt(np.mean(dp ** 2)) / size * 100),
        "object_size_m": size,
        "frames": video.num_frames,
        "image_size": [int(video.frames.shape[2]), int(video.frames.shape[1])],
        "poor_frames": int(result.poor.sum()),
        "mask_iou_background_subtraction": mask_iou,
        "start_error": {"translation_m": start_error[0], "rotation_deg": start_error[1]},
        "track_wall_time_s": track_s,
        "track_time_per_frame_s": float(np.median(result.frame_time_s)),
        "two_stage_wall_time_s": stage.wall_time_s,
        "pixels_wall_time_s": pixels.wall_time_s,
        "pixels_compile_time_s": pixels.compile_time_s,
        "pixels_fit": pixels.as_dict(),
        "ground_height_two_stage_m": float(stage.estimates[stage.labels.index("ground_height")]),
        "two_stage_fit": {"parameters": dict(zip(stage.labels, map(float, stage.estimates))),
                          "rms_residual": stage.rms_residual, "message": stage.message},
        "track_config": asdict(config),
        "per_frame": {"translation_error_mm": (dp * 1000).tolist(), "rotation_error_deg": dr.tolist(),
                      "iou": result.iou.tolist()},
    }
    report["wall_time_s"] = time.perf_counter() - t_start
    write_track_outputs(out / "track", video, result, scene.dano_names[0], report, float(1 / np.diff(video.time)[0]),
                        video_file)
    return report


@dataclass(frozen=True)
class Real2SimConfig:
    """From video to physics on a video with a known answer: poses -> friction and pixels -> friction."""

    task: Annotated[Literal["synthetic-slide"], tyro.conf.Positional, tyro.conf.arg(metavar="TASK")]
    """synthetic-slide: the low-poly bunny slides and tumbles (MuJoCo renders the video from its mesh)."""
    out: Annotated[Path, tyro.conf.arg(aliases=("-o",))] = Path("dano-real2sim")
    """folder to write video/ (frames, masks, background, camera.json, truth.npz) and track/ (poses.npz,
    track.csv, overlay.mp4, report.json)."""
    friction: float = 0.35
    """the true sliding friction of the video."""
    no_video: bool = False
    """skip overlay.mp4."""
    json_: Annotated[bool, tyro.conf.arg(name="json")] = False
    """print one JSON object (mu_true, mu_two_stage, mu_pixels, track_rms_mm, track_rms_deg, wall_time_s, ...)."""
    quiet: bool = False
    """no progress bar."""

    def __post_init__(self):
        check_new_folder(self.out)
        if not 0 < self.friction <= 1.5:
            raise DanoError(f"--friction must be in (0, 1.5], got {self.friction}")


"""Tracking studies on the synthetic-slide video: success against the initial pose error,
and photometric (colour) tracking with a trained radiance field."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..nerf import TrainConfig, load_dataset, train
from ..nerf.synthetic import render_dataset
from ..tracking import TrackConfig, TrackedObject, load_video, pose_errors, track
from ..trajectory import load_trajectory
from .real2sim import perturb
from .slide import slide_scene, surface_mesh


def tracking_success_curve(folder, translations=(0.01, 0.02, 0.04, 0.06, 0.08, 0.10, 0.15, 0.20, 0.30),
                           rotations=(2.0, 5.0, 10.0, 15.0, 20.0, 30.0, 45.0, 60.0, 90.0), seeds: int = 4,
                           frames: int = 10, obj=None, config=None) -> list:
    """Tracking of the first ``frames`` frames of the synthetic-slide video in ``folder`` from
    the true first pose perturbed by (translation · object size, rotation [deg]) about
    ``seeds`` random directions per size: per size, the success rate (final frame within 2 %
    of the size and 5°) and the final errors. obj: the TrackedObject (default: the slide's
    DANO, silhouettes only); config: its TrackConfig (default: TrackConfig())."""
    video = load_video(folder, subtract_background=True)
    truth = load_trajectory(Path(folder) / "truth.npz").qpos[:, :7]
    asset = slide_scene()[0].assets[0]
    size = float(np.linalg.norm(np.ptp(asset.mesh_vertices, axis=0)))
    obj = TrackedObject.from_asset(asset) if obj is None else obj
    config = TrackConfig() if config is None else config
    curve = []
    for dt, dr in zip(translations, rotations):
        runs = []
        for seed in range(seeds):
            result = track(video, obj, perturb(truth[0], dt * size, dr, seed + 1), config, frames=slice(0, frames))
            ep, er = pose_errors(result.poses[-1:], truth[frames - 1 : frames])
            runs.append({"translation_error_percent": float(ep[0] / size * 100), "rotation_error_deg": float(er[0]),
                         "success": bool(ep[0] < 0.02 * size and er[0] < 5.0)})
        curve.append({"start_translation_percent": dt * 100, "start_rotation_deg": dr,
                      "success_rate": float(np.mean([r["success"] for r in runs])), "runs": runs})
    return curve


def tracking_colour(folder, work_dir, minutes: float = 3.0, frames: int = 15,
                    weights=(0.0, 0.02, 0.1, 1.0)) -> dict:
    """Photometric tracking on the synthetic-slide video in ``folder``: a radiance field is
    trained for ``minutes`` on 100 views (128 px, ``render-dataset``) of the surface the video
    shows, in the DANO's object frame; then the first ``frames`` frames are tracked from the
    real2sim start (3 cm, 3°) with each colour weight (0: silhouettes only). Returns the
    field's held-out PSNR and, per weight, RMS / max errors and the median time per frame."""
    import trimesh

    asset = slide_scene()[0].assets[0]
    vertices, faces = surface_mesh(asset)  # what the video shows, body frame; the field's is the object frame
    mesh_path = Path(work_dir) / "surface.obj"
    trimesh.Trimesh(vertices + asset.center_of_mass, faces, process=False).export(mesh_path)
    render_dataset(mesh_path, Path(work_dir) / "views", views=100, size=128)
    train_set, held = load_dataset(Path(work_dir) / "views").split(10)
    trained = train(train_set, TrainConfig(minutes=minutes, background="random"), heldout=held)
    video = load_video(folder, subtract_background=True)
    truth = load_trajectory(Path(folder) / "truth.npz").qpos[:frames, :7]
    size = float(np.linalg.norm(np.ptp(asset.mesh_vertices, axis=0)))
    start = perturb(truth[0], 0.03, 3.0)
    out = {"field_psnr_heldout": trained.psnr_heldout, "field_minutes": minutes, "frames": frames, "runs": []}
    for weight in weights:
        obj = TrackedObject.from_asset(asset, trained.field if weight > 0 else None,
                                       trained.occupancy if weight > 0 else None)
        result = track(video, obj, start, TrackConfig(colour_weight=weight), frames=slice(0, frames))
        dp, dr = pose_errors(result.poses, truth)
        rms = float(np.sqrt(np.mean(dp**2)))
        out["runs"].append({"colour_weight": weight, "rms_mm": rms * 1000, "rms_deg": float(np.sqrt(np.mean(dr**2))),
                            "max_mm": float(dp.max() * 1000), "max_deg": float(dr.max()),
                            "rms_percent_of_size": rms / size * 100,
                            "time_per_frame_s": float(np.median(result.frame_time_s))})
    return out

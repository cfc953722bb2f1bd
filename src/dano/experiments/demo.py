"""``dano demo``: the main job on the embedded default — the paper's NeRF-derived bunny
dropped on the ground (scene ``bunny-drop``), written as a trajectory, a video, a plot of
its boundary samples and a summary."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .._files import atomic_write
from ..data import load_builtin
from ..sim.run import SimulateConfig, simulate, write_outputs
from ..viz import plot_samples


def demo(out_dir: str | Path = "dano-demo", progress=None) -> tuple[object, object, dict]:
    """Run the bunny drop and write ``bunny-drop.npz``, ``bunny-drop.mp4`` (with its
    ``.config.json``), ``bunny_samples.png`` and ``summary.json`` into ``out_dir``.
    Returns (asset, run, summary); ``summary`` holds the asset's summary, the scene, steps,
    dt [s], the final centre of mass [m], speed [m/s] and overlap ψ, the resting overlap
    m·g/k expected from the spring, the wall time [s] and the files written."""
    out_dir = Path(out_dir)
    asset = load_builtin("bunny")
    plot_samples(asset, out_dir / "bunny_samples.png")
    run = simulate(SimulateConfig("bunny-drop"), progress=progress)
    write_outputs(run, out=out_dir / "bunny-drop.npz", video=out_dir / "bunny-drop.mp4", progress=progress)
    traj, setup = run.trajectory, run.setup
    k = float(np.asarray(setup.params.contact.impact_spring)[0])
    summary = {
        "asset": asset.summary(),
        "scene": setup.scene.name,
        "steps": len(traj.time) - 1,
        "dt": setup.scene.dt,
        "final_center_of_mass": traj.dano_pose("bunny")[0][-1].tolist(),
        "final_speed": float(np.linalg.norm(traj.qvel[-1, :3])),
        "final_overlap": float(traj.psi[-1, 0]),
        "rest_overlap_mg_over_k": asset.mass * 9.81 / k,
        "wall_time_s": run.wall_time_s,
        "files": ["bunny-drop.npz", "bunny-drop.mp4", "bunny_samples.png"],
    }
    text = json.dumps(summary, indent=2).encode()
    atomic_write(out_dir / "summary.json", lambda f: f.write(text))
    return asset, run, summary

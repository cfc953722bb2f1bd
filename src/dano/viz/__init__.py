"""Plots (matplotlib figures, no pyplot) and videos (MuJoCo's renderer, headless):
``write_video(scene, trajectory, "run.mp4")`` renders a simulated trajectory."""

from .plot import plot_heldout, plot_samples, plot_sysid, plot_trajopt
from .video import render_frames, write_frames, write_video

__all__ = ["plot_heldout", "plot_samples", "plot_sysid", "plot_trajopt", "render_frames", "write_frames", "write_video"]

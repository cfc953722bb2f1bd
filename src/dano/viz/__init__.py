"""Plots and (later) videos."""

from .plot import plot_heldout, plot_samples, plot_sysid, plot_trajopt

__all__ = ["plot_heldout", "plot_samples", "plot_sysid", "plot_trajopt"]

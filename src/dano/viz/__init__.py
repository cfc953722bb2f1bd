"""Plots and (later) videos."""

from .plot import plot_samples

__all__ = ["plot_samples"]

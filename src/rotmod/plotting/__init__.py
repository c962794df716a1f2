"""Plots (matplotlib is imported inside the functions; each takes ``ax=None`` and returns it)."""

from rotmod.plotting.images import plot_comparison, plot_image

__all__ = ["plot_comparison", "plot_image"]

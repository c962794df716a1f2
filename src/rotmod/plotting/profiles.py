"""Plots of characteristic profiles: models (and optionally Monte Carlo) against mask angle."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

__all__ = ["MODEL_STYLE", "plot_profiles"]

#: Line styles of the models, shared by every profile figure.
MODEL_STYLE: dict[str, dict[str, Any]] = {
    "standard": {"color": "tab:blue", "ls": "--"},
    "advanced": {"color": "tab:red", "ls": "-"},
    "advanced-approx": {"color": "tab:orange", "ls": "-."},
    "advanced-g0": {"color": "tab:purple", "ls": ":"},
    "exact": {"color": "k", "ls": "-", "lw": 0.8},
}


def plot_profiles(
    xi: Any,
    profiles: Mapping[str, Any],
    *,
    mc: Any = None,
    mc_error: Any = None,
    title: str | None = None,
    ax: Any = None,
) -> Any:
    """Draw profiles against mask angle, like the seed paper's profile figures.

    Parameters
    ----------
    xi : array_like, shape (n_angle,)
        Mask angles (rad).
    profiles : mapping of str to array_like, shape (n_angle,)
        One curve per model name.
    mc, mc_error : array_like, shape (n_angle,), optional
        Monte Carlo fraction and its 1-sigma error, drawn as points and a band.
    title : str, optional
    ax : matplotlib Axes, optional
        Axes to draw on; a new figure when None.

    Returns
    -------
    matplotlib.axes.Axes
    """
    import matplotlib.pyplot as plt

    if ax is None:
        _, ax = plt.subplots(figsize=(7, 3))
    deg = np.degrees(np.asarray(xi, dtype=float))
    if mc is not None:
        f = np.asarray(mc, dtype=float)
        if mc_error is not None:
            e = np.asarray(mc_error, dtype=float)
            ax.fill_between(deg, f - e, f + e, color="0.6", lw=0, step="mid", alpha=0.6)
        ax.plot(deg, f, ".", ms=2.0, color="0.3", label="Monte Carlo")
    for name, p in profiles.items():
        ax.plot(deg, np.asarray(p, dtype=float), label=name, **MODEL_STYLE.get(name, {}))
    ax.set_xlabel("mask angle ξ (deg)")
    ax.set_ylabel("transmitted fraction")
    if deg.size:
        ax.set_xlim(min(0.0, deg.min()), max(360.0, deg.max()) if deg.max() > 180 else 180.0)
    ax.set_ylim(-0.02, 1.02)
    if title:
        ax.set_title(title, fontsize=8)
    ax.legend(fontsize=6, loc="upper right", ncol=2)
    return ax

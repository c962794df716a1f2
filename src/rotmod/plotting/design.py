"""Plot of the mask-design trade-off with the Pareto front highlighted."""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["plot_design_tradeoff"]


def plot_design_tradeoff(
    scan: Any,
    *,
    weights: Any = (1.0, 1.0, 1.0),
    best: int | None = None,
    ax: Any = None,
) -> Any:
    """Sensitivity against transmission of every design, coloured by resolution (b/L).

    Pareto-optimal designs (over all three figures, so not a curve in this plane) are
    ringed; designs outside the advanced model's validity are drawn as crosses; the best
    design for ``weights`` is starred.

    Parameters
    ----------
    scan : rotmod.design.DesignScan
    weights : (float, float, float)
        Weights of sensitivity, transmission and resolving power for the best design.
    best : int, optional
        Index of the design to star (default ``scan.best(weights)``).
    ax : matplotlib Axes, optional

    Returns
    -------
    matplotlib.axes.Axes
    """
    import matplotlib.pyplot as plt

    if ax is None:
        _, ax = plt.subplots(figsize=(6.5, 4.5))
    x, y, r = scan.transmission, scan.sensitivity, scan.resolution_deg
    valid = np.asarray(scan.advanced_valid, dtype=bool)
    front = scan.pareto
    norm = plt.Normalize(r.min(), r.max() if r.max() > r.min() else r.min() + 1e-9)
    sc = ax.scatter(x[valid], y[valid], c=r[valid], cmap="viridis", norm=norm, s=22,
                    label="design (advanced model valid)")
    if (~valid).any():
        ax.scatter(x[~valid], y[~valid], c=r[~valid], cmap="viridis", norm=norm, s=28,
                   marker="x", label="design (outside advanced validity)")
    ax.scatter(x[front], y[front], s=70, facecolors="none", edgecolors="tab:red", lw=1.2,
               label="Pareto front")
    i = scan.best(weights) if best is None else int(best)
    ax.scatter([x[i]], [y[i]], marker="*", s=220, color="gold", edgecolors="k", zorder=5,
               label=(f"best: a={scan.slat_width[i]:g}, b={scan.slat_gap[i]:g}, "
                      f"h={scan.thickness[i]:g} cm"))
    plt.colorbar(sc, ax=ax, label="resolution arctan(b/L) (deg)")
    ax.set_xlabel("transmission (mean profile)")
    ax.set_ylabel("sensitivity (std of profile)")
    w = [float(v) for v in np.ravel(weights)]
    ax.set_title(f"mask design trade-off (weights sens/trans/res = {w[0]:g}/{w[1]:g}/{w[2]:g})",
                 fontsize=9)
    ax.legend(fontsize=7, loc="best")
    return ax

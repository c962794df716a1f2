"""Plots of characteristic profiles: models (and optionally Monte Carlo) against mask angle."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from rotmod._validate import as_angle

__all__ = ["MODEL_STYLE", "model_style", "plot_profiles"]

#: Line styles of the models, shared by every profile figure.  A curve whose name is not a
#: key here gets a style of its own from :data:`_OTHER_STYLES` (:func:`model_style`), so a
#: new model needs no edit here.
MODEL_STYLE: dict[str, dict[str, Any]] = {
    "standard": {"color": "tab:blue", "ls": "--"},
    "advanced": {"color": "tab:red", "ls": "-"},
    "advanced-approx": {"color": "tab:orange", "ls": "-."},
    "advanced-g0": {"color": "tab:purple", "ls": ":"},
    "exact": {"color": "k", "ls": "-", "lw": 0.8},
}
#: Styles for the other curves, in turn: colours none of :data:`MODEL_STYLE` uses (the
#: plain colour cycle would repeat the standard model's blue).
_OTHER_STYLES: tuple[dict[str, Any], ...] = (
    {"color": "tab:green", "ls": "-"},
    {"color": "tab:brown", "ls": "--"},
    {"color": "tab:pink", "ls": "-."},
    {"color": "tab:olive", "ls": ":"},
    {"color": "tab:cyan", "ls": "-"},
)


def model_style(name: str, other: int = 0) -> dict[str, Any]:
    """The line style of the curve ``name``.

    Parameters
    ----------
    name : str
        A model name (or any curve label).
    other : int
        For a name without a style in :data:`MODEL_STYLE`: how many such curves the figure
        has drawn before it (they take the fallback styles in turn, cycling).

    Returns
    -------
    dict
        Matplotlib line keywords (a copy).
    """
    style = MODEL_STYLE.get(name)
    if style is None:
        style = _OTHER_STYLES[other % len(_OTHER_STYLES)]
    return dict(style)


def plot_profiles(
    xi: Any,
    profiles: Mapping[str, Any],
    *,
    mc: Any = None,
    mc_error: Any = None,
    title: str | None = None,
    ax: Any = None,
    labels: Mapping[str, str] | None = None,
    residuals: bool = True,
) -> Any:
    """Draw profiles against mask angle, like the seed paper's profile figures.

    With a Monte Carlo, a panel under the profiles shows each model's residual
    ``(model - MC) / sigma_MC``, so agreement within statistics reads as a band of width 1.

    Parameters
    ----------
    xi : array_like or Quantity, shape (n_angle,)
        Mask angles (deg if plain numbers).
    profiles : mapping of str to array_like, shape (n_angle,)
        One curve per model name.
    mc, mc_error : array_like, shape (n_angle,), optional
        Monte Carlo fraction and its 1-sigma error, drawn as points and a band.
    title : str, optional
    ax : matplotlib Axes, optional
        Axes to draw on; a new figure when None.  The residual panel is carved out of it.
    labels : mapping of str to str, optional
        Legend text per model (default the model name).
    residuals : bool
        Draw the residual panel (only when ``mc`` and ``mc_error`` are given).

    Returns
    -------
    matplotlib.axes.Axes
        The profile axes.
    """
    import matplotlib.pyplot as plt

    if ax is None:
        _, ax = plt.subplots(figsize=(7, 3.4))
    deg = np.degrees(as_angle(xi, "xi"))
    rax = None
    if mc is not None and mc_error is not None and residuals:
        from mpl_toolkits.axes_grid1 import make_axes_locatable

        rax = make_axes_locatable(ax).append_axes("bottom", size="32%", pad=0.08, sharex=ax)
    if mc is not None:
        f = np.asarray(mc, dtype=float)
        if mc_error is not None:
            e = np.asarray(mc_error, dtype=float)
            ax.fill_between(deg, f - e, f + e, color="0.6", lw=0, step="mid", alpha=0.6)
        ax.plot(deg, f, ".", ms=2.0, color="0.3", label="Monte Carlo")
    others = 0
    for name, p in profiles.items():
        style = model_style(name, others)
        others += name not in MODEL_STYLE
        label = (labels or {}).get(name, name)
        ax.plot(deg, np.asarray(p, dtype=float), label=label, **style)
        if rax is not None:
            sig = np.where(np.asarray(mc_error) > 0, mc_error, np.nan)
            rax.plot(deg, (np.asarray(p, dtype=float) - f) / sig, **{"lw": 0.8, **style})
    ax.set_ylabel("transmitted fraction", fontsize=8)
    if deg.size:
        ax.set_xlim(min(0.0, deg.min()), max(360.0, deg.max()) if deg.max() > 180 else 180.0)
    ax.set_ylim(-0.02, 1.02)
    if title:
        ax.set_title(title, fontsize=8)
    # Outside the axes, so that no curve is ever hidden behind the legend.
    ax.legend(fontsize=6, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
    if rax is not None:
        rax.axhspan(-1, 1, color="0.85", lw=0)
        rax.axhline(0, color="0.4", lw=0.5)
        rax.set_ylabel("(P − MC)/σ", fontsize=7)
        # One x position for both labels, so they stack instead of overlapping.
        for a_ in (ax, rax):
            a_.yaxis.set_label_coords(-0.07, 0.5)
        rax.set_ylim(-5, 5)
        rax.set_xlabel("mask angle ξ (deg)")
        ax.tick_params(labelbottom=False)
    else:
        ax.set_xlabel("mask angle ξ (deg)")
    return ax

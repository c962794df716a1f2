"""Sky images with the true source positions marked, axes in degrees (the paper's style).

Each grid kind is drawn by the function registered under its
:attr:`~rotmod.sky.SkyGeometry.kind` in :data:`IMAGE_DRAWERS`; a kind without one (e.g.
HEALPix, or a new kind) is drawn pixel by pixel at its instrument directions.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from rotmod._validate import as_angle
from rotmod.errors import ParameterError
from rotmod.registry import Registry
from rotmod.sky.geometry import SkyGeometry

__all__ = ["IMAGE_DRAWERS", "INSTRUMENT_AXIS_LABELS", "plot_comparison", "plot_image"]

#: ``draw(img, grid, sources, ax, cmap) -> (ax, mappable)`` by grid kind: puts the image on
#: ``ax`` (a new figure's axes of the drawer's choice when None), marks the sources, labels
#: the axes.
IMAGE_DRAWERS: Registry[Callable[..., tuple[Any, Any]]] = Registry("grid kind")

#: Axis labels of instrument-frame images: tangent-plane angles, not RA and Dec.
INSTRUMENT_AXIS_LABELS = ("x, instrument frame (deg)", "y, instrument frame (deg)")


def plot_image(
    image: Any,
    grid: SkyGeometry,
    *,
    sources: Any = None,
    ax: Any = None,
    title: str | None = None,
    cmap: str = "viridis",
    colorbar: bool = True,
    relative: bool = False,
    unit: str = "photons s⁻¹ per pixel (one unobstructed detector)",
) -> Any:
    """Show a sky image on its grid with true sources as crosses.

    Instrument-frame grids are drawn in tangent-plane degrees of the instrument frame
    (:data:`INSTRUMENT_AXIS_LABELS`); celestial grids
    (:class:`~rotmod.sky.CelestialGrid`) on WCS axes in RA and Dec, east left; other kinds
    (HEALPix, ...) as one dot per pixel at ``theta (cos phi, sin phi)`` in the instrument
    frame (see :data:`IMAGE_DRAWERS`).

    Parameters
    ----------
    image : ndarray (ny, nx) or ReconstructionResult
    grid : SkyGeometry
    sources : (theta, phi) or SkyCoord, optional
        True source directions (Quantities, or plain numbers in deg; a SkyCoord on a
        celestial grid), marked with ``+``.
    ax : matplotlib Axes, optional
    title : str, optional
    cmap : str
    colorbar : bool
    relative : bool
        Divide by the image maximum.
    unit : str
        Colour-bar label of the image's values (the response's sky units by default).

    Returns
    -------
    matplotlib.axes.Axes
    """
    img = np.asarray(getattr(image, "image", image), dtype=float)
    if img.shape != tuple(grid.shape):
        raise ParameterError(f"image must have the grid's shape {grid.shape}, got {img.shape}")
    if relative and img.max() > 0:
        img = img / img.max()
    draw = (IMAGE_DRAWERS.get(grid.kind) if grid.kind in IMAGE_DRAWERS
            else _draw_directions)
    ax, im = draw(img, grid, sources, ax, cmap)
    if title:
        ax.set_title(title, fontsize=9)
    if colorbar:
        cb = ax.figure.colorbar(im, ax=ax, fraction=0.046, pad=0.04)
        cb.set_label("relative intensity" if relative else unit, fontsize=7)
    return ax


@IMAGE_DRAWERS.register("instrument")
def _draw_tangent_plane(img: np.ndarray, grid: Any, sources: Any, ax: Any,
                        cmap: str) -> tuple[Any, Any]:
    """An instrument-frame grid (:class:`~rotmod.sky.SkyGrid`) in tangent-plane degrees."""
    import matplotlib.pyplot as plt

    if ax is None:
        _, ax = plt.subplots(figsize=(3, 3))
    ny, nx = grid.shape
    cx, cy = grid.center
    ext = [
        cx - nx * grid.pixel_size / 2, cx + nx * grid.pixel_size / 2,
        cy - ny * grid.pixel_size / 2, cy + ny * grid.pixel_size / 2,
    ]
    im = ax.imshow(img, origin="lower", extent=ext, cmap=cmap, interpolation="nearest")
    if sources is not None:
        x, y = grid.to_tangent(np.atleast_1d(sources[0]), np.atleast_1d(sources[1]))
        ax.plot(x, y, "+", color="w", ms=10, mew=1.5)
        ax.set_xlim(ext[0], ext[1])
        ax.set_ylim(ext[2], ext[3])
    # Gnomonic coordinates of the instrument frame (tan theta (cos phi, sin phi) in degrees
    # about the axis), +x to the right as in the image's XLON/XLAT WCS: angles in the
    # instrument frame, not sky positions (those need the attitude).
    ax.set_xlabel(INSTRUMENT_AXIS_LABELS[0], fontsize=8)
    ax.set_ylabel(INSTRUMENT_AXIS_LABELS[1], fontsize=8)
    return ax, im


@IMAGE_DRAWERS.register("celestial")
def _draw_celestial(img: np.ndarray, grid: Any, sources: Any, ax: Any,
                    cmap: str) -> tuple[Any, Any]:
    """A celestial grid (:class:`~rotmod.sky.CelestialGrid`) on WCS axes (RA, Dec; east
    left)."""
    import matplotlib.pyplot as plt

    if ax is None:
        fig = plt.figure(figsize=(3.4, 3))
        ax = fig.add_subplot(projection=grid.wcs())
    im = ax.imshow(img, origin="lower", cmap=cmap, interpolation="nearest")
    if sources is not None:  # SkyCoord of the true sources
        ax.plot(sources.ra.deg, sources.dec.deg, "+", color="w", ms=10, mew=1.5,
                transform=ax.get_transform("icrs"))
    ax.set_xlabel("RA (ICRS)", fontsize=8)
    ax.set_ylabel("Dec (ICRS)", fontsize=8)
    return ax, im


def _draw_directions(img: np.ndarray, grid: SkyGeometry, sources: Any, ax: Any,
                     cmap: str) -> tuple[Any, Any]:
    """Any grid: one dot per pixel at ``theta (cos phi, sin phi)`` (deg) in the instrument
    frame (the azimuthal equidistant projection about the rotation axis)."""
    import matplotlib.pyplot as plt

    if ax is None:
        _, ax = plt.subplots(figsize=(3, 3))
    theta, phi = (v.to_value("rad") for v in grid.directions())
    r = np.degrees(theta)
    im = ax.scatter(r * np.cos(phi), r * np.sin(phi), c=img.ravel(), cmap=cmap, s=12,
                    marker="s", linewidths=0)
    if sources is not None:  # (theta, phi) of the true sources
        th = np.degrees(as_angle(np.atleast_1d(sources[0]), "sources[0]"))
        ph = as_angle(np.atleast_1d(sources[1]), "sources[1]")
        ax.plot(th * np.cos(ph), th * np.sin(ph), "+", color="k", ms=10, mew=1.5)
    ax.set_aspect("equal")
    ax.set_xlabel("theta cos phi (deg)", fontsize=8)
    ax.set_ylabel("theta sin phi (deg)", fontsize=8)
    return ax, im


def plot_comparison(
    images: Sequence[Any],
    grid: SkyGeometry,
    *,
    titles: Sequence[str] | None = None,
    sources: Any = None,
    axes: Any = None,
    **kwargs: Any,
) -> Any:
    """Images side by side on one grid (e.g. standard vs advanced vs exact response).

    Parameters
    ----------
    images : sequence of ndarray or ReconstructionResult
    grid : SkyGeometry
    titles : sequence of str, optional
    sources : (theta, phi), optional
    axes : sequence of Axes, optional
        One per image; default a new row of subplots.
    **kwargs
        Passed to :func:`plot_image`.

    Returns
    -------
    ndarray of matplotlib.axes.Axes
    """
    import matplotlib.pyplot as plt

    n = len(images)
    if n == 0:
        raise ParameterError("images must hold at least one image, got none")
    if titles is not None and len(titles) != n:
        raise ParameterError(f"titles must have one entry per image ({n}), got {len(titles)}")
    if axes is None:
        _, axes = plt.subplots(1, n, figsize=(3.1 * n, 3.0), squeeze=False)
        axes = axes[0]
    axes = np.asarray(axes, dtype=object).ravel()
    if axes.size != n:
        raise ParameterError(f"axes must have one entry per image ({n}), got {axes.size}")
    for i, (img, ax) in enumerate(zip(images, axes, strict=True)):
        plot_image(img, grid, sources=sources, ax=ax,
                   title=None if titles is None else titles[i], **kwargs)
    axes[0].figure.tight_layout()
    return axes

"""Image-quality metrics of reconstructions of known point sources.

Sources are given as zenith/azimuth ``(theta, phi)`` in rad (the Monte Carlo's inputs);
positions on the image use the grid's tangent plane, distances are true angles on the sky
(degrees).  A *source region* is the disc of radius ``radius`` (deg, tangent plane) around
each true source.
"""

from __future__ import annotations

import time
import tracemalloc
from collections.abc import Callable
from typing import Any

import astropy.units as u
import numpy as np
from astropy.coordinates import angular_separation

from rotmod._validate import as_angle
from rotmod.errors import ParameterError

__all__ = [
    "angular_distance",
    "evaluate",
    "find_peaks",
    "localization_errors",
    "measure",
    "peak_fwhm",
    "recovered_flux",
    "source_peaks",
    "spurious_peak_level",
    "two_source_dip",
]


def _check_image(image: Any, grid: Any) -> np.ndarray:
    img = np.asarray(image, dtype=float)
    if img.shape != tuple(grid.shape):
        raise ParameterError(f"image must have the grid's shape {grid.shape}, got {img.shape}")
    return img


def _tangent(grid: Any, sources: Any) -> tuple[np.ndarray, np.ndarray]:
    th, ph = (np.atleast_1d(as_angle(v, n)) for v, n in zip(sources, ("theta", "phi"), strict=True))
    if th.shape != ph.shape:
        raise ParameterError(f"sources theta and phi must match, got {th.shape} and {ph.shape}")
    return grid.to_tangent(th * u.rad, ph * u.rad)


def angular_distance(grid: Any, x1: Any, y1: Any, x2: Any, y2: Any) -> np.ndarray:
    """Great-circle angle (deg) between tangent-plane points ``(x1, y1)`` and ``(x2, y2)``."""
    t1, p1 = (v.to_value(u.rad) for v in grid.from_tangent(x1, y1))
    t2, p2 = (v.to_value(u.rad) for v in grid.from_tangent(x2, y2))
    # astropy's Vincenty formula: full precision at every angle (arccos loses small ones);
    # latitude is 90 deg minus the zenith angle.
    half_pi = np.pi / 2
    return np.degrees(angular_separation(p1, half_pi - t1, p2, half_pi - t2))


def find_peaks(image: Any, *, min_value: float = 0.0) -> np.ndarray:
    """Local maxima (8-neighbourhood, plateaus count once) above ``min_value``.

    Returns an ``(k, 2)`` integer array of ``(iy, ix)`` sorted by decreasing value.
    """
    from scipy.ndimage import maximum_filter  # scipy.ndimage: ~0.1 s, metrics only

    img = np.asarray(image, dtype=float)
    mx = maximum_filter(img, size=3, mode="constant", cval=-np.inf)
    iy, ix = np.nonzero((img == mx) & (img > min_value))
    order = np.argsort(-img[iy, ix], kind="stable")
    return np.stack([iy[order], ix[order]], axis=1)


def _dist_map(grid: Any, x0: float, y0: float) -> np.ndarray:
    px, py = grid.pixel_centers()
    # Relative slack so that a pixel exactly on the circle counts despite round-off.
    return np.hypot(px - x0, py - y0) * (1 - 1e-9)


def source_peaks(
    image: Any, grid: Any, sources: Any, *, radius: float
) -> list[tuple[int, int] | None]:
    """Brightest pixel ``(iy, ix)`` within ``radius`` (deg) of each source (None if empty)."""
    img = _check_image(image, grid)
    xs, ys = _tangent(grid, sources)
    out: list[tuple[int, int] | None] = []
    for x0, y0 in zip(xs, ys, strict=True):
        inside = _dist_map(grid, x0, y0) <= radius
        if not inside.any():
            out.append(None)
            continue
        masked = np.where(inside, img, -np.inf)
        iy, ix = np.unravel_index(int(np.argmax(masked)), img.shape)
        out.append((int(iy), int(ix)))
    return out


def localization_errors(
    image: Any, grid: Any, sources: Any, *, radius: float, centroid_radius: float | None = None
) -> np.ndarray:
    """Angle (deg) between each true source and its reconstructed position.

    The position is the centroid of the positive image above half the local peak within
    ``centroid_radius`` (default ``radius / 2``) of the brightest pixel within ``radius``
    of the source.  NaN when the source region holds no positive pixel.
    """
    img = _check_image(image, grid)
    xs, ys = _tangent(grid, sources)
    px, py = grid.pixel_centers()
    cr = radius / 2 if centroid_radius is None else centroid_radius
    errs = []
    for (x0, y0), pk in zip(
        zip(xs, ys, strict=True), source_peaks(img, grid, sources, radius=radius), strict=True
    ):
        if pk is None or img[pk] <= 0:
            errs.append(np.nan)
            continue
        near = np.hypot(px - px[pk], py - py[pk]) <= cr * (1 + 1e-9)
        w = np.where(near & (img >= 0.5 * img[pk]), img, 0.0)
        cx, cy = float(np.sum(w * px) / w.sum()), float(np.sum(w * py) / w.sum())
        errs.append(float(angular_distance(grid, cx, cy, x0, y0)))
    return np.asarray(errs)


def spurious_peak_level(image: Any, grid: Any, sources: Any, *, radius: float,
                        relative_to: str = "strongest") -> float:
    """Strongest local maximum outside every source region over a true peak.

    ``relative_to="strongest"``: over the brightest pixel inside the source regions;
    ``"weakest"``: over the weakest source's peak (the brightest pixel of each source
    region, the smallest of those) — the level a spurious peak must stay below not to be
    mistaken for the faintest real source.  0 when no positive peak lies outside; ``inf``
    when the reference peak is not positive.
    """
    img = _check_image(image, grid)
    if relative_to not in ("strongest", "weakest"):
        raise ParameterError(
            f"relative_to must be 'strongest' or 'weakest', got {relative_to!r}"
        )
    xs, ys = _tangent(grid, sources)
    inside = np.zeros(img.shape, dtype=bool)
    regions = []
    for x0, y0 in zip(xs, ys, strict=True):
        regions.append(_dist_map(grid, x0, y0) <= radius)
        inside |= regions[-1]
    if relative_to == "weakest":
        true_peak = min(float(img[r].max()) if r.any() else 0.0 for r in regions)
    else:
        true_peak = float(img[inside].max()) if inside.any() else 0.0
    outside = [img[iy, ix] for iy, ix in find_peaks(img) if not inside[iy, ix]]
    spur = max(outside) if outside else 0.0
    if true_peak <= 0:
        return float("inf") if spur > 0 else 0.0
    return float(spur / true_peak)


def peak_fwhm(image: Any, grid: Any, source: Any, *, radius: float) -> float:
    """FWHM (deg) of the peak nearest ``source`` as the equivalent-disc diameter.

    The area of the connected region at or above half the peak, containing the peak, is
    ``A``; the FWHM is ``2 sqrt(A / pi)`` (pixel area in tangent-plane deg^2).  NaN when the
    source region has no positive peak.
    """
    from scipy.ndimage import label  # scipy.ndimage: ~0.1 s, metrics only

    img = _check_image(image, grid)
    (pk,) = source_peaks(img, grid, (np.atleast_1d(source[0]), np.atleast_1d(source[1])),
                         radius=radius)
    if pk is None or img[pk] <= 0:
        return float("nan")
    lab, _ = label(img >= 0.5 * img[pk])
    area = np.count_nonzero(lab == lab[pk]) * grid.pixel_size**2
    return float(2 * np.sqrt(area / np.pi))


def two_source_dip(image: Any, grid: Any, sources: Any, *, radius: float,
                   n_samples: int = 101) -> float:
    """Minimum of the image on the segment between the two source peaks / their mean height.

    < 1 means a dip (resolved; the Rayleigh criterion for two equal Airy peaks is about
    0.81); ~1 means merged.  The image is sampled bilinearly.  NaN if a peak is missing or
    the two sources share one peak pixel (unresolved: returns 1.0 in that case).
    """
    from scipy.ndimage import map_coordinates  # scipy.ndimage: ~0.1 s, metrics only

    img = _check_image(image, grid)
    pks = source_peaks(img, grid, sources, radius=radius)
    if len(pks) != 2:
        raise ParameterError(f"sources must hold exactly two sources, got {len(pks)}")
    if any(p is None for p in pks):
        return float("nan")
    (y1, x1), (y2, x2) = pks  # type: ignore[misc]
    if (y1, x1) == (y2, x2):
        return 1.0
    t = np.linspace(0.0, 1.0, n_samples)
    line = map_coordinates(img, [y1 + t * (y2 - y1), x1 + t * (x2 - x1)], order=1)
    mean_peak = 0.5 * (img[y1, x1] + img[y2, x2])
    if mean_peak <= 0:
        return float("nan")
    return float(line.min() / mean_peak)


def recovered_flux(image: Any, grid: Any, sources: Any, true_flux: Any, *, radius: float) -> float:
    """Sum of the image in the union of the source regions over the true total flux."""
    img = _check_image(image, grid)
    xs, ys = _tangent(grid, sources)
    inside = np.zeros(img.shape, dtype=bool)
    for x0, y0 in zip(xs, ys, strict=True):
        inside |= _dist_map(grid, x0, y0) <= radius
    total = float(np.sum(true_flux))
    if total <= 0:
        raise ParameterError(f"true_flux must sum to > 0, got {total:g}")
    return float(img[inside].sum() / total)


def measure(fn: Callable[..., Any], *args: Any, **kwargs: Any) -> tuple[Any, float, float]:
    """Call ``fn``; return ``(value, run time in s, peak traced memory in MB)``.

    Memory is the peak of Python allocations traced by :mod:`tracemalloc` during the call
    (numpy buffers included).
    """
    already = tracemalloc.is_tracing()
    if not already:
        tracemalloc.start()
    tracemalloc.reset_peak()
    t0 = time.perf_counter()
    try:
        value = fn(*args, **kwargs)
    finally:
        dt = time.perf_counter() - t0
        _, peak = tracemalloc.get_traced_memory()
        if not already:
            tracemalloc.stop()
    return value, dt, peak / 2**20


def evaluate(
    result: Any,
    grid: Any,
    sources: Any,
    *,
    true_flux: Any,
    radius: float,
    resolution: float | None = None,
) -> dict[str, float]:
    """All metrics of one reconstruction as a flat dict.

    Parameters
    ----------
    result : ReconstructionResult
    grid : SkyGrid
    sources : (theta, phi)
        True source directions (Quantities, or plain numbers in deg).
    true_flux : array_like
        True source fluxes (sky units).
    radius : float
        Source-region radius (deg).
    resolution : float, optional
        Geometric resolution ``b/L`` (deg) to express the FWHM in.

    Returns
    -------
    dict
        ``loc_err_max`` (deg), ``spurious`` (ratio to the strongest true peak),
        ``spurious_weakest`` (ratio to the weakest source's peak), ``fwhm`` (deg), ``fwhm_over_bL``,
        ``dip`` (two sources only), ``flux_ratio``, ``chi2_dof``, ``deviance_dof``,
        ``n_iter``, ``run_time``.
    """
    img = result.image
    names = ("theta", "phi")
    th, ph = (np.atleast_1d(as_angle(v, n)) * u.rad for v, n in zip(sources, names, strict=True))
    loc = localization_errors(img, grid, (th, ph), radius=radius)
    out: dict[str, float] = {
        "loc_err_max": float(np.max(loc)) if np.all(np.isfinite(loc)) else float("nan"),
        "spurious": spurious_peak_level(img, grid, (th, ph), radius=radius),
        "spurious_weakest": spurious_peak_level(img, grid, (th, ph), radius=radius,
                                                relative_to="weakest"),
        "flux_ratio": recovered_flux(img, grid, (th, ph), true_flux, radius=radius),
        "chi2_dof": float(result.chi2_dof),
        "deviance_dof": float(result.deviance / max(result.dof, 1)),
        "n_iter": float(result.n_iter),
        "run_time": float(result.run_time),
    }
    if th.size == 1:
        f = peak_fwhm(img, grid, (th, ph), radius=radius)
        out["fwhm"] = f
        out["fwhm_over_bL"] = f / resolution if resolution else float("nan")
    if th.size == 2:
        out["dip"] = two_source_dip(img, grid, (th, ph), radius=radius)
    return out

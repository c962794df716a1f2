"""Source catalogues and regions as sky models and maps: what the files layer cannot build.

:mod:`rotmod.io.catalogue` reads and writes catalogue files and :mod:`rotmod.io.regions`
region files, below this package (``docs/architecture.md``: ``io`` is the files layer,
``sources`` a user of it), so it cannot make the objects of this package.  Here:

* :func:`read_sky_model` -- a catalogue file (rotmod's, or any table with positions) as the
  :class:`~rotmod.sources.SkyModel` of its point sources, to seed a fit or a detection;
* :func:`probability_map` -- a localisation region as HEALPix pixel probabilities (the
  density evaluated at the pixel centres), written by
  :func:`rotmod.io.regions.write_probability_map`.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

import astropy.units as u
import numpy as np
from astropy.coordinates import ICRS

from rotmod.errors import ParameterError
from rotmod.io.catalogue import SourceCatalogue, read_catalogue
from rotmod.io.regions import HealpixProbability
from rotmod.response.columns import position_grid
from rotmod.response.operator import ResponseOperator
from rotmod.sky.healpix import cone_pixels
from rotmod.sources.localisation import Region
from rotmod.sources.model import PointSource, SkyModel

__all__ = ["probability_map", "read_sky_model"]

#: HEALPix pixels per 68 % radius at least (the pixel size is at most ``r68 / 4``).
PIXELS_PER_R68 = 4
#: Largest HEALPix order astropy-healpix takes.
MAX_ORDER = 29


def read_sky_model(
    catalogue: str | os.PathLike | SourceCatalogue,
    *,
    free_positions: bool = False,
    response: ResponseOperator | None = None,
) -> SkyModel:
    """The point sources of a catalogue as a sky model (no background: a fit starts it).

    Parameters
    ----------
    catalogue : path or SourceCatalogue
        A catalogue file (FITS or ECSV; :func:`rotmod.io.catalogue.read_catalogue`) or one
        read already.
    free_positions : bool
        Let a fit move the positions (default: held); the fluxes are always free, starting
        from the catalogue's (0 where it has none).
    response : ResponseOperator, optional
        The response the model will be used with: positions in another frame than its grid's,
        or out of its view (below the instrument's horizon), are refused here.

    Returns
    -------
    SkyModel

    Raises
    ------
    ParameterError
        What :func:`~rotmod.io.catalogue.read_catalogue` refuses, a negative flux, a
        direction at or beyond 90 deg from the axis, or positions the response cannot see.
    """
    cat = catalogue if isinstance(catalogue, SourceCatalogue) else read_catalogue(catalogue)
    if response is not None:
        if not isinstance(response, ResponseOperator):
            raise ParameterError(f"response must be a ResponseOperator, got {type(response)}")
        if len(cat):
            for _, spec in response.components():
                position_grid(spec.grid, cat.positions)
    sources = []
    for k in range(len(cat)):
        name = cat.names[k] or f"S{k + 1}"
        flux = float(cat.flux[k]) if np.isfinite(cat.flux[k]) else 0.0
        if flux < 0:
            raise ParameterError(f"catalogue: the flux of {name!r} must be >= 0 (a start "
                                 f"value), got {flux}")
        if cat.frame == "celestial":
            pos: Any = cat.positions[k]
        else:
            th, ph = float(cat.positions[0][k]), float(cat.positions[1][k])
            if not 0.0 <= th < 90.0:
                raise ParameterError(f"catalogue: THETA of {name!r} must be in [0, 90) deg "
                                     f"(in front of the detectors), got {th}")
            pos = (th, ph)
        sources.append(PointSource(pos, flux=flux, name=name, free_position=free_positions))
    return SkyModel(sources)


def _nside_for(resolution_deg: float) -> int:
    """The smallest HEALPix nside whose pixels (square root of their area) are at most
    ``resolution_deg`` across."""
    # Pixel area 4 pi / (12 nside^2) sr.
    need = np.sqrt(np.pi / 3.0) / np.radians(resolution_deg)
    order = int(np.clip(np.ceil(np.log2(max(need, 1.0))), 0, MAX_ORDER))
    return 2**order


def probability_map(region: Region | Sequence[Region], *, nside: int | None = None,
                    order: str = "nested", weights: Any = None) -> HealpixProbability:
    """A localisation region as HEALPix pixel probabilities (ICRS).

    The region's density (a probability per point of its tangent-plane square) is evaluated
    at the centre of every pixel of the square, as a density per unit solid angle (linear
    interpolation between the points), times the pixel's area; the probabilities are then
    normalised to sum to 1 (what falls outside the square, where the region has no
    density, is dropped).  Several regions (the modes of one position, e.g. a burst's
    mirror images) are summed with their ``weights``.

    Parameters
    ----------
    region : Region or sequence of Region
        The region of a source on the sky, or the regions of its modes.
    nside : int, optional
        HEALPix resolution; default the coarsest whose pixels are at most ``r68 / 4`` across
        (``r68``: :meth:`Region.radius` at 68 % of the first region).
    order : {"nested", "ring"}
    weights : sequence of float, optional
        Probability of each region (default equal); normalised to sum to 1.

    Returns
    -------
    HealpixProbability

    Raises
    ------
    ParameterError
        A region of an instrument-frame source (HEALPix maps are on the sky), weights that
        are not one finite value >= 0 per region with a positive sum, or a bad ``nside``.
    """
    import astropy_healpix as hp  # HEALPix grids' dependency

    regions = [region] if isinstance(region, Region) else (
        list(region) if isinstance(region, Sequence) else [])
    if not regions or not all(isinstance(r, Region) for r in regions):
        raise ParameterError(f"region must be a Region or a sequence of them, got {region!r}")
    for r in regions:
        if r.source.frame != "celestial":
            raise ParameterError(
                f"region: source {r.source.name or '(unnamed)'!r} is in the instrument "
                "frame; a HEALPix probability map is on the sky (use a celestial or HEALPix "
                "grid)")
    w = np.ones(len(regions)) if weights is None else np.asarray(weights, dtype=float)
    if w.shape != (len(regions),) or not np.all(np.isfinite(w)) or np.any(w < 0) \
            or not w.sum() > 0:
        raise ParameterError(f"weights must be {len(regions)} finite values >= 0 with a "
                             f"positive sum, got {weights!r}")
    w = w / w.sum()
    if nside is None:
        nside = _nside_for(regions[0].radius(0.68) / PIXELS_PER_R68)
    healpix = hp.HEALPix(nside=nside, order=order, frame=ICRS())  # refuses a bad nside
    pix_parts, prob_parts = [], []
    for r, weight in zip(regions, w, strict=True):
        half = float(r.offsets[-1])
        # Every pixel whose centre may lie in the square: a cone over its corners, plus a
        # pixel.
        reach = np.degrees(np.arctan(np.sqrt(2.0) * half)) + \
            healpix.pixel_resolution.to_value(u.deg)
        c = r.source.position.icrs
        pixels = cone_pixels(nside, order, c.ra.deg, c.dec.deg, reach)
        # Density per tangent-plane area; the gnomonic plane's area differs from solid angle
        # by (1 + x^2 + y^2)^(3/2), < 1e-4 over a region a few degrees across, left to the
        # normalisation below.
        dens = r.density_at(healpix.healpix_to_skycoord(pixels))
        pix_parts.append(pixels)
        prob_parts.append(weight * dens * healpix.pixel_area.to_value(u.sr))
    pixels, inverse = np.unique(np.concatenate(pix_parts), return_inverse=True)
    prob = np.bincount(inverse, weights=np.concatenate(prob_parts), minlength=pixels.size)
    keep = prob > 0
    if not np.any(keep):
        raise ParameterError(f"nside {nside}: no pixel centre falls in the region's square; "
                             "use a larger nside")
    return HealpixProbability(nside, pixels[keep], prob[keep] / prob[keep].sum(), order,
                              regions[0].source.name)

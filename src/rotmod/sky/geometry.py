"""What every sky grid is: :class:`SkyGeometry`, the registry of grid kinds, and the two FITS
forms of an image on a grid.

A sky grid (the pattern of gammapy's ``Geom`` with ``WcsGeom`` and ``HpxGeom``) is a list of
pixels, each a direction in the instrument frame: the response operators need only
:meth:`SkyGeometry.directions` and :attr:`SkyGeometry.size`; metadata stores
:meth:`SkyGeometry.to_dict`, which :func:`grid_from_dict` reads back through the registry
:data:`GRID_KINDS`; :func:`rotmod.io.images.write_image` writes an image with
:meth:`SkyGeometry.image_hdus` and reads it back with :func:`image_from_hdus`.

Images have one of two FITS forms:

* a WCS image (:class:`WcsGeometry`: :class:`~rotmod.sky.SkyGrid`,
  :class:`~rotmod.sky.CelestialGrid`): the primary HDU holds the ``(ny, nx)`` image with the
  grid's WCS, an ``UNCERTAINTY`` image extension the uncertainty;
* a pixel table (every other geometry, e.g. :class:`~rotmod.sky.HealpixGrid`): an empty
  primary HDU and a binary table with one row per pixel (the values -- ``INTENSITY``, or
  ``VALUE`` in a HEALPix table --, ``UNCERTAINTY``, and any columns that index the pixels);
  such geometries have images of shape ``(1, size)``.

A new grid kind is one subclass of :class:`SkyGeometry` (or :class:`WcsGeometry`) with its
``kind`` registered in :data:`GRID_KINDS`; storage, FITS images, plots and responses take it
without other changes.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any, ClassVar

import astropy.units as u
import numpy as np
from astropy.io import fits
from astropy.wcs import WCS

from rotmod.errors import ParameterError
from rotmod.registry import Registry

__all__ = ["GRID_KINDS", "SkyGeometry", "WcsGeometry", "grid_from_dict", "image_from_hdus",
           "pixel_table_hdus"]

#: Grid classes by :attr:`SkyGeometry.kind`: each registers itself where it is defined.
GRID_KINDS: Registry[type[SkyGeometry]] = Registry("grid kind")

#: The ``SKYFRAME`` card's comment for each :attr:`SkyGeometry.frame`.
FRAME_COMMENTS = {
    "instrument": "axes XLON/XLAT: instrument frame, not RA/Dec",
    "celestial": "pixels fixed on the sky",
}

#: The kind of a stored grid description without ``"kind"`` (stores written before the other
#: kinds existed hold instrument-frame grids).
DEFAULT_KIND = "instrument"


class SkyGeometry(ABC):
    """A pixelised part of the sky: a list of directions in the instrument frame.

    Subclasses (usually frozen dataclasses) set the class attributes :attr:`kind` (the name
    they are registered under in :data:`GRID_KINDS`) and :attr:`frame`, give ``shape`` (the
    image shape, ``(ny, nx)``; ``(1, size)`` for a list of pixels) as a field or a property,
    and implement :attr:`size`, :meth:`directions`, :meth:`to_dict` and :meth:`from_dict`.

    Attributes
    ----------
    kind : str
        Registry name (class attribute).
    frame : {"instrument", "celestial"}
        Where the pixels are fixed: in the instrument frame, or on the sky (placed in the
        instrument frame by an attitude: geometries of the celestial frame hold it as
        ``attitude``, which :func:`rotmod.response.columns.columns_at` uses to place
        positions of one's choosing the same way).
    shape : (int, int)
        Image shape; flattened sky vectors use C order (``n = iy * nx + ix``).
    """

    kind: ClassVar[str]
    frame: ClassVar[str]
    shape: tuple[int, int]

    @property
    @abstractmethod
    def size(self) -> int:
        """Number of pixels ``n_sky``."""

    @abstractmethod
    def directions(self) -> tuple[u.Quantity, u.Quantity]:
        """Zenith and azimuth (Quantities, rad) of every pixel centre in the instrument frame,
        flattened (n_sky,) in the order of the sky vectors."""

    @abstractmethod
    def to_dict(self) -> dict[str, Any]:
        """Plain description (JSON types) for metadata; :meth:`from_dict` reads it back."""

    @classmethod
    @abstractmethod
    def from_dict(cls, d: dict[str, Any]) -> SkyGeometry:
        """Inverse of :meth:`to_dict`."""

    def image_hdus(self, image: np.ndarray, uncertainty: np.ndarray | None,
                   bunit: str) -> list[Any]:
        """The FITS HDUs of an image on this grid (default: the pixel-table form).

        Parameters
        ----------
        image : ndarray
            The image, of shape :attr:`shape`.
        uncertainty : ndarray or None
            Its uncertainty, same shape.
        bunit : str
            Unit of the values.

        Returns
        -------
        list of HDU
            The primary HDU first (the writer adds the metadata cards to its header).
        """
        return pixel_table_hdus(image, uncertainty, bunit)


class WcsGeometry(SkyGeometry):
    """A sky geometry whose images are 2-D arrays placed on the sky by a FITS WCS."""

    @abstractmethod
    def wcs(self) -> WCS:
        """An `astropy.wcs.WCS` for images on this grid."""

    def image_hdus(self, image: np.ndarray, uncertainty: np.ndarray | None,
                   bunit: str) -> list[Any]:
        """Primary image with the WCS; the uncertainty (if any) as an ``UNCERTAINTY`` image
        with the same WCS."""
        header = self.wcs().to_header()
        # Which sky the axes measure, said in words too: a reader that knows no WCS still
        # learns that instrument-frame axes are not RA and Dec.
        header["SKYFRAME"] = (self.frame, FRAME_COMMENTS[self.frame])
        hdus = [fits.PrimaryHDU(image, header=header)]
        hdus[0].header["BUNIT"] = (bunit, "sky units of the response")
        if uncertainty is not None:
            uh = header.copy()
            uh["BUNIT"] = bunit
            uh["EXTNAME"] = "UNCERTAINTY"
            hdus.append(fits.ImageHDU(uncertainty, header=uh, name="UNCERTAINTY"))
        return hdus


#: Names of the value column of a pixel table: rotmod's, then the HEALPix ``SPARSE`` one
#: (gammapy's convention, which rotmod's HEALPix images follow).
VALUE_COLUMNS = ("INTENSITY", "VALUE")


def pixel_table_hdus(image: np.ndarray, uncertainty: np.ndarray | None, bunit: str, *,
                     name: str = "PIXELS", index: Any = None,
                     value: str = "INTENSITY") -> list[Any]:
    """An empty primary HDU and a table of one row per pixel (the pixel-table form).

    Parameters
    ----------
    image, uncertainty : ndarray
        Values per pixel (raveled in C order); ``uncertainty`` may be None.
    bunit : str
        Unit of the values (the primary's ``BUNIT`` and the columns' unit).
    name : str
        ``EXTNAME`` of the table.
    index : (str, array_like), optional
        A first column of explicit integer pixel indices (``("PIX", pixels)`` for HEALPix).
    value : str
        Name of the value column, one of :data:`VALUE_COLUMNS`.
    """
    primary = fits.PrimaryHDU()
    primary.header["BUNIT"] = (bunit, "sky units of the response")
    cols = []
    if index is not None:
        cols.append(fits.Column(index[0], "K", array=np.asarray(index[1], dtype=np.int64)))
    cols.append(fits.Column(value, "D", unit=bunit, array=np.ravel(image)))
    if uncertainty is not None:
        cols.append(fits.Column("UNCERTAINTY", "D", unit=bunit, array=np.ravel(uncertainty)))
    # The unit is the columns' TUNIT: the FITS standard allows no BUNIT in a table.
    return [primary, fits.BinTableHDU.from_columns(cols, name=name)]


def image_from_hdus(hdul: fits.HDUList, source: str = "file") -> tuple[
        np.ndarray, np.ndarray | None, WCS | None]:
    """Image, uncertainty and WCS (None for a pixel table) of either FITS form.

    Parameters
    ----------
    hdul : astropy.io.fits.HDUList
    source : str
        The file's name, for the error message.

    Raises
    ------
    ParameterError
        Neither a 2-D primary image nor a table with an ``INTENSITY`` column.
    """
    primary = hdul[0]
    if primary.data is not None and primary.data.ndim == 2:
        img = np.array(primary.data, dtype=float)
        unc = (np.array(hdul["UNCERTAINTY"].data, dtype=float) if "UNCERTAINTY" in hdul
               else None)
        return img, unc, WCS(primary.header)
    for hdu in hdul[1:]:
        names = hdu.columns.names if isinstance(hdu, fits.BinTableHDU) else []
        value = next((c for c in VALUE_COLUMNS if c in names), None)
        if value is not None:
            data = hdu.data
            unc = (np.array(data["UNCERTAINTY"], dtype=float)[None, :]
                   if "UNCERTAINTY" in names else None)
            return np.array(data[value], dtype=float)[None, :], unc, None
    raise ParameterError(
        f"path {source!r} has no 2-D primary image and no pixel table (a column named "
        f"{' or '.join(VALUE_COLUMNS)})")


def grid_from_dict(d: dict[str, Any]) -> SkyGeometry:
    """The grid a ``to_dict()`` describes, by its ``"kind"`` (default an instrument grid).

    Raises
    ------
    ParameterError
        ``"kind"`` is not a registered grid kind.
    """
    return GRID_KINDS.get(d.get("kind", DEFAULT_KIND), parameter="grid kind").from_dict(d)

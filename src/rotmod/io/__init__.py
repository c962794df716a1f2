"""File input and output: the only package that touches files.

Each format is registered once, for the class it holds (:mod:`rotmod.io.registry`), and
:func:`write` / :func:`read` reach all of them::

    rotmod.io.write(events, "obs.fits")           # event list, FITS (rotmod.io.events)
    rotmod.io.write(folded, "folded.fits")        # folded profiles, FITS
    rotmod.io.write(config, "inst.toml")          # instrument file, TOML (rotmod.io.config)
    rotmod.io.write(attitude_table, "asp.ecsv")   # attitude table, ECSV (rotmod.io.tables)
    rotmod.io.write(result, "image.fits", grid=grid)  # reconstruction, FITS (rotmod.io.images)
    obj = rotmod.io.read("obs.fits")              # whatever the file holds

The functions registered are the one implementation of each format; the older entry points
(:func:`write_events`, :meth:`rotmod.config.InstrumentConfig.write`,
:meth:`rotmod.sky.AttitudeTable.write`, ...) are those functions or call them.  Every writer
refuses an existing file unless ``overwrite=True`` (:func:`rotmod.io.atomic.check_overwrite`)
and writes atomically (:mod:`rotmod.io.atomic`).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

from astropy.io import fits

from rotmod.config import InstrumentConfig
from rotmod.events import EventList, FoldedProfiles
from rotmod.io.config import (
    list_presets,
    load_instrument,
    load_instrument_config,
    read_instrument_config,
    write_instrument_config,
)
from rotmod.io.events import read_events, read_folded, write_events, write_folded
from rotmod.io.images import FitsImage, read_image, write_image
from rotmod.io.registry import FileFormat, formats, read, register, write
from rotmod.io.tables import read_attitude_table, write_attitude_table
from rotmod.sky.attitude import AttitudeTable

__all__ = [
    "FileFormat",
    "formats",
    "list_presets",
    "load_instrument",
    "load_instrument_config",
    "read",
    "read_events",
    "read_folded",
    "register",
    "write",
    "write_events",
    "write_folded",
]


def _fits_identify(hdu: str) -> Callable[[Path], bool]:
    """``identify(path)``: whether a FITS file has the extension ``hdu``."""

    def identify(path: Path) -> bool:
        try:
            with fits.open(path) as hdul:
                return hdu in hdul
        except (OSError, ValueError):
            return False

    return identify


def _is_image(path: Path) -> bool:
    try:
        return fits.getheader(path, 0).get("NAXIS") == 2
    except (OSError, ValueError, IndexError):
        return False


def _write_result(result: Any, path: str | os.PathLike, *, overwrite: bool = False,
                  **kw: Any) -> Path:
    """:func:`write_image` with the registry's argument order (object first)."""
    return write_image(path, result, overwrite=overwrite, **kw)


register(EventList, "fits", reader=read_events, writer=write_events,
         extensions=(".fits", ".fits.gz", ".evt"), identify=_fits_identify("EVENTS"))
register(FoldedProfiles, "fits", reader=read_folded, writer=write_folded,
         extensions=(".fits", ".fits.gz"), identify=_fits_identify("PROFILES"))
register(InstrumentConfig, "toml", reader=read_instrument_config,
         writer=write_instrument_config, extensions=(".toml",))
register(InstrumentConfig, "yaml", reader=read_instrument_config,
         extensions=(".yaml", ".yml"))
register(AttitudeTable, "ecsv", reader=read_attitude_table,
         writer=write_attitude_table, extensions=(".ecsv",))
# By its import path: importing the reconstruction package here would make every reader of
# files load it.
register("rotmod.reconstruction.base.ReconstructionResult", "fits", writer=_write_result,
         extensions=(".fits", ".fits.gz"))
register(FitsImage, "fits", reader=read_image, extensions=(".fits", ".fits.gz"),
         identify=_is_image)

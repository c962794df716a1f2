"""File input and output: the only package that touches files.

Each format is registered once, for the class it holds (:mod:`rotmod.io.registry`), and
:func:`write` / :func:`read` reach all of them::

    rotmod.io.write(events, "obs.fits")           # event list, FITS (rotmod.io.events)
    rotmod.io.write(folded, "folded.fits")        # folded profiles, FITS
    rotmod.io.write(config, "inst.toml")          # instrument file, TOML (rotmod.io.config)
    rotmod.io.write(attitude_table, "asp.ecsv")   # attitude table, ECSV (rotmod.io.tables)
    rotmod.io.write(result, "image.fits", grid=grid)  # reconstruction, FITS (rotmod.io.images)
    rotmod.io.write(detection, "cat.fits")        # source catalogue, FITS or ECSV (io.catalogue)
    rotmod.io.write(detection.ts_map, "ts.fits")  # TS map, FITS (rotmod.io.tsmaps)
    rotmod.io.write(light_curve, "lc.ecsv")       # light curve, FITS or ECSV (rotmod.io.tables)
    rotmod.io.write(spectrum, "src.pha")          # OGIP PHA + RMF + ARF (+ bkg) (rotmod.io.ogip)
                                                  # (counts, or rates with STAT_ERR)
    obj = rotmod.io.read("obs.fits")              # whatever the file holds

The functions registered are the one implementation of each format; the older entry points
(:func:`write_events`, :meth:`rotmod.config.InstrumentConfig.write`,
:meth:`rotmod.sky.AttitudeTable.write`, ...) are those functions or call them.  Every writer
refuses an existing file unless ``overwrite=True`` (:func:`rotmod.io.atomic.check_overwrite`)
and writes atomically (:mod:`rotmod.io.atomic`).
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

from astropy.io import fits
from astropy.table import Table

from rotmod.config import InstrumentConfig
from rotmod.events import EventList, FoldedProfiles
from rotmod.io.catalogue import SourceCatalogue, read_catalogue, write_catalogue, write_detection
from rotmod.io.config import (
    list_presets,
    load_instrument,
    load_instrument_config,
    read_instrument_config,
    write_instrument_config,
)
from rotmod.io.events import read_events, read_folded, write_events, write_folded
from rotmod.io.images import FitsImage, read_image, write_image
from rotmod.io.ogip import poisson_errors, read_ogip, write_ogip
from rotmod.io.regions import HealpixProbability, read_probability_map, write_probability_map
from rotmod.io.registry import FileFormat, formats, read, register, write
from rotmod.io.tables import read_attitude_table, write_attitude_table, write_light_curve
from rotmod.io.tsmaps import TSMapFile, read_ts_map, write_ts_map
from rotmod.sky.attitude import AttitudeTable
from rotmod.spectral.spectrum import CountsSpectrum, RateSpectrum

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
            # A probe only: what astropy warns of (a cut file) the reader then refuses.
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                with fits.open(path) as hdul:
                    return hdu in hdul
        except (OSError, ValueError):
            return False

    return identify


def _ogip_identify(poisson: bool) -> Callable[[Path], bool]:
    """``identify(path)``: whether an OGIP PHA file holds Poisson counts (``poisson``) or
    rates with Gaussian errors (:func:`rotmod.io.ogip.poisson_errors`)."""

    def identify(path: Path) -> bool:
        try:
            with fits.open(path) as hdul:
                ext = hdul["SPECTRUM"]
                return poisson_errors(ext.header, ext.columns.names) == poisson
        except (OSError, ValueError, KeyError):
            return False

    return identify


def _ecsv_identify(rule: Callable[[Table], bool]) -> Callable[[Path], bool]:
    """``identify(path)``: whether an ECSV file's table passes ``rule``."""

    def identify(path: Path) -> bool:
        try:
            return rule(Table.read(path, format="ascii.ecsv"))
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
         writer=write_attitude_table, extensions=(".ecsv",),
         identify=_ecsv_identify(lambda t: {"time", "ra", "dec", "roll"} <= set(t.colnames)))
# By its import path: importing the reconstruction package here would make every reader of
# files load it.
register("rotmod.reconstruction.base.ReconstructionResult", "fits", writer=_write_result,
         extensions=(".fits", ".fits.gz"))
register(FitsImage, "fits", reader=read_image, extensions=(".fits", ".fits.gz"),
         identify=_is_image)
# Source products, by the import paths of the sources package's classes (as above).
for _cls, _writer in (("rotmod.sources.detection.Detection", write_detection),
                      ("rotmod.sources.fitting.FitResult", write_catalogue),
                      ("rotmod.sources.lightcurve.LightCurve", write_light_curve)):
    register(_cls, "fits", writer=_writer, extensions=(".fits", ".fits.gz"))
    register(_cls, "ecsv", writer=_writer, extensions=(".ecsv",))
register(SourceCatalogue, "fits", reader=read_catalogue, extensions=(".fits", ".fits.gz"),
         identify=_fits_identify("CATALOG"))
register(SourceCatalogue, "ecsv", reader=read_catalogue, extensions=(".ecsv",),
         identify=_ecsv_identify(lambda t: t.meta.get("EXTNAME") == "CATALOG"))
register("rotmod.sources.tsmap.TSMap", "fits", writer=write_ts_map,
         extensions=(".fits", ".fits.gz"))
register(TSMapFile, "fits", reader=read_ts_map, extensions=(".fits", ".fits.gz"),
         identify=_fits_identify("SENSITIVITY"))
register(HealpixProbability, "fits", reader=read_probability_map,
         writer=write_probability_map, extensions=(".fits", ".fits.gz"),
         identify=_fits_identify("PROBMAP"))
register(CountsSpectrum, "ogip", reader=read_ogip, writer=write_ogip, extensions=(".pha", ".pi"),
         identify=_ogip_identify(poisson=True))
register(RateSpectrum, "ogip", reader=read_ogip, writer=write_ogip, extensions=(".pha", ".pi"),
         identify=_ogip_identify(poisson=False))

"""FITS event lists and folded profiles.

Event files follow the usual layout of high-energy astronomy event lists (OGIP):

* ``EVENTS`` binary table (``HDUCLAS1 = 'EVENTS'``): ``TIME`` (s), ``DET_ID``, ``ENERGY``
  (keV) and, for simulations, ``SRC_ID`` (emitting source, -1 for background), with
  ``TELESCOP``, ``INSTRUME``, ``TSTART``, ``TSTOP``, ``TIMEUNIT``, ``TIMESYS``,
  ``MJDREFI``/``MJDREFF``, ``TIMEZERO``, ``EXPOSURE``, ``ONTIME``, ``LIVETIME``,
  ``TELAPSE`` and the instrument geometry (``MASK_A``, ``MASK_B``, ``MASK_H``, ``MASK_L``,
  ``MASK_MAT``, ``MASK_RHO``, ``MASK_SIG``, ``MASK_MU``, ``DET_DIAM``, ``NDET``,
  ``ROT_PER``, ``ROT_PHA0``);
* ``GTI`` (``START``, ``STOP``);
* ``DETECTORS`` (``DET_ID``, ``DETX``, ``DETY`` in cm);
* ``SOURCES`` (simulated ``THETA``, ``PHI`` in deg, ``RATE``, ``ENERGY``), when known.

Folded profiles are a ``PROFILES`` table (``BIN_LO``, ``BIN_HI`` in deg, ``EXPOSURE``,
``COUNTS`` a vector of one entry per detector) with the same geometry keywords, ``GTI`` and
``DETECTORS``.  The geometry round-trips through :meth:`Instrument.to_dict` /
:meth:`Instrument.from_dict`; its keywords, comments and units are the ``fits``, ``doc`` and
``unit`` metadata of the fields of :class:`~rotmod.geometry.Mask`,
:class:`~rotmod.geometry.DetectorArray` and :class:`~rotmod.geometry.Instrument`, which
write and read every card.  Writers refuse to overwrite unless asked and write
atomically (temporary file in the same folder, then :func:`os.replace`).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import astropy.units as u
import numpy as np
from astropy.io import fits

from rotmod._validate import as_integers
from rotmod.binning import EnergyBand, TimeBinning
from rotmod.errors import ParameterError, RotmodError
from rotmod.events import EventList, FoldedProfiles
from rotmod.geometry import DetectorArray, Instrument, Mask
from rotmod.io._fits import header_text, open_verified
from rotmod.io.atomic import atomic_path, check_overwrite
from rotmod.io.provenance import provenance_cards
from rotmod.materials import Material
from rotmod.sky import Attitude
from rotmod.sky.sources import PointSources

__all__ = ["read_events", "read_folded", "write_events", "write_folded"]


# --------------------------------------------------------------------------- helpers


def _card_fields(cls: type) -> list[tuple[str, Any, dataclasses.Field]]:
    """``(field name, fits spec, field)`` of the fields of ``cls`` that are header cards, in
    field order with JSON lists after the scalars (as the cards have always been written)."""
    fs = [(f.name, f.metadata["fits"], f) for f in dataclasses.fields(cls)
          if "fits" in f.metadata]
    return sorted(fs, key=lambda t: bool(t[2].metadata.get("list")))


def _optional(f: dataclasses.Field) -> bool:
    """A card that may be absent: the field is optional (None) or written only when set."""
    return f.default is None or bool(f.metadata.get("skip_default"))


#: Units of the Material fields (the cards of a material field carry them).
_MATERIAL_UNITS = {f.name: f.metadata.get("unit") for f in dataclasses.fields(Material)}


#: Material cards that may be absent: a fixed coefficient (the density is always written: a
#: Material holds the database's when none is given).
_MATERIAL_OPTIONAL = ("mass_attenuation",)


def _material_key(name: str) -> str:
    """The key of a Material field in ``to_dict`` (its name is the ``material`` entry)."""
    return "material" if name == "name" else name


def _comment(unit: str | None, doc: str) -> str:
    return f"[{unit}] {doc}" if unit else doc


def _section_cards(cls: type, d: dict[str, Any]) -> list[tuple[str, Any, str]]:
    """Header cards of the fields of ``cls`` in ``d`` (its ``to_dict``), from the fields'
    ``fits``/``doc``/``unit`` metadata; None values are not written."""
    cards: list[tuple[str, Any, str]] = []
    for name, spec, f in _card_fields(cls):
        if isinstance(spec, dict):  # a material: its fields' cards under this field's keys
            for sub, (key, doc) in spec.items():
                v = d.get(_material_key(sub))
                if v is not None:
                    cards.append((key, v, _comment(_MATERIAL_UNITS[sub], doc)))
            continue
        v = d.get(name)
        if v is None:
            continue
        comment = _comment(f.metadata.get("unit"), f.metadata["doc"])
        if f.metadata.get("list"):
            v, comment = json.dumps(v), f"{comment} (JSON list)"
        elif f.metadata.get("inf") and isinstance(v, float) and math.isinf(v):
            v, comment = "INF", f"{comment}: {f.metadata['inf']}"
        cards.append((spec, v, comment))
    return cards


def _instrument_cards(inst: Instrument, start_phase: float) -> list[tuple[str, Any, str]]:
    """The instrument as header cards: the fields of the mask, the detectors and the
    instrument (their metadata name the cards), the detector count and the start phase."""
    d = inst.to_dict()
    return [
        *_section_cards(Mask, d["mask"]),
        *_section_cards(DetectorArray, d["detectors"]),
        ("NDET", len(inst.detectors), "number of detectors"),
        *_section_cards(Instrument, d),
        ("ROT_PHA0", float(u.Quantity(start_phase, u.rad).to_value(u.deg)),
         "[deg] mask angle at TIME = 0"),
    ]


def _detectors_hdu(inst: Instrument) -> fits.BinTableHDU:
    pos = inst.detectors.positions
    hdu = fits.BinTableHDU.from_columns(
        [
            fits.Column("DET_ID", "J", array=np.arange(pos.shape[0], dtype=np.int32)),
            fits.Column("DETX", "D", unit="cm", array=pos[:, 0]),
            fits.Column("DETY", "D", unit="cm", array=pos[:, 1]),
        ],
        name="DETECTORS",
    )
    hdu.header["DET_DIAM"] = (inst.detectors.diameter, "[cm] detector diameter c")
    return hdu


def _gti_hdu(gti: np.ndarray, header: dict[str, Any]) -> fits.BinTableHDU:
    hdu = fits.BinTableHDU.from_columns(
        [
            fits.Column("START", "D", unit="s", array=gti[:, 0]),
            fits.Column("STOP", "D", unit="s", array=gti[:, 1]),
        ],
        name="GTI",
    )
    hdu.header["HDUCLASS"] = "OGIP"
    hdu.header["HDUCLAS1"] = "GTI"
    hdu.header["HDUCLAS2"] = "STANDARD"
    for k in ("TELESCOP", "INSTRUME", "TIMESYS", "TIMEUNIT", "MJDREFI", "MJDREFF", "TIMEZERO"):
        if k in header:
            hdu.header[k] = header[k]
    return hdu


def _provenance(meta: dict[str, Any], seed: Any, command: Any) -> list[tuple[str, Any, str]]:
    """The provenance cards (:func:`rotmod.io.provenance.provenance_cards`) with the names in
    the metadata."""
    return provenance_cards(telescop=str(meta.get("telescop", "ROTMOD")),
                            instrume=str(meta.get("instrume", "RM")), seed=seed,
                            command=command)


def _time_cards(meta: dict[str, Any], t_start: float, t_stop: float, gti: np.ndarray) -> list:
    mjdref = float(meta.get("mjdref", 51544.0))
    ontime = float(np.sum(gti[:, 1] - gti[:, 0]))
    return [
        ("TIMESYS", header_text(str(meta.get("timesys", "TT"))), "time system"),
        ("TIMEUNIT", "s", "unit of TIME, TSTART, TSTOP"),
        ("TIMEREF", "LOCAL", "times are not barycentred"),
        ("MJDREFI", math.floor(mjdref), "integer part of reference MJD"),
        ("MJDREFF", mjdref - math.floor(mjdref), "fractional part of reference MJD"),
        ("TIMEZERO", float(meta.get("timezero", 0.0)), "[s] offset added to TIME"),
        ("TSTART", t_start, "[s] start of the observation"),
        ("TSTOP", t_stop, "[s] end of the observation"),
        ("TELAPSE", t_stop - t_start, "[s] TSTOP - TSTART"),
        ("ONTIME", ontime, "[s] sum of good time intervals"),
        ("LIVETIME", ontime, "[s] ONTIME (no dead time modelled)"),
        ("EXPOSURE", ontime, "[s] exposure"),
    ] + [
        (key.upper(), float(meta[key]), f"[keV] {side} of the energy band folded")
        for key, side in (("e_min", "low edge"), ("e_max", "high edge")) if key in meta
    ]


def _primary_provenance(primary: fits.PrimaryHDU, header: Any) -> None:
    """Copy the provenance cards of a product's table to its primary header (where FITS
    tools look first)."""
    for k in ("TELESCOP", "INSTRUME", "CREATOR", "RMCOMMIT", "DATE", "SEED", "COMMAND",
              "LONGSTRN"):
        if k in header:
            primary.header[k] = (header[k], header.comments[k])


def _write_atomic(hdul: fits.HDUList, path: str | os.PathLike, overwrite: bool) -> Path:
    p = check_overwrite(path, overwrite)
    if not p.parent.exists():
        raise ParameterError(f"path {str(p)!r}: folder {str(p.parent)!r} does not exist")
    with atomic_path(p) as tmp:
        hdul.writeto(tmp, overwrite=True, checksum=True)
    return p


def _open(path: str | os.PathLike) -> fits.HDUList:
    return open_verified(path)


def _ext(hdul: fits.HDUList, name: str, path: Any) -> Any:
    try:
        return hdul[name]
    except KeyError:
        raise RotmodError(f"file {str(path)!r} has no {name} extension") from None


def _key(header: Any, key: str, path: Any, ext: str) -> Any:
    if key not in header:
        raise RotmodError(f"file {str(path)!r}: {ext} header lacks keyword {key}")
    return header[key]


def _col(data: Any, name: str, path: Any, ext: str) -> np.ndarray:
    if data is None or name not in data.columns.names:
        raise RotmodError(f"file {str(path)!r}: {ext} table lacks column {name}")
    return np.asarray(data[name])


def _parse_unit(text: str) -> u.UnitBase:
    """A unit string in the FITS standard's form (``s-1``, what rotmod writes) or OGIP's
    (``1/s``, in files rotmod wrote before)."""
    try:
        return u.Unit(text, format="fits", parse_strict="raise")
    except ValueError:
        return u.Unit(text, format="ogip", parse_strict="raise")


def _to_unit(value: Any, declared: str | None, unit: u.UnitBase, what: str, path: Any) -> Any:
    """``value`` in the file's ``declared`` unit (``unit`` when none), converted to ``unit``."""
    if not declared:
        return value
    try:
        file_unit = _parse_unit(declared)
        return u.Quantity(value, file_unit).to_value(unit)
    except (ValueError, u.UnitsError) as exc:
        raise RotmodError(
            f"file {str(path)!r}: {what} has unit {declared!r}, which is not a unit of {unit}"
        ) from exc


def _col_in(data: Any, name: str, path: Any, ext: str, unit: u.UnitBase) -> np.ndarray:
    """Column ``name`` converted to ``unit`` following its TUNIT (files without TUNIT: ``unit``)."""
    col = _col(data, name, path, ext)
    if not np.issubdtype(col.dtype, np.number):
        raise RotmodError(
            f"file {str(path)!r}: {ext} column {name} must be numeric, got {col.dtype}"
        )
    declared = data.columns[name].unit
    return np.asarray(_to_unit(col.astype(float), declared, unit, f"{ext} column {name}", path))


def _key_in(header: Any, key: str, default: float, unit: u.UnitBase, path: Any) -> float:
    """Header value in ``unit``; the OGIP ``[unit]`` at the start of the comment says its unit."""
    if key not in header:
        return default
    value = header[key]
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise RotmodError(f"file {str(path)!r}: keyword {key} must be a number, got {value!r}")
    comment = header.comments[key]
    has_unit = comment.startswith("[") and "]" in comment
    declared = comment[1 : comment.index("]")] if has_unit else None
    return float(_to_unit(float(value), declared, unit, f"keyword {key}", path))


def _num(header: Any, key: str, path: Any, ext: str) -> float:
    """A required numeric keyword; a missing or non-numeric value names file, key and value."""
    value = _key(header, key, path, ext)
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise RotmodError(f"file {str(path)!r}: {ext} keyword {key} must be a number, "
                          f"got {value!r}")
    return float(value)


def _time_offset(header: Any, path: Any, ext: str) -> tuple[float, u.UnitBase]:
    """``TIMEZERO`` (s) and the time unit (``TIMEUNIT``) of a table, as OGIP defines them."""
    unit_text = header.get("TIMEUNIT", "s")
    try:
        unit = u.Unit(str(unit_text), format="ogip")
        unit.to(u.s)
    except (ValueError, u.UnitsError):
        raise RotmodError(f"file {str(path)!r}: {ext} keyword TIMEUNIT must be a time unit, "
                          f"got {unit_text!r}") from None
    zero = _num(header, "TIMEZERO", path, ext) if "TIMEZERO" in header else 0.0
    return float((zero * unit).to_value(u.s)), unit


def _section_from(cls: type, header: Any, path: Any, ext: str) -> dict[str, Any]:
    """The ``to_dict`` of a ``cls`` from its header cards (the inverse of
    :func:`_section_cards`); a missing required card is an error naming it."""
    out: dict[str, Any] = {}
    for name, spec, f in _card_fields(cls):
        if isinstance(spec, dict):  # a material: required, or present when its name is
            name_key = spec["name"][0]
            if f.default is None and name_key not in header:
                out.update((_material_key(sub), None) for sub in spec)
                continue
            for sub, (key, _) in spec.items():
                if sub == "name":
                    out["material"] = str(_key(header, key, path, ext))
                elif sub in _MATERIAL_OPTIONAL and key not in header:
                    out[sub] = None
                else:
                    out[sub] = _num(header, key, path, ext)
            continue
        if spec not in header:
            if not _optional(f):
                _key(header, spec, path, ext)  # raises: the card is required
            elif f.default is None:
                out[name] = None
            continue
        value = header[spec]
        if f.metadata.get("text"):
            out[name] = str(value)
        elif f.metadata.get("list"):
            try:
                out[name] = [float(v) for v in json.loads(str(value))]
            except (ValueError, TypeError):
                raise RotmodError(f"file {str(path)!r}: {ext} keyword {spec} must be a JSON "
                                  f"list of numbers, got {value!r}") from None
        elif (f.metadata.get("inf") and isinstance(value, str)
              and value.strip().upper() == "INF"):
            out[name] = math.inf
        else:
            out[name] = _num(header, spec, path, ext)
    return out


def _read_instrument(hdul: fits.HDUList, header: Any, path: Any, ext: str) -> Instrument:
    det = _ext(hdul, "DETECTORS", path)
    try:
        ids = as_integers(_col(det.data, "DET_ID", path, "DETECTORS"), "DETECTORS column DET_ID")
    except ParameterError as exc:
        raise RotmodError(f"file {str(path)!r}: {exc}") from None
    order = np.argsort(ids)
    pos = np.stack(
        [_col(det.data, "DETX", path, "DETECTORS"), _col(det.data, "DETY", path, "DETECTORS")],
        axis=1,
    )[order].astype(float)
    d = {
        "mask": _section_from(Mask, header, path, ext),
        "detectors": {**_section_from(DetectorArray, header, path, ext),
                      "positions": pos.tolist()},
        **_section_from(Instrument, header, path, ext),
    }
    try:
        return Instrument.from_dict(d)
    except RotmodError as exc:
        raise RotmodError(f"file {str(path)!r}: invalid instrument geometry: {exc}") from exc


def _read_gti(hdul: fits.HDUList, path: Any) -> np.ndarray:
    g = _ext(hdul, "GTI", path)
    zero, unit = _time_offset(g.header, path, "GTI")
    cols = [_col_in(g.data, c, path, "GTI", unit) * unit.to(u.s) + zero
            for c in ("START", "STOP")]
    return np.stack(cols, axis=1).astype(float)


def _software(creator: str) -> str:
    """The software of a ``CREATOR`` card: ``rotmod`` for any version of rotmod (the
    version is the file's provenance, not the data's metadata)."""
    return "rotmod" if creator.split(" ")[0] == "rotmod" else creator


def _meta_from(header: Any, path: Any) -> dict[str, Any]:
    meta = {
        "telescop": header.get("TELESCOP", "ROTMOD"),
        "instrume": header.get("INSTRUME", "RM"),
        "timesys": header.get("TIMESYS", "TT"),
        "mjdref": (_num(header, "MJDREFI", path, "header") if "MJDREFI" in header else 51544.0)
        + (_num(header, "MJDREFF", path, "header") if "MJDREFF" in header else 0.0),
        "timezero": _num(header, "TIMEZERO", path, "header") if "TIMEZERO" in header else 0.0,
        "creator": _software(str(header.get("CREATOR", "rotmod"))),
    }
    for key in ("E_MIN", "E_MAX"):
        if key in header:
            meta[key.lower()] = _key_in(header, key, 0.0, u.keV, path)
    if "RM_META" in header:
        try:
            meta.update(json.loads(header["RM_META"]))
        except json.JSONDecodeError:
            pass
    return meta


# --------------------------------------------------------------------------- events


def write_events(events: EventList, path: str | os.PathLike, *, overwrite: bool = False,
                 seed: Any = None, command: str | Sequence[str] | None = None) -> Path:
    """Write an event list as a FITS file (see the module notes for the layout).

    Parameters
    ----------
    events : EventList
    path : str or path-like
        Output file.
    overwrite : bool
        Replace an existing file (default: refuse).
    seed : int, SeedSequence or Generator, optional
        The seed of the simulation that made the events (the ``SEED`` card).
    command : str or sequence of str, optional
        The command line or parameters that made the file (the ``COMMAND`` card).

    Returns
    -------
    pathlib.Path
        The written file.

    Raises
    ------
    ParameterError
        ``path`` exists and ``overwrite`` is false, or its folder does not exist.
    """
    if not isinstance(events, EventList):
        raise ParameterError(f"events must be an EventList, got {type(events)}")
    cols = [
        fits.Column("TIME", "D", unit="s", array=events.time),
        fits.Column("DET_ID", "J", array=events.detector.astype(np.int32)),
        fits.Column("ENERGY", "E", unit="keV", array=events.energy.astype(np.float32)),
    ]
    if events.source is not None:
        cols.append(fits.Column("SRC_ID", "J", array=events.source.astype(np.int32)))
    att = events.attitude
    if att is not None:
        # Non-imaging detectors see the whole field: an event's best sky direction is the
        # pointing.  The columns are what GADF readers (gammapy) require; the image comes
        # from the folded counts, never from them.
        n = len(events)
        cols += [fits.Column("RA", "D", unit="deg", array=np.full(n, att.ra)),
                 fits.Column("DEC", "D", unit="deg", array=np.full(n, att.dec))]
    ev = fits.BinTableHDU.from_columns(cols, name="EVENTS")
    h = ev.header
    h["HDUCLASS"] = ("GADF" if att is not None else "OGIP", "format conventions")
    if att is not None:
        h["HDUDOC"] = ("https://gamma-astro-data-formats.readthedocs.io", "format document")
        h["HDUVERS"] = ("0.3", "format version")
        h["HDUCLAS2"] = ("ACCEPTED", "all events recorded")
    h["HDUCLAS1"] = ("EVENTS", "extension contains events")
    if att is not None:
        h["OBS_ID"] = (int(events.meta.get("obs_id", 1)), "observation identifier")
        h["RADESYS"] = ("ICRS", "celestial frame of RA/DEC")
        h["RA_PNT"] = (att.ra, "[deg] pointing: rotation axis, RA")
        h["DEC_PNT"] = (att.dec, "[deg] pointing: rotation axis, Dec")
        h["ROLL_PNT"] = (att.roll, "[deg] position angle of the instrument +y axis")
        h["DEADC"] = (1.0, "dead-time correction: LIVETIME = ONTIME")
        # No GEOLON/GEOLAT/ALTITUDE: GADF's fixed ground observatory does not describe a
        # balloon or a satellite, so gammapy's Observation.read refuses these files
        # (docs/conventions.md says what to use instead).
    for k, v, c in [*_provenance(events.meta, seed, command),
                    *_time_cards(events.meta, events.t_start, events.t_stop, events.gti)]:
        h[k] = (v, c)
    for k, v, c in _instrument_cards(events.instrument, events.start_phase):
        h[k] = (v, c)
    hdus = [fits.PrimaryHDU(), ev, _gti_hdu(events.gti, dict(h)), _detectors_hdu(events.instrument)]
    if events.sources is not None:
        s = events.sources
        hdus.append(
            fits.BinTableHDU.from_columns(
                [
                    fits.Column("THETA", "D", unit="deg", array=s.theta.to_value(u.deg)),
                    fits.Column("PHI", "D", unit="deg", array=s.phi.to_value(u.deg)),
                    fits.Column("RATE", "D", unit="s-1", array=s.rate),
                    fits.Column("ENERGY", "D", unit="keV", array=s.energy),
                ],
                name="SOURCES",
            )
        )
    _primary_provenance(hdus[0], h)
    return _write_atomic(fits.HDUList(hdus), path, overwrite)


def read_events(path: str | os.PathLike) -> EventList:
    """Read an event list written by :func:`write_events`.

    Raises
    ------
    RotmodError
        Missing file, not FITS, or missing extensions, columns or keywords.
    """
    with _open(path) as hdul:
        ev = _ext(hdul, "EVENTS", path)
        h = ev.header
        if h.get("HDUCLAS1") != "EVENTS":
            raise RotmodError(f"file {str(path)!r}: EVENTS extension lacks HDUCLAS1 = 'EVENTS'")
        inst = _read_instrument(hdul, h, path, "EVENTS")
        gti = _read_gti(hdul, path)
        attitude = None
        if "RA_PNT" in h and "DEC_PNT" in h:
            attitude = Attitude(
                _key_in(h, "RA_PNT", 0.0, u.deg, path), _key_in(h, "DEC_PNT", 0.0, u.deg, path),
                _key_in(h, "ROLL_PNT", 0.0, u.deg, path),
            )
        src = None
        if ev.data is not None and "SRC_ID" in ev.data.columns.names:
            src = np.asarray(ev.data["SRC_ID"], dtype=np.int32)
        sources = None
        if "SOURCES" in hdul:
            sd = hdul["SOURCES"].data
            sources = PointSources(
                *(_col_in(sd, c, path, "SOURCES", un) * un for c, un in (
                    ("THETA", u.deg), ("PHI", u.deg), ("RATE", 1 / u.s), ("ENERGY", u.keV)
                ))
            )
        # OGIP time: TIME in TUNIT (else TIMEUNIT), plus TIMEZERO; TSTART/TSTOP likewise.
        # The offset is applied here, so the event list holds times with TIMEZERO = 0.
        zero, unit = _time_offset(h, path, "EVENTS")
        scale = unit.to(u.s)
        time = _col_in(ev.data, "TIME", path, "EVENTS", unit) * scale + zero
        meta = {**_meta_from(h, path), "timezero": 0.0}
        try:
            return EventList(
                time,
                _col(ev.data, "DET_ID", path, "EVENTS"),  # checked by EventList, not cast
                np.asarray(_col(ev.data, "ENERGY", path, "EVENTS"), dtype=np.float32),
                inst,
                gti,
                _key_in(h, "ROT_PHA0", 0.0, u.deg, path) * u.deg,
                _num(h, "TSTART", path, "EVENTS") * scale + zero,
                _num(h, "TSTOP", path, "EVENTS") * scale + zero,
                src,
                sources,
                meta,
                attitude,
            )
        except RotmodError as exc:
            raise RotmodError(f"file {str(path)!r}: invalid event list: {exc}") from exc


# --------------------------------------------------------------------------- folded


def write_folded(
    folded: FoldedProfiles, path: str | os.PathLike, *, overwrite: bool = False,
    seed: Any = None, command: str | Sequence[str] | None = None,
) -> Path:
    """Write folded count profiles as a FITS ``PROFILES`` table.

    The bins are written as ``BIN_LO``/``BIN_HI`` columns (deg, for other tools) and as the
    :class:`~rotmod.binning.TimeBinning` (``NBINS``, ``BINMODE``, ``BINNSUB``); the energy
    band as ``E_MIN``/``E_MAX`` (keV).

    Parameters
    ----------
    folded : FoldedProfiles
    path : str or path-like
    overwrite : bool
        Replace an existing file (default: refuse).
    seed : int, SeedSequence or Generator, optional
        The seed of the simulation behind the counts (the ``SEED`` card).
    command : str or sequence of str, optional
        The command line or parameters that made the file (the ``COMMAND`` card).

    Returns
    -------
    pathlib.Path
    """
    if not isinstance(folded, FoldedProfiles):
        raise ParameterError(f"folded must be FoldedProfiles, got {type(folded)}")
    n_det = folded.counts.shape[0]
    ex = folded.exposure
    tb = folded.time_bins
    cols = [
        fits.Column("BIN_LO", "D", unit="deg", array=folded.bin_edges[:-1].to_value(u.deg)),
        fits.Column("BIN_HI", "D", unit="deg", array=folded.bin_edges[1:].to_value(u.deg)),
        fits.Column(
            "EXPOSURE", f"{ex.shape[0]}D" if ex.ndim == 2 else "D", unit="s",
            array=ex.T if ex.ndim == 2 else ex,
        ),
        fits.Column("COUNTS", f"{n_det}K", array=folded.counts.T.astype(np.int64)),
    ]
    tab = fits.BinTableHDU.from_columns(cols, name="PROFILES")
    h = tab.header
    h["HDUCLAS1"] = ("PROFILES", "count profiles folded on the mask rotation")
    t0 = float(folded.gti[0, 0])
    t1 = float(folded.gti[-1, 1])
    # The band goes where the time cards have always written it (E_MIN, E_MAX in keV).
    band = {} if folded.energy_band is None else folded.energy_band.to_dict()
    for k, v, c in [*_provenance(folded.meta, seed, command),
                    *_time_cards({**folded.meta, **band}, t0, t1, folded.gti)]:
        h[k] = (v, c)
    for k, v, c in _instrument_cards(folded.instrument, folded.start_phase):
        h[k] = (v, c)
    h["NBINS"] = (tb.n_bins, "mask-angle bins over one turn")
    h["BINMODE"] = (tb.mode, "response of a bin: center or average")
    h["BINNSUB"] = (tb.n_sub, "sub-samples per bin in average mode")
    hdus = [
        fits.PrimaryHDU(), tab, _gti_hdu(folded.gti, dict(h)), _detectors_hdu(folded.instrument)
    ]
    _primary_provenance(hdus[0], h)
    return _write_atomic(fits.HDUList(hdus), path, overwrite)


def read_folded(path: str | os.PathLike) -> FoldedProfiles:
    """Read folded count profiles written by :func:`write_folded`.

    The bins are rebuilt as a :class:`~rotmod.binning.TimeBinning` from the ``BIN_LO``/
    ``BIN_HI`` edges (:meth:`~rotmod.binning.TimeBinning.from_edges`, which allows the
    round-off of the degree columns), with ``BINMODE``/``BINNSUB`` when present (files
    written before them: a centre-mode binning).

    Raises
    ------
    RotmodError
        Missing file, not FITS, missing extensions, columns or keywords, or bins that are
        not equal bins over one turn.
    """
    with _open(path) as hdul:
        tab = _ext(hdul, "PROFILES", path)
        h = tab.header
        inst = _read_instrument(hdul, h, path, "PROFILES")
        lo = _col_in(tab.data, "BIN_LO", path, "PROFILES", u.deg)
        hi = _col_in(tab.data, "BIN_HI", path, "PROFILES", u.deg)
        if lo.size == 0:
            raise RotmodError(f"file {str(path)!r}: PROFILES table has no rows (no bins)")
        if lo.size > 1 and not np.array_equal(lo[1:], hi[:-1]):
            raise RotmodError(f"file {str(path)!r}: PROFILES bins are not contiguous "
                              "(BIN_LO of each row must equal BIN_HI of the row before)")
        if "NBINS" in h and _num(h, "NBINS", path, "PROFILES") != lo.size:
            raise RotmodError(f"file {str(path)!r}: PROFILES keyword NBINS = {h['NBINS']!r} "
                              f"must equal the number of rows ({lo.size})")
        counts = np.atleast_2d(_col(tab.data, "COUNTS", path, "PROFILES").T)  # checked, not cast
        if counts.shape[1] != lo.size:
            counts = counts.reshape(-1, lo.size)
        ex = _col(tab.data, "EXPOSURE", path, "PROFILES").astype(float)
        ex = ex.T if ex.ndim == 2 else ex
        meta = _meta_from(h, path)
        try:
            tb = TimeBinning.from_edges(
                np.append(lo, hi[-1]) * u.deg, str(h.get("BINMODE", "center")),
                int(_num(h, "BINNSUB", path, "PROFILES")) if "BINNSUB" in h else 4,
            )
            # E_MIN/E_MAX of a folded file are the band of its counts: the typed band.
            lo_hi = {k: meta.pop(k) for k in ("e_min", "e_max") if k in meta}
            band = EnergyBand.from_dict(lo_hi) if len(lo_hi) == 2 else None
            return FoldedProfiles(
                counts, ex, tb, inst, _read_gti(hdul, path),
                _key_in(h, "ROT_PHA0", 0.0, u.deg, path) * u.deg, band, meta,
            )
        except RotmodError as exc:
            raise RotmodError(f"file {str(path)!r}: invalid folded profiles: {exc}") from exc

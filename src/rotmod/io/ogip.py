"""OGIP spectral files: a counts spectrum (PHA), its redistribution (RMF), effective area (ARF)
and background (PHA), as XSPEC, sherpa, threeML and gammapy read them.

:func:`write_ogip` writes a :class:`rotmod.spectral.CountsSpectrum` as four files beside each
other, the PHA naming the others in its ``RESPFILE``, ``ANCRFILE`` and ``BACKFILE`` cards::

    src.pha       SPECTRUM (CHANNEL, COUNTS, QUALITY, BACKSCAL), EBOUNDS  OGIP/92-007
                  or, for a RateSpectrum, (CHANNEL, RATE, STAT_ERR, QUALITY, BACKSCAL)
    src.rmf       MATRIX (ENERG_LO, ENERG_HI, N_GRP, F_CHAN, N_CHAN, MATRIX), EBOUNDS
                  CAL/GEN/92-002
    src.arf       SPECRESP (ENERG_LO, ENERG_HI, SPECRESP)  CAL/GEN/92-002
    src_bkg.pha   the background's SPECTRUM, when the spectrum has one

Conventions: channels are numbered from 0 (``TLMIN`` = 0, as gammapy assumes); the RMF is of
type ``REDIST`` (probabilities, the area in the ARF); counts are integers with Poisson errors
(``POISSERR = T``).  A :class:`rotmod.spectral.RateSpectrum` (a source's spectrum extracted by
a fit, :func:`rotmod.sources.spectra.extract_spectrum`) is written as Swift-BAT writes its
mask-weighted spectra: ``RATE`` and ``STAT_ERR`` (counts/s) with ``POISSERR = F``
(``HDUCLAS3 = RATE``), and no background file (the fit has removed the background); a tool that
cannot honour ``STAT_ERR`` then fails to read it rather than fitting Poisson statistics to it.
``BACKSCAL`` and ``QUALITY`` are columns as well as the usual cards,
because gammapy reads them as columns.  Every file carries rotmod's provenance cards and
checksums; all four are written atomically together (either all appear or none).
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path
from typing import Any

import numpy as np
from astropy.io import fits

from rotmod.errors import ParameterError
from rotmod.io._fits import open_verified
from rotmod.io.atomic import atomic_path, check_file_target, check_overwrite
from rotmod.io.images import add_meta_cards, stamp_header
from rotmod.spectral.spectrum import CountsSpectrum, RateSpectrum, SpectralResponse

__all__ = ["ogip_paths", "poisson_errors", "read_ogip", "write_ogip"]

#: Cards every OGIP spectral extension carries.
_MISSION = {"TELESCOP": "ROTMOD", "INSTRUME": "RM", "FILTER": "NONE"}


def ogip_paths(path: str | os.PathLike) -> dict[str, Path]:
    """The files :func:`write_ogip` writes for the PHA file ``path`` (``.pha`` or ``.pi``):
    ``{"pha", "rmf", "arf", "bkg"}``."""
    p = Path(path)
    if p.suffix.lower() not in (".pha", ".pi"):
        raise ParameterError(f"path must end in .pha or .pi (an OGIP spectrum), got {str(p)!r}")
    stem = p.with_suffix("")
    return {"pha": p, "rmf": stem.with_suffix(".rmf"), "arf": stem.with_suffix(".arf"),
            "bkg": stem.parent / f"{stem.name}_bkg{p.suffix}"}


def _ebounds(resp: SpectralResponse) -> fits.BinTableHDU:
    ce = resp.channel_edges
    cols = [
        fits.Column("CHANNEL", "J", array=np.arange(ce.size - 1)),
        fits.Column("E_MIN", "E", unit="keV", array=ce[:-1]),
        fits.Column("E_MAX", "E", unit="keV", array=ce[1:]),
    ]
    hdu = fits.BinTableHDU.from_columns(cols, name="EBOUNDS")
    h = hdu.header
    h["TLMIN1"], h["TLMAX1"] = 0, ce.size - 2
    _cards(h, "RESPONSE", "EBOUNDS", "1.2.0", detchans=ce.size - 1)
    return hdu


def _cards(h: fits.Header, clas1: str, clas2: str, vers: str, *, detchans: int) -> None:
    for k, v in _MISSION.items():
        h[k] = v
    h["HDUCLASS"] = ("OGIP", "format conforms to OGIP standard")
    h["HDUCLAS1"] = clas1
    h["HDUCLAS2"] = clas2
    h["HDUVERS"] = vers
    h["CHANTYPE"] = ("PI", "channels are calibrated energies")
    h["DETCHANS"] = (detchans, "number of channels")


def _spectrum_hdu(spec: CountsSpectrum | RateSpectrum, clas2: str, files: dict[str, str]
                  ) -> fits.BinTableHDU:
    poisson = isinstance(spec, CountsSpectrum)
    backscal = spec.backscal if poisson else 1.0
    n = spec.counts.size if poisson else spec.rate.size
    values = [fits.Column("COUNTS", "J", unit="count", array=spec.counts)] if poisson else [
        fits.Column("RATE", "D", unit="count/s", array=spec.rate),
        fits.Column("STAT_ERR", "D", unit="count/s", array=spec.error)]
    cols = [
        fits.Column("CHANNEL", "J", array=np.arange(n)),
        *values,
        fits.Column("QUALITY", "I", array=np.zeros(n, dtype=np.int16)),
        fits.Column("BACKSCAL", "D", array=np.full(n, backscal)),
    ]
    hdu = fits.BinTableHDU.from_columns(cols, name="SPECTRUM")
    h = hdu.header
    h["TLMIN1"], h["TLMAX1"] = 0, n - 1
    _cards(h, "SPECTRUM", clas2, "1.2.1", detchans=n)
    h["HDUCLAS3"] = "COUNT" if poisson else "RATE"
    h["EXPOSURE"] = (spec.exposure, "[s] live time")
    h["AREASCAL"] = 1.0
    h["BACKSCAL"] = (backscal, "background scaling (also a column)")
    h["CORRSCAL"] = 0.0
    h["POISSERR"] = (True, "Poisson errors") if poisson else (
        False, "errors in STAT_ERR (fitted, not Poisson)")
    h["SYS_ERR"] = 0.0
    h["GROUPING"] = 0
    for key in ("RESPFILE", "ANCRFILE", "BACKFILE", "CORRFILE"):
        h[key] = files.get(key, "none")
    h["OBS_ID"] = str(spec.meta.get("OBS_ID", spec.meta.get("OBJECT", "rotmod")))
    add_meta_cards(h, {k: v for k, v in spec.meta.items() if k != "OBS_ID"})
    return hdu


def write_ogip(
    spectrum: CountsSpectrum | RateSpectrum, path: str | os.PathLike, *, overwrite: bool = False,
    seed: Any = None, command: Any = None,
) -> Path:
    """Write ``spectrum`` as OGIP files: ``path`` (PHA) with its RMF, ARF and background PHA
    beside it (:func:`ogip_paths`).

    Parameters
    ----------
    spectrum : CountsSpectrum or RateSpectrum
        With a response (the RMF and ARF come from it).  A RateSpectrum is written as
        ``RATE`` and ``STAT_ERR`` with ``POISSERR = F``.
    path : str or path-like
        The PHA file (``.pha`` or ``.pi``).
    overwrite : bool
        Replace existing files (default: refuse if any of the files exists).
    seed, command
        Provenance cards.

    Returns
    -------
    pathlib.Path
        The PHA file.

    Raises
    ------
    ParameterError
        Before anything is written: no response, another extension, an existing file without
        ``overwrite``, a folder in the way or a missing folder, counts above ``2^31 - 1`` (the
        32-bit ``COUNTS`` column).
    """
    if not isinstance(spectrum, CountsSpectrum | RateSpectrum):
        raise ParameterError("spectrum must be a CountsSpectrum or a RateSpectrum, got "
                             f"{type(spectrum).__name__}")
    if spectrum.response is None:
        raise ParameterError("spectrum has no response: an OGIP spectrum needs its RMF and ARF")
    paths = ogip_paths(path)
    if not isinstance(spectrum, CountsSpectrum) or spectrum.background is None:
        paths.pop("bkg")
    for key, p in paths.items():
        what = f"the {key.upper()} file" if key != "pha" else "path"
        check_overwrite(p, overwrite, parameter=what)
        check_file_target(p, parameter=what)  # all four or none: no rename may fail late
    counted = [spectrum] if isinstance(spectrum, CountsSpectrum) else []
    if counted and spectrum.background is not None:
        counted.append(spectrum.background)
    for s in counted:
        if s.counts.size and s.counts.max() > np.iinfo(np.int32).max:
            raise ParameterError(
                f"spectrum: counts must be at most {np.iinfo(np.int32).max} per channel to be "
                f"written as OGIP COUNTS (32-bit integers), got {s.counts.max()}")
    resp = spectrum.response
    files = {"RESPFILE": paths["rmf"].name, "ANCRFILE": paths["arf"].name}
    if "bkg" in paths:
        files["BACKFILE"] = paths["bkg"].name

    def primary() -> fits.PrimaryHDU:
        hdu = fits.PrimaryHDU()
        stamp_header(hdu.header, seed=seed, command=command)
        return hdu

    ee = resp.energy_edges
    rows = []
    for r in resp.matrix:
        nz = np.flatnonzero(r)
        rows.append((nz[0], nz[-1] + 1) if nz.size else (0, 0))
    n_grp = np.array([1 if b > a else 0 for a, b in rows], dtype=np.int16)
    # F_CHAN and N_CHAN as variable-length arrays (one group per row, none for an empty row):
    # readers index them per group, and a repeat count of 1 would read back as a scalar.
    f_chan = np.empty(len(rows), dtype=object)
    n_chan = np.empty(len(rows), dtype=object)
    for i, (a, b) in enumerate(rows):
        f_chan[i] = np.array([a] if b > a else [], dtype=np.int32)
        n_chan[i] = np.array([b - a] if b > a else [], dtype=np.int32)
    matrix = np.empty(len(rows), dtype=object)
    for i, (a, b) in enumerate(rows):
        matrix[i] = resp.matrix[i, a:b].astype(np.float32)
    mat = fits.BinTableHDU.from_columns([
        fits.Column("ENERG_LO", "E", unit="keV", array=ee[:-1]),
        fits.Column("ENERG_HI", "E", unit="keV", array=ee[1:]),
        fits.Column("N_GRP", "I", array=n_grp),
        fits.Column("F_CHAN", "PJ()", array=f_chan),
        fits.Column("N_CHAN", "PJ()", array=n_chan),
        fits.Column("MATRIX", "PE()", array=matrix),
    ], name="MATRIX")
    _cards(mat.header, "RESPONSE", "RSP_MATRIX", "1.3.0", detchans=resp.n_channels)
    mat.header["HDUCLAS3"] = ("REDIST", "probabilities; the area is in the ARF")
    mat.header["TLMIN4"] = (0, "first channel")
    mat.header["LO_THRES"] = (0.0, "matrix values below are dropped")
    arf = fits.BinTableHDU.from_columns([
        fits.Column("ENERG_LO", "E", unit="keV", array=ee[:-1]),
        fits.Column("ENERG_HI", "E", unit="keV", array=ee[1:]),
        fits.Column("SPECRESP", "E", unit="cm2", array=resp.area),
    ], name="SPECRESP")
    _cards(arf.header, "RESPONSE", "SPECRESP", "1.1.0", detchans=resp.n_channels)
    content = {
        "pha": [primary(), _spectrum_hdu(spectrum, "TOTAL", files), _ebounds(resp)],
        "rmf": [primary(), mat, _ebounds(resp)],
        "arf": [primary(), arf],
    }
    if "bkg" in paths:
        content["bkg"] = [primary(), _spectrum_hdu(spectrum.background, "BKG", {}),
                          _ebounds(resp)]
    # All files are written to temporary names first and renamed together at the end.
    with contextlib.ExitStack() as stack:
        for key, hdus in content.items():
            tmp = stack.enter_context(atomic_path(paths[key]))
            fits.HDUList(hdus).writeto(tmp, overwrite=True, checksum=True)
    return paths["pha"]


def _number(header: fits.Header, key: str, path: Path, default: Any = None) -> float:
    """The numeric card ``key`` (``default`` when absent), or a ParameterError naming the file."""
    value = header.get(key, default)
    if value is None:
        raise ParameterError(f"file {str(path)!r}: the header has no {key}")
    if isinstance(value, bool) or not isinstance(value, int | float | np.number):
        raise ParameterError(f"file {str(path)!r}: {key} must be a number, got {value!r}")
    return float(value)


def _column(data: Any, name: str, path: Path, ext: str, *, kind: str = "number") -> np.ndarray:
    """Column ``name`` of extension ``ext``: one number per row (``kind="integer"``: whole
    numbers), or a ParameterError naming the file, extension and column."""
    if name not in data.columns.names:
        raise ParameterError(f"file {str(path)!r}: the {ext} extension has no {name} column")
    values = np.asarray(data[name])
    if values.dtype.kind not in "iuf" or values.ndim != 1:
        raise ParameterError(f"file {str(path)!r}: {ext} column {name} must hold one number "
                             f"per row, got {values.dtype} of shape {values.shape}")
    if kind == "integer" and not np.all(np.isfinite(values) & (values == np.round(values))):
        raise ParameterError(f"file {str(path)!r}: {ext} column {name} must hold integers")
    return values


def poisson_errors(header: fits.Header, columns: Any) -> bool:
    """Whether a SPECTRUM extension's errors are Poisson: its ``POISSERR`` card, or without
    one, the absence of ``STAT_ERR`` (as a column among ``columns`` or a card)."""
    return bool(header.get("POISSERR", "STAT_ERR" not in columns and "STAT_ERR" not in header))


def _spectrum_from(hdul: fits.HDUList, path: Path
                   ) -> tuple[np.ndarray, np.ndarray | None, float, float, Any]:
    """Values, errors, exposure, backscal and header of a type I spectrum: Poisson ``COUNTS``
    (errors None), or with ``POISSERR = F`` rates and their ``STAT_ERR`` (counts/s; a
    ``COUNTS`` column is divided by the exposure).  What rotmod cannot honour (per-channel
    scaling, bad-quality channels, grouping, systematic errors, Gaussian data without
    errors, Poisson rates) is refused by name rather than dropped."""
    if "SPECTRUM" not in hdul:
        raise ParameterError(f"file {str(path)!r} has no SPECTRUM extension (not an OGIP PHA)")
    h = hdul["SPECTRUM"].header
    d = hdul["SPECTRUM"].data
    names = d.columns.names
    value = next((c for c in ("COUNTS", "RATE") if c in names), None)
    if value is None:
        raise ParameterError(f"file {str(path)!r}: the SPECTRUM has neither a COUNTS nor a "
                             "RATE column (a type II spectrum?)")
    if "EXPOSURE" not in h:
        raise ParameterError(f"file {str(path)!r}: the SPECTRUM header has no EXPOSURE")
    exposure = _number(h, "EXPOSURE", path)
    if len(d) == 0:
        raise ParameterError(f"file {str(path)!r}: the SPECTRUM has no channels (no rows)")
    if not isinstance(h.get("POISSERR", False), bool):
        raise ParameterError(f"file {str(path)!r}: POISSERR must be T or F, got "
                             f"{h['POISSERR']!r}")
    poisson = poisson_errors(h, names)
    if poisson and value == "RATE":
        raise ParameterError(f"file {str(path)!r}: a RATE spectrum with Poisson errors "
                             "(POISSERR = T); rotmod reads Poisson spectra as COUNTS")
    errors = None
    if not poisson:
        if "STAT_ERR" in names:
            errors = _column(d, "STAT_ERR", path, "SPECTRUM").astype(float)
        elif "STAT_ERR" in h:
            errors = np.full(len(d), _number(h, "STAT_ERR", path))
        if errors is None or not np.all(np.isfinite(errors) & (errors > 0)):
            raise ParameterError(f"file {str(path)!r}: POISSERR = F needs errors > 0 in "
                                 "STAT_ERR for every channel")
    sys_err = (_column(d, "SYS_ERR", path, "SPECTRUM") if "SYS_ERR" in names
               else np.array([_number(h, "SYS_ERR", path, 0.0)]))
    if np.any(sys_err != 0):
        raise ParameterError(f"file {str(path)!r}: systematic errors (SYS_ERR != 0), which "
                             "rotmod's fits do not add")
    scal = {}
    for key in ("BACKSCAL", "AREASCAL"):
        v = (_column(d, key, path, "SPECTRUM").astype(float) if key in names
             else np.array([_number(h, key, path, 1.0)]))
        if not np.all(v == v[0]):
            raise ParameterError(f"file {str(path)!r}: {key} differs between channels, which "
                                 "rotmod does not model")
        scal[key] = float(v[0])
    if scal["AREASCAL"] != 1.0:
        raise ParameterError(f"file {str(path)!r}: AREASCAL = {scal['AREASCAL']:g}; rotmod "
                             "reads unscaled spectra only")
    for key in ("QUALITY", "GROUPING"):
        v = np.asarray(d[key]) if key in names else np.array([h.get(key, 0)])
        if key == "QUALITY" and np.any(v != 0):
            raise ParameterError(f"file {str(path)!r}: channels flagged bad (QUALITY != 0); "
                                 "select the good channels in the fit instead")
        if key == "GROUPING" and np.any((v != 0) & (v != 1)):
            raise ParameterError(f"file {str(path)!r}: grouped channels (GROUPING); rotmod "
                                 "fits channels one by one")
    # Counts are whole numbers (an integer column, or a float one holding integers).
    values = _column(d, value, path, "SPECTRUM",
                     kind="integer" if value == "COUNTS" and errors is None else "number")
    if errors is not None and value == "COUNTS":
        values, errors = values / exposure, errors / exposure
    return values, errors, exposure, scal["BACKSCAL"], h


def read_ogip(path: str | os.PathLike) -> CountsSpectrum | RateSpectrum:
    """Read a PHA file and the RMF, ARF and background its cards name (in its folder).

    Returns
    -------
    CountsSpectrum or RateSpectrum
        Poisson counts (``POISSERR = T``), or rates with Gaussian errors (``POISSERR = F``
        and ``STAT_ERR``).

    Raises
    ------
    RotmodError
        A missing, unreadable or corrupt file.
    ParameterError
        A file that is not an OGIP spectrum rotmod can read (type I; COUNTS, or RATE or
        COUNTS with STAT_ERR), or asks for what rotmod cannot honour.
    """
    p = Path(path)
    with open_verified(p) as hdul:
        counts, errors, exposure, backscal, h = _spectrum_from(hdul, p)
        names = {k: str(h.get(k, "none")).strip() for k in ("RESPFILE", "ANCRFILE", "BACKFILE")}
        meta = {k: h[k] for k in ("TELESCOP", "INSTRUME", "OBS_ID", "OBJECT") if k in h}
    resp = None
    if names["RESPFILE"].lower() != "none" and names["ANCRFILE"].lower() != "none":
        rmf_path = p.parent / names["RESPFILE"]
        with open_verified(rmf_path) as rmf:
            # MATRIX (a redistribution) or SPECRESP MATRIX (the OGIP name of a full one).
            ext = next((e for e in ("MATRIX", "SPECRESP MATRIX") if e in rmf), None)
            if ext is None or "EBOUNDS" not in rmf:
                raise ParameterError(f"file {str(rmf_path)!r} has no MATRIX (or SPECRESP "
                                     "MATRIX) and EBOUNDS extensions (not an OGIP RMF)")
            m = rmf[ext].data
            eb = rmf["EBOUNDS"].data
            if len(m) == 0 or len(eb) == 0:
                raise ParameterError(f"file {str(rmf_path)!r}: the {ext} and EBOUNDS "
                                     "extensions must have rows")
            for col in ("ENERG_LO", "ENERG_HI", "N_GRP", "F_CHAN", "N_CHAN", "MATRIX"):
                if col not in m.columns.names:
                    raise ParameterError(f"file {str(rmf_path)!r}: the {ext} extension has no "
                                         f"{col} column")
            # The channels are EBOUNDS' rows; DETCHANS, when given, must say the same.
            n_c = len(eb)
            detchans = _number(rmf[ext].header, "DETCHANS", rmf_path, n_c)
            if detchans != n_c:
                raise ParameterError(f"file {str(rmf_path)!r}: DETCHANS = {detchans:g} but "
                                     f"EBOUNDS has {n_c} channels")
            # The first channel number: TLMIN of the F_CHAN column (OGIP's default 1).
            col = m.columns.names.index("F_CHAN") + 1
            first = int(_number(rmf[ext].header, f"TLMIN{col}", rmf_path, 1))
            matrix = np.zeros((len(m), n_c))
            n_grp = _column(m, "N_GRP", rmf_path, ext, kind="integer")
            for i, row in enumerate(m):
                start = 0
                f = np.atleast_1d(row["F_CHAN"])
                nch = np.atleast_1d(row["N_CHAN"])
                values = np.atleast_1d(row["MATRIX"])
                if not 0 <= n_grp[i] <= min(f.size, nch.size):
                    raise ParameterError(f"file {str(rmf_path)!r}: row {i} has N_GRP = "
                                         f"{n_grp[i]:g} but {min(f.size, nch.size)} groups in "
                                         "F_CHAN and N_CHAN")
                for k in range(int(n_grp[i])):
                    a, n = int(f[k]) - first, int(nch[k])
                    if a < 0 or n < 0 or a + n > n_c or start + n > values.size:
                        raise ParameterError(
                            f"file {str(rmf_path)!r}: row {i} puts channels {a + first}.."
                            f"{a + first + n - 1} outside the {n_c} channels from {first} "
                            f"(or beyond its {values.size} MATRIX values)")
                    matrix[i, a:a + n] = values[start:start + n]
                    start += n
            energy_edges = np.append(_column(m, "ENERG_LO", rmf_path, ext),
                                     m["ENERG_HI"][-1]).astype(float)
            channel_edges = np.append(_column(eb, "E_MIN", rmf_path, "EBOUNDS"),
                                      _column(eb, "E_MAX", rmf_path, "EBOUNDS")[-1]
                                      ).astype(float)
        arf_path = p.parent / names["ANCRFILE"]
        with open_verified(arf_path) as arf:
            if "SPECRESP" not in arf or arf["SPECRESP"].data is None or len(
                    arf["SPECRESP"].data) == 0:
                raise ParameterError(f"file {str(arf_path)!r} has no SPECRESP extension with "
                                     "rows (not an OGIP ARF)")
            a_data = arf["SPECRESP"].data
            area = _column(a_data, "SPECRESP", arf_path, "SPECRESP").astype(float)
            a_edges = np.append(_column(a_data, "ENERG_LO", arf_path, "SPECRESP"),
                                _column(a_data, "ENERG_HI", arf_path, "SPECRESP")[-1]
                                ).astype(float)
        if a_edges.shape != energy_edges.shape or not np.allclose(a_edges, energy_edges,
                                                                   rtol=1e-6):
            raise ParameterError(f"files {names['ANCRFILE']!r} and {names['RESPFILE']!r} "
                                 "have different true-energy grids")
        resp = _named(p, SpectralResponse, energy_edges, channel_edges, matrix, area)
    background = None
    if names["BACKFILE"].lower() != "none":
        if errors is not None:
            raise ParameterError(f"file {str(p)!r}: a background file ({names['BACKFILE']!r}) "
                                 "with Gaussian rates; rotmod fits rates with the background "
                                 "already removed")
        bp = p.parent / names["BACKFILE"]
        with open_verified(bp) as bkg:
            b_counts, b_errors, b_exp, b_scal, _ = _spectrum_from(bkg, bp)
        if b_errors is not None:
            raise ParameterError(f"file {str(bp)!r}: a background must be Poisson counts")
        background = _named(bp, CountsSpectrum, b_counts, b_exp, backscal=b_scal)
    if errors is not None:
        return _named(p, RateSpectrum, counts, errors, exposure, resp, meta)
    return _named(p, CountsSpectrum, counts, exposure, resp, background, backscal, meta)


def _named(path: Path, cls: Any, *args: Any, **kwargs: Any) -> Any:
    """``cls(*args, **kwargs)``, its ParameterError said with the file it was read from."""
    try:
        return cls(*args, **kwargs)
    except ParameterError as exc:
        raise ParameterError(f"file {str(path)!r}: {exc}") from exc

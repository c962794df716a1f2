"""Opening FITS files with their integrity checked.

rotmod writes ``CHECKSUM``/``DATASUM`` on every HDU; reading verifies them, so a flipped bit
in a file rotmod wrote (a changed good-time interval, a changed count) is an error naming the
file and the HDU, never silently different numbers.  Files without checksums (from elsewhere)
are read as they are.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path
from urllib.parse import quote

from astropy.io import fits

from rotmod.errors import RotmodError

__all__ = ["header_text", "open_verified"]


def header_text(value: str) -> str:
    """``value`` made safe for a FITS header: printable ASCII, reversibly.

    FITS header values are printable ASCII; a path such as ``ré.zarr`` is written
    percent-encoded (``r%C3%A9.zarr``, :func:`urllib.parse.unquote` gives it back).  Long
    values are left whole: astropy writes them with CONTINUE cards.
    """
    if all(" " <= ch <= "~" for ch in value):
        return value
    return quote(value, safe="".join(chr(c) for c in range(32, 127) if chr(c) != "%"))


def open_verified(path: str | os.PathLike) -> fits.HDUList:
    """Open ``path``, read every HDU and verify structure and checksums.

    Raises
    ------
    RotmodError
        Missing file, not FITS, a file cut short, or a CHECKSUM/DATASUM that does not match
        the content.
    """
    p = Path(path)
    if not p.is_file():
        raise RotmodError(f"file {str(p)!r} does not exist")
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            hdul = fits.open(p, memmap=False, checksum=True)
            hdul.readall()
        hdul.verify("exception")
    except (OSError, fits.VerifyError, ValueError, TypeError) as exc:
        raise RotmodError(f"file {str(p)!r} is not a readable FITS file: {exc}") from exc
    cut = [str(w.message).strip() for w in caught
           if any(k in str(w.message) for k in ("file is corrupted", "may have been truncated"))]
    if cut:  # astropy read what was there of a cut file, and warned
        hdul.close()
        raise RotmodError(f"file {str(p)!r} is truncated or corrupt: "
                          f"{' '.join(cut[0].split())}")
    bad = [str(w.message).strip() for w in caught if "verification failed" in str(w.message)]
    if bad:
        hdul.close()
        raise RotmodError(
            f"file {str(p)!r} is corrupt: {bad[0]} (the content no longer matches the "
            "checksum written with it; regenerate the file)"
        )
    for w in caught:  # anything else astropy had to say, said again
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return hdul

"""Regenerate rotmod's attenuation data file from the fisx package (run once, by hand).

rotmod ships the NIST XCOM photon cross sections and the element data it needs as
``src/rotmod/materials/xcom.npz`` so that installing rotmod needs no compiler (fisx, the
package that distributes these tables, is a C++ extension published only as source).  This
script is how that file was made and how to remake it::

    pip install fisx==1.3.2
    python scripts/extract_xcom.py          # writes src/rotmod/materials/xcom.npz

It reads fisx's ``fisx_data/XCOM_CrossSections.dat`` (NIST XCOM, public-domain data; fisx is
MIT-licensed) and fisx's element database (``Elements().initializeAsPyMca()``: symbols,
atomic numbers, atomic masses, default densities), keeps the columns rotmod uses and every
row, and stores them as float64 exactly as parsed, so rotmod's coefficients are unchanged to
the bit.  Only the elements with an XCOM table (H to Fm, Z = 1-100) are kept.

Arrays in the file:

``symbol``, ``z``, ``atomic_mass`` (g/mol), ``density`` (g/cm^3, fisx's default)
    one entry per element, in order of Z.
``table`` (n_rows, 5)
    all elements' XCOM rows stacked: energy (keV), coherent, incoherent, photoelectric and
    pair-production cross sections (cm^2/g); rows of element ``k`` are
    ``table[offset[k]:offset[k + 1]]``, in increasing energy (an absorption edge is a
    repeated energy).
``offset`` (n_elements + 1,)
``provenance``
    a JSON string: source, fisx version, date, columns.
"""

from __future__ import annotations

import argparse
import datetime
import json
from pathlib import Path

import numpy as np

OUT = Path(__file__).resolve().parents[1] / "src" / "rotmod" / "materials" / "xcom.npz"

#: XCOM file columns: E, coherent, incoherent, coh+incoh, photo, pair, total.  The sums are
#: not stored: rotmod interpolates the partial cross sections and adds them itself.
_KEEP = [0, 1, 2, 4, 5]
_COLUMNS = ["energy_keV", "coherent_cm2_g", "incoherent_cm2_g", "photoelectric_cm2_g",
            "pair_cm2_g"]


def read_xcom(path: Path) -> dict[str, np.ndarray]:
    """Per element symbol (``#S n Sym`` scan headers), the rows of the XCOM file, as rotmod
    parsed them when it read the file at run time (``float`` of each printed value)."""
    tables: dict[str, list[list[float]]] = {}
    symbol = None
    for line in path.read_text().splitlines():
        if line.startswith("#S"):
            symbol = line.split()[2]
            tables[symbol] = []
        elif symbol is not None and line and not line.startswith("#"):
            tables[symbol].append([float(v) for v in line.split()])
    return {k: np.asarray(v)[:, _KEEP] for k, v in tables.items()}


def extract() -> dict[str, np.ndarray]:
    """The arrays of ``xcom.npz``, from the installed fisx."""
    import fisx
    from fisx import DataDir, Elements

    db = Elements()
    db.initializeAsPyMca()
    xcom = read_xcom(Path(DataDir.FISX_DATA_DIR) / "XCOM_CrossSections.dat")
    symbols = list(xcom)
    # The XCOM scans must be fisx's elements in order of Z (fisx pairs them by position).
    names = db.getElementNames()
    if symbols != names[: len(symbols)]:
        raise RuntimeError("XCOM scans are not fisx's elements in order of Z")
    z = np.array([db.getAtomicNumber(s) for s in symbols], dtype=np.int64)
    if not np.array_equal(z, np.arange(1, len(symbols) + 1)):
        raise RuntimeError("XCOM scans do not run Z = 1, 2, ...")
    offset = np.cumsum([0] + [len(xcom[s]) for s in symbols]).astype(np.int64)
    provenance = {
        "source": "NIST XCOM photon cross sections (M.J. Berger, J.H. Hubbell et al., "
                  "https://www.nist.gov/pml/xcom-photon-cross-sections-database; public-domain "
                  "data), as distributed in fisx_data/XCOM_CrossSections.dat",
        "elements": "symbols, atomic numbers, atomic masses and default densities of fisx's "
                    "element database (Elements().initializeAsPyMca())",
        "fisx_version": fisx.version(),
        "fisx_license": "MIT",
        "created": datetime.date.today().isoformat(),
        "script": "scripts/extract_xcom.py",
        "columns": _COLUMNS,
    }
    return {
        "symbol": np.array(symbols),
        "z": z,
        "atomic_mass": np.array([db.getAtomicMass(s) for s in symbols], dtype=np.float64),
        "density": np.array([db.getDensity(s) for s in symbols], dtype=np.float64),
        "table": np.concatenate([xcom[s] for s in symbols]),
        "offset": offset,
        "provenance": np.array(json.dumps(provenance)),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=OUT, help=f"output file (default {OUT})")
    args = parser.parse_args()
    np.savez_compressed(args.out, **extract())
    print(f"wrote {args.out} ({args.out.stat().st_size / 1024:.0f} KiB)")


if __name__ == "__main__":
    main()

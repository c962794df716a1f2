"""Every FITS product passes HEASARC's fitsverify with no warning and no error."""

from __future__ import annotations

import re
import shutil
import subprocess

import pytest

from tests.io.conftest import write_products

FITSVERIFY = shutil.which("fitsverify")
pytestmark = pytest.mark.skipif(FITSVERIFY is None,
                                reason="fitsverify not installed (apt-get install fitsverify)")

KINDS = ("events", "pointed events", "folded", "instrument image", "celestial image",
         "healpix image", "catalogue", "instrument catalogue", "instrument TS map",
         "celestial TS map", "healpix TS map", "probability map", "light curve",
         "OGIP spectrum", "OGIP background", "OGIP RMF", "OGIP ARF", "OGIP rate spectrum")


def _verify(path) -> tuple[int, int, str]:
    out = subprocess.run([FITSVERIFY, str(path)], capture_output=True, text=True,
                         timeout=60).stdout
    found = re.search(r"Verification found (\d+) warning\(s\) and (\d+) error\(s\)", out)
    assert found, out
    return int(found[1]), int(found[2]), out


@pytest.mark.parametrize("kind", KINDS)
def test_every_product_passes_fitsverify(products, kind) -> None:
    warnings, errors, out = _verify(products[kind])
    assert (warnings, errors) == (0, 0), out


def test_products_without_provenance_arguments_pass_fitsverify(tmp_path) -> None:
    for kind, path in write_products(tmp_path).items():
        warnings, errors, out = _verify(path)
        assert (warnings, errors) == (0, 0), f"{kind}: {out}"

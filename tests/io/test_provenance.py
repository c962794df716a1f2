"""Provenance cards: every product says what wrote it, when, from which commit, with which
seed and command; one function builds them."""

from __future__ import annotations

import datetime

import numpy as np
import pytest
from astropy.io import fits

import rotmod
from rotmod.errors import ParameterError
from rotmod.io.provenance import creator, git_commit, provenance_cards, seed_value
from rotmod.paper import provenance as paper_provenance
from tests.io.conftest import COMMAND, SEED

#: The HDU of each product kind whose header carries the data's description.
MAIN_HDU = {"events": "EVENTS", "pointed events": "EVENTS", "folded": "PROFILES",
            "instrument image": 0, "celestial image": 0, "healpix image": 0,
            "catalogue": "CATALOG", "instrument catalogue": "CATALOG",
            "instrument TS map": 0, "celestial TS map": 0, "healpix TS map": 0,
            "probability map": "PROBMAP", "light curve": "LIGHTCURVE"}


@pytest.mark.parametrize("kind", sorted(MAIN_HDU))
def test_every_product_carries_its_provenance(products, kind) -> None:
    path = products[kind]
    for hdu in {0, MAIN_HDU[kind]}:  # the primary header too: where tools look first
        h = fits.getheader(path, hdu)
        assert h["CREATOR"] == f"rotmod {rotmod.__version__}"
        written = datetime.datetime.fromisoformat(h["DATE"])
        assert abs(datetime.datetime.now(datetime.UTC).replace(tzinfo=None) - written) < (
            datetime.timedelta(hours=1))
        assert h["TELESCOP"] and h["INSTRUME"]
        assert h["SEED"] == SEED and isinstance(h["SEED"], int)
        assert h["COMMAND"] == " ".join(COMMAND)  # whole, on CONTINUE cards
        assert h["LONGSTRN"] == "OGIP 1.0"
        commit = git_commit()
        assert h.get("RMCOMMIT") == commit


def test_images_name_rotmod_as_telescope_unless_told(products) -> None:
    h = fits.getheader(products["instrument image"])
    assert (h["TELESCOP"], h["INSTRUME"]) == ("rotmod", "rotmod")
    # Event files keep the names in their metadata (an EventList's defaults).
    h = fits.getheader(products["events"], "EVENTS")
    assert (h["TELESCOP"], h["INSTRUME"]) == ("ROTMOD", "RM")


def test_seed_is_one_integer() -> None:
    assert seed_value(None) is None
    assert seed_value(42) == 42 and seed_value(np.int64(7)) == 7
    ss = np.random.SeedSequence()  # 128 bits of entropy: more than a FITS integer holds
    assert seed_value(ss) == str(ss.entropy) and "\n" not in seed_value(ss)
    assert seed_value(np.random.SeedSequence(5)) == 5
    assert seed_value(np.random.default_rng(11)) == 11
    assert seed_value(np.random.SeedSequence([1, 2])) == "1 2"
    for bad in (1.5, "8", True):
        with pytest.raises(ParameterError, match="seed must be"):
            seed_value(bad)


def test_one_provenance_function() -> None:
    # The paper's record and the FITS cards name the same commit, through the same function.
    assert paper_provenance.git_commit is git_commit
    assert paper_provenance.provenance()["git_commit"] == git_commit()
    cards = {k: v for k, v, _ in provenance_cards(telescop="T", instrume="I", seed=3)}
    assert cards["CREATOR"] == creator() == f"rotmod {rotmod.__version__}"
    assert (cards["TELESCOP"], cards["INSTRUME"], cards["SEED"]) == ("T", "I", 3)
    assert "COMMAND" not in {k for k, _, _ in provenance_cards()}
    assert rotmod.__version__ and rotmod.__version__ != "0.0.0"


def test_a_long_version_string_keeps_every_card_whole(monkeypatch) -> None:
    # A development version from setuptools-scm is long; no card may be cut (astropy would
    # warn, and the warning is an error here).
    for version in ("0.1.1.dev165+g67c672565.d20261125", "9" * 70):
        monkeypatch.setattr(rotmod, "__version__", version)
        header = fits.Header()
        for key, value, comment in provenance_cards(command="x" * 100):
            header[key] = (value, comment)
        back = fits.Header.fromstring(header.tostring())
        assert back["CREATOR"] == f"rotmod {version}" and back["COMMAND"] == "x" * 100

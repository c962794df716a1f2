"""FITS event lists and folded profiles: round trips, keywords, refusal, bad files."""

from __future__ import annotations

import numpy as np
import pytest
from astropy.io import fits

import rotmod
from rotmod import Instrument, Mask, ParameterError, RotmodError
from rotmod.binning import EnergyBand, TimeBinning
from rotmod.events import fold
from rotmod.io import read_events, read_folded, write_events, write_folded
from rotmod.montecarlo import simulate_observation
from rotmod.sky import PointSources
from rotmod.testing import tiny_instrument
from tests.conftest import rad


@pytest.fixture(scope="module")
def events():
    inst = tiny_instrument(diameter=3.8, rotation_period=30.0)
    src = PointSources([6.0, 12.0], rad([0.3, 2.0]), rate=[40.0, 10.0], energy=662.0)
    return simulate_observation(inst, src, t_stop=100.0, gti=[[0, 40], [55.5, 97.0]],
                                start_phase=rad(0.4), background=2.0, seed=8)


def test_event_round_trip(events, tmp_path):
    p = write_events(events, tmp_path / "ev.fits")
    back = read_events(p)
    assert back.instrument == events.instrument
    for name in ("time", "detector", "energy", "source", "gti"):
        assert np.array_equal(getattr(back, name), getattr(events, name)), name
    # Angles are stored in deg: one deg <-> rad conversion each way (two roundings, 1e-15).
    assert back.start_phase.to_value("rad") == pytest.approx(events.start_phase.to_value("rad"),
                                                             rel=1e-15)
    assert (back.t_start, back.t_stop) == (events.t_start, events.t_stop)
    assert back.meta == events.meta
    np.testing.assert_allclose(back.sources.theta.to_value("rad"),
                               events.sources.theta.to_value("rad"), rtol=1e-15)
    h = fits.getheader(p, "EVENTS")
    assert h["HDUCLAS1"] == "EVENTS" and h["TIMEUNIT"] == "s"
    for key in ("TELESCOP", "INSTRUME", "TSTART", "TSTOP", "TIMESYS", "MJDREFI", "MJDREFF",
                "TIMEZERO", "EXPOSURE", "ONTIME", "MASK_A", "MASK_B", "MASK_H", "MASK_L",
                "DET_DIAM", "ROT_PER", "MASK_MAT"):
        assert key in h, key
    assert h["EXPOSURE"] == pytest.approx(events.exposure)
    assert fits.getheader(p, "GTI")["HDUCLAS1"] == "GTI"


def test_folded_round_trip(events, tmp_path):
    f = fold(events, 24)
    back = read_folded(write_folded(f, tmp_path / "f.fits"))
    assert back.instrument == f.instrument
    assert np.array_equal(back.counts, f.counts)
    assert np.array_equal(back.exposure, f.exposure)
    # Bin edges are stored in deg: one conversion each way, two roundings (1e-15 relative).
    np.testing.assert_allclose(back.bin_edges.to_value("rad"), f.bin_edges.to_value("rad"),
                               rtol=1e-15)
    assert back.start_phase.to_value("rad") == pytest.approx(f.start_phase.to_value("rad"),
                                                             rel=1e-15)


def test_folded_file_holds_the_binning_and_the_band(events, tmp_path):
    f = fold(events, TimeBinning(24, "average", 6), EnergyBand(600.0, 700.0))
    p = write_folded(f, tmp_path / "f.fits")
    back = read_folded(p)
    assert back.time_bins == f.time_bins and back.energy_band == f.energy_band
    h = fits.getheader(p, "PROFILES")
    assert (h["NBINS"], h["BINMODE"], h["BINNSUB"]) == (24, "average", 6)
    assert (h["E_MIN"], h["E_MAX"]) == (600.0, 700.0)
    # The edge columns stay for other tools: 15 deg bins.
    np.testing.assert_allclose(fits.getdata(p, "PROFILES")["BIN_HI"][:2], [15.0, 30.0])


def _as_old_file(src, dst, edit=None):
    """``src`` as the folding code before TimeBinning wrote it: no BINMODE/BINNSUB, the
    edges from linspace, E_MIN/E_MAX the only record of the band."""
    with fits.open(src) as h:
        tab = h["PROFILES"]
        del tab.header["BINMODE"], tab.header["BINNSUB"]
        n = tab.header["NBINS"]
        deg = np.degrees(np.linspace(0.0, 2 * np.pi, n + 1))
        tab.data["BIN_LO"], tab.data["BIN_HI"] = deg[:-1], deg[1:]
        if edit is not None:
            edit(tab)
        h.writeto(dst, checksum=True)
    return dst


def test_an_old_folded_file_reads(events, tmp_path):
    f = fold(events, 24, (600.0, 700.0))
    old = _as_old_file(write_folded(f, tmp_path / "f.fits"), tmp_path / "old.fits")
    back = read_folded(old)
    assert back.time_bins == TimeBinning(24) and back.energy_band == EnergyBand(600.0, 700.0)
    assert np.array_equal(back.counts, f.counts) and np.array_equal(back.exposure, f.exposure)


def test_folded_files_whose_bins_are_not_equal_bins_over_a_turn_are_refused(events, tmp_path):
    p = write_folded(fold(events, 4), tmp_path / "f.fits")

    def unequal(tab):
        tab.data["BIN_HI"][0] = tab.data["BIN_LO"][1] = 80.0

    def half_turn(tab):
        tab.data["BIN_LO"] /= 2
        tab.data["BIN_HI"] /= 2

    def nbins(tab):
        tab.header["NBINS"] = 5

    for edit, match in ((unequal, "must be 4 equal bins over a turn"),
                        (half_turn, "must be 4 equal bins over a turn"),
                        (nbins, "NBINS = 5 must equal the number of rows \\(4\\)")):
        bad = _as_old_file(p, tmp_path / f"{edit.__name__}.fits", edit)
        with pytest.raises(RotmodError, match=match):
            read_folded(bad)


def test_opaque_mask_round_trip(events, tmp_path):
    inst = Instrument(Mask(4.0, 4.0, 0.0, 100.0, mu=np.inf), events.instrument.detectors)
    ev = events.__class__(events.time, events.detector, events.energy, inst, events.gti)
    assert read_events(write_events(ev, tmp_path / "o.fits")).instrument == inst


def test_refuses_overwrite_and_writes_atomically(events, tmp_path):
    p = tmp_path / "ev.fits"
    write_events(events, p)
    with pytest.raises(ParameterError, match="exists; pass overwrite=True"):
        write_events(events, p)
    write_events(events, p, overwrite=True)
    assert sorted(x.name for x in tmp_path.iterdir()) == ["ev.fits"]  # no temporary left


def test_bad_files_raise_rotmod_error(events, tmp_path):
    with pytest.raises(RotmodError, match="does not exist"):
        read_events(tmp_path / "missing.fits")
    junk = tmp_path / "junk.fits"
    junk.write_text("not a fits file")
    with pytest.raises(RotmodError, match="not a readable FITS file"):
        read_events(junk)
    bare = tmp_path / "bare.fits"
    fits.HDUList([fits.PrimaryHDU()]).writeto(bare)
    with pytest.raises(RotmodError, match="no EVENTS extension"):
        read_events(bare)
    with pytest.raises(RotmodError, match="no PROFILES extension"):
        read_folded(bare)
    p = write_events(events, tmp_path / "ev.fits")
    with fits.open(p) as h:
        del h["EVENTS"].header["MASK_A"]
        h.writeto(tmp_path / "nokey.fits", checksum=True)  # a consistent file
    with pytest.raises(RotmodError, match="lacks keyword MASK_A"):
        read_events(tmp_path / "nokey.fits")


def test_units_in_fits_form_and_older_ogip_form_both_read(events, tmp_path):
    p = write_events(events, tmp_path / "ev.fits")
    assert fits.getheader(p, "SOURCES")["TUNIT3"] == "s-1"  # the FITS standard's form
    with fits.open(p) as h:  # as rotmod wrote it before: OGIP's "1/s"
        h["SOURCES"].columns.change_unit("RATE", "1/s")
        h.writeto(tmp_path / "old.fits", checksum=True)
    assert fits.getheader(tmp_path / "old.fits", "SOURCES")["TUNIT3"] == "1/s"
    for path in (p, tmp_path / "old.fits"):
        np.testing.assert_array_equal(read_events(path).sources.rate, events.sources.rate)


def test_creator_names_the_version_and_reads_back_as_rotmod(events, tmp_path):
    p = write_events(events, tmp_path / "ev.fits")
    assert fits.getheader(p, "EVENTS")["CREATOR"] == f"rotmod {rotmod.__version__}"
    assert read_events(p).meta["creator"] == "rotmod"  # the data's metadata: unchanged
    with fits.open(p) as h:  # another tool's file keeps its creator
        h["EVENTS"].header["CREATOR"] = "othertool 2.0"
        h.writeto(tmp_path / "other.fits", checksum=True)
    assert read_events(tmp_path / "other.fits").meta["creator"] == "othertool 2.0"

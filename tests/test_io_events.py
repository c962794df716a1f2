"""FITS event lists and folded profiles: round trips, keywords, refusal, bad files."""

from __future__ import annotations

import numpy as np
import pytest
from astropy.io import fits

from conftest import rad
from rotmod import DetectorArray, Instrument, Mask, Material, ParameterError, RotmodError
from rotmod.events import fold
from rotmod.io import read_events, read_folded, write_events, write_folded
from rotmod.montecarlo import simulate_observation
from rotmod.sky import PointSources


@pytest.fixture(scope="module")
def events():
    mat = Material("Pb", density=11.34, mass_attenuation=0.103)
    inst = Instrument(Mask(4.0, 4.0, 2.0, 100.0, mat), DetectorArray.hexagonal(3.8, rings=1), 30.0)
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

"""Hostile types (issue 25, class 4): a value that is not what its field claims is refused by
the reader or validator that owns the field, naming it and the rule, never truncated,
broadcast or passed on as a library's raw error."""

from __future__ import annotations

import astropy.units as u
import numpy as np
import pytest
from astropy.io import fits

from rotmod import Instrument
from rotmod._validate import as_integers
from rotmod.calibration import LabMeasurement, bins, fit_calibration
from rotmod.errors import ParameterError, RotmodError
from rotmod.events import EventList
from rotmod.io import read_events, read_folded
from rotmod.sky import AttitudeTable
from tests import test_hostile

#: The hostile tests' event list and folded profiles (one fixture, shared).
files = test_hostile.files


def _replace_column(src, dst, ext, name, fmt, values):
    with fits.open(src) as h:
        t = h[ext]
        cols = [fits.Column(name, fmt, array=values)]
        cols += [c for c in t.columns if c.name != name]
        h[ext] = fits.BinTableHDU.from_columns(cols, header=t.header, name=ext)
        h.writeto(dst, checksum=True)


def test_a_fractional_det_id_is_refused_not_truncated(files, tmp_path) -> None:
    ref = read_events(files / "ev.fits")
    n = ref.time.size
    ids = np.zeros(n)
    ids[1] = 0.7  # was read as detector 0
    _replace_column(files / "ev.fits", tmp_path / "bad.fits", "EVENTS", "DET_ID", "D", ids)
    with pytest.raises(RotmodError, match=r"'.*bad\.fits': invalid event list: events\."
                       r"detector must hold integers \(floats only when exactly integral\), "
                       r"got 0\.7"):
        read_events(tmp_path / "bad.fits")
    # Ids stored as floats that are exactly integral are the same ids.
    _replace_column(files / "ev.fits", tmp_path / "ok.fits", "EVENTS", "DET_ID", "D",
                    ref.detector.astype(float))
    np.testing.assert_array_equal(read_events(tmp_path / "ok.fits").detector, ref.detector)
    # The validator owns the rule: the Python API says the same.
    with pytest.raises(ParameterError, match=r"events\.detector must hold integers"):
        EventList(ref.time[:2], [0.0, 0.7], ref.energy[:2], ref.instrument, ref.gti)
    with pytest.raises(ParameterError, match=r"events\.detector must hold integers, got "
                       r"values of type bool"):
        EventList(ref.time[:2], [True, False], ref.energy[:2], ref.instrument, ref.gti)
    # Checked before the cast to int32, where 2^32 would wrap around to detector 0.
    with pytest.raises(ParameterError, match=r"must lie in 0\.\.0 .*got 4294967296"):
        EventList(ref.time[:2], np.array([0, 2**32]), ref.energy[:2], ref.instrument, ref.gti)


def test_a_fractional_detector_table_id_is_refused(files, tmp_path) -> None:
    _replace_column(files / "ev.fits", tmp_path / "d.fits", "DETECTORS", "DET_ID", "D", [0.5])
    with pytest.raises(RotmodError, match=r"'.*d\.fits': DETECTORS column DET_ID must hold "
                       r"integers .* got 0\.5"):
        read_events(tmp_path / "d.fits")


def test_non_integer_counts_are_refused(files, tmp_path) -> None:
    ref = read_folded(files / "f.fits")
    c = ref.counts.T.astype(float)  # rows are bins, one entry per detector
    c[3, 0] = 2.5
    _replace_column(files / "f.fits", tmp_path / "c.fits", "PROFILES", "COUNTS", "1D", c)
    with pytest.raises(RotmodError, match=r"invalid folded profiles: counts must hold integers "
                       r"\(floats only when exactly integral\), got 2\.5"):
        read_folded(tmp_path / "c.fits")
    c[3, 0] = 2.0  # integral floats: the same counts
    _replace_column(files / "f.fits", tmp_path / "i.fits", "PROFILES", "COUNTS", "1D", c)
    back = read_folded(tmp_path / "i.fits")
    assert back.counts[0, 3] == 2 and back.counts.dtype == np.int64
    c[3, 0] = -1.0
    _replace_column(files / "f.fits", tmp_path / "n.fits", "PROFILES", "COUNTS", "1D", c)
    with pytest.raises(RotmodError, match=r"counts must hold integers >= 0, got -1"):
        read_folded(tmp_path / "n.fits")


@pytest.mark.parametrize(
    ("value", "match"),
    [
        ([1.0, np.nan], "got nan"),
        ([1e30], "got 1e\\+30"),  # beyond int64: refused, not wrapped around
        (["1", "2"], "got values of type <U1"),
        ([0.5], "got 0.5"),
    ],
)
def test_as_integers_refuses_what_is_not_an_integer(value, match) -> None:
    with pytest.raises(ParameterError, match=f"x must hold integers.*{match}"):
        as_integers(value, "x")


def test_as_integers_keeps_integers_and_integral_floats() -> None:
    np.testing.assert_array_equal(as_integers([3.0, -2.0], "x"), [3, -2])
    ids = np.array([7], np.int16)
    assert as_integers(ids, "x", lo=0, hi=7) is ids  # integers: checked, not copied
    with pytest.raises(ParameterError, match="x must hold integers <= 6, got 7"):
        as_integers(ids, "x", lo=0, hi=6)


def _measurement(counts, **kw):
    return LabMeasurement(theta=2.0, phi=0.0, distance=kw.pop("distance", 500.0),
                          energy=662.0, counts=counts, time_bins=bins(8), **kw)


def test_lab_measurements_name_their_fields() -> None:
    with pytest.raises(ParameterError, match=r"distance must be numeric, got 'abc'"):
        _measurement(np.ones((1, 8)), distance="abc")
    with pytest.raises(ParameterError, match=r"distance must be > 0 cm"):
        _measurement(np.ones((1, 8)), distance=None)
    with pytest.raises(ParameterError, match=r"counts must hold integers \(floats only when "
                       r"exactly integral\), got 2\.5"):
        _measurement(np.full((1, 8), 2.5))
    assert _measurement(np.ones((1, 8)), distance=np.inf).distance == np.inf


def test_fit_calibration_refuses_counts_for_another_array_and_bad_starts() -> None:
    inst = Instrument.paper()
    assert len(inst.detectors) == 1
    two = _measurement(np.ones((2, 8), int))  # counts for 2 detectors: were broadcast
    with pytest.raises(ParameterError, match=r"measurements\[0\]\.counts must have one row per "
                       r"detector of the instrument \(1\), got 2"):
        fit_calibration(inst, [two], parameters=("axis_offset_x",))
    one = _measurement(np.ones((1, 8), int))
    with pytest.raises(ParameterError, match=r"start\['axis_offset_x'\] must be numeric, got "
                       r"'abc'"):
        fit_calibration(inst, [one], parameters=("axis_offset_x",),
                        start={"axis_offset_x": "abc"})
    with pytest.raises(ParameterError, match=r"start\['tilt_x'\] must be in units of deg"):
        fit_calibration(inst, [one], parameters=("tilt_x",), start={"tilt_x": 1 * u.cm})


def test_attitude_files_astropy_cannot_identify(tmp_path) -> None:
    (tmp_path / "att.dat").write_text("hello world\n1 2 3\n")
    with pytest.raises(ParameterError, match=r"attitude file '.*att\.dat': must be a table named "
                       r"\.ecsv, \.csv or \.fits"):
        AttitudeTable.read(tmp_path / "att.dat")
    (tmp_path / "att.ecsv").write_text("hello")
    with pytest.raises(ParameterError, match=r"att\.ecsv': is not a readable ascii\.ecsv table"):
        AttitudeTable.read(tmp_path / "att.ecsv")
    (tmp_path / "cols.csv").write_text("time,ra\n0,1\n")
    with pytest.raises(ParameterError, match=r"needs columns time, ra, dec, roll; missing dec, "
                       r"roll"):
        AttitudeTable.read(tmp_path / "cols.csv")
    (tmp_path / "ok.csv").write_text("time,ra,dec,roll\n0,10,20,30\n60,11,20,30\n")
    att = AttitudeTable.read(tmp_path / "ok.csv")
    np.testing.assert_array_equal(att.ra, [10.0, 11.0])

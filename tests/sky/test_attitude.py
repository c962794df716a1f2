"""The attitude: celestial coordinates <-> instrument frame, checked with astropy's own
position angles and separations (independent of the offset-frame algebra), near a pole too."""

from __future__ import annotations

import astropy.units as u
import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from rotmod.errors import ParameterError
from rotmod.sky import Attitude, AttitudeTable
from rotmod.sky.attitude import COVER_ABSOLUTE, COVER_ROUND_OFF

POINTINGS = [(83.63, 22.01, 0.0), (10.0, 85.0, 37.0), (250.0, -89.5, -120.0), (0.0, 0.0, 90.0)]


@pytest.mark.parametrize(("ra", "dec", "roll"), POINTINGS)
def test_zenith_is_separation_and_azimuth_follows_the_position_angle(ra, dec, roll) -> None:
    att = Attitude(ra, dec, roll)
    rng = np.random.default_rng(4)
    pa = rng.uniform(0, 360, 50) * u.deg
    sep = rng.uniform(0.01, 40, 50) * u.deg
    src = att.pointing.directional_offset_by(pa, sep)
    theta, phi = att.to_instrument(src)
    # astropy computes the offsets with its own spherical trigonometry: agreement to ~1e-9
    # deg is float64 round-off through two different routes.
    np.testing.assert_allclose(theta.to_value(u.deg), sep.to_value(u.deg), atol=1e-9)
    want = (roll + 90.0 - pa.to_value(u.deg)) % 360
    got = phi.to_value(u.deg) % 360
    np.testing.assert_allclose(np.angle(np.exp(1j * np.radians(got - want))), 0, atol=1e-9)


def test_instrument_axes_on_the_sky() -> None:
    # Roll 0: +y toward north, +x toward east (east, north, up is right-handed).
    att = Attitude(120.0, 30.0, 0.0)
    north = att.pointing.directional_offset_by(0 * u.deg, 1 * u.deg)
    east = att.pointing.directional_offset_by(90 * u.deg, 1 * u.deg)
    assert att.to_instrument(north)[1].to_value(u.deg) == pytest.approx(90.0, abs=1e-9)
    assert att.to_instrument(east)[1].to_value(u.deg) == pytest.approx(0.0, abs=1e-9)
    # Rolling by +30 deg turns the instrument's +y to PA 30 deg.
    rolled = Attitude(120.0, 30.0, 30.0)
    y_axis = rolled.to_sky(1.0, 90.0)
    assert rolled.pointing.position_angle(y_axis).to_value(u.deg) == pytest.approx(30.0, 1e-9)


@pytest.mark.parametrize(("ra", "dec", "roll"), POINTINGS)
def test_round_trip(ra, dec, roll) -> None:
    att = Attitude(ra * u.deg, dec * u.deg, roll * u.deg)
    theta = np.linspace(0, 60, 13)
    phi = np.linspace(-180, 180, 13)
    back = att.to_instrument(att.to_sky(theta, phi))
    np.testing.assert_allclose(back[0].to_value(u.deg), theta, atol=1e-9)
    mask = theta > 0  # the azimuth is undefined on the axis
    d = np.angle(np.exp(1j * (back[1].to_value(u.rad)[mask] - np.radians(phi[mask]))))
    np.testing.assert_allclose(d, 0, atol=1e-9)


def test_bad_input_names_the_parameter() -> None:
    with pytest.raises(ParameterError, match=r"attitude\.dec must be <= 90 deg"):
        Attitude(0.0, 95.0)
    with pytest.raises(ParameterError, match="coords must be an astropy SkyCoord"):
        Attitude(0.0, 0.0).to_instrument((1.0, 2.0))
    with pytest.raises(ParameterError, match=r"attitude\.roll must be in units of deg"):
        Attitude(0.0, 0.0, 3 * u.cm)


def test_roll_adds_to_the_mask_angle_on_the_sky() -> None:
    # At mask angle xi the slats run along (sin xi, cos xi) in the lab (u = x cos xi - y sin
    # xi is constant along them); on the sky that direction has position angle roll + xi.
    att = Attitude(120.0, 30.0, 25.0)
    for xi in (0.0, 30.0, 100.0, 250.0):
        x = np.radians(xi)
        along = att.to_sky(1.0, np.degrees(np.arctan2(np.cos(x), np.sin(x))))
        pa = att.pointing.position_angle(along).deg
        assert (pa - 25.0 - xi + 180.0) % 360.0 - 180.0 == pytest.approx(0.0, abs=1e-6)


# --- an attitude table covers its samples' time span, and no more ---------------------------

#: A 20-minute aspect at 60 s, drifting 1.2 deg and turning 40 deg, starting at t0.
def _aspect(t0: float = 0.0) -> AttitudeTable:
    t = t0 + 60.0 * np.arange(21)
    f = (t - t0) / 1200.0
    return AttitudeTable(t, 200.0 + 1.6 * f, -60.0 - 0.6 * f, 10.0 + 40.0 * f)


@pytest.mark.parametrize("t0", [0.0, -500.0, 4e8])  # from an epoch, before it, a MET
def test_a_table_serves_exactly_its_span_and_refuses_past_it(t0) -> None:
    table = _aspect(t0)
    lo, hi = table.span
    tol = table.tolerance
    assert tol == max(COVER_ABSOLUTE, COVER_ROUND_OFF * max(abs(lo), abs(hi)))
    # The end samples themselves: the samples (1e-9 deg: round-off of the slerp).
    for t, k in ((lo, 0), (hi, -1)):
        att = table.at(t)
        want = Attitude(table.ra[k], table.dec[k], table.roll[k])
        assert att.pointing.separation(want.pointing).deg < 1e-9
        assert att.roll == pytest.approx(want.roll, abs=1e-9)
    # Round-off past the ends (half the tolerance) is the end attitude; twice it is refused.
    assert table.at(hi + 0.5 * tol).pointing.separation(table.at(hi).pointing).deg < 1e-9
    for t, words in ((hi + 2 * tol, "after its last sample"),
                     (lo - 2 * tol, "before its first sample"),
                     (hi + 30.0, "is 30 s after its last sample")):
        with pytest.raises(ParameterError, match=rf"^t: the attitude table covers {lo:.12g} "
                                                 rf"\.\. {hi:.12g} s, but t = .* {words}"):
            table.at(t)
    # Pieces of exactly the span: the first starts and the last ends on the end samples.
    pieces = table.intervals(lo, hi, 100.0)
    assert len(pieces) == 12 and pieces[0][0] == lo and pieces[-1][1] == hi
    with pytest.raises(ParameterError, match=r"t_start \.\. t_stop: the attitude table covers "
                                             r".* ends 60 s after its last sample"):
        table.intervals(lo, hi + 60.0, 100.0)
    with pytest.raises(ParameterError, match=r"starts 1 s before its first sample and ends "
                                             r"1 s after its last sample"):
        table.intervals(lo - 1.0, hi + 1.0, 100.0)


@settings(max_examples=60, deadline=None)
@given(t0=st.floats(-1e9, 1e9), edge=st.sampled_from(["first", "last"]),
       k=st.floats(-3.0, 3.0).filter(lambda k: abs(abs(k) - 1.0) > 0.05))
@example(t0=0.0, edge="last", k=0.0).via("the end sample of a table from 0")
@example(t0=0.0, edge="first", k=0.0).via("the first sample")
def test_at_answers_exactly_within_the_samples(t0, edge, k) -> None:
    """at(t) answers iff t is within round-off of the samples, for tables from any epoch:
    times k tolerances from an end sample (|k| up to 3, away from the boundary |k| = 1 by
    5 %, where the sum's own rounding decides), inside for k >= -1 at the first and k <= 1
    at the last."""
    table = _aspect(t0)
    lo, hi = table.span
    t = (lo if edge == "first" else hi) + k * table.tolerance
    inside = k >= -1.0 if edge == "first" else k <= 1.0
    if inside:
        table.at(t)
    else:
        with pytest.raises(ParameterError, match="outside its samples the attitude is "
                                                 "unknown"):
            table.at(t)


def test_covers_refuses_a_reversed_span() -> None:
    table = _aspect(0.0)
    with pytest.raises(ParameterError, match="t_stop must be >= t_start"):
        table.covers(1e12, 0.0)


def test_times_through_a_double_mjd_are_covered_despite_round_off() -> None:
    # The table's end (1200 s from 0) as a time stamp that went through a double MJD comes
    # back 1.4e-7 s late (the MJD's spacing is 0.63 us): covered (COVER_ABSOLUTE), where a
    # tolerance relative to |t| alone (1.2e-9 s) refused it.
    table = _aspect(0.0)
    mjdref = 60000.5
    end = ((mjdref + 1200.0 / 86400.0) - mjdref) * 86400.0
    assert 1e-7 < end - table.span[1] < COVER_ABSOLUTE
    assert table.covers(0.0, end) and len(table.intervals(0.0, end, 60.0)) == 21
    # Pieces end 1.4e-7 s past the table; their attitudes at their middles, inside it.
    assert not table.covers(0.0, 1200.0 + 2 * COVER_ABSOLUTE)


def test_a_single_sample_covers_its_instant_only() -> None:
    one = AttitudeTable([10.0], [30.0], [20.0], [5.0])
    assert one.at(10.0).pointing.separation(Attitude(30.0, 20.0, 5.0).pointing).deg < 1e-9
    with pytest.raises(ParameterError, match=r"covers 10 \.\. 10 s"):
        one.at(11.0)
    with pytest.raises(ParameterError, match="ends 1 s after its last sample"):
        one.intervals(10.0, 11.0, 1.0)
    with pytest.raises(ParameterError, match=r"t must be finite, got nan s"):
        one.at(float("nan"))

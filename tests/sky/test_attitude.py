"""The attitude: celestial coordinates <-> instrument frame, checked with astropy's own
position angles and separations (independent of the offset-frame algebra), near a pole too."""

from __future__ import annotations

import astropy.units as u
import numpy as np
import pytest

from rotmod.errors import ParameterError
from rotmod.sky import Attitude

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

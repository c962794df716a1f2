"""Sky grids: presets, directions <-> tangent plane, and the WCS."""

from __future__ import annotations

import astropy.units as u
import numpy as np
import pytest
from astropy.coordinates import SkyCoord

from rotmod.errors import ParameterError
from rotmod.sky import SkyGrid


def test_paper_preset():
    g = SkyGrid.paper()
    assert g.shape == (70, 70)
    assert g.size == 4900
    assert g.pixel_size == pytest.approx(0.2)
    theta, phi = (v.to_value(u.rad) for v in g.directions())
    assert theta.shape == phi.shape == (4900,)
    # Corner pixel centre: (6.9, 6.9) deg in the tangent plane.
    assert np.degrees(theta.max()) == pytest.approx(
        np.degrees(np.arctan(np.hypot(*np.radians([6.9, 6.9])))), rel=1e-12
    )


def test_square_constructor_and_quantities():
    g = SkyGrid.square(10 * u.deg, 30 * u.arcmin)
    assert g.shape == (20, 20)
    assert g.pixel_size == pytest.approx(0.5)


def test_directions_tangent_round_trip():
    g = SkyGrid((5, 7), 1.3, center=(2.0, -1.0))
    x, y = g.pixel_centers()
    theta, phi = g.directions()
    xb, yb = g.to_tangent(theta, phi)
    # Pure trigonometric round trip: float64 rounding (~1e-15 relative) only.
    np.testing.assert_allclose(xb, x.ravel(), atol=1e-12)
    np.testing.assert_allclose(yb, y.ravel(), atol=1e-12)
    th2, ph2 = g.from_tangent(xb, yb)
    np.testing.assert_allclose(th2.to_value(u.rad), theta.to_value(u.rad), atol=1e-14)
    np.testing.assert_allclose(ph2.to_value(u.rad), phi.to_value(u.rad), atol=1e-14)


@pytest.mark.parametrize("center", [(0.0, 0.0), (3.0, -2.0)])
def test_wcs_matches_directions(center):
    g = SkyGrid((9, 11), 0.7, center=center)
    w = g.wcs()
    ny, nx = g.shape
    iy, ix = np.mgrid[0:ny, 0:nx]
    ra, dec = w.pixel_to_world_values(ix.ravel(), iy.ravel())
    pix = SkyCoord(ra * u.deg, dec * u.deg)
    axis = SkyCoord(0 * u.deg, 0 * u.deg)
    theta, phi = (v.to_value(u.rad) for v in g.directions())
    # Separation from the pointing axis is the zenith angle (wcslib's TAN: ~1e-12 deg).
    np.testing.assert_allclose(pix.separation(axis).rad, theta, atol=1e-10)
    # Position angle is east (+RA, lab +x) of north (+Dec, lab +y): PA = 90 deg - phi.
    pa = axis.position_angle(pix).rad
    mask = theta > 1e-9  # PA undefined at the axis itself
    d = np.angle(np.exp(1j * (pa[mask] - (np.pi / 2 - phi[mask]))))
    np.testing.assert_allclose(d, 0.0, atol=1e-9)


def test_wcs_axes_orientation():
    g = SkyGrid((3, 3), 1.0)
    w = g.wcs()
    ra, dec = w.pixel_to_world_values([2, 1], [1, 2])  # +x pixel, +y pixel
    # One pixel (1 deg of tangent plane) along +x is toward +RA: RA = atan(tan 1 deg) on
    # the equator; along +y it is toward +Dec.  wcslib is good to ~1e-12 deg.
    expected = np.degrees(np.arctan(np.radians(1.0)))
    assert (ra[0] % 360) == pytest.approx(expected, abs=1e-9) and dec[0] == pytest.approx(0.0)
    assert dec[1] == pytest.approx(expected, abs=1e-9) and (ra[1] % 360) == pytest.approx(0.0)


def test_to_from_dict():
    g = SkyGrid((4, 6), 0.25, center=(1.0, 2.0))
    assert SkyGrid.from_dict(g.to_dict()) == g


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"shape": (0, 3), "pixel_size": 1.0}, "grid.shape"),
        ({"shape": (3,), "pixel_size": 1.0}, "grid.shape"),
        ({"shape": (3, 3), "pixel_size": -1.0}, "grid.pixel_size"),
        ({"shape": (3, 3), "pixel_size": 1.0 * u.m}, "grid.pixel_size"),
    ],
)
def test_bad_grid(kwargs, match):
    with pytest.raises(ParameterError, match=match):
        SkyGrid(**kwargs)

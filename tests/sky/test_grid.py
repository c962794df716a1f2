"""Sky grids: presets, directions <-> tangent plane, the WCS, and the SkyGeometry contract
(a new grid kind is one subclass plus its registration)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import astropy.units as u
import matplotlib
import numpy as np
import pytest
from astropy.coordinates import SkyCoord

import rotmod.montecarlo
from rotmod.conventions import source_angles, source_direction
from rotmod.errors import ParameterError
from rotmod.geometry import DetectorArray, Instrument
from rotmod.io.images import read_image, write_image
from rotmod.materials import PAPER_SIGMA_662
from rotmod.plotting.images import IMAGE_DRAWERS, plot_image
from rotmod.response import MatrixFreeResponse, TimeBinning, build_response
from rotmod.sky import (
    GRID_KINDS,
    CelestialGrid,
    HealpixGrid,
    PointSources,
    SkyGeometry,
    SkyGrid,
    grid_from_dict,
)

matplotlib.use("Agg")


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


def _lab_directions_of_wcs(g: SkyGrid) -> tuple[np.ndarray, np.ndarray]:
    """Pixel directions through astropy's WCS: instrument-frame (XLON, XLAT) -> lab."""
    ny, nx = g.shape
    iy, ix = np.mgrid[0:ny, 0:nx]
    # The axes are not celestial (no SkyCoord): the world values are (XLON, XLAT) in deg.
    ra, dec = np.radians(g.wcs().pixel_to_world_values(ix.ravel(), iy.ravel()))
    # Celestial (X, Y, Z) = lab (z, x, y) (module notes).
    x, y, z = np.cos(dec) * np.sin(ra), np.sin(dec), np.cos(dec) * np.cos(ra)
    return np.arctan2(np.hypot(x, y), z), np.arctan2(y, x)


@pytest.mark.parametrize("tangent", [(48.0, 30.0), (70.0, -135.0), (5.0, 200.0)])
def test_grid_tangent_off_axis_matches_astropy_wcs(tangent):
    g = SkyGrid((7, 9), 1.5, center=(2.0, -3.0), tangent=tangent)
    theta, phi = (v.to_value(u.rad) for v in g.directions())
    th_w, ph_w = _lab_directions_of_wcs(g)
    # wcslib's TAN is good to ~1e-12 deg.
    np.testing.assert_allclose(theta, th_w, atol=1e-12)
    np.testing.assert_allclose(np.angle(np.exp(1j * (phi - ph_w))), 0.0, atol=1e-12)
    # The tangent point itself, and the round trip through the tangent plane.
    t0, p0 = SkyGrid((3, 3), 1.0, tangent=tangent).directions()
    assert np.degrees(t0[4].to_value(u.rad)) == pytest.approx(tangent[0], abs=1e-12)
    assert np.cos(p0[4].to_value(u.rad) - np.radians(tangent[1])) == pytest.approx(1.0)
    x, y = g.to_tangent(theta * u.rad, phi * u.rad)
    xc, yc = g.pixel_centers()
    np.testing.assert_allclose(x, xc.ravel(), atol=1e-11)
    np.testing.assert_allclose(y, yc.ravel(), atol=1e-11)
    assert SkyGrid.from_dict(g.to_dict()) == g


def test_off_axis_pixels_are_square_on_the_sky():
    # Tangent at the field centre 48 deg off axis: the neighbours of the centre pixel are
    # atan(1 deg) = 0.99990 deg away in both directions (gnomonic), where a grid tangent at
    # the axis would stretch them radially by 1/cos^2(48 deg) = 2.2.
    g = SkyGrid((3, 3), 1.0, tangent=(48.0, 0.0))
    th, ph = (v.to_value(u.rad) for v in g.directions())
    vec = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=1)
    sep = np.degrees(np.arccos([vec[4] @ vec[5], vec[4] @ vec[7]]))
    np.testing.assert_allclose(sep, np.degrees(np.arctan(np.radians(1.0))), rtol=1e-12)


def test_grid_below_the_detector_plane_and_bad_tangent_refused():
    with pytest.raises(ParameterError, match="at or below the detector plane"):
        SkyGrid((5, 5), 5.0, tangent=(85.0, 0.0)).directions()
    with pytest.raises(ParameterError, match=r"grid.tangent\[0\] must be < 90"):
        SkyGrid((5, 5), 1.0, tangent=(90.0, 0.0))
    with pytest.raises(ParameterError, match=r"grid\.tangent must be"):
        SkyGrid((5, 5), 1.0, tangent=3.0)


def test_grids_stored_before_tangent_existed_are_tangent_at_the_axis():
    d = SkyGrid((4, 6), 0.25, center=(1.0, 2.0)).to_dict()
    del d["tangent"]
    assert SkyGrid.from_dict(d) == SkyGrid((4, 6), 0.25, center=(1.0, 2.0))


@dataclass(frozen=True)
class Ring(SkyGeometry):
    """A new grid kind written here only: ``n`` pixels on a circle ``theta`` (deg) off axis."""

    kind = "test-ring"
    frame = "instrument"

    theta: float
    n: int

    @property
    def size(self) -> int:
        return self.n

    @property
    def shape(self) -> tuple[int, int]:
        return (1, self.n)

    def directions(self) -> tuple[u.Quantity, u.Quantity]:
        phi = 2 * np.pi * np.arange(self.n) / self.n
        return np.full(self.n, np.radians(self.theta)) * u.rad, phi * u.rad

    def to_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, "theta": self.theta, "n": self.n}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Ring:
        return cls(d["theta"], d["n"])


GRID_KINDS.register(Ring.kind, Ring)


def test_a_new_grid_kind_goes_everywhere_without_other_changes(tmp_path):
    ring = Ring(3.0, 6)
    # Metadata: to_dict -> grid_from_dict through the registry.
    assert grid_from_dict(ring.to_dict()) == ring
    # FITS: the default (pixel-table) form, read back in the grid's image shape.
    rng = np.random.default_rng(2)
    img, unc = rng.random(ring.shape), rng.random(ring.shape)
    back = read_image(write_image(tmp_path / "ring.fits", image=img, grid=ring,
                                  uncertainty=unc, meta={"exposure": 10.0}))
    np.testing.assert_array_equal(back.image, img)
    np.testing.assert_array_equal(back.uncertainty, unc)
    assert back.wcs is None and back.header["EXPOSURE"] == 10.0
    # A response: each pixel's column is that of a one-pixel instrument grid tangent at its
    # direction (the same direction, up to the round trip through a unit vector).
    base = Instrument.paper(sigma=PAPER_SIGMA_662)
    inst = Instrument(base.mask, DetectorArray.hexagonal(3.8, rings=1))
    tb = TimeBinning(24)
    R = build_response(inst, ring, tb, dtype=np.float64).matrix
    assert R.shape == (7, 24, 6)
    np.testing.assert_allclose(MatrixFreeResponse(inst, ring, tb, dtype=np.float64)
                               .forward(np.eye(6)[4]), R[:, :, 4], rtol=1e-12)
    for k, phi in enumerate(ring.directions()[1].to_value(u.deg)):
        one = build_response(inst, SkyGrid((1, 1), 0.1, tangent=(3.0, phi)), tb,
                             dtype=np.float64).matrix
        np.testing.assert_allclose(R[:, :, k], one[:, :, 0], rtol=1e-9, atol=1e-15)
    # A plot: kinds without a drawer of their own are drawn at their directions.
    ax = plot_image(img, ring, sources=([3.0], [60.0]), title="ring")
    assert ax.get_title() == "ring"
    matplotlib.pyplot.close("all")


def test_every_grid_kind_is_registered_under_its_kind():
    assert {"instrument", "celestial", "healpix"} <= set(GRID_KINDS.names())
    for name, cls in GRID_KINDS.items():
        assert cls.kind == name and issubclass(cls, SkyGeometry)
    assert GRID_KINDS.get("celestial") is CelestialGrid
    assert GRID_KINDS.get("healpix") is HealpixGrid
    assert isinstance(SkyGrid.paper(), SkyGeometry)


def test_grid_from_dict_defaults_to_the_instrument_grid_and_names_unknown_kinds():
    g = SkyGrid((4, 6), 0.25, center=(1.0, 2.0))
    assert "kind" not in g.to_dict() and grid_from_dict(g.to_dict()) == g
    with pytest.raises(ParameterError, match=r"grid kind must be one of .*did you mean 'healpix'"):
        grid_from_dict({"kind": "helpix"})


def test_point_sources_are_sky_truth_and_still_importable_from_the_monte_carlo():
    assert rotmod.montecarlo.PointSources is PointSources


def test_source_angles_invert_source_direction():
    theta = np.radians([0.0, 3.0, 45.0, 89.0, 120.0])
    phi = np.radians([0.0, -170.0, 30.0, 179.0, -45.0])
    th, ph = source_angles(source_direction(theta, phi))
    np.testing.assert_allclose(th, theta, atol=1e-15)
    np.testing.assert_allclose(ph[1:], phi[1:], atol=1e-15)
    assert source_angles(2.0 * source_direction(theta, phi))[0] == pytest.approx(theta)


def test_each_grid_kind_is_drawn_by_its_registered_drawer():
    assert set(IMAGE_DRAWERS.names()) == {"instrument", "celestial"}
    g = SkyGrid((3, 4), 0.5)
    ax = plot_image(np.ones(g.shape), g, colorbar=False)
    assert ax.get_xlabel() == "x, instrument frame (deg)"  # angles, not RA
    assert ax.get_ylabel() == "y, instrument frame (deg)"
    ax = plot_image(np.ones((1, 5)), Ring(2.0, 5), colorbar=False)  # the default drawer
    assert ax.get_xlabel() == "theta cos phi (deg)"
    matplotlib.pyplot.close("all")

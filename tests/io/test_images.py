"""FITS round trip of reconstructed images with their WCS."""

from __future__ import annotations

import numpy as np
import pytest
from astropy.coordinates import ICRS, Galactic, SkyCoord
from astropy.io import fits
from astropy.wcs import WCS
from astropy.wcs.utils import wcs_to_celestial_frame
from astropy_healpix import HEALPix

from rotmod import RotmodError
from rotmod.io.images import read_image, write_image
from rotmod.reconstruction import reconstruct
from rotmod.sky import Attitude, HealpixGrid
from rotmod.sky.geometry import pixel_table_hdus
from rotmod.sky.grid import SkyGrid
from rotmod.testing import MatrixOperator


def test_fits_round_trip_with_wcs(tmp_path) -> None:
    grid = SkyGrid((6, 8), 0.5, center=(10.0, -3.0))
    rng = np.random.default_rng(0)
    R = MatrixOperator(rng.uniform(0, 1, (2, 30, grid.size)), grid)
    s = np.zeros(grid.size)
    s[13] = 4.0
    y = rng.poisson(5.0 * (R.forward(s) + 1.0))
    res = reconstruct(R, y, "mlem", exposure=5.0, background=1.0, max_iter=5,
                      uncertainty="bootstrap", n_boot=3, seed=1)
    path = write_image(tmp_path / "img.fits", res)
    back = read_image(path)
    np.testing.assert_array_equal(back.image, res.image)
    np.testing.assert_array_equal(back.uncertainty, res.uncertainty)
    assert back.header["BUNIT"] == "ph s-1 pixel-1"
    assert back.header["RECMETH"] == "mlem" and back.header["NITER"] == res.n_iter
    assert back.params["n_boot"] == 3
    np.testing.assert_allclose(back.history["chi2"], res.history["chi2"])
    # Every pixel centre maps to its direction: pointing axis at (RA, Dec) = (0, 0), lab x
    # toward +RA and y toward +Dec, so the unit vector is (cos t, sin t cos p, sin t sin p).
    # 1e-9 deg is float64 round-off through the TAN projection.
    th, ph = (v.to_value("rad") for v in grid.directions())
    ra = np.degrees(np.arctan2(np.sin(th) * np.cos(ph), np.cos(th)))
    dec = np.degrees(np.arcsin(np.sin(th) * np.sin(ph)))
    iy, ix = np.mgrid[0 : grid.shape[0], 0 : grid.shape[1]]
    rw, dw = back.wcs.wcs_pix2world(ix.ravel(), iy.ravel(), 0)
    np.testing.assert_allclose(rw, ra, atol=1e-9)
    np.testing.assert_allclose(dw, dec, atol=1e-9)
    with pytest.raises(RotmodError, match="exists"):
        write_image(path, res)
    write_image(path, res, overwrite=True)
    assert not list(tmp_path.glob(".*.tmp"))


def test_write_requires_grid(tmp_path) -> None:
    with pytest.raises(RotmodError, match="grid is required"):
        write_image(tmp_path / "x.fits", image=np.zeros((2, 2)))
    with pytest.raises(RotmodError, match="does not exist"):
        read_image(tmp_path / "missing.fits")


def test_healpix_images_are_read_back_from_their_pixel_table(tmp_path) -> None:
    grid = HealpixGrid(16, 300.0, 40.0, 12.0, Attitude(300.0, 40.0, -15.0), "ring")
    rng = np.random.default_rng(3)
    img, unc = rng.random(grid.shape), rng.random(grid.shape)
    back = read_image(write_image(tmp_path / "hp.fits", image=img, grid=grid, uncertainty=unc))
    np.testing.assert_array_equal(back.image, img)
    np.testing.assert_array_equal(back.uncertainty, unc)
    assert back.wcs is None and back.header["BUNIT"] == "ph s-1 pixel-1"
    with pytest.raises(RotmodError, match="uncertainty must have the image's shape"):
        write_image(tmp_path / "x.fits", image=img, grid=grid, uncertainty=unc[:, 1:])


def test_write_requires_a_sky_geometry(tmp_path) -> None:
    with pytest.raises(RotmodError, match="grid must be a sky grid"):
        write_image(tmp_path / "x.fits", image=np.zeros((2, 2)), grid=object())


def _instrument_image(tmp_path):
    grid = SkyGrid((6, 8), 0.5, center=(10.0, -3.0), tangent=(20.0, 40.0))
    img = np.random.default_rng(4).random(grid.shape)
    return grid, img, write_image(tmp_path / "inst.fits", image=img, grid=grid, uncertainty=img)


def test_instrument_frame_images_do_not_claim_to_be_celestial(tmp_path) -> None:
    import gammapy.maps as maps  # a test dependency: the check must run, not skip

    _, _, path = _instrument_image(tmp_path)
    for hdu in (0, "UNCERTAINTY"):
        h = fits.getheader(path, hdu)
        assert (h["CTYPE1"], h["CTYPE2"]) == ("XLON-TAN", "XLAT-TAN")
        assert h["WCSNAME"] == "rotmod instrument frame" and h["SKYFRAME"] == "instrument"
        assert "RADESYS" not in h and h["CDELT1"] > 0
    w = read_image(path).wcs
    # astropy: spherical axes (wcslib's lng/lat) of no known sky frame, so no SkyCoord.
    assert w.world_axis_physical_types == [None, None]
    with pytest.raises(ValueError, match="celestial frame"):
        wcs_to_celestial_frame(w)
    assert not isinstance(w.pixel_to_world(0, 0), SkyCoord)
    # gammapy refuses to place it on the sky rather than putting it at the vernal equinox.
    with pytest.raises(ValueError, match="celestial frame"):
        maps.Map.read(path)


def test_instrument_frame_wcs_maps_pixels_to_the_same_angles_as_before(tmp_path) -> None:
    # The old header (RA---TAN/DEC--TAN, RADESYS ICRS) and the new one differ only in the
    # axis names: wcslib's TAN gives bit-identical angles for every pixel.
    grid, _, path = _instrument_image(tmp_path)
    new = read_image(path).wcs
    old_header = fits.getheader(path)
    old_header["CTYPE1"], old_header["CTYPE2"] = "RA---TAN", "DEC--TAN"
    old_header["RADESYS"] = "ICRS"
    old = WCS(old_header)
    iy, ix = np.mgrid[0 : grid.shape[0], 0 : grid.shape[1]]
    for a, b in zip(new.pixel_to_world_values(ix.ravel(), iy.ravel()),
                    old.pixel_to_world_values(ix.ravel(), iy.ravel()), strict=True):
        np.testing.assert_array_equal(a, b)


def test_images_written_before_the_instrument_frame_axes_still_read(tmp_path) -> None:
    _, img, path = _instrument_image(tmp_path)
    with fits.open(path) as hl:  # the header an older rotmod wrote
        for hdu in hl:
            hdu.header["CTYPE1"], hdu.header["CTYPE2"] = "RA---TAN", "DEC--TAN"
            hdu.header["RADESYS"] = "ICRS"
            for k in ("WCSNAME", "SKYFRAME"):
                del hdu.header[k]
        hl.writeto(tmp_path / "old.fits", checksum=True)
    back = read_image(tmp_path / "old.fits")
    np.testing.assert_array_equal(back.image, img)
    assert back.wcs.wcs.ctype[0] == "RA---TAN"


def _healpix_image(tmp_path):
    grid = HealpixGrid(16, 300.0, 40.0, 12.0, Attitude(300.0, 40.0, -15.0), "nested")
    rng = np.random.default_rng(5)
    img, unc = rng.random(grid.shape), rng.random(grid.shape)
    return grid, img, unc, write_image(tmp_path / "hp.fits", image=img, grid=grid,
                                       uncertainty=unc)


def test_healpix_images_are_read_by_gammapy(tmp_path) -> None:
    import gammapy.maps as maps  # a test dependency: the check must run, not skip

    grid, img, _, path = _healpix_image(tmp_path)
    m = maps.Map.read(path)
    assert m.geom.frame == "icrs" and m.geom.nest and int(m.geom.nside[0]) == 16
    # gammapy holds float32; the cone's pixels carry the image, the rest of the sphere 0.
    np.testing.assert_array_equal(m.data[grid.pixels], img[0].astype(np.float32))
    assert np.count_nonzero(np.delete(m.data, grid.pixels)) == 0
    coords = m.geom.pix_to_coord((grid.pixels,))
    sky = SkyCoord(coords[0], coords[1], unit="deg", frame="icrs")
    assert np.max(sky.separation(grid.sky_coords()).deg) < 1e-9


def test_healpix_images_are_read_by_healpy(tmp_path) -> None:
    healpy = pytest.importorskip("healpy")  # optional: wheels for CPython 3.11 on PyPI

    grid, img, unc, path = _healpix_image(tmp_path)
    values, unc_back = healpy.read_map(path, field=(0, 1), nest=True)
    np.testing.assert_array_equal(values[grid.pixels], img[0])
    np.testing.assert_array_equal(unc_back[grid.pixels], unc[0])
    assert np.all(np.delete(values, grid.pixels) == healpy.UNSEEN)
    header = dict(healpy.read_map(path, h=True, nest=True)[1])
    assert header["COORDSYS"] == "C"


def test_healpix_images_are_described_for_astropy_healpix(tmp_path) -> None:
    grid, img, _, path = _healpix_image(tmp_path)
    h = fits.getheader(path, "HEALPIX")
    data = fits.getdata(path, "HEALPIX")
    frame = {"C": ICRS(), "G": Galactic()}[h["COORDSYS"]]
    hp = HEALPix(nside=h["NSIDE"], order=h["ORDERING"].lower(), frame=frame)
    assert h["NSIDE"] == 2 ** h["ORDER"] and h["LASTPIX"] == hp.npix - 1
    centres = hp.healpix_to_skycoord(data["PIX"])
    assert np.max(centres.separation(grid.sky_coords()).deg) < 1e-9
    np.testing.assert_array_equal(data["VALUE"], img[0])
    assert data.columns["VALUE"].unit == "ph s-1 pixel-1"


def test_healpix_images_written_before_the_gadf_convention_still_read(tmp_path) -> None:
    grid, img, unc, _ = _healpix_image(tmp_path)
    # The table an older rotmod wrote: PIXEL and INTENSITY columns, explicit indexing.
    hdus = pixel_table_hdus(img, unc, "ph s-1 pixel-1", name="HEALPIX",
                            index=("PIXEL", grid.pixels))
    hdus[1].header["PIXTYPE"], hdus[1].header["INDXSCHM"] = "HEALPIX", "EXPLICIT"
    fits.HDUList(hdus).writeto(tmp_path / "old.fits", checksum=True)
    back = read_image(tmp_path / "old.fits")
    np.testing.assert_array_equal(back.image, img)
    np.testing.assert_array_equal(back.uncertainty, unc)


def test_standard_meta_cards_carry_their_unit_and_never_cut(tmp_path) -> None:
    grid = SkyGrid((2, 2), 1.0)
    name = "a balloon mission with a long name, fifty chars!!"
    path = write_image(tmp_path / "m.fits", image=np.ones(grid.shape), grid=grid,
                       meta={"exposure": 1200.0, "e_min": 100.0, "e_max": 145.0,
                             "telescop": name})
    h = fits.getheader(path)
    assert h.comments["EXPOSURE"].startswith("[s]")
    assert h.comments["E_MIN"].startswith("[keV]") and h.comments["E_MAX"].startswith("[keV]")
    assert h["TELESCOP"] == name and h["INSTRUME"] == "rotmod"

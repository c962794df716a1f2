"""FITS round trip of reconstructed images with their WCS."""

from __future__ import annotations

import numpy as np
import pytest

from rotmod import RotmodError
from rotmod.io.images import read_image, write_image
from rotmod.reconstruction import reconstruct
from rotmod.sky import Attitude, HealpixGrid
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

"""One file of every FITS product kind rotmod writes, for the checks that every product must
pass (fitsverify, provenance): event lists with and without a pointing, folded profiles,
images on each grid kind, and the source products (catalogue, TS maps, probability map, light
curve), built from results of known content (:func:`source_results`)."""

from __future__ import annotations

from pathlib import Path

import astropy.units as u
import numpy as np
import pytest
from astropy.coordinates import SkyCoord

from rotmod.events import fold
from rotmod.io import write_events, write_folded
from rotmod.io.catalogue import write_catalogue, write_detection
from rotmod.io.images import write_image
from rotmod.io.ogip import write_ogip
from rotmod.io.regions import write_probability_map
from rotmod.io.tables import write_light_curve
from rotmod.io.tsmaps import write_ts_map
from rotmod.montecarlo import simulate_observation
from rotmod.reconstruction import reconstruct
from rotmod.sky import Attitude, CelestialGrid, HealpixGrid, PointSources, SkyGeometry, SkyGrid
from rotmod.sources import Detection, FitResult, PointSource, Region, SkyModel, TSMap
from rotmod.sources.catalogue import probability_map
from rotmod.sources.lightcurve import LightCurve
from rotmod.spectral import CountsSpectrum, PowerLaw, RateSpectrum
from rotmod.testing import MatrixOperator, tiny_instrument
from tests.conftest import rad
from tests.spectral.test_spectrum import gaussian_response

#: What the products below are written with: a seed and a command long enough to need
#: CONTINUE cards.
SEED = 8
COMMAND = ["rotmod", "simulate", "--seed", str(SEED), "--out", "a/" * 50 + "events.fits"]


#: Where the source products' sky is: the pointing of a small celestial field.
ATTITUDE = Attitude(83.6, 22.0, 30.0)


def gaussian_region(source: PointSource, sigma_x: float = 0.2, sigma_y: float = 0.3, *,
                    n: int = 41) -> Region:
    """A region whose density is a Gaussian of widths ``sigma_x``, ``sigma_y`` (deg) along
    the region's tangent-plane axes, sampled on ``n x n`` points over +-4.5 of the larger
    width: a surface whose regions are known in closed form (the ``q`` region is the
    ellipse of area ``pi sx sy (-2 ln(1 - q))``)."""
    sx, sy = np.radians(sigma_x), np.radians(sigma_y)
    o = np.linspace(-4.5 * max(sx, sy), 4.5 * max(sx, sy), n)
    xx, yy = np.meshgrid(o, o)
    logp = -0.5 * ((xx / sx) ** 2 + (yy / sy) ** 2)
    density = np.exp(logp) / np.exp(logp).sum()
    return Region(source, o, density, 60.0 + 2.0 * logp, 0.0)


def fit_result(sources: list[PointSource], n_det: int = 7) -> FitResult:
    """A fit of ``sources`` with statistics of known values (TS 30, 45, ...)."""
    k = len(sources)
    ts = 30.0 + 15.0 * np.arange(k)
    flux = np.array([s.flux for s in sources])
    err = np.column_stack([0.1 * flux, 0.12 * flux])
    return FitResult(SkyModel(sources, background=np.full(n_det, 2.0)), -1234.5, ts, err,
                     flux + 2.2 * err[:, 1], 0.95, np.zeros((n_det, 12)), n_det * 12)


def ts_map_on(grid: SkyGeometry, seed: int = 0) -> TSMap:
    """A TS map of random content on ``grid``, with unseen (NaN) pixels."""
    rng = np.random.default_rng(seed)
    ts = rng.chisquare(1, grid.shape)
    ts.ravel()[::7] = np.nan
    flux = rng.uniform(0, 0.1, grid.shape)
    return TSMap(grid, ts, flux, 0.3 * flux, 2.0 * flux, np.full(grid.shape, 0.05), 0.95,
                 25.0)


def source_results() -> dict[str, object]:
    """A detection of two sources on the sky (with regions), a fit in the instrument frame,
    TS maps on each grid kind and a light curve: what the source products are written from."""
    sky = [PointSource(SkyCoord(84.5 * u.deg, 23.5 * u.deg), flux=0.4, name="S1"),
           PointSource(SkyCoord(82.9 * u.deg, 21.2 * u.deg), flux=0.25, name="S2")]
    cel = CelestialGrid((6, 8), 0.5, 83.6, 22.0, ATTITUDE)
    det = Detection(fit_result(sky), [gaussian_region(sky[0]), gaussian_region(sky[1], 0.3, 0.2)],
                    ts_map_on(cel, 1), ts_map_on(cel, 2), 25.0)
    inst = [PointSource((2.3, 47.0), flux=0.5, name="A"), PointSource((4.0, 200.0), flux=0.1)]
    n = 4
    lc = LightCurve(np.linspace(0.0, 400.0, n + 1), np.array([100.0, 100.0, 0.0, 100.0]),
                    ["S1", "S2"], np.full((n, 2), 0.3), np.full((n, 2, 2), 0.05),
                    np.full((n, 2), 36.0), np.full((n, 2), 0.4), 0.95)
    return {
        "detection": det, "instrument fit": fit_result(inst),
        "instrument map": ts_map_on(SkyGrid((5, 6), 1.0), 3), "celestial map": det.ts_map,
        "healpix map": ts_map_on(HealpixGrid(64, 83.6, 22.0, 3.0, ATTITUDE), 4),
        "light curve": lc,
    }


def ogip_spectrum(seed: int = 1) -> CountsSpectrum:
    """An E^-2 source of ~4e4 counts on a flat background; the background region is twice the
    source region (BACKSCAL 2) over the same exposure."""
    r = gaussian_response()
    rng = np.random.default_rng(seed)
    bkg = CountsSpectrum(rng.poisson(np.full(48, 50.0)), 1e4, backscal=2.0)
    counts = rng.poisson(r.fold(PowerLaw(1e-4, -2.0), 1e4) + 25.0)
    return CountsSpectrum(counts, 1e4, r, bkg, meta={"OBJECT": "test source"})


def ogip_rate_spectrum(seed: int = 1) -> RateSpectrum:
    """An E^-2 source's rates with Gaussian errors (as a fit extracts them: values that can
    be negative, errors that are not their square roots): ~4e4 source counts, each channel's
    error that of the source on a background of 100 counts."""
    r = gaussian_response()
    rng = np.random.default_rng(seed)
    counts = r.fold(PowerLaw(1e-4, -2.0), 1e4)
    error = np.sqrt(counts + 100.0) / 1e4
    return RateSpectrum(counts / 1e4 + error * rng.standard_normal(48), error, 1e4, r,
                        meta={"OBJECT": "test source"})


def write_products(folder: Path, **provenance) -> dict[str, Path]:
    """Write one product of each kind into ``folder``; ``provenance`` goes to every writer."""
    inst = tiny_instrument(diameter=3.8, rotation_period=30.0)
    src = PointSources([6.0, 12.0], rad([0.3, 2.0]), rate=[40.0, 10.0], energy=662.0)
    ev = simulate_observation(inst, src, t_stop=40.0, background=2.0, seed=SEED)
    pointed = simulate_observation(inst, src, t_stop=40.0, seed=SEED,
                                   attitude=Attitude(10.0, 20.0, 30.0))
    grid = SkyGrid((6, 8), 0.5, center=(10.0, -3.0))
    rng = np.random.default_rng(0)
    R = MatrixOperator(rng.uniform(0, 1, (2, 30, grid.size)), grid)
    y = rng.poisson(5.0 * (R.forward(np.ones(grid.size)) + 1.0))
    res = reconstruct(R, y, "mlem", exposure=5.0, background=1.0, max_iter=3)
    meta = {"EXPOSURE": 40.0, "E_MIN": 600.0, "E_MAX": 700.0}
    cel = CelestialGrid((5, 7), 0.5, 10.0, 20.0, Attitude(10.0, 20.0, 0.0))
    hpx = HealpixGrid(16, 300.0, 40.0, 12.0, Attitude(300.0, 40.0, -15.0), "ring")
    results = source_results()
    det = results["detection"]
    ogip = write_ogip(ogip_spectrum(), folder / "src.pha", **provenance)
    return {
        "OGIP spectrum": ogip,
        "OGIP background": folder / "src_bkg.pha",
        "OGIP RMF": folder / "src.rmf",
        "OGIP ARF": folder / "src.arf",
        "OGIP rate spectrum": write_ogip(ogip_rate_spectrum(), folder / "rate.pha",
                                         **provenance),
        "catalogue": write_detection(det, folder / "cat.fits", **provenance),
        "instrument catalogue": write_catalogue(results["instrument fit"], folder / "icat.fits",
                                                **provenance),
        "instrument TS map": write_ts_map(results["instrument map"], folder / "its.fits",
                                          **provenance),
        "celestial TS map": write_ts_map(results["celestial map"], folder / "cts.fits",
                                         **provenance),
        "healpix TS map": write_ts_map(results["healpix map"], folder / "hts.fits", **provenance),
        "probability map": write_probability_map(probability_map(det.regions[0]),
                                                 folder / "prob.fits", **provenance),
        "light curve": write_light_curve(results["light curve"], folder / "lc.fits",
                                         **provenance),
        "events": write_events(ev, folder / "ev.fits", **provenance),
        "pointed events": write_events(pointed, folder / "ev_pnt.fits", **provenance),
        "folded": write_folded(fold(ev, 24, energy_band=(600, 700)), folder / "folded.fits",
                               **provenance),
        "instrument image": write_image(folder / "img.fits", res, meta=meta, **provenance),
        "celestial image": write_image(folder / "cel.fits", image=rng.random(cel.shape),
                                       grid=cel, uncertainty=rng.random(cel.shape), meta=meta,
                                       **provenance),
        "healpix image": write_image(folder / "hpx.fits", image=rng.random(hpx.shape),
                                     grid=hpx, uncertainty=rng.random(hpx.shape), meta=meta,
                                     **provenance),
    }


@pytest.fixture(scope="module")
def products(tmp_path_factory) -> dict[str, Path]:
    """Every product kind, written with a seed and a (long) command."""
    return write_products(tmp_path_factory.mktemp("products"), seed=SEED, command=COMMAND)

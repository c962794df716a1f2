"""Images on the celestial sphere: sources at known RA/Dec, seen from pointings with rolls
(one 8 deg from the pole), simulated, folded and reconstructed on a celestial grid, land on
their pixel in astropy's WCS."""

from __future__ import annotations

import astropy.units as u
import numpy as np
import pytest
from astropy.coordinates import SkyCoord
from scipy.spatial.transform import Rotation

from rotmod.errors import ParameterError
from rotmod.events import fold
from rotmod.geometry import Instrument
from rotmod.io import load_instrument
from rotmod.montecarlo import simulate_observation
from rotmod.reconstruction import reconstruct
from rotmod.response import TimeBinning, build_response
from rotmod.sky import Attitude, CelestialGrid, HealpixGrid, PointSources, grid_from_dict


def test_wcs_has_east_left_and_north_up() -> None:
    g = CelestialGrid((5, 7), 0.5, 200.0, 40.0, Attitude(200.0, 40.0, 25.0))
    w = g.wcs()
    c = w.pixel_to_world(3, 2)
    assert c.ra.deg == pytest.approx(200.0) and c.dec.deg == pytest.approx(40.0)
    right, up = w.pixel_to_world(4, 2), w.pixel_to_world(3, 3)
    # One pixel right is west (PA 270 deg), one pixel up is north (PA 0): the sky as seen.
    assert c.position_angle(right).deg == pytest.approx(270.0, abs=1e-6)
    assert c.position_angle(up).deg % 360 == pytest.approx(0.0, abs=1e-6)
    assert c.separation(right).deg == pytest.approx(0.5, rel=1e-4)
    # The centre pixel's instrument direction is the attitude's view of the centre.
    theta = g.directions()[0].to_value(u.rad)
    t0 = g.attitude.to_instrument(SkyCoord(200.0 * u.deg, 40.0 * u.deg))[0].to_value(u.rad)
    assert theta[2 * 7 + 3] == pytest.approx(float(t0), abs=1e-12)
    assert grid_from_dict(g.to_dict()) == g


@pytest.mark.parametrize(
    ("pointing", "source"),
    [((150.0, 10.0, 35.0), (151.2, 11.5)),      # roll 35 deg, source 1.9 deg off axis
     ((30.0, 82.0, -70.0), (48.0, 83.2))],      # 8 deg from the pole, source 2.6 deg off
)
def test_source_at_known_radec_lands_on_its_pixel(pointing, source) -> None:
    att = Attitude(*pointing)
    true = SkyCoord(source[0] * u.deg, source[1] * u.deg)
    inst = load_instrument("prototype")
    theta, phi = att.to_instrument(true)
    src = PointSources(theta, phi, rate=30.0, energy=122.0)
    ev = simulate_observation(inst, src, t_stop=1200.0, background=10.0, seed=5)
    folded = fold(ev, 90)
    # 0.5 deg pixels (a quarter of b/L) on a field centred 1 deg from the source, so the
    # source is not on the central pixel by construction.
    centre = true.directional_offset_by(45 * u.deg, 1.0 * u.deg)
    grid = CelestialGrid((15, 15), 0.5, centre.ra, centre.dec, att)
    resp = build_response(inst, grid, TimeBinning(90, "average", 2), energy=122,
                          dtype=np.float64)
    res = reconstruct(resp, folded, fit_background=True)
    iy, ix = np.unravel_index(int(np.argmax(res.image)), res.image.shape)
    found = grid.wcs().pixel_to_world(ix, iy)
    # Within one pixel (0.5 deg; the diagonal of a pixel is 0.71 deg).
    assert found.separation(true).deg < 0.5 * np.sqrt(2)


def test_bad_celestial_grid_input() -> None:
    att = Attitude(0.0, 0.0)
    with pytest.raises(ParameterError, match=r"grid\.dec must be <= 90 deg"):
        CelestialGrid((3, 3), 0.5, 0.0, 91.0, att)
    with pytest.raises(ParameterError, match=r"grid\.attitude must be an Attitude"):
        CelestialGrid((3, 3), 0.5, 0.0, 0.0, None)


def test_events_with_an_attitude_are_read_by_gammapy(tmp_path) -> None:
    import gammapy.data as gammapy_data  # a test dependency: the check must run, not skip

    from rotmod.io import read_events, write_events
    att = Attitude(266.4, -28.9, 15.0)  # Galactic centre, rolled
    src = PointSources.from_sky(SkyCoord([266.0, 267.5] * u.deg, [-29.5, -28.0] * u.deg), att,
                                rate=10.0, energy=122.0)
    ev = simulate_observation(load_instrument("prototype"), src, t_stop=300.0, seed=2,
                              attitude=att, meta={"obs_id": 42})
    path = write_events(ev, tmp_path / "ev.fits")
    back = read_events(path)
    assert back.attitude == att and len(back) == len(ev)
    g = gammapy_data.EventList.read(path)
    assert len(g.table) == len(ev)
    assert g.pointing_radec.separation(att.pointing).deg < 1e-9
    assert g.table.meta["OBS_ID"] == 42
    gti = gammapy_data.GTI.read(path)
    assert gti.time_sum.to_value(u.s) == pytest.approx(ev.exposure)
    # An Observation from the same file (docs/conventions.md): gammapy's Observation.read
    # wants a fixed ground observatory (GEOLON, ...), which a balloon or satellite is not.
    with pytest.raises(KeyError, match="GEOLON"):
        gammapy_data.Observation.read(path)
    obs = gammapy_data.Observation(
        obs_id=g.table.meta["OBS_ID"], events=g, gti=gti,
        pointing=gammapy_data.FixedPointingInfo(fixed_icrs=g.pointing_radec))
    assert obs.get_pointing_icrs(obs.tmid).separation(att.pointing).deg < 1e-9
    assert obs.observation_live_time_duration.to_value(u.s) == pytest.approx(ev.exposure)


def test_two_lines_from_two_places_give_two_images() -> None:
    from rotmod.energy import EnergyResolution

    att = Attitude(120.0, -45.0, 60.0)
    low, high = SkyCoord(121.0 * u.deg, -44.0 * u.deg), SkyCoord(118.8 * u.deg, -46.2 * u.deg)
    src = PointSources.from_sky(SkyCoord([low.ra, high.ra], [low.dec, high.dec]), att,
                                rate=[40.0, 40.0], energy=[122.0, 662.0])
    inst = load_instrument("prototype")
    ev = simulate_observation(inst, src, t_stop=1200.0, seed=9, attitude=att,
                              resolution=EnergyResolution.nai())
    # NaI at 122 keV: FWHM 16 % (19 keV); at 662 keV 7 % (46 keV): windows of +-2 FWHM.
    grid = CelestialGrid((17, 17), 0.5, 120.0, -45.0, att)
    for true, e, band in ((low, 122.0, (100.0, 145.0)), (high, 662.0, (570.0, 755.0))):
        folded = fold(ev, 90, energy_band=band)
        resp = build_response(inst, grid, TimeBinning(90, "average", 2), energy=e,
                              dtype=np.float64)
        res = reconstruct(resp, folded)
        iy, ix = np.unravel_index(int(np.argmax(res.image)), res.image.shape)
        found = grid.wcs().pixel_to_world(ix, iy)
        assert found.separation(true).deg < 0.5 * np.sqrt(2), (e, found, true)


def test_energy_resolution_spreads_a_line_as_stated() -> None:
    from rotmod.energy import FWHM_PER_SIGMA, EnergyResolution

    r = EnergyResolution.nai()
    assert r.fwhm(662.0) == pytest.approx(0.07 * 662.0)
    assert r.fwhm(122.0) == pytest.approx(0.07 * 122.0 * np.sqrt(662.0 / 122.0))
    e = r.smear(np.full(40_000, 662.0), np.random.default_rng(1))
    # 40000 draws: the sample std is within 1 % of sigma (its relative error is 0.35 %).
    assert np.std(e) == pytest.approx(0.07 * 662.0 / FWHM_PER_SIGMA, rel=0.01)
    # The mean's standard error is sigma / 200 = 0.1 keV: 4 standard errors.
    assert np.mean(e, dtype=float) == pytest.approx(662.0, abs=0.4)


def test_celestial_images_are_placed_by_astropy_and_gammapy(tmp_path) -> None:
    import gammapy.maps as maps  # a test dependency: the check must run, not skip

    from rotmod.io.images import read_image, write_image
    att = Attitude(10.0, 80.0, 20.0)
    grid = CelestialGrid((9, 11), 0.4, 12.0, 81.0, att)
    img = np.zeros(grid.shape)
    img[6, 2] = 1.0
    path = write_image(tmp_path / "c.fits", image=img, grid=grid,
                       meta={"exposure": 1200.0, "e_min": 100.0, "e_max": 145.0})
    back = read_image(path)
    assert back.header["EXPOSURE"] == 1200.0 and back.header["E_MIN"] == 100.0
    assert back.header["RADESYS"] == "ICRS" and back.header["CDELT1"] < 0  # east left
    m = maps.Map.read(path)
    want = grid.wcs().pixel_to_world(2, 6)
    lon, lat = m.geom.pix_to_coord((2, 6))
    got = SkyCoord(u.Quantity(lon, u.deg), u.Quantity(lat, u.deg))
    assert got.separation(want).deg < 1e-9
    assert m.geom.center_skydir.separation(SkyCoord(12.0 * u.deg, 81.0 * u.deg)).deg < 1e-9


def test_attitude_table_interpolates_and_round_trips(tmp_path) -> None:
    from rotmod.sky import AttitudeTable

    table = AttitudeTable([0.0, 600.0, 1200.0], [200.0, 200.8, 201.6], [-60.0, -60.4, -60.8],
                          [10.0, 25.0, 40.0])
    # At the samples the interpolation returns the samples (1e-9 deg: round-off).
    mid = table.at(600.0)
    assert mid.pointing.separation(Attitude(200.8, -60.4, 25.0).pointing).deg < 1e-9
    assert mid.roll == pytest.approx(25.0, abs=1e-9)
    # Half-way the instrument has turned half the way, about the same axis (a rigid turn at
    # a constant rate: the pointing moves 0.28 deg while the roll turns by 15 deg).
    def rotation(att: Attitude) -> Rotation:
        z = att.pointing.cartesian.xyz.value
        y = att.to_sky(90.0, 90.0).cartesian.xyz.value.ravel()
        return Rotation.from_matrix(np.column_stack([np.cross(y, z), y, z]))

    a, b, h = (rotation(table.at(t)) for t in (0.0, 600.0, 300.0))
    whole, half = (a.inv() * b).as_rotvec(), (a.inv() * h).as_rotvec()
    np.testing.assert_allclose(half, whole / 2, atol=1e-10)
    path = tmp_path / "aspect.ecsv"
    table.write(path)
    back = AttitudeTable.read(path)
    np.testing.assert_allclose(back.roll, table.roll)
    assert len(table.intervals(0.0, 1200.0, 100.0)) == 12


def test_attitudes_interpolate_as_rotations_through_any_turn() -> None:
    """Slerp of the rotations (issue 25): a half-turn roll is at a quarter turn midway, a
    long slew moves along the great circle at a constant rate, and a half turn between two
    samples (no unique path) is refused."""
    from rotmod.sky import AttitudeTable

    roll = AttitudeTable([0.0, 10.0], [30.0, 30.0], [20.0, 20.0], [0.0, 180.0 - 1e-6])
    for t, expected in ((5.0, 90.0), (2.5, 45.0), (7.5, 135.0)):
        a = roll.at(t)
        assert a.pointing.separation(Attitude(30.0, 20.0, 0.0).pointing).deg < 1e-9
        assert a.roll == pytest.approx(expected, abs=1e-5)
    slew = AttitudeTable([0.0, 100.0], [0.0, 170.0], [0.0, 0.0], [0.0, 0.0])
    for t in (25.0, 50.0, 75.0):
        a = slew.at(t)
        assert a.pointing.ra.deg == pytest.approx(1.7 * t, abs=1e-9)
        assert abs(a.pointing.dec.deg) < 1e-9
    # At the end samples the samples; outside them refused (it held the end attitude).
    assert slew.at(0.0).pointing.ra.deg == pytest.approx(0.0, abs=1e-9)
    assert slew.at(100.0).pointing.ra.deg == pytest.approx(170.0, abs=1e-9)
    for t in (-5.0, 500.0):
        with pytest.raises(ParameterError, match=r"t: the attitude table covers 0 \.\. 100 s"):
            slew.at(t)
    for ra, roll_end in (([0.0, 180.0], [0.0, 0.0]), ([0.0, 0.0], [0.0, 180.0])):
        with pytest.raises(ParameterError, match="half turn"):
            AttitudeTable([0.0, 1.0, 2.0], [0.0, *ra[1:], ra[1]], [0.0, 0.0, 0.0],
                          [0.0, *roll_end[1:], roll_end[1]])


def test_a_dropout_in_the_aspect_is_warned_of() -> None:
    from rotmod.sky import AttitudeTable

    t = np.concatenate([np.arange(0.0, 60.0), np.arange(150.0, 200.0)])  # 1 Hz, 91 s lost
    ra, dec, roll = 10.0 + 1e-3 * t, np.full(t.size, 20.0), np.zeros(t.size)
    with pytest.warns(UserWarning, match=r"1 gap\(s\) .* longer than 10 s, the longest 91 s "
                      r"after t = 59 s"):
        AttitudeTable(t, ra, dec, roll)
    AttitudeTable(t, ra, dec, roll, max_gap=100.0)  # accepted: no warning (errors here)
    with pytest.raises(ParameterError, match="max_gap"):
        AttitudeTable(t, ra, dec, roll, max_gap=-1.0)


def test_a_drifting_rolling_observation_images_with_the_drift_response() -> None:
    from rotmod.montecarlo import simulate_drift
    from rotmod.response.drift import drift_response
    from rotmod.sky import AttitudeTable

    # A gondola drifting 1.2 deg and turning 40 deg in 20 minutes.
    table = AttitudeTable([0.0, 1200.0], [200.0, 201.6], [-60.0, -60.6], [10.0, 50.0])
    steps = table.intervals(0.0, 1200.0, 100.0)
    true = SkyCoord(201.5 * u.deg, -59.2 * u.deg)
    inst = load_instrument("prototype")
    ev = simulate_drift(inst, true, steps, rate=30.0, energy=122.0, background=10.0, seed=4)
    folded = fold(ev, 90)
    grid = CelestialGrid((15, 15), 0.5, 201.0, -59.5, table.at(600.0))
    tb = TimeBinning(90, "average", 2)
    matrix = drift_response(inst, grid, tb, steps, energy=122)
    res = reconstruct(matrix, folded)
    iy, ix = np.unravel_index(int(np.argmax(res.image)), res.image.shape)
    assert grid.wcs().pixel_to_world(ix, iy).separation(true).deg < 0.5 * np.sqrt(2)
    # The same sum kept as per-interval Radon operators: each value within their tolerance
    # (a weighted mean of values each within it), so the products agree to it times |S|_1.
    radon = drift_response(inst, grid, tb, steps, energy=122, operator="radon",
                           tolerance=1e-3)
    x = np.random.default_rng(0).random(grid.size)
    assert np.abs(radon.forward(x) - matrix.forward(x)).max() <= 1e-3 * x.sum()
    y = np.random.default_rng(1).random((len(inst.detectors), 90))
    assert np.abs(radon.adjoint(y) - matrix.adjoint(y)).max() <= 1e-3 * y.sum()


def test_an_extended_disc_goes_through_the_same_path() -> None:
    from rotmod.sky.extended import disc_points, gaussian_points

    centre = SkyCoord(150.0 * u.deg, 20.0 * u.deg)
    pts = disc_points(centre, 1.5, n=200)
    sep = centre.separation(pts).deg
    # Equal-area sampling: all inside, and half the points inside r / sqrt(2).
    assert sep.max() < 1.5 and np.mean(sep < 1.5 / np.sqrt(2)) == pytest.approx(0.5, abs=0.01)
    g = centre.separation(gaussian_points(centre, 0.5, n=400)).deg
    # A 2-D Gaussian holds 39.3 % of its flux within 1 sigma.
    assert np.mean(g < 0.5) == pytest.approx(1 - np.exp(-0.5), abs=0.01)

    att = Attitude(149.0, 19.0, 25.0)
    inst = load_instrument("prototype")
    grid = CelestialGrid((17, 17), 0.5, 150.0, 20.0, att)
    resp = build_response(inst, grid, TimeBinning(90, "average", 2), energy=122,
                          dtype=np.float64)
    half_max_pixels = {}
    for name, pts, n in (("disc", disc_points(centre, 1.5, n=40), 40), ("point", centre, 1)):
        src = PointSources.from_sky(pts, att, rate=80.0 / n, energy=122.0)
        # MLEM, stopped by the discrepancy principle, as when this was measured: the default
        # (NCAR on SGP, iterated to convergence) breaks a disc into a few peaks (2 pixels
        # above half maximum, 36 above 10 %; docs/reconstruction.md, default method).
        folded = fold(simulate_observation(inst, src, t_stop=1200.0, seed=6), 90)
        res = reconstruct(resp, folded, "mlem")
        iy, ix = np.unravel_index(int(np.argmax(res.image)), res.image.shape)
        assert grid.wcs().pixel_to_world(ix, iy).separation(centre).deg < 0.5 * np.sqrt(2)
        half_max_pixels[name] = int(np.sum(res.image > 0.5 * res.image.max()))
    # The same flux spread over a 1.5 deg disc images as a wide peak on the disc (measured 5
    # pixels above half maximum), a point source as one pixel.
    assert half_max_pixels["point"] <= 2
    assert half_max_pixels["disc"] >= 4


def test_a_power_law_source_is_attenuated_band_by_band() -> None:
    from rotmod import Instrument, get_model
    from rotmod.energy import PowerLaw

    spec = PowerLaw(2.0, 100.0, 1000.0)
    src = PointSources.with_spectrum([3.0], [20.0], 200.0, spec, n_bands=6)
    inst = Instrument.paper(h=0.5)  # thin lead: transmission rises from ~0 to ~60 %
    ev = simulate_observation(inst, src, t_stop=600.0, seed=12)
    band = src.band[ev.source]
    assert np.all((ev.energy >= band[:, 0] * (1 - 1e-6)) & (ev.energy <= band[:, 1] * (1 + 1e-6)))
    # Expected events per band: rate x time x the exact model's mean over a rotation at the
    # band's centre energy; Poisson chi-square over the 6 bands (99.9 % point of chi2(6): 22).
    xi = (np.arange(720) + 0.5) * 0.5
    counts = np.bincount(ev.source, minlength=len(src))
    chi2 = 0.0
    for k in range(len(src)):
        p = get_model("exact").profile(inst, src.theta[k:k + 1], src.phi[k:k + 1], xi,
                                       energy=src.energy[k]).mean()
        expected = src.rate[k] * 600.0 * p
        chi2 += (counts[k] - expected) ** 2 / expected
    assert chi2 < 22.5
    # Within a band the energies follow the power law: for index 2 the fraction below the
    # geometric mean of [lo, hi] is sqrt(hi/lo) / (1 + sqrt(hi/lo)) (3 sigma of 0.01 here).
    lo, hi = src.band[0]
    e0 = ev.energy[ev.source == 0]
    r = np.sqrt(hi / lo)
    assert np.mean(e0 < np.sqrt(lo * hi)) == pytest.approx(r / (1 + r), abs=0.03)


_WIDE_ATT = Attitude(300.0, 40.0, -15.0)


@pytest.fixture(scope="module")
def wide() -> tuple[HealpixGrid, Instrument, TimeBinning]:
    """A 45 deg cone (beyond the tangent grids' comfort) at nside 32 (1.8 deg pixels), the
    prototype and 60 time bins."""
    grid = HealpixGrid(32, 300.0, 40.0, 45.0, _WIDE_ATT)
    return grid, load_instrument("prototype"), TimeBinning(60)


def test_healpix_wide_field_equals_explicit_directions(wide) -> None:
    from rotmod.response import MatrixFreeResponse
    from rotmod.sky import SkyGeometry

    grid, inst, tb = wide
    assert grid.size > 1500 and grid_from_dict(grid.to_dict()) == grid

    class Explicit(SkyGeometry):  # the same pixel directions handed over as a plain list
        size, shape = grid.size, grid.shape

        @staticmethod
        def directions():
            return grid.directions()

        @staticmethod
        def to_dict():
            return {"kind": "explicit"}

        @classmethod
        def from_dict(cls, d):
            return cls()

    a = MatrixFreeResponse(inst, grid, tb, energy=122, dtype=np.float64)
    b = MatrixFreeResponse(inst, Explicit(), tb, energy=122, dtype=np.float64)
    x = np.random.default_rng(0).random(grid.size)
    np.testing.assert_array_equal(a.forward(x), b.forward(x))


# The default method's ~900 iterations on ~1500 pixels (~7 s of the ~9): run by `-m slow`.
@pytest.mark.slow
def test_healpix_wide_field_images(wide, tmp_path) -> None:
    from astropy.table import Table

    from rotmod.io.images import write_image

    grid, inst, tb = wide
    true = SkyCoord(310.0 * u.deg, 55.0 * u.deg)  # 18 deg off axis
    src = PointSources.from_sky(true, _WIDE_ATT, rate=30.0, energy=122.0)
    folded = fold(simulate_observation(inst, src, t_stop=1200.0, background=5.0, seed=3), 60)
    res = reconstruct(build_response(inst, grid, tb, energy=122, dtype=np.float64), folded)
    brightest = grid.sky_coords()[int(np.argmax(res.image))]
    # Within one HEALPix pixel (1.8 deg across at nside 32).
    assert brightest.separation(true).deg < 1.9
    path = write_image(tmp_path / "hp.fits", res, meta={"exposure": 1200.0})
    t = Table.read(path, hdu="HEALPIX")
    # The pixel indices, in the GADF sparse convention gammapy and healpy read (an explicit
    # PIXEL column before: tests/io/test_images.py checks those files still read).
    assert t.meta["NSIDE"] == 32 and t.meta["INDXSCHM"] == "SPARSE"
    np.testing.assert_array_equal(t["PIX"], grid.pixels)


def test_a_grid_around_a_skycoord_in_any_frame() -> None:
    from astropy.coordinates import SkyCoord

    att = Attitude(83.6, 22.0, 0.0)
    crab = SkyCoord(184.5575438, -5.7843130, unit="deg", frame="galactic")
    grid = CelestialGrid.around(crab, (5, 5), 0.5, att)
    # The centre pixel is the source: the galactic position taken to ICRS.
    assert grid.sky_coords()[12].separation(crab).to_value("arcsec") < 1e-6
    assert grid == CelestialGrid((5, 5), 0.5, crab.icrs.ra, crab.icrs.dec, att)
    with pytest.raises(ParameterError, match="center must be one astropy SkyCoord"):
        CelestialGrid.around((83.6, 22.0), (5, 5), 0.5, att)

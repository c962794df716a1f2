"""Source products as files: catalogues (FITS, ECSV) that astropy and gammapy read and that seed a
fit, TS maps in their grid's FITS form, DS9 regions, HEALPix probability maps that healpy reads,
light curves.

The results written are of known content (tests/io/conftest.py): regions whose density is a
Gaussian of known widths, so that their areas are known in closed form.
"""

from __future__ import annotations

import dataclasses

import astropy.units as u
import numpy as np
import pytest
from astropy.coordinates import SkyCoord, SkyOffsetFrame
from astropy.io import fits
from astropy.table import Table

import rotmod.io as rio
from rotmod.errors import ParameterError, RotmodError
from rotmod.io.catalogue import SourceCatalogue, read_catalogue, write_catalogue, write_detection
from rotmod.io.regions import (
    HealpixProbability,
    read_probability_map,
    write_ds9,
)
from rotmod.io.tsmaps import MAPS, TSMapFile, read_ts_map
from rotmod.response import build_response
from rotmod.sky import AttitudeTable, CelestialGrid
from rotmod.sources import Detection, FitResult, PointSource, SkyModel
from rotmod.sources.catalogue import probability_map, read_sky_model
from rotmod.testing import tiny_instrument
from tests.io.conftest import ATTITUDE, gaussian_region, source_results

#: ``-2 ln(1 - q)``: the squared Mahalanobis radius of a Gaussian's ``q`` region.
K2_90 = -2.0 * np.log(0.1)


@pytest.fixture(scope="module")
def results() -> dict[str, object]:
    return source_results()


def _ellipse_perimeter(a: float, b: float) -> float:
    """Ramanujan's approximation (relative error < 1e-5 at these axis ratios)."""
    h = ((a - b) / (a + b)) ** 2
    return np.pi * (a + b) * (1 + 3 * h / (10 + np.sqrt(4 - 3 * h)))


# -- catalogues -------------------------------------------------------------------------------


@pytest.mark.parametrize("ext", [".fits", ".ecsv"])
def test_catalogue_round_trips_with_units_and_seeds_a_model(results, tmp_path, ext) -> None:
    det: Detection = results["detection"]
    path = rio.write(det, tmp_path / f"cat{ext}", seed=3, command="rotmod detect ...")
    t = Table.read(path)
    assert t.colnames == ["NAME", "RA", "DEC", "R68", "R90", "SYS_ERR", "TS", "SQRT_TS",
                          "FLUX", "FLUX_ERRN", "FLUX_ERRP", "FLUX_UL"]
    for name in ("RA", "DEC", "R68", "R90", "SYS_ERR"):
        assert t[name].unit == u.deg
    for name in ("FLUX", "FLUX_ERRN", "FLUX_ERRP", "FLUX_UL"):
        assert t[name].unit == u.Unit("1 / s")
    assert (t.meta["UL_CONF"], t.meta["THRESH"], t.meta["SKYFRAME"], t.meta["RADESYS"]) == (
        0.95, 25.0, "celestial", "ICRS")
    assert t.meta["CREATOR"].startswith("rotmod") and t.meta["SEED"] == 3
    res = det.result
    np.testing.assert_array_equal(t["TS"], res.ts)
    np.testing.assert_array_equal(t["SQRT_TS"], np.sqrt(res.ts))
    np.testing.assert_array_equal(t["FLUX_ERRN"], res.flux_err[:, 0])
    np.testing.assert_array_equal(t["FLUX_UL"], res.flux_ul)
    np.testing.assert_array_equal(t["R90"], [r.radius(0.9) for r in det.regions])
    np.testing.assert_array_equal(t["R68"], [r.radius(0.68) for r in det.regions])

    cat = rio.read(path)  # the file says what it holds
    assert isinstance(cat, SourceCatalogue) and cat.frame == "celestial"
    assert cat.names == ("S1", "S2") and cat.threshold == 25.0 and cat.ul_confidence == 0.95
    truth = SkyCoord([s.position for s in det.sources])
    # float64 written whole (FITS binary, ECSV full repr): the same positions to rounding.
    assert cat.positions.separation(truth).deg.max() < 1e-9
    model = read_sky_model(path)
    assert [s.name for s in model.sources] == ["S1", "S2"]
    assert [s.flux for s in model.sources] == [s.flux for s in det.sources]
    assert not any(s.free_position for s in model.sources)
    assert model.background is None  # a fit starts the background from the counts
    assert all(s.free_position for s in read_sky_model(cat, free_positions=True).sources)


@pytest.mark.parametrize("ext", [".fits", ".ecsv"])
def test_a_detection_writes_its_confusion_noise(results, tmp_path, ext) -> None:
    det = dataclasses.replace(results["detection"], confusion=1.5)
    t = Table.read(rio.write(det, tmp_path / f"cat{ext}"))
    assert t.meta["CONFUSN"] == 1.5
    np.testing.assert_allclose(t["TS_CONF"], det.result.ts / 3.25, rtol=1e-15)
    np.testing.assert_allclose(det.ts_confused, det.result.ts / 3.25, rtol=1e-15)


def test_gammapy_reads_positions_and_names(results, tmp_path) -> None:
    catalog = pytest.importorskip("gammapy.catalog")

    class RotmodCatalog(catalog.SourceCatalog):
        tag = "rotmod"
        description = "a rotmod source catalogue"

    path = write_detection(results["detection"], tmp_path / "cat.fits")
    cat = RotmodCatalog(Table.read(path), source_name_key="NAME")
    truth = SkyCoord([s.position for s in results["detection"].sources])
    assert cat.positions.separation(truth).deg.max() < 1e-9
    assert cat["S2"].position.separation(truth[1]).deg < 1e-9


def test_instrument_frame_and_empty_catalogues(results, tmp_path) -> None:
    fit: FitResult = results["instrument fit"]
    path = write_catalogue(fit, tmp_path / "inst.ecsv")
    t = Table.read(path)
    assert {"THETA", "PHI"} <= set(t.colnames) and "RA" not in t.colnames
    assert t["THETA"].unit == u.deg and t.meta["SKYFRAME"] == "instrument"
    assert "RADESYS" not in t.meta and "THRESH" not in t.meta
    assert np.all(np.isnan(t["R90"])) and np.all(np.isnan(t["SYS_ERR"]))  # no regions
    model = read_sky_model(path)
    # The unnamed second source gets the name detection would give it.
    assert [s.name for s in model.sources] == ["A", "S2"]
    assert [s.position for s in model.sources] == [s.position for s in fit.model.sources]

    # No source: a valid empty catalogue, in the frame of the detection's grid.
    empty = FitResult(SkyModel(background=np.ones(7)), -1.0, np.zeros(0), np.zeros((0, 2)),
                      np.zeros(0), 0.95, np.zeros((7, 12)), 84)
    det = results["detection"]
    none = Detection(empty, [], det.ts_map, det.first_map, 25.0)
    cat = read_catalogue(write_detection(none, tmp_path / "none.fits"))
    assert len(cat) == 0 and cat.frame == "celestial" and {"RA", "DEC"} <= set(cat.table.colnames)
    assert read_sky_model(cat).sources == ()
    with pytest.raises(ParameterError, match="frame: give the frame"):
        write_catalogue(empty, tmp_path / "x.fits")
    with pytest.raises(ParameterError, match="regions must have one entry per source"):
        write_catalogue(fit, tmp_path / "x.fits", regions=[None])


def _write(table: Table, path) -> str:
    table.write(path, format="ascii.ecsv" if str(path).endswith(".ecsv") else "fits")
    return str(path)


def test_foreign_tables_seed_models(tmp_path) -> None:
    # gammapy's column names, no units (deg), no fluxes (start at 0).
    t = Table({"Source_Name": ["Crab", "Geminga"], "RAJ2000": [83.633, 98.476],
               "DEJ2000": [22.014, 17.770]})
    model = read_sky_model(_write(t, tmp_path / "a.ecsv"))
    assert [s.name for s in model.sources] == ["Crab", "Geminga"]
    assert [s.flux for s in model.sources] == [0.0, 0.0]
    assert model.sources[0].position.separation(SkyCoord(83.633, 22.014, unit="deg")).deg < 1e-9
    # Positions with a unit are converted; lower-case names are fine.
    t = Table({"ra": [np.radians(83.633)] * u.rad, "dec": [np.radians(22.014)] * u.rad,
               "flux": [0.2] / u.s})
    model = read_sky_model(_write(t, tmp_path / "b.fits"))
    assert model.sources[0].position.separation(SkyCoord(83.633, 22.014, unit="deg")).deg \
        < 1e-9
    assert model.sources[0].flux == pytest.approx(0.2)


@pytest.mark.parametrize(("table", "message"), [
    (Table({"NAME": ["a"], "GLON": [1.0], "GLAT": [2.0]}),
     r"needs position columns RA and DEC .* the table has NAME, GLON, GLAT"),
    (Table({"NAME": ["a", "b"], "RA": [1.0, np.nan], "DEC": [2.0, 3.0]}),
     r"the position of row 1 \(b\) is not finite"),
    (Table({"RA": [1.0], "DEC": [95.0]}), r"DEC of row 0 must be in \[-90, 90\] deg"),
    (Table({"RA": [1.0], "DEC": [2.0], "FLUX": [1e-11] * u.Unit("erg cm-2 s-1")}),
     r"column FLUX must be in units of 1 / s"),
    (Table({"NAME": ["a"], "RA": [1.0], "DEC": [2.0], "FLUX": [-0.1]}),
     r"the flux of 'a' must be >= 0"),
    (Table({"NAME": ["a"], "THETA": [95.0], "PHI": [2.0]}),
     r"THETA of 'a' must be in \[0, 90\) deg"),
])
def test_bad_catalogues_are_refused_with_the_rule(tmp_path, table, message) -> None:
    with pytest.raises(ParameterError, match=message):
        read_sky_model(_write(table, tmp_path / "bad.fits"))


def test_positions_the_response_cannot_see_are_refused(tmp_path) -> None:
    inst = tiny_instrument()
    response = build_response(inst, CelestialGrid((1, 1), 1.0, 83.6, 22.0, ATTITUDE), 12,
                              "exact", 300.0)
    # 95 deg from the pointing: behind the detectors.
    behind = SkyCoord(83.6 * u.deg, 22.0 * u.deg).directional_offset_by(0 * u.deg, 95 * u.deg)
    t = Table({"NAME": ["near", "behind"], "RA": [84.0, behind.ra.deg],
               "DEC": [22.5, behind.dec.deg]})
    with pytest.raises(ParameterError, match="below the instrument's horizon"):
        read_sky_model(_write(t, tmp_path / "c.fits"), response=response)
    # Instrument directions for a response on the sky.
    t = Table({"THETA": [1.0], "PHI": [2.0]})
    with pytest.raises(ParameterError, match="positions must be an astropy SkyCoord"):
        read_sky_model(_write(t, tmp_path / "d.ecsv"), response=response)
    model = read_sky_model(_write(Table({"RA": [84.0], "DEC": [22.5]}), tmp_path / "e.ecsv"),
                           response=response)
    assert len(model.sources) == 1


def test_one_overwrite_policy_and_the_registry(results, tmp_path) -> None:
    det = results["detection"]
    path = rio.write(det, tmp_path / "cat.ecsv")
    with pytest.raises(ParameterError, match="already exists; pass overwrite=True"):
        rio.write(det, path)
    rio.write(det, path, overwrite=True)
    with pytest.raises(ParameterError, match=r"must end with \.fits, \.fits\.gz, \.ecsv"):
        write_detection(det, tmp_path / "cat.txt")
    with pytest.raises(ParameterError, match="the extension names no format"):
        rio.write(det, tmp_path / "cat.txt")
    # ECSV files of two classes: each reader knows its own.
    aspect = rio.write(AttitudeTable([0.0, 60.0], [10.0, 10.5], [20.0, 20.2], [0.0, 5.0]),
                       tmp_path / "aspect.ecsv")
    assert isinstance(rio.read(aspect), AttitudeTable)
    assert isinstance(rio.read(path), SourceCatalogue)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["aspect.ecsv", "cat.ecsv"]


# -- TS maps ----------------------------------------------------------------------------------


@pytest.mark.parametrize("kind", ["instrument map", "celestial map", "healpix map"])
def test_ts_maps_round_trip_in_their_grid_form(results, tmp_path, kind) -> None:
    ts_map = results[kind]
    path = rio.write(ts_map, tmp_path / "ts.fits", command="rotmod detect ...")
    back = rio.read(path)
    assert isinstance(back, TSMapFile) and back.grid == ts_map.grid
    assert (back.ul_confidence, back.sensitivity_ts) == (0.95, 25.0)
    for name, (attr, _) in MAPS.items():
        np.testing.assert_array_equal(back.maps[name], getattr(ts_map, attr))  # NaN too
    with fits.open(path) as hl:
        assert [h.name for h in hl[1:]] == list(MAPS)
        if kind == "healpix map":  # pixel tables: PIX, VALUE, as HEALPix readers take them
            assert back.wcs is None
            np.testing.assert_array_equal(hl["FLUX"].data["PIX"], ts_map.grid.pixels)
            assert hl["FLUX"].columns["VALUE"].unit == "s-1"
            assert hl["TS"].header["NSIDE"] == 64
        else:  # WCS images that ds9 and astropy place
            assert hl["FLUX"].header["BUNIT"] == "s-1"
            assert hl["TS"].header["CTYPE1"] == ts_map.grid.wcs().wcs.ctype[0]
            ny, nx = ts_map.grid.shape
            corners = ([0, nx - 1, 0, nx - 1], [0, 0, ny - 1, ny - 1])
            np.testing.assert_allclose(back.wcs.celestial.all_pix2world(*corners, 0),
                                       ts_map.grid.wcs().all_pix2world(*corners, 0))


@pytest.mark.parametrize("kind", ["instrument map", "healpix map"])
def test_a_screened_map_keeps_which_pixels_are_exact(results, tmp_path, kind) -> None:
    ts_map = results[kind]
    exact = np.zeros(ts_map.grid.shape, dtype=bool)
    exact.ravel()[::3] = True
    screened = dataclasses.replace(ts_map, exact=exact, exact_above=25.0, screen_cut=19.5)
    back = rio.read(rio.write(screened, tmp_path / "ts.fits"))
    np.testing.assert_array_equal(back.exact, exact)
    assert (back.header["EXACTAB"], back.header["SCRNCUT"]) == (25.0, 19.5)
    assert rio.read(rio.write(ts_map, tmp_path / "all.fits")).exact is None


def test_healpix_ts_maps_read_in_healpy(results, tmp_path) -> None:
    healpy = pytest.importorskip("healpy")
    ts_map = results["healpix map"]
    path = rio.write(ts_map, tmp_path / "ts.fits")
    m = healpy.read_map(str(path), hdu=list(MAPS).index("FLUX") + 1, partial=True,
                        nest=True, dtype=float)
    np.testing.assert_array_equal(m[ts_map.grid.pixels], ts_map.flux.ravel())


def test_a_file_without_maps_is_not_a_ts_map(tmp_path) -> None:
    fits.HDUList([fits.PrimaryHDU()]).writeto(tmp_path / "x.fits")
    with pytest.raises(ParameterError, match="is not a TS-map file"):
        read_ts_map(tmp_path / "x.fits")
    with pytest.raises(RotmodError, match="does not exist"):
        read_ts_map(tmp_path / "missing.fits")


# -- regions ----------------------------------------------------------------------------------


def _tangent_area(vertices: SkyCoord, centre: SkyCoord) -> float:
    """Area (deg^2) of a small spherical polygon, by the shoelace formula in the tangent
    plane at ``centre`` (the plane's distortion is < 1e-4 within a degree)."""
    off = vertices.transform_to(SkyOffsetFrame(origin=centre))
    x, y = off.lon.deg, off.lat.deg
    return 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def test_ds9_regions_parse_back_as_the_regions(results, tmp_path) -> None:
    regions = pytest.importorskip("regions")
    det = results["detection"]
    path = write_ds9(det.regions, tmp_path / "det.reg")
    parsed = regions.Regions.read(str(path), format="ds9")
    points = [r for r in parsed if isinstance(r, regions.PointSkyRegion)]
    polygons = [r for r in parsed if isinstance(r, regions.PolygonSkyRegion)]
    assert [p.meta["text"] for p in points] == ["S1", "S2"]
    assert [p.meta["text"] for p in polygons] == ["S1 90%", "S1 68%", "S2 90%", "S2 68%"]
    for p, s in zip(points, det.sources, strict=True):
        assert p.center.separation(s.position).deg < 1e-6  # 7 decimals written
    # The 90 % outline of S1 (Gaussian widths 0.2 x 0.3 deg) encloses the Gaussian's 90 %
    # ellipse.  Discretisation: the contour interpolates a density sampled every
    # `step`, so the outline may move by up to half a step along the ellipse's perimeter.
    region = det.regions[0]
    area = _tangent_area(polygons[0].vertices, det.sources[0].position)
    a, b = 0.2 * np.sqrt(K2_90), 0.3 * np.sqrt(K2_90)
    step = np.degrees(region.offsets[1] - region.offsets[0])
    assert area == pytest.approx(np.pi * a * b, abs=_ellipse_perimeter(a, b) * step / 2)
    # Elongated north-south as the density is (its second tangent axis points north here).
    v = polygons[0].vertices.transform_to(SkyOffsetFrame(origin=det.sources[0].position))
    assert np.ptp(v.lat.deg) / np.ptp(v.lon.deg) == pytest.approx(1.5, rel=0.05)


def test_ds9_refuses_instrument_frame_regions(tmp_path) -> None:
    region = gaussian_region(PointSource((2.0, 30.0), name="A"))
    with pytest.raises(ParameterError, match="'A' is in the instrument frame"):
        write_ds9([region], tmp_path / "r.reg")
    assert not (tmp_path / "r.reg").exists()
    with pytest.raises(ParameterError, match="'A' is in the instrument frame"):
        probability_map(region)


def test_probability_map_is_the_region_on_healpix(results, tmp_path) -> None:
    healpy = pytest.importorskip("healpy")
    hp = pytest.importorskip("astropy_healpix")
    region = results["detection"].regions[0]  # Gaussian, 0.2 x 0.3 deg
    prob = probability_map(region)
    # The coarsest nside with pixels at most r68 / 4 across.
    res = hp.nside_to_pixel_resolution(prob.nside).to_value(u.deg)
    assert res <= region.radius(0.68) / 4 < 2 * res
    path = rio.write(prob, tmp_path / "prob.fits")
    m = healpy.read_map(str(path), partial=True, nest=True, dtype=float)
    seen = np.flatnonzero(m != healpy.UNSEEN)
    np.testing.assert_array_equal(seen, prob.pixels)
    assert m[seen].sum() == pytest.approx(1.0, abs=1e-12)
    # The source's pixel holds the most probability (the Gaussian's peak).
    own = hp.HEALPix(prob.nside, "nested", frame="icrs").skycoord_to_healpix(region.source.position)
    assert prob.pixels[np.argmax(prob.prob)] == own
    # Its 90 % highest-density set has the region's area: both discretise one Gaussian, the
    # map's boundary uncertain by half a pixel and the region's by half a grid step along
    # the 90 % ellipse's perimeter.
    p = np.sort(m[seen])[::-1]
    n90 = int(np.searchsorted(np.cumsum(p), 0.9)) + 1
    area = n90 * hp.nside_to_pixel_area(prob.nside).to_value(u.deg**2)
    a, b = 0.2 * np.sqrt(K2_90), 0.3 * np.sqrt(K2_90)
    step = np.degrees(region.offsets[1] - region.offsets[0])
    band = _ellipse_perimeter(a, b) * (res + step) / 2
    assert area == pytest.approx(region.area(0.9), abs=band)
    assert area == pytest.approx(np.pi * a * b, abs=band)
    back = read_probability_map(path)
    np.testing.assert_array_equal(back.pixels, prob.pixels)
    np.testing.assert_array_equal(back.prob, prob.prob)
    assert (back.nside, back.order, back.name) == (prob.nside, "nested", "S1")


def test_probability_map_of_several_regions_holds_their_weights() -> None:
    # Two modes of one position, weighted 3 : 1, far apart: each one's pixels hold its
    # weight (the squares' densities are each normalised; the map sums them).
    pytest.importorskip("astropy_healpix")
    a = gaussian_region(PointSource(SkyCoord(10.0 * u.deg, 20.0 * u.deg), name="A"))
    b = gaussian_region(PointSource(SkyCoord(40.0 * u.deg, -5.0 * u.deg), name="B"))
    prob = probability_map([a, b], weights=[3.0, 1.0])
    assert prob.prob.sum() == pytest.approx(1.0, abs=1e-12)
    import astropy_healpix as hp
    centres = hp.HEALPix(prob.nside, "nested", frame="icrs").healpix_to_skycoord(prob.pixels)
    near_a = centres.separation(a.source.position).deg < 5.0
    # The square's density is sampled at the pixel centres: the sum over pixels equals the
    # square's total to the discretisation of a Gaussian at a quarter of r68 (< 1 %).
    assert prob.prob[near_a].sum() == pytest.approx(0.75, rel=0.01)
    assert prob.name == "A"
    with pytest.raises(ParameterError, match="weights must be 2 finite values"):
        probability_map([a, b], weights=[1.0, -1.0])
    with pytest.raises(ParameterError, match="a Region or a sequence"):
        probability_map([a, "b"])


def test_probability_maps_refuse_what_is_no_map() -> None:
    with pytest.raises(ParameterError, match="nside must be a power of 2"):
        HealpixProbability(3, [0], [1.0])
    with pytest.raises(ParameterError, match="sum to 1"):
        HealpixProbability(4, [0, 1], [0.5, 0.4])
    with pytest.raises(ParameterError, match="distinct HEALPix indices"):
        HealpixProbability(4, [0, 0], [0.5, 0.5])


# -- light curves -----------------------------------------------------------------------------


@pytest.mark.parametrize("ext", [".fits", ".ecsv"])
def test_light_curves_as_tables(results, tmp_path, ext) -> None:
    lc = results["light curve"]
    t = Table.read(rio.write(lc, tmp_path / f"lc{ext}", command="rotmod lightcurve ..."))
    assert len(t) == 4 and t["flux"].shape == (4, 2)
    assert t["time_min"].unit == u.s and t["flux_ul"].unit == u.Unit("1 / s")
    np.testing.assert_array_equal(t["exposure"], lc.exposure)
    assert t.meta["SOURCES"] == "S1,S2" and t.meta["UL_CONF"] == 0.95
    assert t.meta["COMMAND"] == "rotmod lightcurve ..."

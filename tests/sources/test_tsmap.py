"""TS maps against independent per-pixel fits, the Asimov definition of sensitivity and the
null distribution of a bounded flux."""

from __future__ import annotations

import astropy.units as u
import numpy as np
import pytest
from astropy.coordinates import SkyCoord
from scipy import stats

from rotmod.errors import ParameterError
from rotmod.reconstruction import PoissonData
from rotmod.response import RadonResponse, TimeBinning, build_response
from rotmod.response.columns import columns_at
from rotmod.sky import Attitude, HealpixGrid
from rotmod.sources import PointSource, SkyModel, SourceFitter, fit, ts_map
from rotmod.sources.detection import pixel_position
from rotmod.sources.tsmap import null_state, scan_test_source

BKG = 2.0


@pytest.fixture(scope="module")
def data(field):
    truth = SkyModel([PointSource((3.3, 47.0), flux=0.08)], background=np.full(7, BKG))
    return truth.simulate(field, 3000.0, seed=7)


def test_every_pixel_is_the_fit_of_a_source_there(field, data):
    m = ts_map(field, data)
    for pixel in (0, 40, int(np.argmax(m.ts)), 143):
        ref = fit(field, data, SkyModel([PointSource(pixel_position(field, pixel))]))
        # Two maximisers (numba Newton per pixel, the projected Newton of the fit) of the
        # same likelihood: they agree to their convergence, ~1e-8 of ln L.
        assert m.ts.ravel()[pixel] == pytest.approx(ref.ts[0], abs=1e-6)
        assert m.flux.ravel()[pixel] == pytest.approx(ref.model.sources[0].flux, abs=1e-9)
        assert m.flux_ul.ravel()[pixel] == pytest.approx(ref.flux_ul[0], rel=1e-5)
    k, ts = m.peak()
    assert ts == np.nanmax(m.ts) and ts > 25
    assert PointSource(pixel_position(field, k)).separation(PointSource((3.3, 47.0))) < 1.0


def test_sensitivity_is_the_flux_whose_asimov_data_reach_the_chosen_ts(field):
    null = SkyModel(background=np.full(7, BKG))
    m = ts_map(field, null.simulate(field, 3000.0, seed=2), sensitivity_ts=25.0)
    pixel = 77
    s = m.sensitivity.ravel()[pixel]
    src = PointSource(pixel_position(field, pixel), flux=s)
    # The Asimov data of that flux over the *fitted* null of the map's data.
    fitted_null = SourceFitter(field, null.simulate(field, 3000.0, seed=2)).maximise(null)[0]
    asimov = fitted_null.replace(sources=(src,))
    counts = asimov.expected_counts(field, 3000.0)
    res = fit(field, PoissonData(counts, 3000.0), SkyModel([PointSource(src.position)]))
    assert res.ts[0] == pytest.approx(25.0, rel=1e-5)


def test_null_ts_at_a_fixed_position_is_half_chi2_0_half_chi2_1(field):
    """Chernoff's mixture, measured (benchmarks/sources_calibration.py does it at scale)."""
    rng = np.random.default_rng(12)
    null = SkyModel(background=np.full(7, BKG))
    column = columns_at(field, ([4.0], [120.0]))
    ts = []
    for _ in range(400):
        fitter = SourceFitter(field, null.simulate(field, 500.0, seed=rng))
        ts.append(scan_test_source(fitter, null_state(fitter, None), fitter.on_bins(column),
                                   0.0, 0.0)[0, 0])
    ts = np.array(ts)
    zero = np.mean(ts < 1e-9)
    # 400 draws: the fraction at 0 has sd 0.025; 3 sd either side of 1/2.
    assert abs(zero - 0.5) < 0.075
    assert stats.kstest(ts[ts >= 1e-9], stats.chi2(1).cdf).pvalue > 1e-3


def test_a_known_background_is_held_not_fitted(field):
    truth = SkyModel(background=np.full(7, BKG))
    counts = truth.simulate(field, 1000.0, seed=4).counts
    known = PoissonData(counts, 1000.0, background=BKG)
    m = ts_map(field, known)
    ref = fit(field, known, SkyModel([PointSource(pixel_position(field, 30))]))
    assert m.ts.ravel()[30] == pytest.approx(ref.ts[0], abs=1e-6)


def test_a_healpix_map_finds_a_sky_source(survey_instrument):
    att = Attitude(83.6, 22.0)
    grid = HealpixGrid(64, 83.6, 22.0, 6.0, att)
    resp = build_response(survey_instrument, grid, 60, energy=300, dtype=np.float64)
    pos = SkyCoord(85.0 * u.deg, 24.0 * u.deg)
    truth = SkyModel([PointSource(pos, flux=0.05)], background=np.full(7, BKG))
    calls = []
    m = ts_map(resp, truth.simulate(resp, 3000.0, seed=1),
               progress=lambda done, total: calls.append((done, total)))
    assert m.ts.shape == (1, grid.size) and calls[-1] == (grid.size, grid.size)
    best = grid.sky_coords()[m.peak()[0]]
    assert best.separation(pos).deg < 1.0  # pixels are 0.9 deg across


# -- screened maps (exact_above) ------------------------------------------------------------


@pytest.mark.parametrize("kind", ["materialised", "radon", "radon-averaged-bins"])
def test_a_screened_map_is_the_exact_map_wherever_ts_reaches_the_cut(field, kind):
    # The Radon response is what wide fields use; with bins averaged over sub-samples its
    # squared table overestimates the information, which the calibration must catch.
    tb = TimeBinning(60, "average", 3) if kind == "radon-averaged-bins" else 60
    resp = field if kind == "materialised" else RadonResponse(
        field.instrument, field.grid, tb, 300.0, dtype=np.float64)
    truth = SkyModel([PointSource((3.3, 47.0), flux=0.08), PointSource((6.0, 200.0),
                                                                        flux=0.03)],
                     background=np.full(7, BKG))
    data = truth.simulate(resp, 3000.0, seed=11)
    full = ts_map(resp, data)
    cut = 4.0
    screened = ts_map(resp, data, exact_above=cut)
    e = screened.exact
    # The pixels computed exactly are those of the full map, bit for bit (the same kernel on
    # the same columns), every pixel whose TS reaches the cut is among them, and the screen
    # decided from below the cut.
    for name in ("ts", "flux", "flux_err", "flux_ul", "sensitivity"):
        np.testing.assert_array_equal(getattr(screened, name)[e], getattr(full, name)[e])
    assert np.all(e[full.ts >= cut])
    assert 0 < e.sum() < e.size and screened.screen_cut < cut
    # Elsewhere the score test: below the likelihood ratio by the pooled background
    # correction, never above it by more than the score's own excess for these faint
    # signals (TS < 4: |score - LR| ~ TS^1.5 / sqrt(bins per detector), ~1e-2 here).
    below = ~e
    assert np.all(screened.ts[below] <= full.ts[below] + 0.02)
    assert np.all(screened.ts[below] >= screened.screen_cut / cut * full.ts[below] - 0.02)


def test_the_screen_is_the_score_test_of_a_faint_source(field):
    """With the background known (no pooling), the screen's readings are the likelihood's
    to the first order in the source's share of the counts: on Asimov data of a source
    giving ~0.2 % of the counts they agree to ~1e-3."""
    src = PointSource((3.3, 47.0), flux=0.004)
    counts = SkyModel([src], background=np.full(7, BKG)).expected_counts(field, 3000.0)
    data = PoissonData(counts, 3000.0, background=BKG)
    full = ts_map(field, data)
    screen = ts_map(field, data, exact_above=1e9)  # nothing computed exactly
    assert not screen.exact.any()
    seen = full.ts > 0.1
    for name in ("ts", "flux", "flux_err", "flux_ul", "sensitivity"):
        np.testing.assert_allclose(getattr(screen, name)[seen], getattr(full, name)[seen],
                                   rtol=2e-3)


def test_a_screened_map_is_refused_what_it_cannot_do(field):
    data = SkyModel(background=np.full(7, BKG)).simulate(field, 100.0, seed=1)
    for bad in (-1.0, float("nan"), "abc", [1.0, 2.0]):
        with pytest.raises(ParameterError, match="exact_above"):
            ts_map(field, data, exact_above=bad)

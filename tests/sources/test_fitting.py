"""Fits of sky models: truth recovered from noiseless data, the likelihood's own intervals,
the Monte Carlo's counts, and refusals of bad input."""

from __future__ import annotations

import astropy.units as u
import numpy as np
import pytest
from astropy.coordinates import SkyCoord

from rotmod.errors import ParameterError
from rotmod.events import fold
from rotmod.montecarlo import simulate_observation
from rotmod.reconstruction import PoissonData
from rotmod.response import build_response
from rotmod.sky import Attitude, CelestialGrid
from rotmod.sources import PointSource, SkyModel, SourceFitter, fit

BKG = 2.0  # counts/s per detector


def _asimov(model, response, exposure):
    """The noiseless data set: counts equal to their expectation."""
    return PoissonData(model.expected_counts(response, exposure), exposure)


def test_noiseless_data_give_back_the_truth_in_the_instrument_frame(field):
    truth = SkyModel([PointSource((3.3, 47.0), flux=0.05)], background=np.full(7, BKG))
    res = fit(field, _asimov(truth, field, 4000.0),
              SkyModel([PointSource((2.5, 40.0), free_position=True)]))
    src = res.model.sources[0]
    # The maximum of an Asimov likelihood is the truth; the tolerances are the optimiser's
    # (Nelder-Mead stops at ~1e-4 of a quarter of b/L = 0.43 deg).
    assert src.separation(truth.sources[0]) < 1e-3
    assert src.flux == pytest.approx(0.05, rel=1e-4)
    np.testing.assert_allclose(res.model.background, BKG, rtol=1e-5)
    assert res.ts[0] > 25


def test_noiseless_data_give_back_the_truth_on_the_sky(survey_instrument):
    att = Attitude(266.4, -28.9, roll=15.0)
    grid = CelestialGrid((9, 9), 1.5, 266.4, -28.9, att)
    resp = build_response(survey_instrument, grid, 60, energy=300, dtype=np.float64)
    pos = SkyCoord(268.0 * u.deg, -27.5 * u.deg)
    truth = SkyModel([PointSource(pos, flux=0.08)], background=np.full(7, BKG))
    start = SkyCoord(267.0 * u.deg, -28.0 * u.deg)
    res = fit(resp, _asimov(truth, resp, 4000.0),
              SkyModel([PointSource(start, free_position=True)]), errors=False)
    assert res.model.sources[0].position.separation(pos).deg < 1e-3
    assert res.model.sources[0].flux == pytest.approx(0.08, rel=1e-4)


def test_errors_and_limits_are_where_the_profile_likelihood_says(field):
    truth = SkyModel([PointSource((3.3, 47.0), flux=0.02)], background=np.full(7, BKG))
    data = truth.simulate(field, 4000.0, seed=3)
    res = fit(field, data, SkyModel([PointSource((3.3, 47.0))]))
    fitter = SourceFitter(field, data)
    f = res.model.sources[0].flux
    lo, hi = res.flux_err[0]
    # Independent of the root finder: re-evaluate the profile at the reported bounds.
    for flux, level in ((f - lo, 1.0), (f + hi, 1.0), (res.flux_ul[0], 2.706)):
        delta = 2 * (res.loglike - fitter.profile(res.model, 0, flux))
        assert delta == pytest.approx(level, abs=2e-3) or (flux == 0 and delta < level)
    # With ~1e6 counts the profile is close to a parabola: errors close to symmetric and to
    # the curvature error (10 %).
    assert lo == pytest.approx(hi, rel=0.1)


def test_a_flux_below_zero_is_held_at_the_bound(field):
    truth = SkyModel(background=np.full(7, BKG))
    data = truth.simulate(field, 1000.0, seed=11)
    # Seeds where the test source's unconstrained flux would be negative: TS is 0 there.
    fluxes, ts = [], []
    for th, ph in ((2.0, 10.0), (4.0, 100.0), (5.0, 200.0), (3.0, 300.0)):
        r = fit(field, data, SkyModel([PointSource((th, ph))]))
        fluxes.append(r.model.sources[0].flux)
        ts.append(r.ts[0])
    fluxes, ts = np.array(fluxes), np.array(ts)
    assert np.all(fluxes >= 0) and np.all(ts >= 0)
    assert np.all(ts[fluxes == 0] == 0)


def test_the_monte_carlo_and_the_fit_agree(survey_instrument, field):
    """Photons transported by the Monte Carlo, folded, fitted with the exact model's
    response: the flux and background come back within their errors."""
    truth = SkyModel([PointSource((3.3, 47.0), flux=0.6)], background=np.full(7, BKG))
    ev = simulate_observation(survey_instrument, truth.point_sources(300.0), t_stop=6000.0,
                              background=BKG, seed=5)
    res = fit(field, fold(ev, field.time_bins), SkyModel([PointSource((3.3, 47.0))]))
    lo, hi = res.flux_err[0]
    # 3 sigma: a fixed seed, so this is a check of bias, not a flaky draw.
    assert abs(res.model.sources[0].flux - 0.6) < 3 * max(lo, hi)
    err_b = np.sqrt(BKG / 6000.0)  # Poisson error of a level from 6000 s of counts
    assert np.all(np.abs(res.model.background - BKG) < 4 * err_b)


def test_bad_input_is_refused_with_the_parameter_named(field):
    data = SkyModel(background=np.full(7, BKG)).simulate(field, 100.0, seed=1)
    with pytest.raises(ParameterError, match="theta must be finite"):
        PointSource((np.nan, 3.0))
    with pytest.raises(ParameterError, match="theta"):
        PointSource((95.0, 3.0))
    with pytest.raises(ParameterError, match="flux"):
        PointSource((1.0, 3.0), flux=-1.0)
    with pytest.raises(ParameterError, match="model must be a SkyModel"):
        fit(field, data, [PointSource((1.0, 2.0))])
    with pytest.raises(ParameterError, match="instrument directions"):
        fit(field, data, SkyModel([PointSource(SkyCoord(1 * u.deg, 2 * u.deg))]))
    with pytest.raises(ParameterError, match="ul_confidence"):
        fit(field, data, SkyModel([PointSource((1.0, 2.0))]), ul_confidence=1.5)
    with pytest.raises(ParameterError, match="shape"):
        fit(field, PoissonData(np.ones((3, 4))), SkyModel())
    with pytest.raises(ParameterError, match="one frame"):
        SkyModel([PointSource((1.0, 2.0)), PointSource(SkyCoord(1 * u.deg, 2 * u.deg))])

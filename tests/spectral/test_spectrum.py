"""Counts spectra, folding and forward-folded fits: statistics against independent code and the
fitted errors calibrated over injections."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import erf

from rotmod.errors import ParameterError
from rotmod.spectral import (
    Band,
    CountsSpectrum,
    PowerLaw,
    SpectralResponse,
    cash,
    fit_spectrum,
    wstat,
)


def gaussian_response(n_e: int = 120, n_c: int = 48, eff: float = 0.8) -> SpectralResponse:
    """A scintillator-like response: Gaussian redistribution of 4 % FWHM-ish width at 662 keV
    scaling as E^-1/2, ``eff`` of the photons in the channels, 100 cm^2."""
    ee = np.geomspace(20.0, 3000.0, n_e + 1)
    ce = np.geomspace(30.0, 2000.0, n_c + 1)
    ec = np.sqrt(ee[:-1] * ee[1:])
    sig = (0.04 * ec * (ec / 662.0) ** -0.5)[:, None] * np.sqrt(2.0)
    m = 0.5 * (erf((ce[None, 1:] - ec[:, None]) / sig) - erf((ce[None, :-1] - ec[:, None]) / sig))
    return SpectralResponse(ee, ce, eff * m, np.full(n_e, 100.0))


def test_fold_is_linear_and_conserves_photons() -> None:
    """Folding is linear in the model, and with a diagonal unit matrix the counts are the
    photons of each bin times area and exposure."""
    ee = np.geomspace(50.0, 500.0, 11)
    r = SpectralResponse(ee, ee, np.eye(10), np.full(10, 20.0))
    pl = PowerLaw(1e-3, -2.0)
    np.testing.assert_allclose(r.fold(pl, 100.0), 100.0 * 20.0 * pl.integral(ee[:-1], ee[1:]))
    np.testing.assert_allclose(r.fold(pl.with_parameters(K=3e-3), 100.0), 3 * r.fold(pl, 100.0))


def test_statistics_match_gammapy() -> None:
    """Cash and W statistics against gammapy's implementations (independent code), summed over
    channels, including channels with zero counts on and off."""
    stats = pytest.importorskip("gammapy.stats")
    rng = np.random.default_rng(3)
    mu = rng.uniform(0.1, 30.0, 40)
    n = rng.poisson(mu)
    n[:3] = 0
    # gammapy's cash is 2 (mu - n ln mu); ours is relative to the saturated model (mu = n),
    # which differs by the data-only constant 2 sum (n - n ln n).
    sat = 2.0 * np.sum(n - n * np.log(np.where(n > 0, n, 1)))
    assert cash(n, mu) == pytest.approx(stats.cash(n, mu).sum() - sat, rel=1e-12)
    off = rng.poisson(2.0 * mu)
    off[5:8] = 0
    sig = rng.uniform(0.0, 10.0, 40)
    assert wstat(n, off, 0.5, sig) == pytest.approx(stats.wstat(n, off, 0.5, sig).sum(), rel=1e-10)


@pytest.mark.parametrize("with_background", [False, True])
def test_fit_errors_cover_and_are_unbiased(with_background: bool) -> None:
    """Over 150 Poisson injections of an E^-2 power law (with and without a measured
    background, W statistic), the index's and K's 1-sigma errors hold the truth at 68 % within
    the 2-sigma binomial band for 150 (0.60-0.76), the pulls have unit width, and the bias is
    below a third of the error (the issue's criterion)."""
    r = gaussian_response()
    truth = PowerLaw(1e-4, -2.0)
    expo = 1e4
    rng = np.random.default_rng(11)
    pulls = []
    for _ in range(150):
        counts = rng.poisson(r.fold(truth, expo) + (20.0 if with_background else 0.0))
        bkg = (CountsSpectrum(rng.poisson(np.full(48, 40.0)), expo, backscal=2.0)
               if with_background else None)
        fit = fit_spectrum(CountsSpectrum(counts, expo, r, bkg), PowerLaw(2e-4, -1.5))
        pulls.append([(fit.model.K - truth.K) / fit.errors["K"],
                      (fit.model.index - truth.index) / fit.errors["index"]])
    pulls = np.array(pulls)
    inside = np.mean(np.abs(pulls) < 1.0, axis=0)
    assert np.all((inside > 0.60) & (inside < 0.76)), inside
    assert np.all(np.abs(pulls.mean(0)) < 1 / 3), pulls.mean(0)
    # Width of the pulls: 150 draws give a standard error of ~0.06 on the std.
    assert np.all(np.abs(pulls.std(0) - 1.0) < 0.15), pulls.std(0)


def test_band_fit_recovers_a_burst() -> None:
    """A bright Band burst: every parameter within 3 sigma of the truth, and the statistic
    near its expectation (the number of channels less parameters, within 5 sigma)."""
    r = gaussian_response()
    truth = Band(5e-3, -0.9, 300.0, -2.5)
    rng = np.random.default_rng(5)
    spec = CountsSpectrum(rng.poisson(r.fold(truth, 20.0)), 20.0, r)
    fit = fit_spectrum(spec, Band(3e-3, -1.2, 400.0, -2.2))
    for p in ("K", "alpha", "xp", "beta"):
        assert abs(fit.model.parameters[p] - truth.parameters[p]) < 3 * fit.errors[p], p
    dof = 48 - 4
    assert abs(fit.statistic - dof) < 5 * np.sqrt(2 * dof)


def test_a_parameter_the_data_do_not_bound_is_pegged() -> None:
    """Band bursts whose counts above the peak are too few to tell beta from a cutoff: among
    Poisson draws at ~1e4 counts some fits stop beta at astromodels' limit of -5 (1.5 % in the
    calibration); such a fit says so (pegged, no error) while the other parameters keep
    finite curvature errors.  The draws are searched, so the test does not hang on one
    generator's stream."""
    r = gaussian_response()
    truth = Band(5e-3, -0.9, 300.0, -2.5)
    rng = np.random.default_rng(7)
    for _ in range(200):
        spec = CountsSpectrum(rng.poisson(r.fold(truth, 20.0)), 20.0, r)
        # A quick screen: a Band fit pegs where a cutoff power law describes the data as
        # well; only those draws get the full fit.
        fit = fit_spectrum(spec, Band(3e-3, -1.2, 400.0, -2.2))
        if fit.pegged:
            break
    else:
        pytest.fail("no pegged fit in 200 draws (the calibration pegs 1.5 %)")
    assert fit.pegged == ("beta",)
    assert fit.model.beta == pytest.approx(-5.0, abs=1e-3)
    assert np.isnan(fit.errors["beta"])
    assert all(np.isfinite(fit.errors[p]) for p in ("K", "alpha", "xp"))
    assert fit.converged


def test_bad_input() -> None:
    r = gaussian_response()
    with pytest.raises(ParameterError, match="non-negative integers"):
        CountsSpectrum(np.full(48, 2.5), 10.0, r)
    with pytest.raises(ParameterError, match="response has 48 channels, counts 47"):
        CountsSpectrum(np.ones(47), 10.0, r)
    with pytest.raises(ParameterError, match="exposure"):
        CountsSpectrum(np.ones(48), 0.0, r)
    with pytest.raises(ParameterError, match="rows summing to <= 1"):
        SpectralResponse(r.energy_edges, r.channel_edges, 2 * r.matrix + 0.1, r.area)
    with pytest.raises(ParameterError, match="matrix must have shape"):
        SpectralResponse(r.energy_edges, r.channel_edges, r.matrix[:, :-1], r.area)
    with pytest.raises(ParameterError, match="no response"):
        fit_spectrum(CountsSpectrum(np.ones(48), 10.0), PowerLaw())
    with pytest.raises(ParameterError, match="free must name parameters"):
        fit_spectrum(CountsSpectrum(np.ones(48), 10.0, r), PowerLaw(), free=["gamma"])
    with pytest.raises(ParameterError, match="selects no channel"):
        fit_spectrum(CountsSpectrum(np.ones(48), 10.0, r), PowerLaw(), channels=slice(0, 0))
    with pytest.raises(ParameterError, match="channels must select"):
        fit_spectrum(CountsSpectrum(np.ones(48), 10.0, r), PowerLaw(), channels=[99])
    with pytest.raises(ParameterError, match="alpha"):
        wstat(np.ones(3), np.ones(3), 0.0, np.ones(3))

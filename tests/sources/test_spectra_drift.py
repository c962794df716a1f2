"""The energy-resolved response of a drifting observation: each attitude interval sees a
source at its own zenith angle, so with its own redistribution.  Checked against the
single-attitude columns built at each interval's attitude and summed with the intervals'
weights (an independent path: ``matrix_at(theta_k)`` per interval rather than the angle
nodes' shares), and by a fit of Poisson counts simulated from it."""

from __future__ import annotations

import dataclasses

import astropy.units as u
import numpy as np
import pytest
from astropy.coordinates import SkyCoord

from rotmod import Instrument
from rotmod.energy import EnergyResolution
from rotmod.errors import ParameterError
from rotmod.geometry import DetectorArray, Mask
from rotmod.materials import Material
from rotmod.response import build_response
from rotmod.response.drift import drift_response
from rotmod.sky import Attitude, CelestialGrid
from rotmod.sources.spectra import (
    SpectralColumns,
    expected_counts,
    extract_spectrum,
    fit_spectra,
    spectral_columns,
)
from rotmod.spectral import PowerLaw
from rotmod.spectral.detector import tabulate_response

NODES = np.geomspace(80.0, 2000.0, 7)
CHANNELS = np.geomspace(60.0, 1800.0, 9)
ANGLES = [0.0, 3.0, 6.0, 10.0, 20.0]
N_T = 12
#: A zenith-pointed gondola: the axis sweeps 3 deg of RA per interval past the sources.
INTERVALS = [(0.0, 37.0, Attitude(10.0, 5.0, roll=0.0)),
             (37.0, 90.0, Attitude(13.0, 5.0, roll=15.0)),
             (90.0, 160.0, Attitude(16.0, 5.0, roll=30.0)),
             (160.0, 200.0, Attitude(19.0, 5.0, roll=45.0))]
SOURCES = SkyCoord([14.0, 11.0] * u.deg, [5.5, 4.0] * u.deg)


def _instrument() -> Instrument:
    """3 detectors of 5 cm x 5 cm NaI (the centre and two of its neighbours) under 3/3/3 cm
    lead slats 1 m up."""
    hexa = DetectorArray.hexagonal(5.0, rings=1)
    det = DetectorArray(hexa.positions[:3], 5.0, thickness=5.0,
                        material=Material("NaI", density=3.67))
    return Instrument(Mask(3.0, 3.0, 3.0, 100.0, material=Material("Pb")), det,
                      rotation_period=60.0)


@pytest.fixture(scope="module")
def setup():
    """The instrument, a detector response tabulated with few photons (only identities are
    tested with it, and a fit that uses the same table to simulate), and a small grid."""
    inst = _instrument()
    table = tabulate_response(inst.detectors, NODES, ANGLES, CHANNELS,
                              resolution=EnergyResolution.nai(), n_photons=300, seed=3)
    grid = CelestialGrid((3, 3), 2.0, 14.0, 5.0, Attitude(14.0, 5.0))
    return inst, table, grid


def _single(inst, grid, att):
    """The one-attitude response of the grid at ``att``."""
    return build_response(inst, dataclasses.replace(grid, attitude=att), N_T, energy=300.0,
                          dtype=np.float64)


@pytest.fixture(scope="module")
def drift(setup):
    """The drift's response, its spectral columns, and the single-attitude columns of each
    interval (each with ``matrix_at`` at the interval's own angle)."""
    inst, table, grid = setup
    response = drift_response(inst, grid, N_T, INTERVALS, energy=300.0)
    singles = [spectral_columns(_single(inst, grid, att), SOURCES, table)
               for _, _, att in INTERVALS]
    return response, spectral_columns(response, SOURCES, table), singles


def test_angle_weights_are_matrix_at(setup) -> None:
    """The hat weights rebuild the interpolated redistribution (the identity the drift's
    columns rest on), to rounding."""
    _, table, _ = setup
    theta = np.array([0.0, 1.3, 3.0, 7.9, 19.99])
    h = table.angle_weights(theta)
    np.testing.assert_allclose(h.sum(axis=1), 1.0, rtol=1e-15)
    np.testing.assert_allclose(np.einsum("na,aec->nec", h, table.matrix),
                               table.matrix_at(theta), rtol=1e-13, atol=1e-16)


def test_one_attitude_drift_is_the_pointed_columns(setup) -> None:
    """A drift whose intervals all have one attitude predicts the pointed observation's
    rates: the intervals' weights sum to 1 in every bin.  1e-12: rounding of that sum."""
    inst, table, grid = setup
    att = INTERVALS[1][2]
    steady = drift_response(inst, grid, N_T, [(0.0, 37.0, att), (37.0, 90.0, att)],
                            energy=300.0)
    cols = spectral_columns(steady, SOURCES, table)
    one = spectral_columns(_single(inst, grid, att), SOURCES, table)
    assert cols.columns.shape[1] == 1            # one angle node: the sources do not move
    for k, m in enumerate([PowerLaw(1e-3, -2.0), PowerLaw(3e-3, -1.5)]):
        got, want = cols.rates(k, m), one.rates(k, m)
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=0)
        print(f"one-attitude drift vs pointed: max relative {np.max(np.abs(got / want - 1)):.1e}")


@pytest.mark.parametrize("with_air", [False, True])
def test_drift_is_the_weighted_sum_of_its_intervals(setup, drift, with_air) -> None:
    """The drift's rates are the sum over intervals of the single-attitude columns at each
    interval's attitude (their redistribution ``matrix_at(theta_k)``) weighted bin by bin
    by the interval's share of the bin's exposure -- with a transmission per interval too
    (a zenith-pointed balloon: each source's zenith changes; applied to each interval's
    columns as ``spectral_columns`` applies one).  The sources cross tabulated angles (at
    1.1-5.0 and 1.4-8.0 deg: 3 and 6 deg) during the drift.  1e-10: the identity is
    exact, rounding only."""
    _, table, _ = setup
    response, cols, singles = drift
    air = None
    if with_air:
        depth = np.array([3.0, 4.0, 5.0, 6.5])[:, None, None]   # g/cm2, per interval
        air = np.exp(-depth * 0.15 * (NODES / 100.0) ** -0.35) * np.ones((1, 2, 1))
        cols = spectral_columns(response, SOURCES, table, interval_transmission=air)
    theta = np.array([att.to_instrument(SOURCES)[0].to_value(u.deg)
                      for _, _, att in INTERVALS])
    assert np.ptp(theta[:, 0]) > 3.0 and np.ptp(theta[:, 1]) > 3.0, theta
    assert cols.columns.shape[1] >= 3            # the tabulated angles the sources visit
    worst = 0.0
    for s, m in enumerate([PowerLaw(1e-3, -2.0), PowerLaw(3e-3, -1.5)]):
        want = 0.0
        for k, ((w, _), one) in enumerate(zip(response.components(), singles, strict=True)):
            np.testing.assert_allclose(one.theta[:, 0], theta[k], atol=1e-9)
            if air is not None:
                one = SpectralColumns(one.columns * air[k][:, None, :, None, None],
                                      one.redistribution, one.energies, one.channel_edges,
                                      one.theta)
            want = want + w[None, :, None] * one.rates(s, m)
        got = cols.rates(s, m)
        assert np.all(want >= 0) and want.max() > 0
        np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-12 * want.max())
        worst = max(worst, float(np.abs(got - want).max() / want.max()))
    print(f"drift vs the intervals' sum: max |diff| / max = {worst:.2e}")


def test_fit_of_a_drift_recovers_the_power_law(drift) -> None:
    """Poisson counts simulated from a drift's rates (source + a flat background), fitted
    with the drift's columns and a background level per detector and channel: the index
    and normalisation lie within 3 sigma of the truth (a correct fit fails each with
    probability ~0.3 %; fixed seed).  The index's error is below 0.2 (a fit that lost the
    source's modulation would not constrain it)."""
    _, both, singles = drift
    cols = SpectralColumns(both.columns[:1], both.redistribution[:1], both.energies,
                           both.channel_edges, both.theta[:1])
    truth = PowerLaw(2e-2, -2.0)
    expo = np.full(N_T, 2000.0)
    mu = expected_counts(cols, expo, [truth], 0.05)
    y = np.random.default_rng(23).poisson(mu)
    fit = fit_spectra(cols, y, expo, [PowerLaw(1e-2, -1.7)], free=[["K", "index"]])
    err = fit.errors[0]
    print(f"fitted {fit.models[0].parameters}, errors {err}")
    assert fit.converged
    assert 0 < err["index"] < 0.2, err
    assert abs(fit.models[0].parameters["index"] + 2.0) < 3 * err["index"], (fit.models, err)
    assert abs(fit.models[0].parameters["K"] - 2e-2) < 3 * err["K"], (fit.models, err)
    # The same counts fitted as a pointed observation at the middle interval's attitude
    # (its columns and redistribution): the drift's own columns fit far better.
    mid = singles[2]
    pointed = SpectralColumns(mid.columns[:1], mid.redistribution[:1], mid.energies,
                              mid.channel_edges, mid.theta[:1])
    wrong = fit_spectra(pointed, y, expo, [PowerLaw(1e-2, -1.7)], free=[["K", "index"]])
    print(f"2 ln L ratio, drift vs pointed columns: {2 * (fit.loglike - wrong.loglike):.1f}")
    assert 2 * (fit.loglike - wrong.loglike) > 100.0


def test_bad_input_is_refused(setup, drift) -> None:
    _, table, _ = setup
    drift = drift[0]
    with pytest.raises(ParameterError, match="interval_transmission must have shape"):
        spectral_columns(drift, SOURCES, table, interval_transmission=np.ones((3, 2, 7)))
    with pytest.raises(ParameterError, match="interval_transmission"):
        spectral_columns(drift, SOURCES, table, transmission=np.ones((2, 7)),
                         interval_transmission=np.ones((4, 2, 7)))
    with pytest.raises(ParameterError, match="one attitude each"):
        spectral_columns(drift, SOURCES, table, transmission=np.ones((3, 2, 7)))
    with pytest.raises(ParameterError, match="interval_transmission must broadcast"):
        spectral_columns(drift, SOURCES, table, interval_transmission=np.ones((4, 2, 5)))
    with pytest.raises(ParameterError, match=r"interval_transmission must lie in \[0, 1\]"):
        spectral_columns(drift, SOURCES, table, interval_transmission=np.full((4, 2, 7), 2.0))
    with pytest.raises(ParameterError, match="columns must have shape"):
        SpectralColumns(np.ones((1, 7, 3, N_T)), np.ones((1, 7, 8)), NODES, CHANNELS,
                        np.array([5.0]))
    with pytest.raises(ParameterError, match="theta must have shape"):
        SpectralColumns(np.ones((1, 1, 7, 3, N_T)), np.ones((1, 1, 7, 8)), NODES, CHANNELS,
                        np.array([5.0]))


def test_extracted_spectrum_of_a_drift_is_predicted_by_its_response(drift) -> None:
    """Per-source spectra of a drift (expected counts of both sources and a background as
    data): with the true patterns the extracted rate is the source's own rate per channel
    (from the columns, without the extraction) to rounding; with a wrong pattern (E^-2 for
    E^-1.5) it differs from that by more than 0.2 %, and folding the true spectrum through
    the response returned (its angle nodes' areas summed) gives it -- to the response's
    tabulation between nodes, second order (these nodes are 1.7x apart: measured 2.4e-3 at
    subdivide 4, 6.0e-4 at 8), so asserted as at least 3x closer at subdivide 8 than at 4
    and below 2e-3 there.  The RMF's rows sum to at most 1."""
    _, cols, _ = drift
    truth = [PowerLaw(1e-2, -1.5), PowerLaw(2e-2, -2.2)]
    expo = np.full(N_T, 500.0)
    mu = expected_counts(cols, expo, truth, 0.04)
    spec = extract_spectrum(cols, mu, expo, 0, models=truth)
    own = np.einsum("dtc,t->c", cols.rates(0, truth[0]), expo) / spec.exposure
    np.testing.assert_allclose(spec.rate, own, rtol=1e-10)
    errs = []
    for sub in (4, 8):
        wrong = extract_spectrum(cols, mu, expo, 0, models=[PowerLaw(), truth[1]],
                                 subdivide=sub)
        assert np.max(np.abs(wrong.rate / own - 1.0)) > 2e-3
        assert np.all(wrong.response.matrix.sum(axis=1) <= 1.0 + 1e-12)
        folded = wrong.response.fold(truth[0], wrong.exposure) / wrong.exposure
        errs.append(float(np.max(np.abs(folded / wrong.rate - 1.0))))
    print(f"extracted vs folded through its response, subdivide 4, 8: {errs}")
    assert errs[1] < errs[0] / 3 and errs[1] < 2e-3


@pytest.fixture(scope="module")
def slices(setup):
    """A drift cut into two time slices (intervals 0-1 and 2-3), one drift response each."""
    inst, _, grid = setup
    return [drift_response(inst, grid, N_T, part, energy=300.0)
            for part in (INTERVALS[:2], INTERVALS[2:])]


@pytest.mark.parametrize("air", ["none", "slice", "interval"])
def test_time_slices_of_a_drift_are_each_slice_alone(setup, slices, air) -> None:
    """A flight cut into time slices with a response each (a zenith-pointed gondola: the
    sources move from slice to slice): each slice's rates are those of its own response's
    columns built alone -- with a transmission per slice, or per attitude interval across
    the slices (the intervals of every slice in order).  The slices' columns share the
    angle nodes of the whole flight, the one built alone only those of its slice; the nodes
    a slice does not visit get no share, so the identity is exact: 1e-12 is rounding."""
    _, table, _ = setup
    kw: list[dict] = [{}, {}]
    both: dict = {}
    if air == "slice":
        trans = np.exp(-np.array([3.0, 6.0])[:, None, None] * 0.15 * (NODES / 100.0) ** -0.35)
        trans = trans * np.ones((1, 2, 1))
        both, kw = {"transmission": trans}, [{"transmission": t} for t in trans]
    elif air == "interval":
        depth = np.array([3.0, 4.0, 5.0, 6.5])[:, None, None]
        trans = np.exp(-depth * 0.15 * (NODES / 100.0) ** -0.35) * np.ones((1, 2, 1))
        both = {"interval_transmission": trans}
        kw = [{"interval_transmission": trans[:2]}, {"interval_transmission": trans[2:]}]
    cols = spectral_columns(slices, SOURCES, table, **both)
    assert cols.shape == (2, 3, N_T, CHANNELS.size - 1) and cols.n_sources == 2
    worst = 0.0
    for s, m in enumerate([PowerLaw(1e-3, -2.0), PowerLaw(3e-3, -1.5)]):
        got = cols.rates(s, m)
        for i, response in enumerate(slices):
            want = spectral_columns(response, SOURCES, table, **kw[i]).rates(s, m)
            assert want.max() > 0
            np.testing.assert_allclose(got[i], want, rtol=1e-12, atol=1e-14 * want.max())
            worst = max(worst, float(np.abs(got[i] - want).max() / want.max()))
    print(f"time slices vs each slice alone ({air}): max |diff| / max = {worst:.1e}")


def test_fit_of_a_sliced_drift_recovers_the_power_law(setup, slices) -> None:
    """Poisson counts of a drift cut into two time slices (source + a background whose
    level differs between the slices), fitted with the sliced columns and a level per
    detector and channel shaped in time by a template: the index and normalisation lie
    within 3 sigma of the truth (each fails with probability ~0.3 % for a correct fit;
    fixed seed), and the fit of the same counts with the second slice's columns in both
    (the source taken as not moving) is far worse."""
    _, table, _ = setup
    cols = spectral_columns(slices, SOURCES[:1], table)
    truth = PowerLaw(2e-2, -2.0)
    expo = np.full((2, N_T), 1000.0)
    template = np.array([1.0, 1.6])[:, None] * np.ones(CHANNELS.size - 1)   # (n_slice, n_c)
    mu = expected_counts(cols, expo, [truth], 0.05 * template)
    y = np.random.default_rng(29).poisson(mu)
    fit = fit_spectra(cols, y, expo, [PowerLaw(1e-2, -1.7)], free=[["K", "index"]],
                      background=template)
    err = fit.errors[0]
    pull = (fit.scales - 0.05) / fit.scale_errors
    print(f"fitted {fit.models[0].parameters}, errors {err}; background scales' pulls "
          f"{pull.mean():.2f} +- {pull.std():.2f} ({pull.size})")
    assert fit.converged and 0 < err["index"] < 0.2, err
    assert abs(fit.models[0].parameters["index"] + 2.0) < 3 * err["index"], (fit.models, err)
    assert abs(fit.models[0].parameters["K"] - 2e-2) < 3 * err["K"], (fit.models, err)
    still = SpectralColumns(np.stack([cols.columns[1]] * 2), cols.redistribution,
                            cols.energies, cols.channel_edges, cols.theta)
    wrong = fit_spectra(still, y, expo, [PowerLaw(1e-2, -1.7)], free=[["K", "index"]],
                        background=template)
    print(f"2 ln L ratio, sliced vs still columns: {2 * (fit.loglike - wrong.loglike):.1f}")
    assert 2 * (fit.loglike - wrong.loglike) > 25.0


def test_time_slices_bad_input(setup, slices) -> None:
    inst, table, grid = setup
    with pytest.raises(ParameterError, match="sequence of one or more"):
        spectral_columns([], SOURCES, table)
    with pytest.raises(ParameterError, match="sequence of one or more"):
        spectral_columns([slices[0], "x"], SOURCES, table)
    other = drift_response(inst, grid, N_T + 1, INTERVALS[2:], energy=300.0)
    with pytest.raises(ParameterError, match="mask-angle bins"):
        spectral_columns([slices[0], other], SOURCES, table)
    slow = dataclasses.replace(inst, rotation_period=120.0)
    with pytest.raises(ParameterError, match="rotation period"):
        spectral_columns([slices[0], drift_response(slow, grid, N_T, INTERVALS[2:],
                                                    energy=300.0)], SOURCES, table)
    with pytest.raises(ParameterError, match="one slice per response"):
        spectral_columns(slices, SOURCES, table, transmission=np.ones((3, 2, 7)))
    with pytest.raises(ParameterError, match="interval_transmission must have shape"):
        spectral_columns(slices, SOURCES, table, interval_transmission=np.ones((2, 2, 7)))
    cols = spectral_columns(slices, SOURCES, table)
    with pytest.raises(ParameterError, match="transmission must have shape"):
        SpectralColumns(cols.columns, cols.redistribution, cols.energies, cols.channel_edges,
                        cols.theta, np.ones((3, 2, 7)))
    with pytest.raises(ParameterError, match="time slices are fitted with fit_spectra"):
        extract_spectrum(cols, np.ones(cols.shape), np.ones(N_T))

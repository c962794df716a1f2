"""The energy-resolved response against the whole chain simulated photon by photon (issue 23).

The response (:func:`rotmod.sources.spectra.spectral_columns`) predicts counts per detector,
mask-angle bin and channel from node energies: the exact model's columns at each node, a
tabulated redistribution (forced-collision Monte Carlo, histogrammed, folded with the
resolution), both taken as linear in ``ln E`` between the nodes.  The chain
(:func:`rotmod.montecarlo.simulate_channel_counts`) has none of that: each photon has its own
energy, crosses the 3-D slats and the crystal in the instrument Monte Carlo, gets its own
deposit from an analog detector history and its own Gaussian smearing.  The slats are 1 cm
of lead, whose transmission goes from 1 % at 300 keV to 45 % at 1 MeV and 59 % at 2 MeV,
so the modulation changes with energy across the channels.  Shared by both (not
tested here): the cross-sections, the uniformly lit crystal, the resolution's law.
"""

from __future__ import annotations

import numpy as np
import pytest

from rotmod import Instrument
from rotmod.binning import TimeBinning
from rotmod.energy import EnergyResolution
from rotmod.energy import PowerLaw as PhotonPowerLaw
from rotmod.errors import ParameterError
from rotmod.geometry import DetectorArray, Mask
from rotmod.limits import TimeBudgetError
from rotmod.materials import Material
from rotmod.montecarlo import simulate_channel_counts, simulate_profiles
from rotmod.response import build_response
from rotmod.sky import SkyGrid
from rotmod.sources.spectra import SpectralColumns, spectral_columns
from rotmod.spectral import Gaussian, PowerLaw
from rotmod.spectral.detector import draw_deposits, simulate_deposits, tabulate_response

NAI = Material("NaI", density=3.67)
THETA, PHI, N_TIME = 10.0, 30.0, 8
CHANNELS = np.geomspace(120.0, 2000.0, 7)
RESOLUTION = EnergyResolution.nai()
LINE = 662.0
#: Power-law nodes 4.9 % apart (the docs' advice: closer than the resolution's FWHM, 7.5 %
#: at 662 keV for NaI).
NODES = np.geomspace(200.0, 2000.0, 48)
SEEDS = {"line_table": 1, "pl_table": 2, "line_mc": 3, "pl_energies": 4, "pl_mc": 5}


def _instrument() -> Instrument:
    """7 detectors of 5 cm x 5 cm NaI under lead slats 3 cm wide, 3 cm apart, 1 cm thick,
    1 m up."""
    hexa = DetectorArray.hexagonal(5.0, rings=1)
    det = DetectorArray(hexa.positions, 5.0, thickness=5.0, material=NAI)
    return Instrument(Mask(3.0, 3.0, 1.0, 100.0, material=Material("Pb")), det,
                      rotation_period=60.0)


def predicted(response, table, model, face_photons: np.ndarray) -> np.ndarray:
    """The response's expected counts ``(n_det, n_time, n_c)`` when ``face_photons`` of the
    spectrum ``model`` (normalised over the table's nodes) cross each detector's face in
    each bin: rates per photon cm^-2 s^-1 over the projected face area."""
    cols = spectral_columns(response, (THETA, PHI), table)
    return _scaled(cols, model, face_photons)


def _scaled(cols: SpectralColumns, model, face_photons: np.ndarray) -> np.ndarray:
    rate = cols.rates(0, model)
    flux = model.node_weights(cols.energies).sum()
    area = np.pi * 2.5**2 * np.cos(np.radians(THETA))
    return rate * face_photons[:, None, None] / (area * flux)


def pearson(counts: np.ndarray, mu: np.ndarray) -> tuple[float, int, float]:
    """Pearson chi-square over the cells expecting 5 counts or more, its degrees of freedom
    (those cells; nothing is fitted) and the largest ``|pull|``.  The other cells (a line's
    Gaussian tail beyond its channel) must hold what they expect, within 5 sigma."""
    ok = mu >= 5.0
    rest = mu[~ok].sum()
    assert counts[~ok].sum() <= rest + 5.0 * np.sqrt(rest) + 5.0
    pull = (counts[ok] - mu[ok]) / np.sqrt(mu[ok])
    return float(pull @ pull), int(ok.sum()), float(np.abs(pull).max())


@pytest.fixture(scope="module")
def chain():
    inst = _instrument()
    binning = TimeBinning(N_TIME)
    response = build_response(inst, SkyGrid.square(4, 1.0), binning, "exact", energy=300.0)
    return inst, response, np.degrees(binning.angles())


def test_line_between_nodes_agrees_with_the_chain(chain) -> None:
    """A 662 keV line, between two nodes 3.3 % apart (at 40 % of the interval in ``ln E``):
    expected counts per detector, bin and channel against 20 000 photons per detector and
    bin (4 channels hold counts: 56 x 4 = 224 cells of 420 to 4300 counts).

    Tolerance: the Pearson chi-square of ``dof`` cells has mean ``dof`` and standard
    deviation ``sqrt(2 dof)`` (21); the table's own Monte Carlo (1e5 photons a node) moves
    every cell of a channel together by ~0.3 %, a fifth to a half of a cell's 1-4 %
    Poisson error, which can add up to ~25 % of ``dof``.  So ``chi2/dof < 1.45`` (20 seeds
    of the chain: 0.79-1.15, mean 0.96) and ``|pull| < 4.5`` (over 224 cells, 1.5e-3 by
    chance; 20 seeds: at most 3.7)."""
    inst, response, xi = chain
    table = tabulate_response(inst.detectors, [650.0, 672.0], [THETA], CHANNELS,
                              resolution=RESOLUTION, n_photons=100_000,
                              seed=SEEDS["line_table"])
    mc = simulate_channel_counts(inst, THETA, PHI, np.full(20_000, LINE), CHANNELS, xi=xi,
                                 resolution=RESOLUTION, seed=SEEDS["line_mc"])
    mu = predicted(response, table, Gaussian(1.0, LINE, 0.01), mc.face_photons)
    chi2, dof, worst = pearson(mc.counts, mu)
    assert dof == 7 * N_TIME * 4
    assert chi2 / dof < 1.45, (chi2, dof)
    assert worst < 4.5


def test_power_law_agrees_with_the_chain(chain) -> None:
    """An ``E^-2`` continuum over 200 keV-2 MeV: 24 000 photons per detector and bin, each
    with its own energy, against the response on 48 nodes (336 cells of 180 to 4800
    counts).  Tolerance as for the line (the table's noise, 1e4 photons a node, averages
    over the nodes a channel collects from; photons of one energy in different cells add a
    little to the spread of chi2): ``chi2/dof < 1.45`` (20 seeds: 0.76-1.28, mean 0.97)
    and ``|pull| < 4.5`` (20 seeds: at most 3.7).  At 48 nodes the lowest channel
    (120-192 keV, the resolution's tail of the lowest photopeaks) is 2 % low, a fifth of a
    cell's error there (benchmarks/spectra_chain.py: 96 nodes remove it).

    The check has the power to see the energy dependence of the modulation: the same
    response with every node's modulation pattern taken from the 662 keV node (its
    normalisation per detector kept) is refused by it (``chi2/dof`` > 2; 20 seeds:
    6.6-7.6)."""
    inst, response, xi = chain
    table = tabulate_response(inst.detectors, NODES, [THETA], CHANNELS,
                              resolution=RESOLUTION, n_photons=10_000,
                              seed=SEEDS["pl_table"])
    rng = np.random.default_rng(SEEDS["pl_energies"])
    energies = PhotonPowerLaw(2.0, NODES[0], NODES[-1]).draw(
        np.full(24_000, NODES[0]), np.full(24_000, NODES[-1]), rng)
    mc = simulate_channel_counts(inst, THETA, PHI, energies, CHANNELS, xi=xi,
                                 resolution=RESOLUTION, seed=SEEDS["pl_mc"])
    model = PowerLaw(1.0, -2.0, 100.0)
    cols = spectral_columns(response, (THETA, PHI), table)
    mu = _scaled(cols, model, mc.face_photons)
    chi2, dof, worst = pearson(mc.counts, mu)
    assert dof == 7 * N_TIME * 6
    assert chi2 / dof < 1.45, (chi2, dof)
    assert worst < 4.5
    # Modulation frozen at one energy: each node's pattern over the bins is that of 662 keV.
    k = int(np.argmin(np.abs(NODES - LINE)))
    c = cols.columns
    frozen = c[:, :, k:k + 1] * (c.sum(axis=4, keepdims=True)
                                 / c[:, :, k:k + 1].sum(axis=4, keepdims=True))
    wrong = SpectralColumns(frozen, cols.redistribution, cols.energies, cols.channel_edges,
                            cols.theta)
    chi2_wrong, _, _ = pearson(mc.counts, _scaled(wrong, model, mc.face_photons))
    assert chi2_wrong / dof > 2.0, chi2_wrong / dof


def test_drawn_deposits_follow_the_tabulated_redistribution() -> None:
    """Deposits drawn photon by photon (analog, one interacting history each) against the
    histogrammed forced-collision transport at 662 keV, 10 deg: the photofraction within 4
    standard errors (both Monte Carlos' errors) and the escape-free share alike; a deposit
    never exceeds its photon's energy."""
    det = _instrument().detectors
    d = draw_deposits(det, np.full(100_000, LINE), THETA, seed=11)
    s = simulate_deposits(det, LINE, THETA, n_photons=100_000, seed=12)
    full = np.mean(d >= LINE * (1 - 1e-9))
    err = np.hypot(np.sqrt(full * (1 - full) / d.size), s.error("full_energy"))
    assert abs(full - s.full_energy) < 4 * err
    assert np.all((d >= 0) & (d <= LINE * (1 + 1e-9)))
    mixed = draw_deposits(det, [100.0, 2000.0] * 10, THETA, seed=1)
    assert np.all(mixed[0::2] <= 100.0 * (1 + 1e-9))
    # ... and each photon has its own energy: 2 MeV photons deposit more than 100 keV.
    assert np.any(mixed[1::2] > 100.0)


def test_per_source_energies_set_each_sources_attenuation() -> None:
    """One energy per source: the same direction at 300 keV (lead opaque) and 2 MeV (60 %
    through 1 cm) gives each its own profile, as separate runs do (binomial errors,
    5 sigma)."""
    inst = _instrument()
    edges = np.linspace(0.0, 360.0, 5)
    both = simulate_profiles(inst, [THETA] * 2, [PHI] * 2, xi_edges=edges,
                             energy=[300.0, 2000.0], n_photons=20_000, seed=1)
    spread = both.fraction.std(axis=1) / both.fraction.mean(axis=1)   # (n_det, n_src)
    assert spread[:, 0].mean() > 1.5 * spread[:, 1].mean()     # opaque slats modulate more
    for j, e in enumerate((300.0, 2000.0)):
        one = simulate_profiles(inst, [THETA], [PHI], xi_edges=edges, energy=e,
                                n_photons=20_000, seed=2 + j)
        p = one.fraction[..., 0]
        err = np.sqrt(2 * one.scale[:, :, 0] * p / 20_000)
        assert np.all(np.abs(both.fraction[..., j] - p) < 5 * err)
    with pytest.raises(ParameterError, match="one per source"):
        simulate_profiles(inst, [THETA] * 2, [PHI] * 2, xi_edges=edges,
                          energy=[300.0, 400.0, 500.0], n_photons=10)


def test_chain_bad_input(chain) -> None:
    inst, _, xi = chain
    flat = Instrument(inst.mask, DetectorArray(inst.detectors.positions, 5.0),
                      rotation_period=60.0)
    with pytest.raises(ParameterError, match="thickness"):
        simulate_channel_counts(flat, THETA, PHI, [300.0], CHANNELS, xi=xi)
    with pytest.raises(ParameterError, match="energies"):
        simulate_channel_counts(inst, THETA, PHI, [], CHANNELS, xi=xi)
    with pytest.raises(ParameterError, match="theta"):
        simulate_channel_counts(inst, 95.0, PHI, [300.0], CHANNELS, xi=xi)
    with pytest.raises(ParameterError, match="exactly one of xi"):
        simulate_channel_counts(inst, THETA, PHI, [300.0], CHANNELS)
    with pytest.raises(ParameterError, match="resolution"):
        simulate_channel_counts(inst, THETA, PHI, [300.0], CHANNELS, xi=xi,
                                resolution=0.07)
    with pytest.raises(ParameterError, match="energies"):
        draw_deposits(inst.detectors, [-1.0], THETA)


def test_draw_deposits_refuses_hopeless_analog_work_and_takes_read_only_energies(
        monkeypatch) -> None:
    """Drawn until one interacts, a photon costs ~1/P primaries: a 10 um crystal at 20 MeV
    (P ~ 1.2e-4) with 1e5 photons is ~8.5e8 primaries, ~30 s at the Monte Carlo's rate --
    refused under a 1 s budget before it starts, naming the parameter; a read-only energies
    array (as PointSources hold) gives the same deposits as a writable one."""
    monkeypatch.setenv("ROTMOD_TIME_BUDGET", "1s")
    thin = DetectorArray([[0.0, 0.0]], 5.0, thickness=1e-3, material=NAI)
    with pytest.raises(TimeBudgetError, match="energies"):
        draw_deposits(thin, np.full(100_000, 20_000.0), 0.0)
    monkeypatch.delenv("ROTMOD_TIME_BUDGET")
    det = DetectorArray([[0.0, 0.0]], 5.0, thickness=5.0, material=NAI)
    ro = np.full(50, 662.0)
    ro.flags.writeable = False
    np.testing.assert_array_equal(draw_deposits(det, ro, 10.0, seed=3),
                                  draw_deposits(det, ro.copy(), 10.0, seed=3))

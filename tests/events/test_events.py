"""Event lists and folding: exact exposure, counts, and the model profile recovered."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from rotmod import ParameterError, get_model
from rotmod.binning import EnergyBand, TimeBinning
from rotmod.events import EventList, FoldedProfiles, exposure_per_bin, fold
from rotmod.montecarlo import simulate_observation
from rotmod.sky import PointSources
from rotmod.testing import tiny_instrument
from tests.conftest import rad


def _inst(n_rings=0, T=60.0):
    return tiny_instrument(rings=n_rings, rotation_period=T)


# ----------------------------------------------------------------------------- exposure


@pytest.mark.parametrize(
    ("gti", "phase", "expected"),
    [
        # 1.5 rotations of 60 s in 4 bins of 15 s each: one full turn, then bins 0 and 1.
        ([[0.0, 90.0]], 0.0, [30, 30, 15, 15]),
        # Start a quarter turn in: q runs 0.25 .. 1.75.
        ([[0.0, 90.0]], np.pi / 2, [15, 30, 30, 15]),
        # A gap from 30 s to 45 s (q 0.5 .. 0.75, bin 2) is never exposed.
        ([[0.0, 30.0], [45.0, 90.0]], 0.0, [30, 30, 0, 15]),
        # Non-integer edges: q 1/6 .. 5/12 -> 5 s in bin 0, 10 s in bin 1.
        ([[10.0, 25.0]], 0.0, [5, 10, 0, 0]),
        # Negative times and a phase beyond one turn: q runs 1.0 .. 1.5.
        ([[-30.0, 0.0]], 2 * np.pi + np.pi, [15, 15, 0, 0]),
    ],
)
def test_exposure_per_bin_analytic(gti, phase, expected):
    ex = exposure_per_bin(gti, 4, 60.0, rad(phase))
    # Exact arithmetic up to rounding of t / T (relative 1e-15 of ~100 s).
    np.testing.assert_allclose(ex, expected, atol=1e-9)


def test_exposure_matches_brute_force():
    rng = np.random.default_rng(1)
    edges = np.sort(rng.uniform(0, 1000, 12)).reshape(6, 2)
    ex = exposure_per_bin(edges, 7, 37.3, rad(0.9))
    assert ex.sum() == pytest.approx(np.sum(edges[:, 1] - edges[:, 0]), rel=1e-12)
    # Brute force on a 1 ms grid: each sample carries 1 ms, so bins agree within a few ms
    # (each GTI end can misplace at most one sample per bin crossing).
    t = np.concatenate([np.arange(a, b, 1e-3) + 5e-4 for a, b in edges])
    q = t / 37.3 + 0.9 / (2 * np.pi)
    k = ((q - np.floor(q)) * 7).astype(int)
    np.testing.assert_allclose(np.bincount(k, minlength=7) * 1e-3, ex, atol=0.02)


# ----------------------------------------------------------------------------- folding


def test_fold_counts_hand_made():
    inst = _inst()
    # T = 60 s, 4 bins: bin k covers t mod 60 in [15k, 15k + 15).
    t = np.array([1.0, 16.0, 17.0, 50.0, 61.0, 200.0])
    ev = EventList(t, np.zeros(6, int), np.full(6, 662.0), inst, [[0.0, 120.0]])
    f = fold(ev, 4)  # the event at 200 s lies outside the GTI and is dropped
    assert f.counts.tolist() == [[2, 2, 0, 1]]
    np.testing.assert_allclose(f.exposure, [30, 30, 30, 30])
    np.testing.assert_allclose(f.rate, [[2 / 30, 2 / 30, 0, 1 / 30]])
    np.testing.assert_allclose(f.error, [[np.sqrt(2) / 30, np.sqrt(2) / 30, 0, 1 / 30]])
    np.testing.assert_allclose(f.bin_edges.to_value("rad"), np.linspace(0, 2 * np.pi, 5))


def test_fold_takes_the_response_binning_and_a_typed_band():
    inst = _inst()
    t = np.array([1.0, 16.0, 17.0, 50.0, 61.0])
    e = np.array([100.0, 122.0, 122.0, 662.0, 145.0])
    ev = EventList(t, np.zeros(5, int), e, inst, [[0.0, 120.0]], meta={"e_min": 1.0})
    tb = TimeBinning(4, "average", 8)
    f = fold(ev, tb, EnergyBand(100.0, 145.0))
    assert f.time_bins is tb and f.n_bins == 4
    assert f.counts.tolist() == [[2, 2, 0, 0]]  # 662 keV is outside the band
    # The same fold with an int and a (lo, hi) pair; the band has one owner, energy_band
    # (an event file's E_MIN/E_MAX in its meta do not describe the folded window).
    g = fold(ev, 4, (100.0, 145.0))
    assert np.array_equal(g.counts, f.counts) and np.array_equal(g.exposure, f.exposure)
    assert g.time_bins == TimeBinning(4) and g.energy_band == f.energy_band
    assert "e_min" not in f.meta and "e_min" not in g.meta
    # Without a window the band recorded is the range of the energies folded.
    assert fold(ev, 4).energy_band == EnergyBand(100.0, 662.0)
    np.testing.assert_array_equal(f.bin_edges.to_value("rad"), tb.edges())
    np.testing.assert_array_equal(f.bin_centers.to_value("rad"), tb.angles())
    with pytest.raises(ParameterError, match="time_bins must be a TimeBinning or an integer"):
        fold(ev, 4.0)
    with pytest.raises(ParameterError, match=r"time_bins must have one bin per counts column "
                                             r"\(4\), got 5"):
        FoldedProfiles(f.counts, f.exposure, 5, inst, f.gti)
    # The band has one owner: untyped keys would be ignored by the energy check of a fit.
    with pytest.raises(ParameterError, match=r"meta must not hold e_max, e_min: give the band "
                                             r"of the folded counts as energy_band="):
        FoldedProfiles(f.counts, f.exposure, 4, inst, f.gti, meta={"e_min": 1, "e_max": 2})


def test_folded_simulation_recovers_model():
    """Fold a simulated observation and compare with the exact model's expected counts."""
    inst = _inst(n_rings=1, T=20.0)  # 7 detectors
    th, ph = np.radians([8.0]), np.radians([35.0])
    rate, bkg = 400.0, 30.0
    src = PointSources(rad(th), rad(ph), rate=rate, energy=662.0)
    gti = [[3.0, 71.0], [90.0, 177.7]]  # 7.8 turns, a gap, non-integer turns
    phase = 0.7
    ev = simulate_observation(inst, src, t_stop=180.0, gti=gti, start_phase=rad(phase),
                              background=bkg, seed=11)
    n_bins, sub = 40, 20
    f = fold(ev, n_bins)
    # Expected counts: rate x integral of P over the good time in each bin, evaluated on 20
    # sub-bins per bin (exposure per sub-bin exact; P varies by < 1e-3 across a sub-bin, so
    # the quadrature error is << the Poisson error of ~30 counts per bin).
    ex_sub = exposure_per_bin(gti, n_bins * sub, inst.rotation_period, rad(phase))
    xi_sub = (np.arange(n_bins * sub) + 0.5) * 2 * np.pi / (n_bins * sub)
    P = get_model("exact").profile(inst, rad(th), rad(ph), rad(xi_sub))[:, :, 0]
    mu = (rate * P * ex_sub).reshape(7, n_bins, sub).sum(axis=2) + bkg * f.exposure
    chi2 = np.sum((f.counts - mu) ** 2 / mu)
    dof = mu.size
    # Pearson chi-square with ~1000 counts per bin is chi-square distributed; 1e-3 tails.
    assert stats.chi2.ppf(1e-3, dof) < chi2 < stats.chi2.isf(1e-3, dof), chi2 / dof
    np.testing.assert_allclose(f.exposure.sum(), ev.exposure)
    # Background rate recovered from the MC truth column within 5 sigma.
    nb = np.sum(ev.source == -1)
    assert abs(nb - 7 * bkg * ev.exposure) < 5 * np.sqrt(7 * bkg * ev.exposure)


def test_observation_reproducible_and_sorted():
    inst = _inst()
    src = PointSources(rad([0.1, 0.2]), rad([0.0, 1.0]), rate=[100.0, 50.0], energy=[662.0, 122.0])
    kw = dict(t_stop=50.0, background=5.0, background_energy=300.0, seed=3, chunk_size=500)
    a = simulate_observation(inst, src, **kw)
    b = simulate_observation(inst, src, **kw)
    assert np.array_equal(a.time, b.time) and np.array_equal(a.energy, b.energy)
    assert np.all(np.diff(a.time) >= 0)
    assert set(np.unique(a.energy)) == {np.float32(662.0), np.float32(122.0),
                                        np.float32(300.0)}
    c = simulate_observation(inst, src, **{**kw, "seed": 4})
    assert not np.array_equal(a.time, c.time)


# ----------------------------------------------------------------------------- errors


def test_bad_input_names_parameter():
    inst = _inst()
    src = PointSources(rad([0.1]), [0.0], rate=1.0)
    with pytest.raises(ParameterError, match="n_bins must be an integer >= 1"):
        exposure_per_bin([[0, 1]], 0, 60.0)
    with pytest.raises(ParameterError, match="gti must contain at least one interval"):
        exposure_per_bin(np.zeros((0, 2)), 4, 60.0)
    with pytest.raises(ParameterError, match="gti intervals must have start < stop"):
        simulate_observation(inst, src, gti=[[5.0, 5.0]])
    with pytest.raises(ParameterError, match="sorted and non-overlapping"):
        simulate_observation(inst, src, t_stop=20.0, gti=[[0.0, 10.0], [5.0, 15.0]])
    with pytest.raises(ParameterError, match="t_stop must be > t_start"):
        simulate_observation(inst, src, t_start=10.0, t_stop=5.0)
    with pytest.raises(ParameterError, match="background must be >= 0"):
        simulate_observation(inst, src, t_stop=1.0, background=-1.0)
    with pytest.raises(ParameterError, match="rotation_period must be > 0"):
        exposure_per_bin([[0, 1]], 4, 0.0)
    with pytest.raises(ParameterError, match=r"events\.detector must lie in 0\.\.0"):
        EventList([1.0], [3], [662.0], inst, [[0.0, 2.0]])
    with pytest.raises(ParameterError, match=r"events\.time must be sorted"):
        EventList([2.0, 1.0], [0, 0], [662.0, 662.0], inst, [[0.0, 3.0]])
    with pytest.raises(ParameterError, match="n_bins must be an integer >= 1"):
        fold(EventList([1.0], [0], [662.0], inst, [[0.0, 2.0]]), 0)

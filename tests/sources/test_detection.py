"""The iterative search on a small field, and light curves of the sources it finds."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from rotmod.errors import ParameterError
from rotmod.events import EventList
from rotmod.montecarlo import simulate_observation
from rotmod.sky import SkyGrid
from rotmod.sources import PointSource, SkyModel, TSMap, detect, ts_map
from rotmod.sources.detection import confusion_noise
from rotmod.sources.lightcurve import light_curve

BKG = 2.0
TRUE = (PointSource((3.3, 47.0), flux=0.12), PointSource((4.5, 230.0), flux=0.08))


@pytest.fixture(scope="module")
def found(field):
    truth = SkyModel(TRUE, background=np.full(7, BKG))
    return detect(field, truth.simulate(field, 4000.0, seed=21), threshold=25.0)


def test_both_sources_are_found_inside_their_regions(found):
    assert len(found.sources) == 2
    for true in TRUE:
        k = int(np.argmin([s.separation(true) for s in found.sources]))
        assert found.regions[k].contains(true.position, 0.99) or \
            found.sources[k].separation(true) < found.regions[k].radius(0.9)
        lo, hi = found.result.flux_err[k]
        assert abs(found.sources[k].flux - true.flux) < 3 * max(lo, hi)
    assert np.all(found.result.ts > 25)
    # Nothing left: the residual map has no peak that would have been added.
    assert np.nanmax(found.ts_map.ts) < 25
    assert found.first_map.peak()[1] > np.nanmax(found.ts_map.ts)


def test_an_empty_field_yields_nothing(field):
    null = SkyModel(background=np.full(7, BKG))
    empty = detect(field, null.simulate(field, 4000.0, seed=2), threshold=25.0,
                   localise_sources=False)
    assert empty.sources == () and empty.result.ts.size == 0


def test_detect_refuses_bad_arguments(field):
    data = SkyModel(background=np.full(7, BKG)).simulate(field, 10.0, seed=1)
    with pytest.raises(ParameterError, match="threshold"):
        detect(field, data, threshold=0.0)
    with pytest.raises(ParameterError, match="max_sources"):
        detect(field, data, max_sources=-1)


def _events(instrument, model, t0, t1, seed):
    return simulate_observation(instrument, model.point_sources(300.0), t_start=t0, t_stop=t1,
                                background=BKG, seed=seed)


def test_a_light_curve_follows_a_source_that_switches_off(survey_instrument, field):
    on = SkyModel([PointSource((3.3, 47.0), flux=0.5, name="A")])
    off = SkyModel([PointSource((3.3, 47.0), flux=0.0, name="A")])
    a, b = _events(survey_instrument, on, 0.0, 3000.0, 1), _events(
        survey_instrument, off, 3000.0, 6000.0, 2)
    ev = EventList(np.concatenate([a.time, b.time]), np.concatenate([a.detector, b.detector]),
                   np.concatenate([a.energy, b.energy]), survey_instrument,
                   [[0.0, 3000.0], [3000.0, 6000.0]])
    lc = light_curve(field, ev, on, [0.0, 1000.0, 2000.0, 3000.0, 4500.0, 6000.0, 7000.0])
    flux, (lo, hi) = lc.flux[:, 0], lc.flux_err[:, 0].T
    # On: each 1000 s interval within 3 sigma of 0.5 and mutually consistent (chi2).
    assert np.all(np.abs(flux[:3] - 0.5) < 3 * np.maximum(lo[:3], hi[:3]))
    chi2 = np.sum(((flux[:3] - flux[:3].mean()) / hi[:3]) ** 2)
    assert stats.chi2(2).sf(chi2) > 1e-3
    # Off: no detection, and an upper limit above the true 0 and below the on-state flux.
    assert np.all(lc.ts[3:5, 0] < 25) and np.all(lc.flux_ul[3:5, 0] < 0.5)
    # The last interval has no good time: no measurement, said as such.
    assert lc.exposure[-1] == 0 and np.isnan(lc.flux[-1, 0])
    table = lc.to_table()
    assert len(table) == 6 and table["flux"].unit == "1 / s"


def test_light_curve_refuses_bad_edges(survey_instrument, field):
    ev = _events(survey_instrument, SkyModel([PointSource((3.3, 47.0), flux=0.5)]), 0.0,
                 100.0, 1)
    model = SkyModel([PointSource((3.3, 47.0))])
    with pytest.raises(ParameterError, match="time_edges"):
        light_curve(field, ev, model, [10.0, 5.0])
    with pytest.raises(ParameterError, match="at least one source"):
        light_curve(field, ev, SkyModel(), [0.0, 100.0])


def test_the_residual_map_carries_limits_also_when_every_candidate_is_pruned(field):
    # A seed threshold low enough to try noise peaks, a threshold none of them passes.
    null = SkyModel(background=np.full(7, BKG))
    found = detect(field, null.simulate(field, 4000.0, seed=5), threshold=1e6,
                   seed_threshold=0.5, max_sources=2, localise_sources=False)
    assert found.sources == ()
    assert [h["pruned"] for h in found.history if "pruned" in h] == ["S2", "S1"]
    assert np.all(np.isfinite(found.ts_map.flux_ul))


def _synthetic_map(width: float, n: int, seed: int) -> TSMap:
    """A map whose pixels' signed significances are independent N(0, width^2)."""
    s = np.random.default_rng(seed).normal(0.0, width, (1, n))
    ts = np.where(s > 0, s * s, 0.0)
    flux = np.maximum(s, 0.0)
    nan = np.full_like(ts, np.nan)
    return TSMap(SkyGrid((n, 1), 0.01), ts.reshape(n, 1), flux.reshape(n, 1), nan.reshape(n, 1),
                 nan.reshape(n, 1), nan.reshape(n, 1), 0.95, 25.0)


@pytest.mark.parametrize("width", [1.0, 1.5, 3.0])
def test_confusion_noise_is_the_excess_width_of_the_significance(width):
    # 20000 independent pixels: the 84 % quantile's sd is sqrt(0.134 / 2e4) / 0.242 = 0.034
    # of the width; 3 sd.  Width 1 (a complete model): at most sqrt(1.1^2 - 1) = 0.46.
    c = confusion_noise(_synthetic_map(width, 20000, 3))
    expected = np.sqrt(width**2 - 1.0)
    assert abs(np.sqrt(1.0 + c * c) - width) < 3 * 0.034 * width
    assert c <= 0.46 if width == 1.0 else abs(c - expected) < 0.15 * expected


def test_unmodelled_faint_sources_widen_the_residual_map(field):
    """Twelve sources of TS ~ 4-10 each that no model holds: the map of the background
    alone is wider than a complete model's, whose width is that of an empty field."""
    rng = np.random.default_rng(5)
    faint = [PointSource((float(t), float(p)), flux=0.02)
             for t, p in zip(rng.uniform(0.5, 7.0, 12), rng.uniform(0, 360, 12), strict=True)]
    truth = SkyModel(faint, background=np.full(7, BKG))
    none, complete = (
        [confusion_noise(ts_map(field, truth.simulate(field, 4000.0, seed=s), model,
                                limits=False)) for s in range(4)] for model in (None, truth))
    # Measured: 1.75-2.47 unmodelled, 0 with every source in the model; an empty field's
    # estimate scatters from 0 to 0.63 on this 144-pixel map (12 realisations: the
    # quantile's noise over its few independent beams).
    assert min(none) > 1.2 and max(complete) < 0.7

"""The burst trigger: bursts found where they are, false alarms at or below the stated rate,
super-uniform p-values, data edges and gaps, energy bands and bad input."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from rotmod.bursts.search import DEFAULT_TIMESCALES, Candidate, search, window_tests
from rotmod.errors import ParameterError
from rotmod.events import EventList
from rotmod.testing import tiny_instrument

N_DET = 7
#: Per detector: 7 x 7.1 = ~50 counts/s summed.
RATE = 7.1


def _background(rng: np.random.Generator, gti: list[list[float]], rate: float = RATE,
                rates: list[float] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Flat Poisson background in each good-time interval: times and energies (keV; 90 % in
    20-100 keV, 10 % in 100-1000 keV)."""
    times = []
    for k, (a, b) in enumerate(gti):
        r = (rate if rates is None else rates[k]) * N_DET
        times.append(rng.uniform(a, b, rng.poisson(r * (b - a))))
    t = np.concatenate(times)
    high = rng.random(t.size) < 0.1
    e = np.where(high, rng.uniform(100.0, 1000.0, t.size), rng.uniform(20.0, 100.0, t.size))
    return t, e


def _events(rng: np.random.Generator, gti: list[list[float]], *, burst: tuple | None = None,
            rates: list[float] | None = None) -> EventList:
    """Background events plus an optional Gaussian pulse ``(t0, sigma, counts, (elo,
    ehi))``, events outside good time dropped."""
    t, e = _background(rng, gti, rates=rates)
    if burst is not None:
        t0, sigma, n, (elo, ehi) = burst
        tb = rng.normal(t0, sigma, n)
        t = np.concatenate([t, tb])
        e = np.concatenate([e, rng.uniform(elo, ehi, n)])
    g = np.asarray(gti, dtype=float)
    inside = np.any((t[:, None] >= g[:, 0]) & (t[:, None] < g[:, 1]), axis=1)
    t, e = t[inside], e[inside]
    order = np.argsort(t)
    det = rng.integers(0, N_DET, t.size)
    return EventList(t[order], det, e[order], tiny_instrument(), g)


@pytest.fixture(scope="module")
def hour() -> EventList:
    """One hour of background only, ~50 counts/s summed."""
    return _events(np.random.default_rng(101), [[0.0, 3600.0]])


def test_a_clear_burst_is_one_candidate_at_its_time_on_its_timescale():
    ev = _events(np.random.default_rng(1), [[0.0, 600.0]],
                 burst=(300.0, 0.3, 200, (20.0, 1000.0)))
    res = search(ev)
    assert len(res.candidates) == 1
    c = res.candidates[0]
    assert isinstance(c, Candidate) and c.band is None
    assert c.interval[0] <= 300.0 <= c.interval[1]
    # A pulse of sigma 0.3 s is best caught by a window of about its width.
    assert 0.25 <= c.timescale <= 2.1
    assert c.significance > 10 and c.p_value < res.threshold
    assert c.counts > c.background + 150
    assert res.threshold_sigma == pytest.approx(stats.norm.isf(res.threshold))
    assert res.timescales == pytest.approx(DEFAULT_TIMESCALES)
    # Bonferroni count: a test every half window, of each timescale.
    assert res.trials_per_second == pytest.approx(sum(2.0 / d for d in DEFAULT_TIMESCALES))
    assert res.threshold == pytest.approx(res.far / res.trials_per_second)
    assert res.searched == pytest.approx(600.0)
    table = res.to_table()
    assert len(table) == 1 and str(table["time"].unit) == "s"
    assert table["significance"][0] == pytest.approx(c.significance)


def test_false_alarms_on_background_only_are_within_the_stated_rate(hour):
    far = 1.0 / 60.0  # deliberately loose: ~60 false alarms an hour allowed
    res = search(hour, far=far)
    assert res.searched == pytest.approx(3600.0)
    n = len(res.candidates)
    allowed = far * res.searched
    # The Bonferroni bound: E[n] <= far * searched; n may exceed it only by Poisson noise.
    assert n <= stats.poisson.ppf(0.999, allowed)
    # ... and the test has power: the rate is not far below the bound (measured ~0.4 of it).
    assert n >= 0.1 * allowed
    assert all(c.p_value < res.threshold for c in res.candidates)
    times = [c.time for c in res.candidates]
    assert times == sorted(times)
    # Merged: no two candidates overlap.
    assert all(a.interval[1] < b.interval[0]
               for a, b in zip(res.candidates, res.candidates[1:], strict=False))


@pytest.mark.parametrize("timescale", [0.064, 1.024])
def test_p_values_on_background_only_are_super_uniform(hour, timescale):
    wt = window_tests(hour, timescale)
    p = wt.p_value[::2]  # every other window: the tested windows do not overlap
    assert p.size > 3000
    for a in (0.5, 0.1, 0.01):
        frac = np.mean(p < a)
        assert frac <= a + 4.0 * np.sqrt(a * (1 - a) / p.size)
    # Not vacuous: at ~50 counts a window the test is nearly exact.
    if timescale > 1.0:
        assert np.mean(p < 0.5) > 0.4 and np.mean(p < 0.1) > 0.07
    assert np.all(np.diff(wt.time) > 0) and wt.timescale == pytest.approx(timescale)
    # The conditional on/off test: n_on ~ Binomial(n_on + n_off, alpha / (1 + alpha)).
    on, off = wt.counts[:50], np.rint(wt.background[:50] / wt.alpha)
    ref = stats.binom.sf(on - 1, on + off, wt.alpha / (1 + wt.alpha))
    np.testing.assert_allclose(wt.p_value[:50], ref, rtol=1e-10)


def test_a_burst_at_the_start_of_the_data_is_found_with_the_background_after():
    ev = _events(np.random.default_rng(4), [[0.0, 300.0]],
                 burst=(1.0, 0.2, 120, (20.0, 1000.0)))
    res = search(ev)
    assert len(res.candidates) == 1
    assert res.candidates[0].interval[0] <= 1.0 <= res.candidates[0].interval[1]
    assert res.candidates[0].significance > 8


def test_a_gap_in_good_time_does_not_trigger():
    # The rate doubles across a 200 s gap (as after a passage through the SAA); windows and
    # background windows never straddle the gap.
    gti = [[0.0, 1000.0], [1200.0, 2000.0], [2030.0, 2600.0]]
    ev = _events(np.random.default_rng(5), gti, rates=[RATE, 2 * RATE, RATE])
    res = search(ev, far=1.0 / 3600.0)
    assert res.candidates == ()
    assert res.searched <= ev.exposure
    table = res.to_table()
    assert len(table) == 0 and "significance" in table.colnames
    # Windows after the gaps use the background after them: good time is still all searched.
    assert res.searched == pytest.approx(ev.exposure, abs=0.1)


def test_a_burst_only_at_high_energy_is_found_in_its_band():
    burst = (200.0, 0.4, 30, (200.0, 1000.0))
    ev = _events(np.random.default_rng(6), [[0.0, 400.0]], burst=burst)
    assert search(ev).candidates == ()  # diluted by the low-energy background
    bands = [(20.0, 100.0), (100.0, 1000.0)]
    res = search(ev, bands=bands)
    assert res.bands == tuple(bands)
    assert res.trials_per_second == pytest.approx(2 * sum(2.0 / d for d in DEFAULT_TIMESCALES))
    assert len(res.candidates) == 1
    c = res.candidates[0]
    assert c.band == (100.0, 1000.0)
    assert c.interval[0] <= 200.0 <= c.interval[1]
    row = res.to_table()[0]
    assert row["band_lo"] == 100.0 and row["band_hi"] == 1000.0


@pytest.mark.parametrize(("kwargs", "name"), [
    ({"events": np.arange(10.0)}, "events"),
    ({"timescales": [0.1, -1.0]}, "timescales"),
    ({"timescales": [0.1, 0.1]}, "timescales"),
    ({"timescales": [1.0, 0.5]}, "timescales"),
    ({"timescales": [0.1, 500.0]}, "timescales"),
    ({"far": 0.0}, "far"),
    ({"far": 1e6}, "far"),
    ({"background_window": -5.0}, "background_window"),
    ({"gap": -1.0}, "gap"),
    ({"bands": [(100.0, 50.0)]}, "bands[0]"),
    ({"bands": [(20.0, 100.0), (-1.0, 50.0)]}, "bands[1]"),
    ({"bands": [(20.0, np.inf)]}, "bands[0]"),
    ({"background_window": 250.0}, "events"),
])
def test_bad_input_names_the_parameter(kwargs, name):
    ev = _events(np.random.default_rng(7), [[0.0, 200.0]])
    kwargs = {"events": ev, **kwargs}
    events = kwargs.pop("events")
    with pytest.raises(ParameterError, match=rf"^{name.replace('[', '.').replace(']', '.')}"):
        search(events, **kwargs)

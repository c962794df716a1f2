r"""The burst trigger: a search of the detector-summed count rate for gamma-ray bursts.

Like the rate triggers of Fermi-GBM and Swift-BAT, :func:`search` tests the summed counts of
all detectors in windows of several lengths ``Delta`` (:data:`DEFAULT_TIMESCALES`: 0.064 s
to 16.384 s, doubling) and, optionally, several energy bands, each against a running
background, and sets its threshold from a stated false-alarm rate.

Binning
    Good-time intervals that touch are joined; each is binned once per band, with
    :func:`numpy.bincount`, into fine bins of ``delta = min(timescales) / 4`` starting at the
    interval's start, and the cumulative sums give the counts in any run of bins in one
    subtraction.  Each timescale is a whole number of fine bins (``w = round(Delta /
    delta)``; the defaults are exact, others are rounded and reported as used).  Windows of
    ``w`` bins start every ``max(w // 2, 1)`` bins (``Delta / 2``), so a burst shorter than
    ``Delta / 2`` lies wholly in some window.  A window, and the background window it is
    compared with, lie wholly inside one good-time interval: no test touches a gap or an
    interval's partial last bin.

Background
    The off counts are those of a window of ``background_window`` seconds (``B``) ending a
    ``gap`` before the tested window.  The default gap is ``max(Delta, 4 s)``: 4 s is the
    gap of GBM's flight trigger (a 17 s background ending 4 s before the tested interval),
    which keeps the rise of a few-second pulse out of its own background, and ``Delta`` for
    the long timescales, because a burst found at timescale ``Delta`` rises over about
    ``Delta``: the background then ends before the emission that is being tested began.  A
    linear background trend ``r'`` biases the expected on counts by ``r' Delta (gap + (B +
    Delta) / 2)`` -- for orbital variations of minutes a small fraction of the window's
    Poisson error, which is why the gap costs little.  Where the data before the window are
    missing (the start of the data, just after a gap in good time), the background window
    *after* it (``gap`` later) is used, so that a burst at the data's edge is still found.
    A window with neither is not tested and not counted in the searched time.

Significance
    With ``n_on`` counts in the window, ``n_off`` in the background window and ``alpha =
    Delta / B`` their exposure ratio, the null hypothesis (one constant rate) makes ``n_on``,
    given ``N = n_on + n_off``, a binomial variable of ``N`` trials with success probability
    ``rho = alpha / (1 + alpha)``: two independent Poisson counts conditioned on their sum.
    The single-trial p-value is the binomial tail

        p = P(X >= n_on | N, rho) = I_rho(n_on, n_off + 1)

    (the regularised incomplete beta function), the exact conditional on/off test ``Z_Bi``
    of Cousins, Linnemann & Tucker (2008, NIM A 595, 480).  It does not depend on the
    unknown rate, so it keeps the background estimate's own Poisson error, and it holds at a
    few counts: ``P(p <= a) <= a`` for every ``a`` (equality up to the discreteness of the
    counts, which makes it conservative).  ``significance = norm.isf(p)``; where ``p``
    underflows (beyond ~37 sigma) the significance is Li & Ma's (1983) eq. 17, its
    asymptotic form.

Threshold from the false-alarm rate
    A test of ``Delta`` is made every ``Delta / 2`` of good time, so per second of data
    there are at most

        T = sum_bands sum_Delta 1 / step(Delta)

    tests (``trials_per_second``; 62.4 per band for the default timescales).  ``n`` windows
    stepped by ``s`` on one run of good time cover ``(n + 1) s`` or more, so the number of
    tests of each timescale and band is at most ``searched / s``, ``searched`` the length
    of the union of every tested window.  With each test's ``P(p < p_thr) <= p_thr``, the
    expected number of false triggers is then at most ``T p_thr searched``, and the
    threshold ``p_thr = far / T`` makes the expected number of false candidates at most
    ``far * searched``: a Bonferroni bound.  It is conservative -- overlapping windows,
    windows of neighbouring timescales and bands sharing counts, and background windows
    shared by neighbouring tests are strongly correlated, so they trigger together and are
    merged into one candidate, and the discrete p-values are themselves conservative;
    ``benchmarks/bursts_far.py`` measures by how much.

Candidates
    Every window with ``p < p_thr`` is a trigger; triggers whose intervals overlap or touch,
    of any timescale and band, are one burst, and the candidate is its most significant
    window.  Everything is vectorised over windows (a lookup table of the smallest
    triggering ``n_on`` for each ``N``; exact p-values only for triggers): a day of data at
    55 counts/s is searched in a few seconds.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import astropy.units as u
import numpy as np
from scipy.special import betainc
from scipy.stats import norm

from rotmod._validate import as_array, as_scalar
from rotmod.bursts.measure import _check_events
from rotmod.errors import ParameterError
from rotmod.events import EventList
from rotmod.events.gti import join_touching
from rotmod.limits import check_memory
from rotmod.progress import ProgressArg, progress_callbacks

if TYPE_CHECKING:
    from astropy.table import Table

__all__ = [
    "DEFAULT_TIMESCALES",
    "Candidate",
    "SearchResult",
    "WindowTests",
    "search",
    "window_tests",
]

#: Window lengths (s) of the default search: 64 ms to 16.384 s, doubling (GBM's set).
DEFAULT_TIMESCALES: tuple[float, ...] = tuple(0.064 * 2.0**k for k in range(9))

#: Smallest gap (s) between a tested window and its background window by default (GBM's).
MIN_GAP = 4.0

#: Largest ``n_on + n_off`` of the lookup table of triggering counts (a few ms to build).
_TABLE_MAX = 20000

Band = tuple[float, float] | None


@dataclass(frozen=True)
class Candidate:
    """A burst candidate: the most significant window of one burst.

    Parameters
    ----------
    time : float
        Start of the triggering window (s).
    timescale : float
        Window length (s).
    band : tuple of float or None
        Energy band ``(lo, hi)`` (keV, ``lo <= E < hi``); ``None``: all energies.
    counts : int
        Counts in the window, summed over detectors.
    background : float
        Expected background counts in the window, ``alpha * n_off``.
    significance : float
        Gaussian-equivalent significance (sigma) of the single-trial p-value.
    p_value : float
        Single-trial p-value of the conditional on/off test.
    """

    time: float
    timescale: float
    band: Band
    counts: int
    background: float
    significance: float
    p_value: float

    @property
    def interval(self) -> tuple[float, float]:
        """The window ``(time, time + timescale)`` (s)."""
        return (self.time, self.time + self.timescale)


@dataclass(frozen=True)
class SearchResult:
    """What :func:`search` found, and the false-alarm rate it was set for.

    Parameters
    ----------
    candidates : tuple of Candidate
        One per burst (overlapping or touching triggers of any timescale and band merged,
        the most significant kept), sorted by time.
    threshold : float
        Single-trial p-value threshold (a trigger has ``p < threshold``).
    threshold_sigma : float
        The threshold as a Gaussian-equivalent significance.
    far : float
        False-alarm rate (1/s) the threshold was set for.
    trials_per_second : float
        Tests per second of data (the Bonferroni count): ``threshold = far /
        trials_per_second``.
    timescales : tuple of float
        Window lengths (s) used.
    bands : tuple
        Energy bands ``(lo, hi)`` (keV) searched; ``None`` is all energies.
    searched : float
        Seconds of data searched: the union of every tested window.  The expected number of
        false candidates is at most ``far * searched``.
    n_tests : int
        Number of windows tested (all timescales and bands).
    """

    candidates: tuple[Candidate, ...]
    threshold: float
    threshold_sigma: float
    far: float
    trials_per_second: float
    timescales: tuple[float, ...]
    bands: tuple[Band, ...]
    searched: float
    n_tests: int = 0

    def __len__(self) -> int:
        return len(self.candidates)

    def to_table(self) -> Table:
        """One row per candidate, with units: ``time``, ``time_stop``, ``timescale`` (s),
        ``band_lo``, ``band_hi`` (keV; 0 and inf for all energies), ``counts``,
        ``background``, ``significance``, ``p_value``; the search's settings in the
        metadata."""
        from astropy.table import Table  # ~90 ms; the search itself does not need it

        c = self.candidates
        lo = [0.0 if x.band is None else x.band[0] for x in c]
        hi = [np.inf if x.band is None else x.band[1] for x in c]
        t = Table()
        t["time"] = np.array([x.time for x in c], dtype=float) * u.s
        t["time_stop"] = np.array([x.interval[1] for x in c], dtype=float) * u.s
        t["timescale"] = np.array([x.timescale for x in c], dtype=float) * u.s
        t["band_lo"] = np.array(lo, dtype=float) * u.keV
        t["band_hi"] = np.array(hi, dtype=float) * u.keV
        t["counts"] = np.array([x.counts for x in c], dtype=np.int64)
        t["background"] = np.array([x.background for x in c], dtype=float)
        t["significance"] = np.array([x.significance for x in c], dtype=float)
        t["p_value"] = np.array([x.p_value for x in c], dtype=float)
        t["counts"].description = "counts in the window, summed over detectors"
        t["background"].description = "expected background counts in the window"
        t["significance"].description = "Gaussian-equivalent sigma of the single-trial p-value"
        t["p_value"].description = "single-trial p-value of the conditional on/off test"
        t.meta["THRESHOLD"] = self.threshold
        t.meta["THRESHOLD_SIGMA"] = self.threshold_sigma
        t.meta["FAR"] = self.far
        t.meta["TRIALS_PER_SECOND"] = self.trials_per_second
        t.meta["SEARCHED"] = self.searched
        t.meta["N_TESTS"] = self.n_tests
        t.meta["TIMESCALES"] = [float(x) for x in self.timescales]
        t.meta["BANDS"] = [None if b is None else [float(b[0]), float(b[1])] for b in self.bands]
        return t


@dataclass(frozen=True)
class WindowTests:
    """Every tested window of one timescale and band (:func:`window_tests`).

    Parameters
    ----------
    time : numpy.ndarray
        Window starts (s).
    timescale : float
        Window length (s).
    band : tuple of float or None
        Energy band (keV), ``None`` for all energies.
    counts : numpy.ndarray of int
        Counts in each window.
    background : numpy.ndarray
        Expected background counts in each window.
    p_value : numpy.ndarray
        Single-trial p-values.
    alpha : float
        Exposure ratio of the tested to the background window (``background = alpha *
        n_off``).
    """

    time: np.ndarray
    timescale: float
    band: Band
    counts: np.ndarray
    background: np.ndarray
    p_value: np.ndarray
    alpha: float

    @property
    def significance(self) -> np.ndarray:
        """Gaussian-equivalent significance of each p-value (sigma)."""
        off = self.background / self.alpha
        return _significance(self.p_value, self.counts, off, self.alpha)


# --------------------------------------------------------------------------- statistics


def _tail(k: np.ndarray, n: np.ndarray, rho: float) -> np.ndarray:
    """``P(X >= k)`` for ``X ~ Binomial(n, rho)``, elementwise (1 for ``k <= 0``, 0 for
    ``k > n``)."""
    k = np.asarray(k, dtype=float)
    n = np.asarray(n, dtype=float)
    inside = (k >= 1) & (k <= n)
    a = np.where(inside, k, 1.0)
    b = np.where(inside, n - k + 1.0, 1.0)
    p = betainc(a, b, rho)
    return np.where(k <= 0, 1.0, np.where(k > n, 0.0, p))


def _p_values(on: np.ndarray, off: np.ndarray, alpha: float) -> np.ndarray:
    """The conditional on/off (``Z_Bi``) p-values: ``P(X >= on)``, ``X ~ Bin(on + off,
    alpha / (1 + alpha))``."""
    return _tail(on, on + off, alpha / (1.0 + alpha))


def _li_ma(on: np.ndarray, off: np.ndarray, alpha: np.ndarray | float) -> np.ndarray:
    """Li & Ma (1983) eq. 17 (signed): the asymptotic significance of an on/off test."""
    on = np.asarray(on, dtype=float)
    off = np.asarray(off, dtype=float)
    n = on + off
    with np.errstate(divide="ignore", invalid="ignore"):
        t_on = np.where(on > 0, on * np.log((1.0 + alpha) / alpha * on / n), 0.0)
        t_off = np.where(off > 0, off * np.log((1.0 + alpha) * off / n), 0.0)
    s = np.sqrt(np.maximum(2.0 * (t_on + t_off), 0.0))
    return np.where(on >= alpha * off, s, -s)


def _significance(p: np.ndarray, on: np.ndarray, off: np.ndarray,
                  alpha: np.ndarray | float) -> np.ndarray:
    """``norm.isf(p)``, and Li & Ma's form where ``p`` underflows."""
    sig = np.array(norm.isf(p), dtype=float, ndmin=1)
    bad = ~np.isfinite(sig)
    if np.any(bad):
        a = np.broadcast_to(alpha, sig.shape)
        sig[bad] = _li_ma(np.asarray(on)[bad], np.asarray(off)[bad], a[bad])
    return sig


def _min_on_counts(n_max: int, rho: float, p_thr: float) -> np.ndarray:
    """For each ``N = 0..n_max`` the smallest ``k`` with ``P(X >= k | N, rho) < p_thr``
    (``N + 1`` when none): a window triggers iff ``n_on >= table[n_on + n_off]``.  Found by
    bisection on the monotone tail, vectorised over ``N``."""
    n = np.arange(n_max + 1, dtype=np.int64)
    lo = np.zeros_like(n)        # tail(lo) >= p_thr (tail(0) = 1)
    hi = n + 1                   # tail(hi) = 0 < p_thr
    while np.any(hi - lo > 1):
        mid = (lo + hi) // 2
        below = _tail(mid, n, rho) < p_thr
        hi = np.where(below, mid, hi)
        lo = np.where(below, lo, mid)
    return hi


# --------------------------------------------------------------------------- arguments


def _check_timescales(timescales: Any) -> np.ndarray:
    ts = as_array(timescales, "timescales", u.s, lo=0.0, lo_open=True, ndim=1)
    if ts.size == 0:
        raise ParameterError("timescales must hold at least one window length, got none")
    if ts.size > 1 and np.any(np.diff(ts) <= 0):
        i = int(np.argmax(np.diff(ts) <= 0))
        raise ParameterError(
            f"timescales must be increasing without duplicates, got {ts[i + 1]:g} s after "
            f"{ts[i]:g} s"
        )
    return ts


def _check_bands(bands: Any) -> tuple[Band, ...]:
    if bands is None:
        return (None,)
    if isinstance(bands, str) or not isinstance(bands, Sequence | np.ndarray):
        raise ParameterError(f"bands must be None or a sequence of (lo, hi) keV pairs, got "
                             f"{bands!r}")
    out: list[Band] = []
    for j, b in enumerate(bands):
        if b is None:
            out.append(None)
            continue
        arr = as_array(b, f"bands[{j}]", u.keV, lo=0.0)
        if arr.shape != (2,):
            raise ParameterError(f"bands[{j}] must be a (lo, hi) pair, got shape {arr.shape}")
        if not arr[0] < arr[1]:
            raise ParameterError(
                f"bands[{j}] must have lo < hi, got ({arr[0]:g}, {arr[1]:g}) keV"
            )
        out.append((float(arr[0]), float(arr[1])))
    if not out:
        raise ParameterError("bands must hold at least one band, got none")
    if len(set(out)) != len(out):
        raise ParameterError(f"bands must not repeat a band, got {out}")
    return tuple(out)


# --------------------------------------------------------------------------- the scan


@dataclass(frozen=True)
class _Plan:
    """The fine grid and, per timescale, window, step, gap and background lengths in bins."""

    delta: float
    width: np.ndarray
    step: np.ndarray
    gap: np.ndarray
    n_bkg: int
    gti: np.ndarray
    n_bins: np.ndarray

    @property
    def timescales(self) -> np.ndarray:
        return self.width * self.delta


def _plan(events: EventList, ts: np.ndarray, background_window: Any, gap: Any,
          delta: float, n_bands: int) -> _Plan:
    b = as_scalar(background_window, "background_window", u.s, lo=0.0, lo_open=True)
    g = None if gap is None else as_scalar(gap, "gap", u.s, lo=0.0)
    width = np.maximum(np.rint(ts / delta), 1).astype(np.int64)
    gaps = np.maximum(ts, MIN_GAP) if g is None else np.full(ts.size, g)
    gti = join_touching(events.gti)
    n_bins = np.floor((gti[:, 1] - gti[:, 0]) / delta * (1.0 + 1e-12))
    # The fine bins' cumulative counts (per band) and the window starts of the finest scale
    # are arrays of about one value per fine bin each: counted before any is made.
    check_memory(8.0 * float(n_bins.max()) * (n_bands + 4),
                 f"{n_bins.max():.3g} fine bins of {delta:.3g} s (a quarter of the shortest "
                 f"of timescales) over the longest good-time interval, in {n_bands} band(s)",
                 hint="a longer shortest timescale")
    n_bins = n_bins.astype(np.int64)
    plan = _Plan(
        delta=delta, width=width, step=np.maximum(width // 2, 1),
        gap=np.rint(gaps / delta).astype(np.int64), n_bkg=max(round(b / delta), 1),
        gti=gti, n_bins=n_bins,
    )
    longest = float(np.max(gti[:, 1] - gti[:, 0]))
    if width[-1] > n_bins.max():
        raise ParameterError(
            f"timescales must not be longer than the longest good-time interval "
            f"({longest:g} s), got {ts[-1]:g} s"
        )
    need = plan.width + plan.gap + plan.n_bkg
    if need.min() > n_bins.max():
        raise ParameterError(
            f"events must have a good-time interval long enough for a window, its gap and "
            f"its background window ({need.min() * delta:g} s at the shortest timescale with "
            f"background_window={b:g} s); the longest is {longest:g} s"
        )
    return plan


def _windows(n_bins: int, w: int, s: int, g: int, nb: int) -> tuple[np.ndarray, np.ndarray]:
    """Starts of the tested windows of one good-time interval, and of their background
    windows (before when it fits, else after), in fine bins."""
    if n_bins < w + g + nb:
        empty = np.zeros(0, dtype=np.int64)
        return empty, empty
    i = np.arange(0, n_bins - w + 1, s, dtype=np.int64)
    before = i >= g + nb
    after = i + w + g + nb <= n_bins
    keep = before | after
    i, before = i[keep], before[keep]
    return i, np.where(before, i - g - nb, i + w + g)


def _cover(starts: np.ndarray, w: int, s: int) -> list[tuple[int, int]]:
    """The runs of good time (fine bins) that windows of ``w`` bins at ``starts`` (stepped
    by ``s <= w``) cover."""
    if starts.size == 0:
        return []
    cut = np.flatnonzero(np.diff(starts) > s) + 1
    first = starts[np.r_[0, cut]]
    last = starts[np.r_[cut - 1, starts.size - 1]]
    return [(int(a), int(b) + w) for a, b in zip(first, last, strict=True)]


def _union_length(runs: list[tuple[int, int]]) -> int:
    total, end = 0, -1
    for a, b in sorted(runs):
        if a > end:
            total += b - a
            end = b
        elif b > end:
            total += b - end
            end = b
    return total


def _band_mask(energy: np.ndarray, band: Band) -> np.ndarray | None:
    if band is None:
        return None
    return (energy >= band[0]) & (energy < band[1])


def _binned(events: EventList, plan: _Plan, k: int,
            masks: list[np.ndarray | None]) -> list[np.ndarray]:
    """Cumulative counts (length ``n_bins + 1``) of good-time interval ``k``, per band."""
    a, b = plan.gti[k]
    lo = int(np.searchsorted(events.time, a, side="left"))
    hi = int(np.searchsorted(events.time, b, side="right"))
    idx = np.floor((events.time[lo:hi] - a) / plan.delta).astype(np.int64)
    inside = (idx >= 0) & (idx < plan.n_bins[k])
    out = []
    for m in masks:
        sel = inside if m is None else inside & m[lo:hi]
        counts = np.bincount(idx[sel], minlength=int(plan.n_bins[k]))
        out.append(np.concatenate(([0], np.cumsum(counts, dtype=np.int64))))
    return out


def _triggers(csum: np.ndarray, starts: np.ndarray, off_starts: np.ndarray, w: int, nb: int,
              p_thr: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Indices into ``starts`` of the windows with ``p < p_thr``, with their on and off
    counts."""
    on = csum[starts + w] - csum[starts]
    off = csum[off_starts + nb] - csum[off_starts]
    total = on + off
    rho = w / (w + nb)
    # The table stops at _TABLE_MAX counts; the rare windows above it (bright bursts) are
    # tested one by one.
    table = _min_on_counts(min(int(total.max()), _TABLE_MAX), rho, p_thr)
    big = total > _TABLE_MAX
    hit = on >= table[np.minimum(total, _TABLE_MAX)]
    if np.any(big):
        hit[big] = _tail(on[big], total[big], rho) < p_thr
    hit = np.flatnonzero(hit)
    return hit, on[hit], off[hit]


# --------------------------------------------------------------------------- public


def window_tests(events: EventList, timescale: Any, *, band: Any = None,
                 background_window: Any = 20.0, gap: Any = None) -> WindowTests:
    """The on/off test of every window of one timescale and band, as :func:`search` makes it.

    Fine bins of ``timescale / 4``; windows stepped by half a window; the background window
    before the tested window (after it where the data before are missing).  For studies of
    the null distribution and light curves; :func:`search` tests every timescale at once.

    Parameters
    ----------
    events : EventList
        The events (all detectors summed).
    timescale : float or Quantity
        Window length (s).
    band : (lo, hi) or None
        Energy band (keV), ``None`` for all energies.
    background_window : float or Quantity
        Length of the background window (s).
    gap : float or Quantity, optional
        Time between the tested and the background window (s); default
        ``max(timescale, 4 s)``.

    Returns
    -------
    WindowTests

    Raises
    ------
    ParameterError
        As :func:`search`.
    """
    events = _check_events(events)
    ts = _check_timescales([as_scalar(timescale, "timescale", u.s, lo=0.0, lo_open=True)])
    (bnd,) = _check_bands(None if band is None else [band])
    plan = _plan(events, ts, background_window, gap, ts[0] / 4.0, 1)
    w, s, g, nb = int(plan.width[0]), int(plan.step[0]), int(plan.gap[0]), plan.n_bkg
    mask = _band_mask(events.energy, bnd)
    times, ons, offs = [], [], []
    for k in range(plan.gti.shape[0]):
        starts, off_starts = _windows(int(plan.n_bins[k]), w, s, g, nb)
        if starts.size == 0:
            continue
        (csum,) = _binned(events, plan, k, [mask])
        times.append(plan.gti[k, 0] + starts * plan.delta)
        ons.append(csum[starts + w] - csum[starts])
        offs.append(csum[off_starts + nb] - csum[off_starts])
    on = np.concatenate(ons) if ons else np.zeros(0, dtype=np.int64)
    off = np.concatenate(offs) if offs else np.zeros(0, dtype=np.int64)
    alpha = w / nb
    return WindowTests(
        time=np.concatenate(times) if times else np.zeros(0), timescale=float(w * plan.delta),
        band=bnd, counts=on, background=alpha * off, p_value=_p_values(on, off, alpha),
        alpha=alpha,
    )


def search(
    events: EventList,
    *,
    timescales: Any = DEFAULT_TIMESCALES,
    bands: Any = None,
    far: Any = 1.0 / 86400.0,
    background_window: Any = 20.0,
    gap: Any = None,
    progress: ProgressArg = None,
) -> SearchResult:
    """Search the detector-summed count rate for bursts at a stated false-alarm rate.

    Every window of every timescale (stepped by half its length) and band that lies in good
    time is tested against the counts of a background window before it (after it at the
    start of the data or of a good-time interval) with the exact conditional on/off test;
    the threshold is ``far / trials_per_second``.  See the module docstring for the method
    and the derivation of the bound.

    Parameters
    ----------
    events : EventList
        The events; detectors are summed, good-time intervals honoured.
    timescales : sequence of float or Quantity
        Window lengths (s), increasing; the finest sets the fine bins (a quarter of it),
        and each is rounded to a whole number of them.
    bands : sequence of (lo, hi) or None
        Energy bands (keV, ``lo <= E < hi``, finite, ``0 <= lo < hi``); ``None`` (default)
        is one band of all energies, as is a ``None`` entry of the sequence.
    far : float or Quantity
        False-alarm rate (1/s; default one a day) the threshold is set for: the expected
        number of false candidates is at most ``far * searched``.
    background_window : float or Quantity
        Length of the background window (s).
    gap : float or Quantity, optional
        Time between a tested window and its background window (s); default
        ``max(timescale, 4 s)`` for each timescale.
    progress : bool or callable, optional
        Progress over the good-time intervals and timescales (:mod:`rotmod.progress`).

    Returns
    -------
    SearchResult
        Candidates (one per burst, sorted by time), threshold, trials per second, searched
        time.

    Raises
    ------
    ParameterError
        ``events`` not an EventList; ``timescales`` not positive and increasing, or one
        longer than the longest good-time interval; ``far``, ``background_window`` not
        > 0, ``gap`` < 0; a band with ``lo >= hi``, negative or not finite; no good-time
        interval long enough for a window and its background.
    """
    events = _check_events(events)
    ts = _check_timescales(timescales)
    band_list = _check_bands(bands)
    f = as_scalar(far, "far", 1 / u.s, lo=0.0, lo_open=True)
    plan = _plan(events, ts, background_window, gap, ts[0] / 4.0, len(band_list))
    used = plan.timescales
    trials = len(band_list) * float(np.sum(1.0 / (plan.step * plan.delta)))
    p_thr = f / trials
    if not p_thr < 1.0:
        raise ParameterError(
            f"far must be < trials_per_second ({trials:g} /s), the rate at which every test "
            f"would trigger, got {f:g} /s"
        )
    masks = [_band_mask(events.energy, b) for b in band_list]
    nb = plan.n_bkg
    n_gti, n_ts = plan.gti.shape[0], ts.size
    update, close = progress_callbacks(progress, n_gti * n_ts, "burst search", "window sets")
    hits: list[np.ndarray] = []  # rows: start, stop, on, off, scale index, band index
    searched_bins = 0
    n_tests = 0
    try:
        for k in range(n_gti):
            csums: list[np.ndarray] | None = None
            gti_runs: list[tuple[int, int]] = []
            for j in range(n_ts):
                w, s, g = int(plan.width[j]), int(plan.step[j]), int(plan.gap[j])
                starts, off_starts = _windows(int(plan.n_bins[k]), w, s, g, nb)
                update(k * n_ts + j + 1, n_gti * n_ts)
                if starts.size == 0:
                    continue
                if csums is None:
                    csums = _binned(events, plan, k, masks)
                gti_runs.extend(_cover(starts, w, s))
                n_tests += starts.size * len(band_list)
                for m, csum in enumerate(csums):
                    idx, on, off = _triggers(csum, starts, off_starts, w, nb, p_thr)
                    if idx.size:
                        t0 = plan.gti[k, 0] + starts[idx] * plan.delta
                        hits.append(np.stack([t0, t0 + w * plan.delta, on, off,
                                              np.full(idx.size, j), np.full(idx.size, m)]))
            searched_bins += _union_length(gti_runs)
    finally:
        close()
    candidates = _merge(np.concatenate(hits, axis=1) if hits else np.zeros((6, 0)),
                        plan, band_list)
    return SearchResult(
        candidates=candidates, threshold=p_thr, threshold_sigma=float(norm.isf(p_thr)),
        far=f, trials_per_second=trials, timescales=tuple(float(x) for x in used),
        bands=band_list, searched=searched_bins * plan.delta, n_tests=int(n_tests),
    )


def _merge(rows: np.ndarray, plan: _Plan, bands: tuple[Band, ...]) -> tuple[Candidate, ...]:
    """One candidate per group of overlapping or touching triggers: the most significant."""
    if rows.shape[1] == 0:
        return ()
    start, stop, on, off = rows[0], rows[1], rows[2], rows[3]
    scale, band = rows[4].astype(np.int64), rows[5].astype(np.int64)
    alpha = plan.width[scale] / plan.n_bkg
    p = _tail(on, on + off, alpha / (1.0 + alpha))
    sig = _significance(p, on, off, alpha)
    # Sorted by start, a trigger opens a new burst when it starts after every earlier one
    # has ended; within each burst the most significant trigger is kept.
    order = np.argsort(start, kind="stable")
    reach = np.maximum.accumulate(stop[order])
    group = np.concatenate(([0], np.cumsum(start[order][1:] > reach[:-1])))
    ranked = np.lexsort((-sig[order], group))  # by burst, then most significant first
    first = np.r_[True, np.diff(group[ranked]) > 0]
    out = []
    for i in order[ranked[first]]:
        j = int(scale[i])
        out.append(Candidate(
            time=float(rows[0, i]), timescale=float(plan.width[j] * plan.delta),
            band=bands[int(band[i])], counts=int(on[i]), background=float(alpha[i] * off[i]),
            significance=float(sig[i]), p_value=float(p[i]),
        ))
    return tuple(sorted(out, key=lambda c: c.time))

"""Counts-level measurements of a burst: the background under it, its light curve, its durations.

Three steps, each from the detector counts alone (no response, no sky position):

* :func:`fit_background` fits every detector's background rate, a polynomial in time, by
  Poisson maximum likelihood to the counts in intervals before and after the burst
  (:class:`Background`, with the covariance of its coefficients);
* :func:`burst_light_curve` cuts the detector-summed counts around the burst into Bayesian
  blocks (Scargle et al. 2013) and compares each block with the background: the blocks
  significantly above it are the burst, their net rates its relative light curve
  (:class:`BurstLightCurve`; ``shape`` is the template the localisation fits);
* :func:`durations` measures T90 and T50 from the cumulative background-subtracted counts
  (Koshut et al. 1996, as the BATSE and GBM catalogues do), the net counts and the peak rate,
  with statistical errors from resampling (:class:`Durations`).

:func:`norris_pulse` (Norris et al. 2005) and :func:`true_durations` are the noiseless side:
a pulse shape to inject, and the durations of a known rate curve to compare with.

Times are seconds on the event list's clock.  A light curve or a duration is measured on an
interval covered by good time (a burst is seconds long; a gap inside it would need an
exposure-weighted Bayesian-block fitness this module does not have); the background is
fitted on any intervals, clipped to the good time.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import astropy.units as u
import numpy as np
from astropy.stats import bayesian_blocks

from rotmod._validate import as_array, as_int, as_scalar
from rotmod.errors import ParameterError
from rotmod.events.eventlist import EventList
from rotmod.events.gti import join_touching
from rotmod.limits import check_memory, check_time

__all__ = [
    "Background",
    "BurstLightCurve",
    "Durations",
    "burst_light_curve",
    "durations",
    "fit_background",
    "norris_pulse",
    "true_durations",
]

#: Most fine bins a light curve is cut into: Bayesian blocks cost ``N^2`` operations.
MAX_BINS = 100_000
#: Default significance (Gaussian sigma, one-sided) from which a block is burst emission.
#: Bayesian blocks (p0 = 0.01) leave a window of pure background in one block most of the
#: time and split it in a few per cent of windows, and a block split off is by construction
#: off the background: at 3 sigma about 1 % of background windows then hold a "burst" block
#: (2 of 200 windows of 65 s in 0.032 s bins, with 7 detectors at 30 counts/s each), at 2
#: sigma nearly every split one would.  The background's own error is part of the
#: significance, so a poorly known background does not make a burst.
DEFAULT_THRESHOLD = 3.0
#: Fraction of the window at each end whose mean cumulative net counts are a plateau level of
#: :func:`durations`.
PLATEAU = 0.05
#: How far (sigma, either way) the counts of a plateau stretch of :func:`durations` may be
#: from the background: a guard against a window that cuts through the burst (then it is
#: tens of sigma off), not a test at the light curve's threshold, which would refuse a window
#: of pure background once in a few hundred.
MARGIN_SIGMA = 5.0
#: Bootstrap draws held in memory at once (elements of a (draws, bins) array).
_CHUNK_ELEMENTS = 2_000_000


def _check_events(events: Any) -> EventList:
    if not isinstance(events, EventList):
        raise ParameterError(f"events must be an EventList, got {type(events)}")
    return events


def _span(value: Any, name: str, events: EventList) -> tuple[float, float]:
    """A ``(start, stop)`` interval (s) covered by the good time of ``events``."""
    arr = as_array(value, name, u.s, ndim=1)
    if arr.shape != (2,) or not arr[1] > arr[0]:
        raise ParameterError(f"{name} must be (start, stop) in s with stop > start, got "
                             f"{np.array2string(arr, precision=6)}")
    a, b = float(arr[0]), float(arr[1])
    gti = join_touching(events.gti)
    if not np.any((gti[:, 0] <= a) & (b <= gti[:, 1])):
        where = ", ".join(f"[{g0:g}, {g1:g}]" for g0, g1 in gti[:5])
        more = ", ..." if len(gti) > 5 else ""
        raise ParameterError(f"{name} must lie within one good-time interval of the events "
                             f"({where}{more} s), got [{a:g}, {b:g}] s")
    return a, b


def _bin_width(value: Any) -> float:
    return as_scalar(value, "bin_width", u.s, lo=0.0, lo_open=True)


def _grid(a: float, b: float, width: float, name: str) -> np.ndarray:
    """Equal bins over ``[a, b]`` as close to ``width`` as divide it (at least two)."""
    n = round((b - a) / width)
    if n < 2:
        raise ParameterError(f"bin_width must be at most half the {name} ({(b - a) / 2:g} s), "
                             f"got {width:g} s")
    if n > MAX_BINS:
        raise ParameterError(f"bin_width must give at most {MAX_BINS} bins over the {name} "
                             f"({b - a:g} s), got {width:g} s ({n} bins)")
    return np.linspace(a, b, n + 1)


def _edges(value: Any, name: str) -> np.ndarray:
    e = as_array(value, name, u.s, ndim=1)
    if e.size < 2 or np.any(np.diff(e) <= 0):
        raise ParameterError(f"{name} must be at least two increasing times (s), got "
                             f"{e.size} values")
    return e


def _binned(events: EventList, edges: np.ndarray) -> np.ndarray:
    """Detector-summed counts in ``[e_i, e_i+1)`` (the times are sorted)."""
    return np.diff(np.searchsorted(events.time, edges, side="left")).astype(float)


def _gaussian_draws(rng: np.random.Generator, mean: np.ndarray, cov: np.ndarray,
                    n: int) -> np.ndarray:
    """``n`` draws of a normal vector; a covariance with rounding-negative eigenvalues is
    taken as the nearest positive semi-definite one (no warning, unlike numpy's)."""
    w, v = np.linalg.eigh(cov)
    z = rng.standard_normal((n, mean.size))
    return mean + (z * np.sqrt(np.clip(w, 0.0, None))) @ v.T


# ---------------------------------------------------------------------------------------------
# Background


@dataclass(frozen=True)
class Background:
    """Per-detector background rate, a polynomial in time fitted to the counts around a burst.

    ``B_d(t) = sum_j coefficients[d, j] x^j`` with ``x = (t - t_ref) / scale``: the scaled
    time runs over ``[-1, 1]`` across the fitted intervals, so the powers are a
    well-conditioned basis whatever the clock's origin.

    Attributes
    ----------
    coefficients : ndarray, shape (n_det, degree + 1)
        Counts/s, in powers of the scaled time.
    t_ref : float
        Centre of the fitted span (s).
    intervals : ndarray, shape (k, 2)
        The intervals fitted (s): those asked for, clipped to the good time.
    covariance : ndarray, shape (n_det, degree + 1, degree + 1)
        Covariance of each detector's coefficients (the inverse Fisher information); the
        detectors are independent.
    scale : float
        Half the fitted span (s).
    """

    coefficients: np.ndarray
    t_ref: float
    intervals: np.ndarray
    covariance: np.ndarray
    scale: float = 1.0

    def __post_init__(self) -> None:
        c = as_array(self.coefficients, "coefficients", ndim=2)
        n_det, p = c.shape
        cov = as_array(self.covariance, "covariance", ndim=3)
        if cov.shape != (n_det, p, p):
            raise ParameterError(f"covariance must have shape ({n_det}, {p}, {p}), got "
                                 f"{cov.shape}")
        iv = as_array(self.intervals, "intervals", u.s, ndim=2)
        if iv.shape[1] != 2:
            raise ParameterError(f"intervals must have shape (k, 2), got {iv.shape}")
        t_ref = as_scalar(self.t_ref, "t_ref", u.s)
        scale = as_scalar(self.scale, "scale", u.s, lo=0.0, lo_open=True)
        for name, val in (("coefficients", c), ("covariance", cov), ("intervals", iv)):
            val = np.array(val)
            val.flags.writeable = False
            object.__setattr__(self, name, val)
        object.__setattr__(self, "t_ref", t_ref)
        object.__setattr__(self, "scale", scale)

    @property
    def degree(self) -> int:
        """Degree of the polynomial."""
        return self.coefficients.shape[1] - 1

    @property
    def n_detectors(self) -> int:
        """Number of detectors."""
        return self.coefficients.shape[0]

    def _x(self, t: np.ndarray) -> np.ndarray:
        return (t - self.t_ref) / self.scale

    def _design(self, edges: np.ndarray) -> np.ndarray:
        """``(n_bins, degree + 1)``: the integral of each power of ``x`` over each bin (s)."""
        powers = np.arange(1, self.degree + 2)
        prim = self._x(edges)[:, None] ** powers / powers
        return self.scale * np.diff(prim, axis=0)

    def _polynomial(self, t: np.ndarray) -> np.ndarray:
        return self.coefficients @ (self._x(t)[None, :] ** np.arange(self.degree + 1)[:, None])

    def rate(self, t: Any) -> np.ndarray:
        """Background rate of every detector at times ``t`` (s).

        Parameters
        ----------
        t : float or array_like
            Times (s).

        Returns
        -------
        ndarray, shape (n_det, len(t))
            Counts/s, the polynomial where it is positive and 0 where it is not.
        """
        return np.maximum(self._polynomial(as_array(t, "t", u.s, ndim=1)), 0.0)

    def counts(self, edges: Any) -> np.ndarray:
        """Expected background counts of every detector in bins.

        The exact integral of :meth:`rate` (the polynomial, cut at 0 where it would be
        negative) over each bin.

        Parameters
        ----------
        edges : array_like, shape (n + 1,)
            Increasing bin edges (s).

        Returns
        -------
        ndarray, shape (n_det, n)
        """
        e = _edges(edges, "edges")
        x = self._x(e)
        out = np.empty((self.n_detectors, e.size - 1))
        powers = np.arange(1, self.degree + 2)
        for d, coef in enumerate(self.coefficients):
            trimmed = np.trim_zeros(coef, "b")
            roots = (np.polynomial.polynomial.polyroots(trimmed) if trimmed.size > 1
                     else np.empty(0))
            roots = roots.real[(np.abs(roots.imag) < 1e-12) & (roots.real > x[0])
                               & (roots.real < x[-1])]
            xs = np.union1d(x, roots)
            seg = self.scale * np.diff((xs[:, None] ** powers / powers) @ coef)
            mid = 0.5 * (xs[1:] + xs[:-1])
            positive = (mid[:, None] ** np.arange(self.degree + 1)) @ coef > 0
            which = np.clip(np.searchsorted(x, mid) - 1, 0, e.size - 2)
            out[d] = np.bincount(which, weights=np.where(positive, seg, 0.0),
                                 minlength=e.size - 1)
        return out

    def summed_counts(self, edges: Any) -> tuple[np.ndarray, np.ndarray]:
        """Expected detector-summed background counts in bins and their 1-sigma errors.

        Parameters
        ----------
        edges : array_like, shape (n + 1,)
            Increasing bin edges (s).

        Returns
        -------
        counts, error : ndarray, shape (n,)
            The sum of :meth:`counts` over the detectors, and its error propagated from the
            coefficients' covariance (linearly: the polynomial, the detectors independent).
        """
        e = _edges(edges, "edges")
        a = self._design(e)
        var = np.einsum("bi,ij,bj->b", a, self.covariance.sum(axis=0), a)
        return self.counts(e).sum(axis=0), np.sqrt(np.maximum(var, 0.0))

    def _summed_draws(self, edges: np.ndarray, rng: np.random.Generator,
                      n: int) -> np.ndarray:
        """``(n, n_bins)`` detector-summed background counts with the coefficients drawn
        from their covariance."""
        c = _gaussian_draws(rng, self.coefficients.sum(axis=0), self.covariance.sum(axis=0), n)
        return c @ self._design(edges).T


def _clip_intervals(iv: np.ndarray, gti: np.ndarray) -> np.ndarray:
    lo = np.maximum(iv[:, None, 0], gti[None, :, 0]).ravel()
    hi = np.minimum(iv[:, None, 1], gti[None, :, 1]).ravel()
    keep = hi > lo
    pieces = np.column_stack([lo[keep], hi[keep]])
    return pieces[np.argsort(pieces[:, 0])]


def _poisson_fit(a: np.ndarray, n: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Poisson ML of ``mu = a @ c`` to counts ``n`` by Fisher scoring (IRLS), the rate kept
    positive at every bin edge (``v @ c > 0``) by halving steps.  Returns ``(c, cov)``."""
    exposure = a[:, 0].sum()
    c = np.zeros(a.shape[1])
    c[0] = max(n.sum(), 1.0) / exposure  # with no counts: the rate of one count, for the errors
    if n.sum() == 0:
        mu = a @ c
        return np.zeros_like(c), np.linalg.inv((a.T / mu) @ a)
    mu = a @ c
    ll = float(np.sum(n * np.log(mu) - mu))
    for _ in range(100):
        fisher = (a.T / mu) @ a
        step = np.linalg.solve(fisher, a.T @ (n / mu - 1.0))
        s, moved = 1.0, False
        while s > 1e-10:
            trial = c + s * step
            mu_t = a @ trial
            if np.all(mu_t > 0) and np.all(v @ trial > 0):
                ll_t = float(np.sum(n * np.log(mu_t) - mu_t))
                if ll_t >= ll - 1e-12 * abs(ll):
                    moved = True
                    break
            s *= 0.5
        if not moved:
            break
        gain = ll_t - ll
        c, mu, ll = trial, mu_t, ll_t
        if gain < 1e-9:  # log-likelihood units: the step is ~1e-4 sigma
            break
    return c, np.linalg.inv((a.T / mu) @ a)


def fit_background(events: EventList, intervals: Any, *, degree: int = 1,
                   bin_width: float = 1.0) -> Background:
    """Fit every detector's background rate around a burst.

    Each detector's rate is a polynomial of ``degree`` in time, fitted by Poisson maximum
    likelihood to its counts binned in ``bin_width`` within ``intervals``.  The intervals are
    clipped to the good time; each clipped piece is cut into bins of ``bin_width`` from its
    start, the last one shorter, and every bin's expected counts are the exact integral of
    the polynomial over it (so partial bins weigh as their exposure).  The maximum is found
    by Fisher scoring (iteratively reweighted least squares) from a constant rate, halving
    steps that would make the rate negative at a bin edge or lower the likelihood; the
    covariance is the inverse Fisher information at the maximum.

    Parameters
    ----------
    events : EventList
    intervals : array_like, shape (k, 2) or (2,)
        Background intervals (s), before and after the burst, not overlapping.
    degree : int
        Degree of the polynomial (0: a constant rate).
    bin_width : float
        Bin width (s) of the fitted counts.

    Returns
    -------
    Background

    Raises
    ------
    ParameterError
        Bad intervals (not ``start < stop``, overlapping, outside the good time, holding no
        events), a negative degree or one the bins cannot constrain, or ``bin_width <= 0``.
    """
    events = _check_events(events)
    degree = as_int(degree, "degree", lo=0)
    width = _bin_width(bin_width)
    iv = as_array(intervals, "intervals", u.s)
    if iv.shape == (2,):
        iv = iv[None, :]
    if iv.ndim != 2 or iv.shape[1] != 2 or iv.shape[0] == 0:
        raise ParameterError(f"intervals must have shape (k, 2), got {iv.shape}")
    if np.any(iv[:, 1] <= iv[:, 0]):
        i = int(np.argmax(iv[:, 1] <= iv[:, 0]))
        raise ParameterError(f"intervals must have start < stop, got [{iv[i, 0]:g}, "
                             f"{iv[i, 1]:g}] s (row {i})")
    iv = iv[np.argsort(iv[:, 0])]
    if np.any(iv[1:, 0] < iv[:-1, 1]):
        raise ParameterError("intervals must not overlap")
    pieces = _clip_intervals(iv, events.gti)
    if pieces.size == 0:
        raise ParameterError(f"intervals must overlap the good time of the events "
                             f"({events.t_start:g} to {events.t_stop:g} s), got "
                             f"[{iv[0, 0]:g}, {iv[-1, 1]:g}] s")
    n_bins = float(np.sum(np.maximum(1.0, np.ceil((pieces[:, 1] - pieces[:, 0]) / width
                                                  - 1e-9))))
    # Bin edges, their design rows and the counts per detector: a few values per bin.
    check_memory(8.0 * n_bins * (len(events.instrument.detectors) + 2 * degree + 8),
                 f"{n_bins:.3g} background bins of bin_width = {width:g} s", hint="a larger "
                 "bin_width")
    lo, hi = [], []
    for p0, p1 in pieces:
        n = max(1, int(np.ceil((p1 - p0) / width - 1e-9)))
        starts = p0 + width * np.arange(n)
        lo.append(starts)
        hi.append(np.append(starts[1:], p1))
    lo_a, hi_a = np.concatenate(lo), np.concatenate(hi)
    if lo_a.size < degree + 1:
        raise ParameterError(f"degree must be < the number of background bins "
                             f"({lo_a.size}), got {degree}; use a smaller bin_width")
    t_ref = 0.5 * (lo_a[0] + hi_a[-1])
    scale = 0.5 * (hi_a[-1] - lo_a[0])
    powers = np.arange(1, degree + 2)

    def prim(t: np.ndarray) -> np.ndarray:
        return ((t - t_ref) / scale)[:, None] ** powers / powers

    a = scale * (prim(hi_a) - prim(lo_a))
    v = ((np.concatenate([lo_a, hi_a]) - t_ref) / scale)[:, None] ** np.arange(degree + 1)
    t = events.time
    idx = np.searchsorted(lo_a, t, side="right") - 1
    inside = (idx >= 0) & (t < hi_a[np.maximum(idx, 0)])
    if not np.any(inside):
        raise ParameterError(f"intervals hold no events (good time {np.sum(hi_a - lo_a):g} s "
                             f"in [{iv[0, 0]:g}, {iv[-1, 1]:g}] s)")
    n_det, m = len(events.instrument.detectors), lo_a.size
    counts = np.bincount(events.detector[inside].astype(np.int64) * m + idx[inside],
                         minlength=n_det * m).reshape(n_det, m).astype(float)
    coef = np.empty((n_det, degree + 1))
    cov = np.empty((n_det, degree + 1, degree + 1))
    for d in range(n_det):
        coef[d], cov[d] = _poisson_fit(a, counts[d], v)
    return Background(coef, t_ref, pieces, cov, scale)


# ---------------------------------------------------------------------------------------------
# Light curve


def _significance(n: np.ndarray, b: np.ndarray, sigma_b: np.ndarray) -> np.ndarray:
    """Signed significance (sigma) of ``n`` counts over an expected background ``b`` known
    to ``sigma_b``.

    The Poisson likelihood-ratio significance for a known background, ``sign(n - b)
    sqrt(2 (n ln(n / b) - (n - b)))`` (right in the few-count tail of short blocks), divided
    by ``sqrt(1 + sigma_b^2 / b)`` so that for many counts it is ``(n - b) / sqrt(b +
    sigma_b^2)``: the background's error counts as much as its Poisson noise.
    """
    b = np.maximum(b, 1e-12)
    log_term = np.where(n > 0, n * np.log(np.where(n > 0, n, 1.0) / b), 0.0)
    s = np.sign(n - b) * np.sqrt(2.0 * np.maximum(log_term - (n - b), 0.0))
    return s / np.sqrt(1.0 + sigma_b**2 / b)


@dataclass(frozen=True)
class BurstLightCurve:
    """A burst's detector-summed light curve in Bayesian blocks, against the background.

    Attributes
    ----------
    edges : ndarray, shape (n_blocks + 1,)
        Block edges (s) over the analysed interval.
    counts : ndarray, shape (n_blocks,)
        Detector-summed counts per block.
    background : ndarray, shape (n_blocks,)
        Expected detector-summed background counts per block.
    interval : (float, float)
        The burst's extent (s): the start of its first block significantly above the
        background to the end of its last one; ``(nan, nan)`` when no block is.
    background_err : ndarray, shape (n_blocks,)
        1-sigma error of ``background``.
    significance : ndarray, shape (n_blocks,)
        Signed significance (sigma) of each block's counts over the background.
    threshold : float
        Significance from which a block is burst emission.
    """

    edges: np.ndarray
    counts: np.ndarray
    background: np.ndarray
    interval: tuple[float, float]
    background_err: np.ndarray
    significance: np.ndarray
    threshold: float = DEFAULT_THRESHOLD

    @property
    def widths(self) -> np.ndarray:
        """Block lengths (s)."""
        return np.diff(self.edges)

    @property
    def net_rate(self) -> np.ndarray:
        """Net detector-summed rate per block, ``(counts - background) / width`` (counts/s)."""
        return (self.counts - self.background) / self.widths

    @property
    def burst(self) -> np.ndarray:
        """Boolean per block: significantly above the background (burst emission)."""
        return self.significance >= self.threshold

    @property
    def level(self) -> np.ndarray:
        """The relative light curve per block: the net rate of the burst blocks, at most 1
        (at the brightest block), and 0 in the blocks consistent with the background."""
        lev = np.where(self.burst, np.maximum(self.net_rate, 0.0), 0.0)
        top = lev.max()
        return lev / top if top > 0 else lev

    def shape(self, t_edges: Any) -> np.ndarray:
        """The burst's relative light curve ``L(t)`` averaged over each bin of ``t_edges``.

        ``L`` is :attr:`level` in each block (1 in the brightest, 0 in the blocks
        consistent with the background) and 0 outside the analysed interval; a bin across
        block edges gets the time average, so the template conserves the burst's profile
        at any binning.

        Parameters
        ----------
        t_edges : array_like, shape (n + 1,)
            Increasing bin edges (s).

        Returns
        -------
        ndarray, shape (n,)
            Values in ``[0, 1]``.
        """
        te = _edges(t_edges, "t_edges")
        level = self.level
        cum = np.concatenate([[0.0], np.cumsum(level * self.widths)])
        out = np.diff(np.interp(te, self.edges, cum)) / np.diff(te)
        # A bin inside one block takes its level as it is (no rounding of the averages).
        first = np.searchsorted(self.edges, te[:-1], side="right") - 1
        last = np.searchsorted(self.edges, te[1:], side="left") - 1
        inside = (first == last) & (first >= 0) & (first < level.size)
        out[inside] = level[first[inside]]
        return out


def _check_background(background: Any, events: EventList) -> None:
    if not isinstance(background, Background):
        raise ParameterError(f"background must be a Background, got {type(background)}")
    n_det = len(events.instrument.detectors)
    if background.n_detectors != n_det:
        raise ParameterError(f"background must have one rate per detector ({n_det}), got "
                             f"{background.n_detectors}")


def _blocks(events: EventList, span: tuple[float, float], name: str, background: Background,
            width: float, p0: float, threshold: float) -> BurstLightCurve:
    """The light curve over ``span`` (``name``: the argument, for messages)."""
    _check_background(background, events)
    grid = _grid(*span, width, name)
    fine = _binned(events, grid)
    if fine.sum() == 0:
        raise ParameterError(f"{name} holds no events: [{span[0]:g}, {span[1]:g}] s")
    step = (span[1] - span[0]) / fine.size
    # astropy's cell of a point runs half-way to its neighbours, and from the first (to the
    # last) point itself: at the bin centres every bin's cell is the bin, but the two end
    # cells are half bins, whose counts then look like twice the rate (a one-bin block of an
    # upward fluctuation at an end).  An empty point half a bin outside each end makes every
    # bin's cell exactly the bin; it adds half a bin without counts to the end blocks.
    centres = span[0] + step * (np.arange(-1, fine.size + 1) + 0.5)
    bb = bayesian_blocks(centres, np.concatenate([[0.0], fine, [0.0]]), fitness="events",
                         p0=p0)
    inner = np.rint((bb[1:-1] - span[0]) / step).astype(int)
    inner = inner[(inner > 0) & (inner < fine.size)]
    cut = np.unique(np.concatenate([[0], inner, [fine.size]]))
    edges = grid[cut]
    counts = np.add.reduceat(fine, cut[:-1])
    bkg, bkg_err = background.summed_counts(edges)
    sig = _significance(counts, bkg, bkg_err)
    hot = np.flatnonzero(sig >= threshold)
    extent = ((float(edges[hot[0]]), float(edges[hot[-1] + 1])) if hot.size
              else (float("nan"), float("nan")))
    return BurstLightCurve(edges, counts, bkg, extent, bkg_err, sig, threshold)


def _threshold(value: Any) -> float:
    return as_scalar(value, "threshold", lo=0.0, lo_open=True)


def burst_light_curve(events: EventList, interval: Any, background: Background, *,
                      bin_width: float = 0.016, p0: float = 0.01,
                      threshold: float = DEFAULT_THRESHOLD) -> BurstLightCurve:
    """Cut the detector-summed counts over ``interval`` into Bayesian blocks.

    The counts of all detectors are binned in ``bin_width`` and segmented by
    :func:`astropy.stats.bayesian_blocks` with the "events" fitness on binned data (the bin
    centres as times, the counts as values) and false-alarm probability ``p0`` per change
    point.  Each block's counts are compared with the background model's expected counts
    by the Poisson likelihood-ratio significance for a known background, ``sign(n - b)
    sqrt(2 (n ln(n / b) - (n - b)))``, divided by ``sqrt(1 + sigma_b^2 / b)`` so that the
    background's error ``sigma_b`` counts as much as its Poisson noise (for many counts
    ``(n - b) / sqrt(b + sigma_b^2)``; right also in the few-count tail of short blocks,
    where the Gaussian form would make bursts of fluctuations); a block at least
    ``threshold`` sigma above it is burst emission, the others count as background.

    Parameters
    ----------
    events : EventList
    interval : (float, float)
        The analysed interval (s), covered by good time; it should hold background on both
        sides of the burst.
    background : Background
        The background under the burst (:func:`fit_background`).
    bin_width : float
        Fine bin width (s); the bins are equal, as close to it as divide the interval.
    p0 : float
        False-alarm probability of a change point, in (0, 1).
    threshold : float
        Significance (sigma) from which a block is burst emission (default 3; see
        :data:`DEFAULT_THRESHOLD` for why).

    Returns
    -------
    BurstLightCurve

    Raises
    ------
    ParameterError
        An interval not covered by good time or holding no events, ``bin_width <= 0`` or
        more than half the interval, ``p0`` outside (0, 1).
    """
    events = _check_events(events)
    span = _span(interval, "interval", events)
    width = _bin_width(bin_width)
    p0 = as_scalar(p0, "p0", lo=0.0, hi=1.0, lo_open=True, hi_open=True)
    return _blocks(events, span, "interval", background, width, p0, _threshold(threshold))


# ---------------------------------------------------------------------------------------------
# Durations


@dataclass(frozen=True)
class Durations:
    """T90, T50, net counts and peak rate of a burst, with statistical errors.

    Attributes
    ----------
    t90, t90_err : float
        Time (s) from 5 % to 95 % of the burst's net counts, and its 1-sigma error.
    t50, t50_err : float
        Time (s) from 25 % to 75 %, and its error.
    t90_start, t50_start : float
        Start times (s) of the T90 and T50 intervals.
    net_counts, net_counts_err : float
        Detector-summed net counts of the burst, and their error.
    peak_rate, peak_rate_err : float
        Highest net detector-summed rate (counts/s) averaged over ``peak_timescale``, and its
        error.
    peak_time : float
        Centre (s) of the ``peak_timescale`` interval with the peak rate.
    peak_timescale : float
        The peak rate's averaging time (s).
    """

    t90: float
    t90_err: float
    t50: float
    t50_err: float
    t90_start: float
    t50_start: float
    net_counts: float
    net_counts_err: float
    peak_rate: float
    peak_rate_err: float
    peak_time: float
    peak_timescale: float

    def to_dict(self) -> dict[str, float]:
        """The fields as plain floats, by name (e.g. for a table row or a JSON file)."""
        return {k: float(v) for k, v in dataclasses.asdict(self).items()}


def _crossings(cum: np.ndarray, t: np.ndarray, level: np.ndarray) -> np.ndarray:
    """When each row of a cumulative curve ``cum`` (m, n + 1) at times ``t`` passes
    ``level`` (m,): the mean of its first arrival at the level and the last time it is
    below it (linear in each bin); they are one time for a rising curve, and their mean
    does not lean to either side for a noisy one.  NaN where it never gets there."""
    m, n1 = cum.shape
    rows = np.arange(m)
    ge = cum >= level[:, None]
    reached = ge.any(axis=1)
    k1 = np.argmax(ge, axis=1)
    below = ~ge
    k2 = n1 - 1 - np.argmax(below[:, ::-1], axis=1)
    k2 = np.where(below.any(axis=1), k2, -1)

    def between(k: np.ndarray) -> np.ndarray:  # the crossing in (t[k], t[k + 1])
        k = np.clip(k, 0, n1 - 2)
        c0, c1 = cum[rows, k], cum[rows, k + 1]
        frac = np.clip((level - c0) / np.where(c1 > c0, c1 - c0, 1.0), 0.0, 1.0)
        return t[k] + frac * (t[k + 1] - t[k])

    first = np.where(k1 == 0, t[0], between(k1 - 1))
    last = np.where(k2 < 0, t[0], between(k2))
    out = 0.5 * (first + last)
    return np.where(reached & (k2 < n1 - 1), out, np.nan)


def _measure(cum: np.ndarray, t: np.ndarray, pre: slice, post: slice,
             k: int) -> dict[str, np.ndarray]:
    """Durations of each row of net cumulative counts ``cum`` at edges ``t``: the plateau
    levels are the means of the cumulative over ``pre`` and ``post`` edges, the peak the
    highest ``k``-bin increase."""
    lo = cum[:, pre].mean(axis=1)
    total = cum[:, post].mean(axis=1) - lo
    ok = total > 0
    at = {f: _crossings(cum, t, lo + f * np.where(ok, total, np.nan))
          for f in (0.05, 0.25, 0.75, 0.95)}
    rise = cum[:, k:] - cum[:, :-k]
    j = np.argmax(rise, axis=1)
    return {
        "t90": at[0.95] - at[0.05], "t50": at[0.75] - at[0.25],
        "t90_start": at[0.05], "t50_start": at[0.25],
        "net_counts": total,
        "peak_rate": rise[np.arange(cum.shape[0]), j] / (t[k] - t[0]),
        "peak_time": 0.5 * (t[j] + t[j + k]),
    }


def _std(x: np.ndarray) -> float:
    x = x[np.isfinite(x)]
    return float(np.std(x, ddof=1)) if x.size > 1 else float("nan")


def durations(events: EventList, window: Any, background: Background, *,
              bin_width: float = 0.016, n_boot: int = 200, peak_timescale: float = 1.024,
              seed: int | np.random.Generator | None = 0,
              threshold: float = DEFAULT_THRESHOLD,
              light_curve: BurstLightCurve | None = None) -> Durations:
    """T90, T50, net counts and peak rate of the burst in ``window``.

    The method of Koshut et al. (1996), as the BATSE and GBM catalogues apply it: the
    detector-summed counts in bins of ``bin_width`` less the background model's, summed
    into a cumulative curve over ``window``; it is flat before the burst, rises through it
    and is flat again after it.  The two plateau levels are fixed from the data at the
    ends: the mean of the cumulative over the first and over the last 5 % of the window
    (:data:`PLATEAU`), which must hold background only (their counts within
    :data:`MARGIN_SIGMA` of the background model's); the net counts are their difference.
    T90 runs from the time the curve passes 5 % of the net counts above the first plateau
    to the time it passes 95 %, T50 from 25 % to 75 % (each passage the mean of the curve's
    first arrival at the level and the last time it is below it, so that noise on the curve
    moves it neither way).  The peak rate is the highest net rate averaged over
    ``peak_timescale`` (1.024 s, like GBM's), sliding by one bin.

    The errors are the standard deviations over ``n_boot`` redraws of the data, every
    quantity measured again on each: the background coefficients drawn from a normal law of
    their covariance, and every bin's counts from a Poisson law of the model -- the
    background plus the burst's ``light_curve`` (its blocks' net rates) -- or, without a
    light curve, of the observed counts (the blocks above its threshold: a tail below it is
    background in the redraws).  Redraws of the observed counts count the observed
    noise twice (the counts are a draw already): over 216 injected bursts
    (``benchmarks/bursts_t90.py``) they put 0.92 of the bright ones within 1 sigma
    (Gaussian: 0.68) and 0.62 of the faint ones within 2 sigma; the model's put 0.69 and
    0.92 of all within 1 and 2 sigma (Gaussian: 0.68, 0.95), but of the bursts below a
    10-sigma trigger only 0.76 within 2 sigma, their T90 long by ~0.9 sigma (the crossings
    fall in the background's noise). They are statistical only: the
    choice of background polynomial, of window and plateaus, and of energy band (the
    systematic part of a catalogue's T90) is not in them. The peak rate, a maximum over
    noisy values, is biased up by a fraction of its error.

    Parameters
    ----------
    events : EventList
    window : (float, float)
        The analysed interval (s), covered by good time: the whole burst with margins of
        background on both sides.
    background : Background
    bin_width : float
        Fine bin width (s); the bins are equal, as close to it as divide the window.
    n_boot : int
        Number of redraws for the errors (at least 2).
    peak_timescale : float
        Averaging time (s) of the peak rate, rounded to whole bins; at least one bin, at most
        the window.
    seed : int, Generator or None
        Random state of the redraws.
    threshold : float
        Significance (sigma) over the background that the window's counts must have.
    light_curve : BurstLightCurve, optional
        The burst's blocks (:func:`burst_light_curve`): the model the errors' redraws are
        drawn from (default: the observed counts).

    Returns
    -------
    Durations

    Raises
    ------
    ParameterError
        A window not covered by good time, holding no events or no burst, or without
        background margins; ``bin_width <= 0`` or more than 5 % of the window;
        ``n_boot < 2``; a ``peak_timescale`` shorter than a bin or longer than the window.
    """
    events = _check_events(events)
    span = _span(window, "window", events)
    width = _bin_width(bin_width)
    n_boot = as_int(n_boot, "n_boot", lo=2)
    timescale = as_scalar(peak_timescale, "peak_timescale", u.s, lo=0.0, lo_open=True)
    threshold = _threshold(threshold)
    _check_background(background, events)
    if light_curve is not None and not isinstance(light_curve, BurstLightCurve):
        raise ParameterError(f"light_curve must be a BurstLightCurve, got {type(light_curve)}")
    grid = _grid(*span, width, "window")
    fine = _binned(events, grid)
    if fine.sum() == 0:
        raise ParameterError(f"window holds no events: [{span[0]:g}, {span[1]:g}] s")
    n = fine.size
    m = int(PLATEAU * n)
    if m < 1:
        raise ParameterError(f"bin_width must be at most {PLATEAU:g} of the window "
                             f"({PLATEAU * (span[1] - span[0]):g} s, a plateau stretch), "
                             f"got {width:g} s")
    step = grid[1] - grid[0]
    k = round(timescale / step)
    if k < 1 or k > n:
        raise ParameterError(f"peak_timescale must be between one bin ({step:g} s) and the "
                             f"window ({span[1] - span[0]:g} s), got {timescale:g} s")
    design = background._design(grid)
    bkg = design @ background.coefficients.sum(axis=0)
    cov = background.covariance.sum(axis=0)
    for name, sel in (("whole", slice(0, n)), ("start", slice(0, m)), ("end", slice(n - m, n))):
        a = design[sel].sum(axis=0)
        sig = float(_significance(fine[sel].sum(), bkg[sel].sum(), np.sqrt(a @ cov @ a)))
        if name == "whole" and sig < threshold:
            raise ParameterError(f"window holds no burst: its counts in [{span[0]:g}, "
                                 f"{span[1]:g}] s are {sig:.2g} sigma above the background, "
                                 f"less than threshold = {threshold:g}")
        if name != "whole" and abs(sig) >= MARGIN_SIGMA:
            lo, hi = grid[sel.start], grid[sel.stop]
            raise ParameterError(f"window must have a margin of background on both sides of "
                                 f"the burst: the counts at its {name} ([{lo:g}, {hi:g}] s, "
                                 f"the plateau stretch) are {sig:.2g} sigma off the background")
    pre, post = slice(0, m + 1), slice(n - m, n + 1)

    def cumulative(net: np.ndarray) -> np.ndarray:
        return np.concatenate([np.zeros((net.shape[0], 1)), np.cumsum(net, axis=1)], axis=1)

    best = {key: float(val[0]) for key, val in
            _measure(cumulative((fine - bkg)[None, :]), grid, pre, post, k).items()}
    if not best["net_counts"] > 0:
        raise ParameterError(f"window holds no net counts above the background between its "
                             f"plateaus ({best['net_counts']:g})")
    if light_curve is None:
        mean = fine.astype(float)
    else:
        top = np.max(np.where(light_curve.burst, light_curve.net_rate, 0.0), initial=0.0)
        mean = np.maximum(bkg, 0.0) + top * light_curve.shape(grid) * np.diff(grid)
    # Each redraw keeps one value per measurement: counted before the first, and the time of
    # the rest estimated from the first chunk's.
    check_memory(8.0 * n_boot * len(best), f"n_boot = {n_boot} bootstrap redraws",
                 hint="a smaller n_boot")
    rng = np.random.default_rng(seed)
    chunk = max(1, _CHUNK_ELEMENTS // grid.size)
    draws: dict[str, list[np.ndarray]] = {key: [] for key in best}
    t0 = time.perf_counter()
    for start in range(0, n_boot, chunk):
        size = min(chunk, n_boot - start)
        counts = rng.poisson(mean, size=(size, n))
        bkg_draws = background._summed_draws(grid, rng, size)
        for key, val in _measure(cumulative(counts - bkg_draws), grid, pre, post, k).items():
            draws[key].append(val)
        if start == 0 and n_boot > size:
            check_time(n_boot - size, size / max(time.perf_counter() - t0, 1e-9),
                       f"n_boot = {n_boot} bootstrap redraws of the window's {n} bins",
                       unit="redraws", hint="a smaller n_boot")
    err = {key: _std(np.concatenate(val)) for key, val in draws.items()}
    return Durations(
        best["t90"], err["t90"], best["t50"], err["t50"], best["t90_start"],
        best["t50_start"], best["net_counts"], err["net_counts"], best["peak_rate"],
        err["peak_rate"], best["peak_time"], float(k * step),
    )


# ---------------------------------------------------------------------------------------------
# Noiseless pulses


def norris_pulse(t: Any, start: float, rise: float, decay: float,
                 amplitude: float = 1.0) -> np.ndarray:
    """A pulse of Norris et al. (2005, ApJ 627, 324).

    ``I(t) = A lambda exp(-tau1 / (t - ts) - (t - ts) / tau2)`` after ``ts``, 0 before, with
    ``lambda = exp(2 sqrt(tau1 / tau2))``: the peak, ``A``, is at ``ts + sqrt(tau1 tau2)``.

    Parameters
    ----------
    t : float or array_like
        Times (s).
    start : float
        Start ``ts`` (s).
    rise, decay : float
        ``tau1`` and ``tau2`` (s), both > 0.
    amplitude : float
        Peak value ``A`` (e.g. counts/s), >= 0.

    Returns
    -------
    ndarray
        ``I(t)``, the shape of ``t``.
    """
    tt = as_array(t, "t", u.s)
    ts = as_scalar(start, "start", u.s)
    tau1 = as_scalar(rise, "rise", u.s, lo=0.0, lo_open=True)
    tau2 = as_scalar(decay, "decay", u.s, lo=0.0, lo_open=True)
    amp = as_scalar(amplitude, "amplitude", lo=0.0)
    return amp * norris_shape(tt - ts, tau1, tau2)


def norris_shape(dt: np.ndarray, rise: Any, decay: Any) -> np.ndarray:
    """:func:`norris_pulse` of peak 1 at times ``dt`` after its start (unchecked; ``rise``
    and ``decay`` may be arrays that broadcast with ``dt``)."""
    after = dt > 0
    safe = np.where(after, dt, 1.0)
    return np.where(after, np.exp(2.0 * np.sqrt(rise / decay) - rise / safe - safe / decay),
                    0.0)


def true_durations(rate_fn: Callable[[np.ndarray], Any], t0: float, t1: float,
                   n: int = 200001, *, peak_timescale: float = 1.024) -> Durations:
    """Durations of a noiseless light curve: the truth a measured T90 is compared with.

    The cumulative of ``rate_fn`` (trapezoids on ``n`` equally spaced times over ``[t0,
    t1]``) from 0 to its total; T90 from 5 % to 95 % of it, T50 from 25 % to 75 %, as
    :func:`durations` measures them (to the grid's accuracy, ``(t1 - t0) / (n - 1)``).  The
    plateaus are the curve's ends, 0 and the total: for a window that holds the whole burst,
    as :func:`durations` requires, the same as the means over its end stretches.

    Parameters
    ----------
    rate_fn : callable
        ``rate_fn(t)`` -> rates (e.g. counts/s, >= 0) at an array of times (s).
    t0, t1 : float
        The window (s).
    n : int
        Number of grid times (at least 3).
    peak_timescale : float
        Averaging time (s) of the peak rate, rounded to whole grid steps.

    Returns
    -------
    Durations
        With zero errors; ``net_counts`` is the integral of the rate over the window.

    Raises
    ------
    ParameterError
        ``t1 <= t0``, ``n < 3``, rates not finite or negative or summing to 0, or a
        ``peak_timescale`` outside one grid step to the window.
    """
    a = as_scalar(t0, "t0", u.s)
    b = as_scalar(t1, "t1", u.s)
    if not b > a:
        raise ParameterError(f"t1 must be > t0 ({a:g} s), got {b:g} s")
    n = as_int(n, "n", lo=3)
    t = np.linspace(a, b, n)
    r = np.asarray(rate_fn(t), dtype=float)
    if r.shape != t.shape or not np.all(np.isfinite(r)) or np.any(r < 0):
        raise ParameterError("rate_fn must return finite rates >= 0, one per time")
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (r[1:] + r[:-1]) * np.diff(t))])
    if not cum[-1] > 0:
        raise ParameterError(f"rate_fn must be positive somewhere in [{a:g}, {b:g}] s")
    step = t[1] - t[0]
    timescale = as_scalar(peak_timescale, "peak_timescale", u.s, lo=0.0, lo_open=True)
    k = round(timescale / step)
    if k < 1 or k > n - 1:
        raise ParameterError(f"peak_timescale must be between one grid step ({step:g} s) "
                             f"and the window ({b - a:g} s), got {timescale:g} s")
    m = _measure(cum[None, :], t, slice(0, 1), slice(n - 1, n), k)
    v = {key: float(val[0]) for key, val in m.items()}
    return Durations(v["t90"], 0.0, v["t50"], 0.0, v["t90_start"], v["t50_start"],
                     v["net_counts"], 0.0, v["peak_rate"], 0.0, v["peak_time"],
                     float(k * step))

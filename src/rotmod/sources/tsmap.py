"""TS maps: the likelihood ratio of a test point source in every pixel of a sky geometry.

For pixel ``n`` with response column ``c_n`` (times the exposure) the expected counts are
``m0 + f c_n``, ``m0`` the current model (background and known sources, held fixed), and

    TS_n = 2 max_{f >= 0} sum_i [ y_i ln(1 + f c_ni / m0_i) - f c_ni ].

The one-parameter likelihood is concave in ``f`` and its derivative is convex, so Newton's
method started at ``f = 0`` climbs to the maximum without overshooting (each tangent of a
convex decreasing function crosses zero before it does); a pixel whose slope at 0 is
negative has ``f = 0`` and ``TS = 0``.  With the flux bounded at 0, TS at a fixed position
follows ``1/2 chi2_0 + 1/2 chi2_1`` under the null, so ``sqrt(TS)`` is the significance in
sigma (Chernoff 1954; measured in ``benchmarks/sources_calibration.py``).  The same pass gives
each pixel's flux error (curvature), the upper limit (the flux above the fit where the
likelihood has fallen by the one-sided ``chi2_1`` quantile) and the sensitivity: the flux a
source would need for its Asimov data set (``y = m0 + f c``) to reach a chosen TS, the
expected detection threshold (Cowan et al. 2011).  Limits and sensitivity are thus two
readings of one likelihood.

Pixels are taken in blocks of columns (:meth:`ResponseOperator.block`), so any response --
held, matrix-free, Radon, stored -- gives its TS map within a memory budget.

A wide field (10^6 pixels, 10^5 bins) has too many values for that: ``exact_above`` screens
every pixel first with the **score test** at ``f = 0``, which needs no column, only three
adjoint products of the whole sky,

    g_n = sum_i c_ni (y_i / m0_i - 1),     I_n = sum_i c_ni^2 / m0_i - X_n^2 / H,
    X_n = sum_i c_ni tb_i / m0_i,          H = sum_i tb_i^2 / m0_i,

(``P^T``, :meth:`ResponseOperator.adjoint_squared` and ``P^T`` again) and gives
``TS_score = g^2 / I`` (0 for ``g <= 0``), flux ``g / I`` and error ``I^-1/2``.  ``I`` is the
expected information of the flux with the background levels profiled (a Schur complement),
except that the levels' correction is pooled over detectors: by Cauchy-Schwarz
``(sum_d X_d)^2 / sum_d H_d <= sum_d X_d^2 / H_d``, so the screen's ``I`` is too large and
its TS too small, by the spread between detectors of the pixel's mean response over a turn.
That spread is largest within a few degrees of the axis, where a source's ray sweeps
circles on the mask no larger than the detector array: the screen's TS is there down to
0.74 of the profiled score's for 7 detectors, 0.91 for 37 or 61, and above 0.96 beyond
10 deg (``benchmarks/bench_tsmap_wide.py``).  With time bins averaged over sub-samples,
the Radon response's squared table gives the mean of their squares, larger than the
square of their mean, so that ``I`` is too large there too.  Each map measures the ratio of
the profiled score's information to the screen's on a sample of pixels (their columns,
:func:`_calibrate`) and takes the lowest, ``r``.  For faint
signals the score and the likelihood ratio agree (both are ``chi2`` under the null); for
bright ones the score, with the expected information, exceeds the ratio.  So every pixel
whose screen TS reaches ``SCREEN_MARGIN r exact_above`` is then computed exactly, as above,
and the map holds the likelihood ratio wherever TS is near or above ``exact_above`` and the
score test elsewhere (:attr:`TSMap.exact` says which).  The screen's upper limit and
sensitivity are the same quadratic likelihood's.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numba as nb
import numpy as np

from rotmod._validate import as_scalar
from rotmod.errors import ParameterError
from rotmod.limits import check_memory, memory_budget
from rotmod.progress import ProgressArg, progress_callbacks
from rotmod.response.operator import ResponseOperator
from rotmod.response.parallel import block_grid, iter_blocks
from rotmod.response.unfolded import UnfoldedResponse
from rotmod.sky.geometry import SkyGeometry
from rotmod.sources.fitting import FitBins, SourceFitter, ul_threshold
from rotmod.sources.model import SkyModel

__all__ = ["TSMap", "ts_map"]

#: Newton steps at most (each solve converges in ~5-15).
_MAX_NEWTON = 60
#: A screened map (``exact_above``) computes the likelihood ratio exactly wherever the
#: screen's TS reaches ``SCREEN_MARGIN * r * exact_above``, with ``r`` the lowest ratio of
#: the screen's TS to the profiled score's measured on :data:`CALIBRATION_PIXELS` pixels of
#: the map (module notes); 0.9 covers what the sample misses and the score's departure from
#: the likelihood ratio near the cut (both measured in ``benchmarks/bench_tsmap_wide.py``).
SCREEN_MARGIN = 0.9
#: Pixels of the screen's calibration: half the nearest to the axis, half at directions with
#: ``theta`` uniform over the field (the pooling matters most within a few degrees of it).
CALIBRATION_PIXELS = 128
#: Columns per block of the exact pass over a screened map's selected pixels.
_REFINE_BLOCK = 256


@nb.njit(cache=True)
def _loglike(c, y, m_rest, det, tb, f, b):  # pragma: no cover - numba
    """``ln L`` of ``mu = m_rest + f c + b[det] tb`` (-inf if a mu <= 0 has counts), as
    ``sum y ln(mu / y) + y - mu``: ``sum y ln mu - mu`` less a constant, in terms that are
    small near a fit, so that differences of ln L keep their digits."""
    acc = 0.0
    for i in range(y.size):
        mu = m_rest[i] + f * c[i] + b[det[i]] * tb[i]
        if y[i] > 0.0:
            if mu <= 0.0:
                return -np.inf
            acc += y[i] * np.log1p((mu - y[i]) / y[i]) + y[i] - mu
        else:
            acc -= mu
    return acc


@nb.njit(cache=True)
def _sums(c, y, m_rest, det, tb, f, b, gb, hb, hfb):  # pragma: no cover - numba
    """Gradient and information of ``(f, b)``: returns ``(g_f, h_ff)``, fills the rest."""
    gb[:] = 0.0
    hb[:] = 0.0
    hfb[:] = 0.0
    gf = 0.0
    hff = 0.0
    for i in range(y.size):
        mu = m_rest[i] + f * c[i] + b[det[i]] * tb[i]
        r = y[i] / mu
        w = r / mu
        d = det[i]
        gf += c[i] * (r - 1.0)
        hff += c[i] * c[i] * w
        gb[d] += tb[i] * (r - 1.0)
        hb[d] += tb[i] * tb[i] * w
        hfb[d] += c[i] * tb[i] * w
    return gf, hff


@nb.njit(cache=True)
def _fit_background(c, y, m_rest, det, tb, f, b, gb, hb, hfb):  # pragma: no cover - numba
    """Maximise over the background levels ``b`` (in place) with ``f`` held: each detector's
    level is a separate concave problem, solved by Newton kept positive.  Returns ln L."""
    for _ in range(_MAX_NEWTON):
        _sums(c, y, m_rest, det, tb, f, b, gb, hb, hfb)
        worst = 0.0
        for d in range(b.size):
            if hb[d] > 0.0:
                new = b[d] + gb[d] / hb[d]
                if new <= 0.0:
                    new = 0.5 * b[d]
                worst = max(worst, abs(new - b[d]) / max(b[d], 1e-300))
                b[d] = new
        if worst < 1e-10:
            break
    return _loglike(c, y, m_rest, det, tb, f, b)


@nb.njit(cache=True)
def _fit_pixel(c, y, m_rest, det, tb, b, gb, hb, hfb):  # pragma: no cover - numba
    """Maximise over ``f >= 0`` and the levels ``b`` (in place) from ``f = 0``: Newton on
    the joint problem (an arrow-shaped Hessian, solved through its Schur complement) with a
    backtracking line search.  Returns ``(f, ln L, Schur information of f)``."""
    f = 0.0
    ll = _loglike(c, y, m_rest, det, tb, f, b)
    schur = 0.0
    for _ in range(_MAX_NEWTON):
        gf, hff = _sums(c, y, m_rest, det, tb, f, b, gb, hb, hfb)
        schur = hff
        rhs = gf
        for d in range(b.size):
            if hb[d] > 0.0:
                schur -= hfb[d] * hfb[d] / hb[d]
                rhs -= hfb[d] * gb[d] / hb[d]
        df = rhs / schur if schur > 0.0 else 0.0
        if f <= 0.0 and df < 0.0:
            df = 0.0  # the bound is active: only the levels move
        dec = df * gf
        for d in range(b.size):
            if hb[d] > 0.0:
                dec += (gb[d] - hfb[d] * df) / hb[d] * gb[d]
        # Converged: the remaining gain is below 1e-9 or the rounding of ln L itself.
        if dec < 1e-9 + 1e-13 * abs(ll):
            break
        t = 1.0
        b_old = b.copy()
        improved = False
        for _ls in range(30):
            fn = max(f + t * df, 0.0)
            ok = True
            for d in range(b.size):
                if hb[d] > 0.0:
                    b[d] = b_old[d] + t * (gb[d] - hfb[d] * df) / hb[d]
                    if b[d] <= 0.0:
                        ok = False
            if ok:
                lln = _loglike(c, y, m_rest, det, tb, fn, b)
                if lln >= ll:
                    f = fn
                    ll = lln
                    improved = True
                    break
            t *= 0.5
        if not improved:
            b[:] = b_old
            break
    return f, ll, schur


@nb.njit(parallel=True, cache=True)
def _ts_pixels(C, y, m_rest, det, tb, b0, q_ul, q_sens, out):  # pragma: no cover - numba
    # q_ul or q_sens <= 0: that reading is skipped (NaN).
    """Fill ``out[k] = (ts, flux, flux_err, flux_ul, sensitivity)`` for columns ``C[k]``:
    a test source with the background levels ``b`` refitted (from ``b0``, the null's)."""
    n_det = b0.size
    ll0 = _loglike(C[0], y, m_rest, det, tb, 0.0, b0)
    for k in nb.prange(C.shape[0]):
        c = C[k]
        csum = 0.0
        for i in range(c.size):
            csum += c[i]
        if csum <= 0.0:  # a pixel the data cannot see
            for j in range(5):
                out[k, j] = np.nan
            continue
        b = b0.copy()
        gb = np.empty(n_det)
        hb = np.empty(n_det)
        hfb = np.empty(n_det)
        gf, schur = _sums(c, y, m_rest, det, tb, 0.0, b, gb, hb, hfb)
        for d in range(n_det):
            if hb[d] > 0.0:
                schur -= hfb[d] * hfb[d] / hb[d]
        f = 0.0
        ll = ll0
        if gf > 0.0:  # the profile's slope at 0 (the levels are the null's optimum)
            f, ll, schur = _fit_pixel(c, y, m_rest, det, tb, b, gb, hb, hfb)
        out[k, 0] = max(2.0 * (ll - ll0), 0.0)
        out[k, 1] = f
        out[k, 2] = 1.0 / np.sqrt(schur) if schur > 0.0 else np.inf
        # Upper limit: 2 (ln L - profile(u)) = q_ul above f.  The profile is concave, so
        # this is convex increasing in u and Newton (slope from the envelope theorem: the
        # profile's derivative is the partial in f at the refitted levels) converges after
        # at most one overshoot.
        out[k, 3] = np.nan
        out[k, 4] = np.nan
        if q_ul <= 0.0:
            continue
        u = f + (np.sqrt(q_ul / schur) if schur > 0.0 else q_ul / (2.0 * csum))
        bu = b.copy()
        for _ in range(_MAX_NEWTON):
            llu = _fit_background(c, y, m_rest, det, tb, u, bu, gb, hb, hfb)
            gu, _ = _sums(c, y, m_rest, det, tb, u, bu, gb, hb, hfb)
            val = 2.0 * (ll - llu) - q_ul
            slope = -2.0 * gu
            if slope <= 0.0:
                u = f + 2.0 * (u - f) + 1e-300
                continue
            du = val / slope
            u = max(u - du, 0.5 * (u + f))
            if abs(du) <= 1e-9 * u:
                break
        out[k, 3] = u
        if q_sens <= 0.0:
            continue
        # Sensitivity: the flux s whose Asimov data m0 + s c reach TS = q_sens against the
        # null refitted to them (the levels absorb what of the source they can).  Newton
        # with dTS/ds = 2 sum c ln(y_A / mu_null) (envelope theorem again).
        ya = np.empty(y.size)
        s = np.sqrt(q_sens / schur) if schur > 0.0 else 1.0
        bn = b0.copy()
        for _ in range(_MAX_NEWTON):
            for i in range(y.size):
                ya[i] = m_rest[i] + b0[det[i]] * tb[i] + s * c[i]
            lln = _fit_background(c, ya, m_rest, det, tb, 0.0, bn, gb, hb, hfb)
            lla = _loglike(c, ya, m_rest, det, tb, s, b0)
            ts = 2.0 * (lla - lln)
            dts = 0.0
            for i in range(y.size):
                if c[i] > 0.0:
                    dts += 2.0 * c[i] * np.log(ya[i] / (m_rest[i] + bn[det[i]] * tb[i]))
            if dts <= 0.0:
                s *= 2.0
                continue
            ds = (ts - q_sens) / dts
            s = max(s - ds, 0.5 * s)
            if abs(ds) <= 1e-9 * s:
                break
        out[k, 4] = s


@dataclass(frozen=True)
class TSMap:
    """A TS map and the other per-pixel readings of the same likelihood.

    All maps have the grid's image shape; pixels the data cannot see are NaN.

    Attributes
    ----------
    grid : SkyGeometry
    ts : ndarray
        Test statistic of a point source in each pixel (>= 0).
    flux, flux_err : ndarray
        Fitted flux (>= 0) and its curvature error (the response's sky unit).
    flux_ul : ndarray
        Upper limit at ``ul_confidence``.
    sensitivity : ndarray
        Flux whose Asimov data set has ``TS = sensitivity_ts``.
    ul_confidence, sensitivity_ts : float
    exact : ndarray of bool or None
        Pixels whose readings are the likelihood's (the others hold the score screen's,
        module notes); ``None``: every pixel.
    exact_above, screen_cut : float or None
        The screened map's ``exact_above`` and the screen TS from which pixels were
        computed exactly (``None``: not screened).
    """

    grid: SkyGeometry
    ts: np.ndarray
    flux: np.ndarray
    flux_err: np.ndarray
    flux_ul: np.ndarray
    sensitivity: np.ndarray
    ul_confidence: float
    sensitivity_ts: float
    exact: np.ndarray | None = None
    exact_above: float | None = None
    screen_cut: float | None = None

    @property
    def sqrt_ts(self) -> np.ndarray:
        """``sqrt(TS)``: significance (sigma) of a source at a fixed, pre-chosen pixel."""
        return np.sqrt(self.ts)

    def peak(self) -> tuple[int, float]:
        """Flat index and TS of the highest pixel."""
        flat = np.where(np.isfinite(self.ts), self.ts, -np.inf).ravel()
        k = int(np.argmax(flat))
        return k, float(flat[k])


def null_state(fitter: SourceFitter, model: SkyModel | None) -> tuple[np.ndarray, ...]:
    """The fitted null model as the kernels take it: ``(m_rest, det, tb, b0)``.

    ``m_rest`` are the expected counts of everything but the fitted background levels,
    ``det`` each valid bin's detector, ``tb`` its background template times exposure (0
    when the background is known, not fitted) and ``b0`` the null's levels.
    """
    return _fit_null(fitter, model)[1]


def _fit_null(fitter: SourceFitter, model: SkyModel | None
              ) -> tuple[SkyModel, tuple[np.ndarray, ...]]:
    """The fitted null model and its :func:`null_state`."""
    model, res = fitter.maximise(SkyModel() if model is None else model)
    n_det = fitter.data.shape[0]
    det = fitter.bins.detector
    if fitter.fit_background:
        tb = fitter.bins(fitter.exposure * fitter.template(model))
        b0 = np.asarray(model.background, dtype=float)
    else:
        tb, b0 = np.zeros(det.size), np.zeros(n_det)
    m_rest = res.mu - b0[det] * tb
    if np.any(m_rest < -1e-9 * np.abs(res.mu).max()):
        raise ParameterError("the null model's expected counts are negative")
    if np.any((res.mu <= 0) & (fitter.y > 0)):
        raise ParameterError("the model predicts no counts in bins that have counts: fit a "
                             "background (or give a positive known background)")
    return model, (np.maximum(m_rest, 0.0), det, np.ascontiguousarray(tb), b0)


def _screen(fitter: SourceFitter, model: SkyModel, q_ul: float, q_sens: float
            ) -> tuple[np.ndarray, float]:
    """The score screen of every pixel (module notes): ``(n_sky, 5)`` readings as
    :func:`scan_test_source`'s, from three adjoint products (NaN where a pixel is not seen:
    no information left once the background levels are profiled), and the calibration's
    ratio (:func:`_calibrate`)."""
    resp = fitter.response
    mu = fitter.expected(model)
    ex = fitter.exposure
    seen = ex > 0
    inv = np.divide(1.0, mu, out=np.zeros_like(mu), where=seen & (mu > 0))
    g = np.asarray(resp.adjoint(np.where(seen, ex * (fitter.data.counts * inv - 1.0), 0.0)),
                   dtype=np.float64)
    info1 = resp.adjoint_squared(ex * ex * inv)
    info = info1
    tb = ex * fitter.template(model) if fitter.fit_background else np.zeros_like(ex)
    if fitter.fit_background:
        x = np.asarray(resp.adjoint(tb * ex * inv), dtype=np.float64)
        info = info1 - x * x / np.sum(tb * tb * inv)
    ratio = _calibrate(fitter, info, tb, inv)
    out = np.full((resp.n_sky, 5), np.nan)
    # Pooling the levels' correction can only leave too much information (module notes),
    # so a pixel with none left relative to its own is one the background hides.
    ok = info > 1e-9 * info1
    i = info[ok]
    fhat = g[ok] / i
    flux = np.maximum(fhat, 0.0)
    out[ok, 0] = np.where(fhat > 0.0, g[ok] * fhat, 0.0)
    out[ok, 1] = flux
    out[ok, 2] = 1.0 / np.sqrt(i)
    # The quadratic likelihood's readings: 2 (ln L(flux) - ln L(u)) = q_ul above the
    # bounded fit, and the Asimov TS s^2 I = q_sens.
    if q_ul > 0.0:
        out[ok, 3] = fhat + np.sqrt((flux - fhat) ** 2 + q_ul / i)
    if q_sens > 0.0:
        out[ok, 4] = np.sqrt(q_sens / i)
    return out, ratio


def _calibrate(fitter: SourceFitter, info: np.ndarray, tb: np.ndarray, inv: np.ndarray
               ) -> float:
    """The lowest ratio of the profiled score's information (per-detector background
    correction, from the columns) to the screen's ``info`` on the calibration pixels: the
    screen's TS over the score's, with every approximation of the screen in it (the pooling,
    and the squared table of :meth:`~rotmod.response.RadonResponse.adjoint_squared`)."""
    resp = fitter.response
    n = min(CALIBRATION_PIXELS, resp.n_sky)
    if resp.grid is None:
        idx = np.arange(n)
    else:
        theta = resp.grid.directions()[0].to_value("rad").ravel()
        order = np.argsort(theta, kind="stable")
        # theta uniform: the pixel whose theta is nearest each of n/2 equally spaced values
        want = np.linspace(theta.min(), theta.max(), n - n // 2)
        rank = np.clip(np.searchsorted(theta[order], want), 0, theta.size - 1)
        idx = np.unique(np.concatenate([order[: n // 2], order[rank]]))
    ex = fitter.exposure
    c = ex[:, :, None] * np.asarray(resp.columns(idx), dtype=np.float64)
    profiled = np.einsum("dtn,dt->n", c * c, inv)
    h = np.sum(tb * tb * inv, axis=1)
    seen = h > 0
    if np.any(seen):
        x = np.einsum("dtn,dt->dn", c[seen], (tb * inv)[seen])
        profiled -= np.sum(x * x / h[seen, None], axis=0)
    good = (info[idx] > 0) & (profiled > 0)
    return float(min(1.0, np.min(profiled[good] / info[idx][good], initial=1.0)))


def scan_test_source(fitter: SourceFitter, state: tuple[np.ndarray, ...], columns: np.ndarray,
                     q_ul: float = 2.706, q_sens: float = 25.0) -> np.ndarray:
    """``(ts, flux, flux_err, flux_ul, sensitivity)`` of a test source per column.

    Parameters
    ----------
    fitter : SourceFitter
    state : tuple
        :func:`null_state` of the null model.
    columns : ndarray, shape (n_fit, k)
        Exposure-weighted columns of the test positions on the fit bins
        (:meth:`SourceFitter.columns_on_bins`).
    q_ul, q_sens : float
        ``2 delta ln L`` of the upper limit and TS of the sensitivity (<= 0: skipped).
    """
    return _scan_bins(columns, fitter.y, *state, q_ul, q_sens)


def _scan_bins(ec: np.ndarray, y: np.ndarray, m_rest: np.ndarray, det: np.ndarray,
               tb: np.ndarray, b0: np.ndarray, q_ul: float, q_sens: float) -> np.ndarray:
    out = np.empty((ec.shape[1], 5))
    _ts_pixels(np.ascontiguousarray(ec.T, dtype=np.float64), y, m_rest, det, tb,
               np.array(b0, dtype=float), float(q_ul), float(q_sens), out)
    return out


def _scan_block(columns: np.ndarray, _block: Any, exposure: np.ndarray, bins: FitBins,
                y: np.ndarray, m_rest: np.ndarray, det: np.ndarray, tb: np.ndarray,
                b0: np.ndarray, q_ul: float, q_sens: float) -> np.ndarray:
    """The scan of one block of columns (the ``reduce`` of the block walk: on a Dask
    worker, only the ``(k, 5)`` result travels back)."""
    return _scan_bins(bins(columns, exposure), y, m_rest, det, tb, b0, q_ul,
                      q_sens)


def ts_map(
    response: ResponseOperator,
    data: Any,
    model: SkyModel | None = None,
    *,
    ul_confidence: float = 0.95,
    sensitivity_ts: float | None = 25.0,
    limits: bool = True,
    exact_above: float | None = None,
    fitter: SourceFitter | None = None,
    progress: ProgressArg = None,
    block_pixels: int | None = None,
    scheduler: str | None = None,
    client: Any = None,
) -> TSMap:
    """TS, flux, error, upper limit and sensitivity of a test source in every pixel.

    Parameters
    ----------
    response : ResponseOperator
        On the sky geometry of the map (its pixels are the test positions).
    data : PoissonData or FoldedProfiles
    model : SkyModel, optional
        The null model: its free amplitudes (background levels, known sources' fluxes) are
        fitted first, then held fixed.  Default: background only.
    ul_confidence : float
        Confidence of the upper limits, in (0.5, 1).
    sensitivity_ts : float or None
        TS that defines the sensitivity (25: 5 sigma at a fixed position), > 0; ``None``
        skips the sensitivity (NaN), which costs more than the rest of the map.
    limits : bool
        Compute the upper limits and the sensitivity (``False``: TS, flux and error only,
        ~5x faster; the others NaN).
    exact_above : float, optional
        Screen every pixel with the score test first (three adjoint products, no columns;
        module notes) and compute the likelihood ratio only where the screen's TS reaches
        a calibrated fraction of ``exact_above``: what makes 10^6-pixel maps of a Radon response
        take a minute.  The other pixels keep the screen's readings (:attr:`TSMap.exact`).
        Needs folded data; the exact pass runs locally.  Default: every pixel exact.
    fitter : SourceFitter, optional
        Reuse one built for the same response and data.
    progress : bool or callable, optional
        Progress over the pixels.
    block_pixels : int, optional
        Pixels per block (default: as many as fit the memory budget, at most 4096).
    scheduler, client : optional
        Scan the blocks of pixels on a Dask cluster (address or ``distributed.Client``),
        as responses compute their blocks; default local (numba's threads).

    Returns
    -------
    TSMap
    """
    q_ul = ul_threshold(ul_confidence)
    if sensitivity_ts is not None and not (np.isfinite(sensitivity_ts) and sensitivity_ts > 0):
        raise ParameterError(f"sensitivity_ts must be > 0 or None, got {sensitivity_ts!r}")
    q_sens = 0.0 if sensitivity_ts is None or not limits else float(sensitivity_ts)
    if not limits:
        q_ul = 0.0
    if exact_above is not None:
        exact_above = as_scalar(exact_above, "exact_above", lo=0.0)
        if isinstance(response, UnfoldedResponse):
            raise ParameterError("exact_above: the score screen needs folded data (a "
                                 "response on the data's own bins), got an unfolded response")
    f = SourceFitter(response, data) if fitter is None else fitter
    fitted, state = _fit_null(f, model)
    n_bins, n_sky = f.y.size, response.n_sky
    per_pixel = 8.0 * (2 * n_bins + response.n_det * response.n_time)
    check_memory(per_pixel + 8.0 * 6 * n_sky, f"a TS map of {n_sky} pixels",
                 hint="use fewer pixels")
    width = int(max(1, min(n_sky, memory_budget() // 8 // per_pixel, 4096)))
    if block_pixels is not None:
        if isinstance(block_pixels, bool) or not isinstance(block_pixels, int | np.integer) \
                or block_pixels < 1:
            raise ParameterError(f"block_pixels must be an integer >= 1, got {block_pixels!r}")
        width = min(int(block_pixels), n_sky)
    shape = response.grid.shape if response.grid is not None else (1, n_sky)
    if exact_above is not None:
        out, ratio = _screen(f, fitted, q_ul, q_sens)
        cut = SCREEN_MARGIN * ratio * exact_above
        chosen = np.flatnonzero(out[:, 0] >= cut)  # NaN: not chosen
        update, close = progress_callbacks(progress, chosen.size, "TS map (exact pixels)",
                                           "pixel")
        try:
            for k0 in range(0, chosen.size, min(width, _REFINE_BLOCK)):
                idx = chosen[k0:k0 + min(width, _REFINE_BLOCK)]
                out[idx] = _scan_bins(f.on_bins(response.columns(idx)), f.y, *state, q_ul,
                                      q_sens)
                update(k0 + idx.size, chosen.size)
        finally:
            close()
        exact = np.zeros(n_sky, dtype=bool)
        exact[chosen] = True
        maps = [out[:, j].reshape(shape) for j in range(5)]
        return TSMap(response.grid, *maps, ul_confidence, q_sens, exact.reshape(shape),
                     exact_above, cut)
    blocks = block_grid((response.n_det, response.n_time, n_sky), (response.n_time, width))
    out = np.empty((n_sky, 5))
    update, close = progress_callbacks(progress, n_sky, "TS map", "pixel")
    done = 0
    try:
        # The one block walk of responses: blocks of pixels (all bins), locally in order or
        # as tasks on a Dask cluster; each result lands at its own pixels, so the map is the
        # same bit for bit either way.
        for _, (_, (n0, n1)), res in iter_blocks(
                response, blocks, f.exposure, f.bins, f.y, *state, q_ul, q_sens,
                reduce=_scan_block, scheduler=scheduler,
                client=client):
            out[n0:n1] = res
            done += n1 - n0
            update(done, n_sky)
    finally:
        close()
    maps = [out[:, j].reshape(shape) for j in range(5)]
    return TSMap(response.grid, *maps, ul_confidence, q_sens)

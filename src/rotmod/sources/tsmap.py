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
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numba as nb
import numpy as np

from rotmod.errors import ParameterError
from rotmod.limits import check_memory, memory_budget
from rotmod.progress import ProgressArg, progress_callbacks
from rotmod.response.operator import ResponseOperator
from rotmod.response.parallel import block_grid, iter_blocks
from rotmod.sky.geometry import SkyGeometry
from rotmod.sources.fitting import FitBins, SourceFitter, ul_threshold
from rotmod.sources.model import SkyModel

__all__ = ["TSMap", "ts_map"]

#: Newton steps at most (each solve converges in ~5-15).
_MAX_NEWTON = 60


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
    """

    grid: SkyGeometry
    ts: np.ndarray
    flux: np.ndarray
    flux_err: np.ndarray
    flux_ul: np.ndarray
    sensitivity: np.ndarray
    ul_confidence: float
    sensitivity_ts: float

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
    return np.maximum(m_rest, 0.0), det, np.ascontiguousarray(tb), b0


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
    return _scan_bins(bins(exposure[:, :, None] * columns), y, m_rest, det, tb, b0, q_ul,
                      q_sens)


def ts_map(
    response: ResponseOperator,
    data: Any,
    model: SkyModel | None = None,
    *,
    ul_confidence: float = 0.95,
    sensitivity_ts: float | None = 25.0,
    limits: bool = True,
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
    f = SourceFitter(response, data) if fitter is None else fitter
    state = null_state(f, model)
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
    shape = response.grid.shape if response.grid is not None else (1, n_sky)
    maps = [out[:, j].reshape(shape) for j in range(5)]
    return TSMap(response.grid, *maps, ul_confidence, q_sens)

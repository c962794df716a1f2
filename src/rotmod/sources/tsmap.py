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
from rotmod.progress import Progress, progress_callbacks
from rotmod.response.operator import ResponseOperator
from rotmod.sky.geometry import SkyGeometry
from rotmod.sources.fit import SourceFitter, ul_threshold
from rotmod.sources.model import SkyModel

__all__ = ["TSMap", "ts_map"]

#: Newton steps per pixel at most; convergence (relative step < 1e-10) takes ~5-15.
_MAX_NEWTON = 60


@nb.njit(cache=True)
def _loglike_gain(c, y, m0, f):  # pragma: no cover - numba
    """``sum y ln(1 + f c / m0) - f c``: ln L(f) - ln L(0)."""
    acc = 0.0
    for i in range(c.size):
        ci = c[i]
        if ci > 0.0:
            acc += y[i] * np.log1p(f * ci / m0[i]) - f * ci
    return acc


@nb.njit(cache=True)
def _slope_curv(c, y, m0, f):  # pragma: no cover - numba
    """First derivative and minus the second of ``ln L`` at ``f``."""
    g = 0.0
    h = 0.0
    for i in range(c.size):
        ci = c[i]
        if ci > 0.0:
            r = y[i] / (m0[i] + f * ci)
            g += ci * (r - 1.0)
            h += ci * ci * r / (m0[i] + f * ci)
    return g, h


@nb.njit(cache=True)
def _asimov_ts(c, m0, s):  # pragma: no cover - numba
    """TS of the Asimov data ``m0 + s c`` and its derivative in ``s``."""
    ts = 0.0
    d = 0.0
    for i in range(c.size):
        ci = c[i]
        if ci > 0.0:
            lg = np.log1p(s * ci / m0[i])
            ts += 2.0 * ((m0[i] + s * ci) * lg - s * ci)
            d += 2.0 * ci * lg
    return ts, d


@nb.njit(parallel=True, cache=True)
def _ts_pixels(C, y, m0, q_ul, q_sens, out):  # pragma: no cover - numba
    """Fill ``out[k] = (ts, flux, flux_err, flux_ul, sensitivity)`` for columns ``C[k]``."""
    for k in nb.prange(C.shape[0]):
        c = C[k]
        csum = 0.0
        for i in range(c.size):
            csum += c[i]
        if csum <= 0.0:  # a pixel the data cannot see
            out[k, 0] = np.nan
            out[k, 1] = np.nan
            out[k, 2] = np.nan
            out[k, 3] = np.nan
            out[k, 4] = np.nan
            continue
        f = 0.0
        g, h = _slope_curv(c, y, m0, 0.0)
        if g > 0.0:
            for _ in range(_MAX_NEWTON):
                if h <= 0.0:
                    break
                step = g / h
                f += step
                if step <= 1e-10 * f:
                    break
                g, h = _slope_curv(c, y, m0, f)
            g, h = _slope_curv(c, y, m0, f)
        ll = _loglike_gain(c, y, m0, f)
        out[k, 0] = max(2.0 * ll, 0.0)
        out[k, 1] = f
        out[k, 2] = 1.0 / np.sqrt(h) if h > 0.0 else np.inf
        # Upper limit: 2 (l(f) - l(u)) = q_ul for u > f; convex increasing in u, so Newton
        # converges from either side of the root after at most one overshoot.
        u = f + (np.sqrt(q_ul) / np.sqrt(h) if h > 0.0 else q_ul / (2.0 * csum))
        for _ in range(_MAX_NEWTON):
            gu, _hu = _slope_curv(c, y, m0, u)
            val = 2.0 * (ll - _loglike_gain(c, y, m0, u)) - q_ul
            slope = -2.0 * gu
            if slope <= 0.0:
                u = f + 2.0 * (u - f)
                continue
            du = val / slope
            u = max(u - du, 0.5 * (u + f))
            if abs(du) <= 1e-10 * u:
                break
        out[k, 3] = u
        # Sensitivity: TS of the Asimov data reaches q_sens (convex increasing in s).
        fisher = 0.0
        for i in range(c.size):
            fisher += c[i] * c[i] / m0[i]
        s = np.sqrt(q_sens / fisher)
        for _ in range(_MAX_NEWTON):
            ts, d = _asimov_ts(c, m0, s)
            if d <= 0.0:
                break
            ds = (ts - q_sens) / d
            s = max(s - ds, 0.5 * s)
            if abs(ds) <= 1e-10 * s:
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


def null_expectation(fitter: SourceFitter, model: SkyModel | None) -> tuple[SkyModel,
                                                                           np.ndarray]:
    """The fitted null model and its expected counts in the valid bins (all > 0)."""
    if model is None:
        model = SkyModel()
    model, res = fitter.maximise(model)
    m0 = res.mu
    if np.any((m0 <= 0) & (fitter.y > 0)) or np.any(m0 < 0):
        raise ParameterError("the model predicts no counts in bins that have counts: fit a "
                             "background (or give a positive known background)")
    return model, np.maximum(m0, 1e-300)


def ts_map(
    response: ResponseOperator,
    data: Any,
    model: SkyModel | None = None,
    *,
    ul_confidence: float = 0.95,
    sensitivity_ts: float = 25.0,
    fitter: SourceFitter | None = None,
    progress: Progress = None,
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
    sensitivity_ts : float
        TS that defines the sensitivity (25: 5 sigma at a fixed position), > 0.
    fitter : SourceFitter, optional
        Reuse one built for the same response and data.
    progress : bool or callable, optional
        Progress over the pixel blocks.

    Returns
    -------
    TSMap
    """
    q_ul = ul_threshold(ul_confidence)
    if not (np.isfinite(sensitivity_ts) and sensitivity_ts > 0):
        raise ParameterError(f"sensitivity_ts must be > 0, got {sensitivity_ts!r}")
    f = SourceFitter(response, data) if fitter is None else fitter
    _, m0 = null_expectation(f, model)
    n_bins, n_sky = f.y.size, response.n_sky
    per_pixel = 8.0 * (2 * n_bins + response.n_det * response.n_time)
    check_memory(per_pixel + 8.0 * 6 * n_sky, f"a TS map of {n_sky} pixels",
                 hint="use fewer pixels")
    width = int(max(1, min(n_sky, memory_budget() // 8 // per_pixel, 4096)))
    out = np.empty((n_sky, 5))
    blocks = list(range(0, n_sky, width))
    update, close = progress_callbacks(progress, n_sky, "TS map", "pixel")
    try:
        for n0 in blocks:
            n1 = min(n0 + width, n_sky)
            cols = response.block(n=(n0, n1))
            ec = (f.exposure[:, :, None] * cols)[f.valid]      # (n_bins, width)
            _ts_pixels(np.ascontiguousarray(ec.T), f.y, m0, q_ul, float(sensitivity_ts),
                       out[n0:n1])
            update(n1, n_sky)
    finally:
        close()
    shape = response.grid.shape if response.grid is not None else (1, n_sky)
    maps = [out[:, j].reshape(shape) for j in range(5)]
    return TSMap(response.grid, *maps, ul_confidence, float(sensitivity_ts))

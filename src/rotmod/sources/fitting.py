"""Fitting a sky model to folded counts: fluxes, background, positions, TS, errors, limits.

The likelihood is Poisson in every bin with exposure (the Cash statistic, ``C = -2 ln L``
up to a constant).  For fixed positions the model is linear in its amplitudes -- source
fluxes, the diffuse scale, the background levels -- and :func:`rotmod.sources.likelihood.maximise`
finds the maximum with every flux ``>= 0``.  Free positions are fitted continuously around
it: each source's position moves in its tangent plane (Nelder-Mead on the profile
likelihood, every amplitude re-maximised at each trial position), with the source's column
recomputed at the trial direction (:func:`rotmod.response.columns_at`).

Per source the fit reports

* ``ts = 2 (ln L - ln L_without)``, the likelihood ratio of the source (everything else
  refitted without it); with the flux bounded at 0 its null distribution is
  ``1/2 chi2_0 + 1/2 chi2_1`` for a fixed position;
* flux errors from the profile likelihood (``2 delta ln L = 1``, everything else
  refitted), asymmetric and stopping at 0;
* an upper limit at ``ul_confidence`` (one-sided: ``2 delta ln L = chi2_1^-1(2 CL - 1)``,
  2.71 at 95 %) above the fitted flux.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import sparse
from scipy.optimize import brentq, minimize
from scipy.stats import chi2 as chi2_dist

from rotmod.errors import ParameterError
from rotmod.geometry import Instrument
from rotmod.reconstruction.data import PoissonData, as_data
from rotmod.response.columns import columns_at
from rotmod.response.operator import ResponseOperator
from rotmod.response.unfolded import UnfoldedResponse
from rotmod.sources.likelihood import Groups, LinearPoissonFit, log_likelihood, maximise
from rotmod.sources.model import PointSource, SkyModel, positions_of, tangent_basis

__all__ = ["FitBins", "FitResult", "SourceFitter", "fit", "fit_with"]


def ul_threshold(confidence: float) -> float:
    """``2 delta ln L`` of a one-sided upper limit at ``confidence`` (2.706 at 0.95)."""
    if not 0.5 < confidence < 1.0:
        raise ParameterError(f"ul_confidence must be in (0.5, 1), got {confidence!r}")
    return float(chi2_dist.ppf(2.0 * confidence - 1.0, 1))


def geometric_scale(response: ResponseOperator | Instrument) -> float:
    """The instrument's angular scale ``b / L`` (rad): the slat gap over the mask height
    (of a response's instrument, or of an instrument)."""
    inst = response if isinstance(response, Instrument) else response.instrument
    mask = inst.mask
    return float(max(mask.slat_gap, 1e-3 * mask.period) / mask.height)


@dataclass(frozen=True)
class FitResult:
    """A fitted sky model and what the likelihood says about each source.

    Attributes
    ----------
    model : SkyModel
        The fitted model (fluxes, positions, background levels, diffuse scale).
    loglike : float
        ``sum(y ln mu - mu)`` at the maximum (Cash ``C = -2 loglike`` up to a constant).
    ts : ndarray, shape (n_sources,)
        Test statistic of each source.
    flux_err : ndarray, shape (n_sources, 2)
        Profile-likelihood ``(lower, upper)`` 1-sigma errors of each flux (the lower one
        stops at 0).
    flux_ul : ndarray, shape (n_sources,)
        Upper limit of each flux at ``ul_confidence``.
    ul_confidence : float
    expected : ndarray, shape (n_det, n_time)
        Expected counts of the fitted model (0 in bins without exposure).
    n_bins : int
        Bins with exposure.
    """

    model: SkyModel
    loglike: float
    ts: np.ndarray
    flux_err: np.ndarray
    flux_ul: np.ndarray
    ul_confidence: float
    expected: np.ndarray
    n_bins: int

    @property
    def sqrt_ts(self) -> np.ndarray:
        """``sqrt(ts)``: the significance (sigma) of each source at a fixed position."""
        return np.sqrt(np.maximum(self.ts, 0.0))


@dataclass(frozen=True, eq=False)
class FitBins:
    """The bins a likelihood is summed over: every bin with counts, and per detector one
    bin that merges all its bins without counts.

    A bin without counts adds ``-mu`` to ``ln L``, which is linear in the amplitudes, so
    merging such bins (summing their expected counts) leaves the likelihood, its gradient
    and its Hessian exactly as they were, while the sums run over the counts rather than
    the bins.  For time-tagged counts in short bins (a burst,
    :class:`~rotmod.response.UnfoldedResponse`) most bins are empty and the fit becomes
    as cheap as an unbinned one with the same answer.

    Attributes
    ----------
    counted : ndarray of bool, shape (n_det, n_time)
        Bins with exposure and counts (kept one by one).
    empty : ndarray of bool, shape (n_det, n_time)
        Bins with exposure and no counts (merged per detector).
    merged : ndarray of int
        The detectors that have such bins, in order (one merged bin each, after the
        counted bins).
    detector : ndarray of int
        Detector of each fit bin.
    """

    counted: np.ndarray
    empty: np.ndarray
    merged: np.ndarray
    detector: np.ndarray
    #: Flat indices of the counted bins, of the empty bins (detector by detector, as the
    #: flattening orders them) and where each merged detector's run of them starts: the
    #: fit bins are gathered, not masked, so that ``k`` columns cost ``n_fit k``, not
    #: ``n_det n_time k`` passes over temporaries.
    _take: np.ndarray = field(init=False, repr=False)
    _empty_flat: np.ndarray = field(init=False, repr=False)
    _starts: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        empty_flat = np.flatnonzero(self.empty)
        first = np.searchsorted(empty_flat // self.empty.shape[1], self.merged)
        object.__setattr__(self, "_take", np.flatnonzero(self.counted))
        object.__setattr__(self, "_empty_flat", empty_flat)
        object.__setattr__(self, "_starts", first)

    @classmethod
    def of(cls, counts: np.ndarray, valid: np.ndarray) -> FitBins:
        """The fit bins of ``counts`` ``(n_det, n_time)`` over the ``valid`` bins."""
        counted = valid & (counts > 0)
        empty = valid & (counts == 0)
        n_det, n_t = counts.shape
        merged = np.flatnonzero(empty.any(axis=1))
        rows = np.broadcast_to(np.arange(n_det)[:, None], (n_det, n_t))[counted]
        return cls(counted, empty, merged, np.concatenate([rows, merged]).astype(np.int64))

    def __call__(self, v: np.ndarray, weight: np.ndarray | None = None) -> np.ndarray:
        """Values ``(n_det, n_time)`` or ``(n_det, n_time, k)`` on the fit bins (summed
        over each merged bin), times ``weight`` ``(n_det, n_time)`` if given: ``(n_fit,)``
        or ``(n_fit, k)``, float64."""
        v = np.asarray(v)
        flat = v.reshape(self.empty.size, *v.shape[2:])
        w = None if weight is None else np.asarray(weight, dtype=float).ravel()

        def gather(idx: np.ndarray) -> np.ndarray:
            out = flat[idx]
            if w is None:
                return out.astype(float, copy=False)
            # float64 in one pass: w is float64
            return out * (w[idx] if out.ndim == 1 else w[idx, None])

        kept = gather(self._take)
        if not self.merged.size:
            return kept
        sums = np.add.reduceat(gather(self._empty_flat), self._starts, axis=0)
        return np.concatenate([kept, sums])

    def unfolded_maps(self, response: UnfoldedResponse, exposure: np.ndarray
                      ) -> list[sparse.csr_matrix]:
        """Per part of an unfolded response, the sparse map from its folded columns
        (flattened ``(n_det * n_phase, k)``) to the exposure-weighted columns on the fit
        bins: a fit bin's value is a sum of ``E_k w_k P[d, t(k)]`` over the time bins it
        holds, so the unfolded ``(n_det, n_time, k)`` columns are never formed (their size
        grows with the window; the maps' work with the number of bins once)."""
        n_det, n_t = self.counted.shape
        n_phase = response.parts[0].n_time
        row = np.full((n_det, n_t), -1, dtype=np.int64)
        n_counted = int(np.count_nonzero(self.counted))
        row[self.counted] = np.arange(n_counted)
        slot = np.full(n_det, -1, dtype=np.int64)
        slot[self.merged] = n_counted + np.arange(self.merged.size)
        row = np.where(self.empty, slot[:, None], row)
        col = np.arange(n_det)[:, None] * n_phase + response.phase[None, :]
        val = exposure * response.weight[None, :]
        maps = []
        for j in range(len(response.parts)):
            sel = (row >= 0) & (response.segment == j)[None, :]
            maps.append(sparse.csr_matrix((val[sel], (row[sel], np.broadcast_to(
                col, row.shape)[sel])), shape=(self.detector.size, n_det * n_phase)))
        return maps

    def detector_sums(self, v: np.ndarray) -> np.ndarray:
        """Per-detector sums of values on the fit bins ``(n_fit,)``."""
        return np.bincount(self.detector, weights=v, minlength=self.counted.shape[0])


class SourceFitter:
    """The likelihood of one data set through one response, for any sky model.

    Holds the data (bins with exposure), the background design and a cache of source
    columns by position, so that fits, profiles and TS maps on the same data share them.

    Parameters
    ----------
    response : ResponseOperator
        Any response with a spec (for source columns at arbitrary positions).
    data : PoissonData or FoldedProfiles
        Counts and exposure.  A known background (``data.background`` without
        ``fit_background``) is held fixed; otherwise the model's background levels are
        fitted (its template, else ``data.background`` as the template, else flat).
    """

    def __init__(self, response: ResponseOperator, data: Any) -> None:
        if not isinstance(response, ResponseOperator):
            raise ParameterError(f"response must be a ResponseOperator, got {type(response)}")
        self.response = response
        self.data: PoissonData = as_data(data)
        if self.data.shape != (response.n_det, response.n_time):
            raise ParameterError(
                f"data counts must have shape ({response.n_det}, {response.n_time}) to match "
                f"the response, got {self.data.shape}")
        self.valid = self.data.valid
        self.exposure = np.where(self.valid, self.data.exposure, 0.0)
        self.bins = FitBins.of(self.data.counts, self.valid)
        self.y = self.bins(self.data.counts)
        known = self.data.background is not None and not self.data.fit_background
        self.m_fixed = self.bins(self.exposure * self.data.background) if known else None
        self.fit_background = not known
        self.columns: dict[Any, np.ndarray] = {}
        self._unfolded = (self.bins.unfolded_maps(response, self.exposure)
                          if isinstance(response, UnfoldedResponse) else None)

    def columns_on_bins(self, positions: Any) -> np.ndarray:
        """Exposure-weighted response columns ``(n_fit, k)`` at ``positions`` on the fit
        bins (:class:`FitBins`): what the likelihood of a source there is made of."""
        if self._unfolded is None:
            return self.on_bins(columns_at(self.response, positions))
        return sum(m @ columns_at(part, positions).reshape(m.shape[1], -1)
                   for m, part in zip(self._unfolded, self.response.parts, strict=True))

    def on_bins(self, columns: np.ndarray) -> np.ndarray:
        """Response columns ``(n_det, n_time, k)`` times the exposure, on the fit bins:
        ``(n_fit, k)``."""
        return self.bins(columns, self.exposure)

    def source_bins(self, model: SkyModel) -> np.ndarray:
        """:meth:`columns_on_bins` of ``model``'s sources, cached by position."""
        out = np.empty((self.y.size, len(model.sources)))
        todo = []
        for k, src in enumerate(model.sources):
            key = (src.frame, *np.round(src.vector(), 15))
            if key in self.columns:
                out[:, k] = self.columns[key]
            else:
                todo.append((k, key))
        if todo:
            cols = self.columns_on_bins(positions_of([model.sources[k] for k, _ in todo]))
            for j, (k, key) in enumerate(todo):
                out[:, k] = self.columns[key] = cols[:, j]
        return out

    # -- the linear problem of a model --------------------------------------------------

    def template(self, model: SkyModel) -> np.ndarray:
        """The background template ``T[d, t]`` of ``model`` on these data."""
        n_det, n_t = self.data.shape
        if model.template is None and self.data.background is not None:
            return np.asarray(self.data.background, dtype=float)
        return model.background_template(n_det, n_t)

    def design(self, model: SkyModel, *, full: bool = False
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, Groups | None]:
        """``(A, x, free, m0, groups)``: the columns, amplitudes, free flags, fixed counts
        and the background levels' groups (one per detector; ``None`` when the background
        is known), on the fit's bins (:class:`FitBins`) or, with ``full``, on every bin
        with exposure.

        Amplitudes in order: source fluxes, the diffuse scale (with a diffuse image), the
        background levels (when fitted).
        """
        n_det, n_t = self.data.shape
        if full:
            def pick(v: np.ndarray) -> np.ndarray:
                return v[self.valid]
            rows = np.broadcast_to(np.arange(n_det)[:, None], (n_det, n_t))[self.valid]
        else:
            pick, rows = self.bins, self.bins.detector
        cols, x, free = [], [], []
        if model.sources:
            cols.append(pick(self.exposure[:, :, None] * model.source_columns(self.response))
                        if full else self.source_bins(model))
            x += [s.flux for s in model.sources]
            free += [s.free_flux for s in model.sources]
        if model.diffuse is not None:
            d = self.exposure * self.response.forward(model.diffuse)
            cols.append(pick(d)[:, None])
            x.append(model.diffuse_norm)
            free.append(model.free_diffuse)
        if full:
            m0 = np.zeros(rows.size) if self.m_fixed is None else pick(
                self.exposure * self.data.background)
        else:
            m0 = np.zeros(self.y.size) if self.m_fixed is None else self.m_fixed.copy()
        groups = None
        if self.fit_background:
            et = pick(self.exposure * self.template(model))
            groups = Groups(rows, et, n_det)
            per_det = groups.sum(et)
            if np.any(per_det <= 0):
                raise ParameterError("background template times exposure must be > 0 on "
                                     "every detector")
            if model.background is None:
                # Start: each detector's counts per unit of its template.
                level = self.bins.detector_sums(self.y) / per_det
            else:
                level = model.background
                if level.shape != (n_det,):
                    raise ParameterError(f"background must have {n_det} levels, got "
                                         f"{level.size}")
            x += list(np.maximum(level, 1e-12))
            free += [True] * n_det
        A = np.concatenate(cols, axis=1) if cols else np.zeros((rows.size, 0))
        return A, np.array(x, dtype=float), np.array(free, dtype=bool), m0, groups

    def _with_amplitudes(self, model: SkyModel, x: np.ndarray) -> SkyModel:
        k = len(model.sources)
        sources = tuple(dataclasses.replace(s, flux=float(f))
                        for s, f in zip(model.sources, x[:k], strict=True))
        changes: dict[str, Any] = {"sources": sources}
        j = k
        if model.diffuse is not None:
            changes["diffuse_norm"] = float(x[j])
            j += 1
        if self.fit_background:
            changes["background"] = x[j:].copy()
        return model.replace(**changes)

    def maximise(self, model: SkyModel, *, hold: dict[int, float] | None = None
                 ) -> tuple[SkyModel, LinearPoissonFit]:
        """Fit the free amplitudes of ``model`` (positions fixed).

        ``hold`` maps source indices to fluxes held fixed (a profile likelihood).
        """
        A, x, free, m0, groups = self.design(model)
        fixed = ~free
        for k, f in (hold or {}).items():
            x[k], fixed[k] = f, True
        # A start away from the bound lets every flux move (projected Newton holds
        # variables sitting at 0 with an outward gradient).
        res = maximise(A, self.y, m0, np.where(fixed, x, np.maximum(x, 1e-12)), fixed=fixed,
                       groups=groups)
        return self._with_amplitudes(model, res.x), res

    def loglike(self, model: SkyModel) -> float:
        """``ln L`` of ``model`` as it is (nothing fitted)."""
        return log_likelihood(self.y, self._mu(model))

    def expected(self, model: SkyModel) -> np.ndarray:
        """Expected counts ``(n_det, n_time)`` of ``model`` (0 where no exposure)."""
        out = np.zeros(self.data.shape)
        out[self.valid] = self._mu(model, full=True)
        return out

    def _mu(self, model: SkyModel, *, full: bool = False) -> np.ndarray:
        A, x, _, m0, groups = self.design(model, full=full)
        k = A.shape[1]
        mu = m0 + A @ x[:k]
        if groups is not None:
            mu += x[k:][groups.index] * groups.value
        return mu

    # -- positions ------------------------------------------------------------------------

    def fit_positions(self, model: SkyModel, *, only: list[int] | None = None,
                      scale: float | None = None, precision: float = 1e-4) -> SkyModel:
        """Fit each free position (one source at a time, all amplitudes re-maximised).

        ``only`` restricts the fit to those source indices; ``scale`` is the first step
        (rad; default a quarter of the instrument's angular scale ``b / L``);
        ``precision`` the simplex's final size as a fraction of it (and, times 0.1, the
        tolerance in ``ln L``).
        """
        step = 0.25 * geometric_scale(self.response) if scale is None else float(scale)
        if not 0.0 < precision < 1.0:
            raise ParameterError(f"precision must be in (0, 1) (a fraction of the first "
                                 f"step), got {precision!r}")
        for k, src in enumerate(model.sources):
            if not src.free_position or (only is not None and k not in only):
                continue
            v0 = src.vector()
            e1, e2 = tangent_basis(v0)

            def moved(p: np.ndarray, m: SkyModel = model, k: int = k,
                      src: PointSource = src, v0: np.ndarray = v0,
                      e1: np.ndarray = e1, e2: np.ndarray = e2) -> SkyModel:
                s = src.at_vector(v0 + p[0] * e1 + p[1] * e2)
                return m.replace(sources=(*m.sources[:k], s, *m.sources[k + 1:]))

            def cost(p: np.ndarray, moved: Any = moved) -> float:
                try:
                    return -self.maximise(moved(p))[1].loglike
                except ParameterError:  # moved out of view
                    return np.inf

            # Nelder-Mead, restarted from where it stopped with a simplex a quarter the size
            # until a restart no longer moves: a large first simplex crosses the rings of
            # an RM's likelihood surface, and one run may stop short of the peak on them
            # (measured: 0.1 deg and 5 in ln L short for a source of TS 570).
            x, size = np.zeros(2), step
            for _ in range(6):
                simplex = np.array([x, x + np.array([size, 0.0]), x + np.array([0.0, size])])
                res = minimize(cost, x, method="Nelder-Mead",
                               options={"initial_simplex": simplex,
                                        "xatol": precision * step,
                                        "fatol": 0.1 * precision, "maxiter": 400})
                moved_by = float(np.hypot(*(res.x - x)))
                x = res.x
                if moved_by < 10.0 * precision * step:
                    break
                size = max(0.25 * size, 10.0 * precision * step)
            model = self.maximise(moved(x))[0]
        return model

    # -- per-source statistics ------------------------------------------------------------

    def source_ts(self, model: SkyModel, k: int, loglike: float) -> float:
        """TS of source ``k``: everything else refitted without it."""
        without = model.replace(sources=model.sources[:k] + model.sources[k + 1:])
        if not without.sources and without.diffuse is None and not self.fit_background:
            ll0 = self.loglike(without)
        else:
            ll0 = self.maximise(without)[1].loglike
        return max(2.0 * (loglike - ll0), 0.0)

    def profile(self, model: SkyModel, k: int, flux: float) -> float:
        """Profile ``ln L`` with the flux of source ``k`` held at ``flux``."""
        return self.maximise(model, hold={k: flux})[1].loglike

    def flux_interval(self, model: SkyModel, k: int, loglike: float, level: float,
                      sigma: float) -> tuple[float, float]:
        """Fluxes below and above the fit where ``2 (ln L - profile) = level``.

        The lower one is 0 when the profile at 0 stays within ``level``.
        """
        f = model.sources[k].flux

        def excess(flux: float) -> float:
            return 2.0 * (loglike - self.profile(model, k, flux)) - level

        scale = max(sigma, 1e-6 * max(f, 1.0), 1e-12)
        hi = f + np.sqrt(level) * scale
        for _ in range(60):
            if excess(hi) > 0:
                break
            hi = f + 2.0 * (hi - f)
        upper = brentq(excess, f, hi, xtol=1e-6 * scale, rtol=1e-8)
        lower = 0.0
        if f > 0 and excess(0.0) > 0:
            lower = brentq(excess, 0.0, f, xtol=1e-6 * scale, rtol=1e-8)
        return lower, upper


def fit(
    response: ResponseOperator,
    data: Any,
    model: SkyModel,
    *,
    errors: bool = True,
    ul_confidence: float = 0.95,
) -> FitResult:
    """Fit ``model`` to ``data``: free fluxes, free positions and the background.

    Parameters
    ----------
    response : ResponseOperator
        Any rotmod response (instrument, celestial, HEALPix grid; a drift response).
    data : PoissonData or FoldedProfiles
        Folded counts with exposure.
    model : SkyModel
        Sources (with start values and free flags), diffuse image, background.
    errors : bool
        Compute each source's TS, profile-likelihood flux errors and upper limit (one
        refit per source and a few per bound); ``False`` returns NaN for them.
    ul_confidence : float
        Confidence of the upper limits, in (0.5, 1).

    Returns
    -------
    FitResult

    Raises
    ------
    ParameterError
        Data that do not match the response, sources in another frame than the
        response's grid, a source below the horizon.

    Examples
    --------
    >>> model = SkyModel([PointSource((2.0, 30.0), free_position=True)])  # doctest: +SKIP
    >>> result = fit(response, folded, model)                              # doctest: +SKIP
    >>> result.model.sources[0].position, result.ts                        # doctest: +SKIP
    """
    if not isinstance(model, SkyModel):
        raise ParameterError(f"model must be a SkyModel, got {type(model)}")
    ul_threshold(ul_confidence)
    fitter = SourceFitter(response, data)
    m = fitter.maximise(model)[0]
    if any(s.free_position for s in m.sources):
        m = fitter.fit_positions(m)
    return fit_with(fitter, m, errors=errors, ul_confidence=ul_confidence)


def fit_with(fitter: SourceFitter, model: SkyModel, *, errors: bool = True,
             ul_confidence: float = 0.95) -> FitResult:
    """The amplitudes of ``model`` fitted (positions as they are), with the per-source
    statistics of :func:`fit`."""
    level = ul_threshold(ul_confidence)
    m, res = fitter.maximise(model)
    k = len(m.sources)
    ts = np.full(k, np.nan)
    err = np.full((k, 2), np.nan)
    ul = np.full(k, np.nan)
    if errors and k:
        cov = res.covariance()
        for i in range(k):
            ts[i] = fitter.source_ts(m, i, res.loglike)
            sigma = float(np.sqrt(max(cov[i, i], 0.0)))
            lo, hi = fitter.flux_interval(m, i, res.loglike, 1.0, sigma)
            flux = m.sources[i].flux
            err[i] = (flux - lo, hi - flux)
            ul[i] = fitter.flux_interval(m, i, res.loglike, level, sigma)[1]
    return FitResult(m, res.loglike, ts, err, ul, ul_confidence, fitter.expected(m),
                     int(np.count_nonzero(fitter.valid)))

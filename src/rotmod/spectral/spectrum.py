"""Counts spectra, their response (RMF x ARF) and forward-folded fits.

A :class:`SpectralResponse` is what X-ray astronomy splits into two OGIP files: the
redistribution matrix ``R[e, c]`` (probability that a photon of true energy bin ``e`` is
recorded in channel ``c``; the RMF) and the effective area ``A[e]`` (cm^2; the ARF).  The
counts a source model ``dN/dE`` predicts in channel ``c`` over an exposure ``T`` are

    mu_c = T sum_e A_e R_ec ∫_e dN/dE dE,

the bin integral taken exactly (:meth:`rotmod.spectral.models.SpectralModel.integral`).  A
:class:`CountsSpectrum` holds Poisson counts per channel with that response and, optionally,
a measured background spectrum, whose counts scale to the source's by the OGIP ratio
``(backscal_src T_src) / (backscal_bkg T_bkg)``.  A :class:`RateSpectrum` holds rates with
Gaussian errors instead: a source's counts per channel extracted by a fit (a coded mask's or a
modulator's per-source spectrum, :func:`rotmod.sources.spectra.extract_spectrum`), which are
not Poisson counts.

:func:`fit_spectrum` maximises the Poisson likelihood: the Cash statistic without a
background, and with a measured background the W statistic (XSPEC's ``wstat``: the
background's expected counts per channel profiled out in closed form; Cash 1979, Wachter et
al. 1979, the XSPEC manual's appendix "Statistics in XSPEC"); a rate spectrum is fitted by
``chi2 = sum ((r_c - mu_c / T) / sigma_c)^2`` (XSPEC's ``chi`` with ``POISSERR = F``).
Errors come from the likelihood's curvature at the maximum.  These statistics are the ones
sherpa, XSPEC, threeML and gammapy use, so a spectrum written as OGIP files
(:mod:`rotmod.io.ogip`) fits to the same numbers there.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import optimize

from rotmod._validate import as_integers, as_scalar
from rotmod.errors import ParameterError
from rotmod.spectral.models import SpectralModel

__all__ = [
    "CountsSpectrum", "RateSpectrum", "SpectralFit", "SpectralResponse", "StatisticMinimum",
    "cash", "check_edges", "fit_spectrum", "minimise_statistic", "wstat",
]


def check_edges(values: Any, name: str) -> np.ndarray:
    """Energy bin edges (keV) as a float array: at least two finite, strictly increasing
    values >= 0, or a ParameterError naming ``name`` (every channel and energy grid of the
    spectral code is checked here)."""
    try:
        e = np.asarray(values, dtype=float)
    except (TypeError, ValueError):
        e = np.array([np.nan])
    if e.ndim != 1 or e.size < 2 or not np.all(np.isfinite(e)) or np.any(np.diff(e) <= 0):
        raise ParameterError(f"{name} must be at least two finite, increasing values (keV)")
    if e[0] < 0:
        raise ParameterError(f"{name} must be >= 0 keV, got {e[0]:g}")
    return e


@dataclass(frozen=True, eq=False)
class SpectralResponse:
    """Redistribution matrix and effective area of one spectrum (an RMF and an ARF).

    Parameters
    ----------
    energy_edges : array_like, shape (n_e + 1,)
        True-energy bin edges (keV), increasing, the first > 0.
    channel_edges : array_like, shape (n_c + 1,)
        Nominal energy bounds of the channels (keV; the RMF's EBOUNDS), increasing.
    matrix : array_like, shape (n_e, n_c)
        Probability that a detected photon of true-energy bin ``e`` lands in channel ``c``
        (each row sums to <= 1: photons recorded outside the channels are lost).
    area : array_like, shape (n_e,)
        Effective area (cm^2) per true-energy bin, >= 0.
    """

    energy_edges: np.ndarray
    channel_edges: np.ndarray
    matrix: np.ndarray
    area: np.ndarray

    def __post_init__(self) -> None:
        ee = check_edges(self.energy_edges, "energy_edges")
        if not ee[0] > 0:
            raise ParameterError("energy_edges must start above 0 keV")
        ce = check_edges(self.channel_edges, "channel_edges")
        m = np.asarray(self.matrix, dtype=float)
        a = np.asarray(self.area, dtype=float)
        if m.shape != (ee.size - 1, ce.size - 1):
            raise ParameterError(
                f"matrix must have shape (n_energies, n_channels) = {(ee.size - 1, ce.size - 1)}, "
                f"got {m.shape}"
            )
        if not np.all(np.isfinite(m)) or np.any(m < 0) or np.any(m.sum(1) > 1 + 1e-6):
            raise ParameterError("matrix must be finite, >= 0, with rows summing to <= 1")
        if a.shape != (ee.size - 1,) or not np.all(np.isfinite(a)) or np.any(a < 0):
            raise ParameterError(f"area must be {ee.size - 1} finite values >= 0 (cm2)")
        for name, v in (("energy_edges", ee), ("channel_edges", ce), ("matrix", m), ("area", a)):
            v.setflags(write=False)
            object.__setattr__(self, name, v)

    @property
    def n_channels(self) -> int:
        return self.channel_edges.size - 1

    def fold(self, model: SpectralModel, exposure: float) -> np.ndarray:
        """Expected counts per channel of ``model`` over ``exposure`` seconds."""
        flux = model.integral(self.energy_edges[:-1], self.energy_edges[1:])
        return exposure * ((flux * self.area) @ self.matrix)


@dataclass(frozen=True, eq=False)
class CountsSpectrum:
    """Counts per channel over an exposure, with their response and background.

    Parameters
    ----------
    counts : array_like of int, shape (n_c,)
        Recorded counts per channel (non-negative integers).
    exposure : float
        Live time (s), > 0.
    response : SpectralResponse
    background : CountsSpectrum, optional
        A measured background (its own counts, exposure and ``backscal``; no response).
    backscal : float
        The OGIP scaling: a background spectrum's counts scale to this one's by
        ``(backscal / background.backscal) (exposure / background.exposure)``.
    meta : dict
        Header cards for files (``TELESCOP``, ``INSTRUME``, ``OBJECT`` ...).
    """

    counts: np.ndarray
    exposure: float
    response: SpectralResponse | None = None
    background: CountsSpectrum | None = None
    backscal: float = 1.0
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        c = np.asarray(self.counts)
        if c.ndim != 1 or c.size == 0:
            raise ParameterError("counts must be a 1-D array, one value per channel")
        try:
            c = np.array(as_integers(c, "counts", lo=0), dtype=np.int64)
        except ParameterError as err:
            raise ParameterError(f"counts must be non-negative integers (Poisson counts): "
                                 f"{err}") from None
        if self.response is not None and not isinstance(self.response, SpectralResponse):
            raise ParameterError(f"response must be a SpectralResponse, got "
                                 f"{type(self.response).__name__}")
        if self.background is not None and not isinstance(self.background, CountsSpectrum):
            raise ParameterError(f"background must be a CountsSpectrum, got "
                                 f"{type(self.background).__name__}")
        c.setflags(write=False)
        object.__setattr__(self, "counts", c)
        object.__setattr__(self, "exposure", as_scalar(self.exposure, "exposure", lo=0.0,
                                                       lo_open=True))
        object.__setattr__(self, "backscal", as_scalar(self.backscal, "backscal", lo=0.0,
                                                       lo_open=True))
        if self.response is not None and self.response.n_channels != c.size:
            raise ParameterError(
                f"response has {self.response.n_channels} channels, counts {c.size}"
            )
        if self.background is not None and self.background.counts.size != c.size:
            raise ParameterError(
                f"background has {self.background.counts.size} channels, counts {c.size}"
            )

    @property
    def background_ratio(self) -> float:
        """``alpha``: a background count's weight in this spectrum (exposure and backscal)."""
        if self.background is None:
            raise ParameterError("this spectrum has no background")
        b = self.background
        return (self.backscal * self.exposure) / (b.backscal * b.exposure)


@dataclass(frozen=True, eq=False)
class RateSpectrum:
    """Rates per channel with Gaussian 1-sigma errors, and their response.

    What a fit extracts from data that are not a source's own counts -- a coded mask's or a
    rotating modulator's counts of one source among others and a background
    (:func:`rotmod.sources.spectra.extract_spectrum`): the values may be negative and their
    errors are not ``sqrt`` of the counts, so they are fitted by chi-square
    (:func:`fit_spectrum`) and written with ``STAT_ERR`` and ``POISSERR = F``
    (:mod:`rotmod.io.ogip`).

    Parameters
    ----------
    rate : array_like, shape (n_c,)
        Counts per second in each channel.
    error : array_like, shape (n_c,)
        Their 1-sigma errors (counts/s, > 0).
    exposure : float
        Live time (s), > 0: ``rate x exposure`` are the counts the response predicts.
    response : SpectralResponse, optional
    meta : dict
        Header cards for files.
    """

    rate: np.ndarray
    error: np.ndarray
    exposure: float
    response: SpectralResponse | None = None
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        r = np.array(self.rate, dtype=float)
        e = np.array(self.error, dtype=float)
        if r.ndim != 1 or r.size == 0 or not np.all(np.isfinite(r)):
            raise ParameterError("rate must be a 1-D array of finite values, one per channel")
        if e.shape != r.shape or not np.all(np.isfinite(e)) or np.any(e <= 0):
            raise ParameterError(f"error must be {r.size} finite values > 0 (counts/s), one "
                                 "per channel")
        for name, v in (("rate", r), ("error", e)):
            v.setflags(write=False)
            object.__setattr__(self, name, v)
        object.__setattr__(self, "exposure", as_scalar(self.exposure, "exposure", lo=0.0,
                                                       lo_open=True))
        if self.response is not None and self.response.n_channels != r.size:
            raise ParameterError(f"response has {self.response.n_channels} channels, rate "
                                 f"{r.size}")


def cash(counts: np.ndarray, mu: np.ndarray) -> float:
    """The Cash statistic ``2 sum (mu - n + n ln(n / mu))`` (0 for a perfect fit; the form
    XSPEC and sherpa call ``cstat`` and gammapy ``cash`` up to a constant: differences are what
    count)."""
    n = np.asarray(counts, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        term = np.where(n > 0, n * np.log(n / mu), 0.0)
    return float(2.0 * np.sum(mu - n + term))


def wstat(n_on: np.ndarray, n_off: np.ndarray, alpha: float, mu_sig: np.ndarray) -> float:
    """The W statistic: Poisson on/off likelihood with the background's expectation per
    channel profiled out (XSPEC manual, "Statistics in XSPEC", W statistic).

    With ``b`` the background's expected counts in the off spectrum, ``mu_on = mu_sig + alpha
    b`` and ``mu_off = b``; for each channel the ``b`` maximising the likelihood solves a
    quadratic, ``b = (C + sqrt(C^2 + 4 (1 + alpha) alpha n_off mu_sig)) / (2 alpha (1 +
    alpha))`` with ``C = alpha (n_on + n_off) - (1 + alpha) mu_sig``.  Returned as ``-2 ln L``
    relative to the saturated model (so a perfect fit is 0), as XSPEC and gammapy do.
    """
    n_on = np.asarray(n_on, dtype=float)
    n_off = np.asarray(n_off, dtype=float)
    s = np.asarray(mu_sig, dtype=float)
    a = float(alpha)
    if not (np.isfinite(a) and a > 0):
        raise ParameterError(f"alpha (the background's scaling) must be finite and > 0, got {a}")
    c = a * (n_on + n_off) - (1.0 + a) * s
    root = np.sqrt(c * c + 4.0 * (1.0 + a) * a * n_off * s)
    # The root of the quadratic without cancellation: for c < 0 the textbook form subtracts
    # two nearly equal numbers (a bright source on a faint background), so use the product
    # of the roots, b = 2 n_off s / (root - c).
    with np.errstate(divide="ignore", invalid="ignore"):
        b = np.where(c >= 0, (c + root) / (2.0 * a * (1.0 + a)),
                     2.0 * n_off * s / np.where(root - c > 0, root - c, 1.0))
    mu_on = s + a * b
    with np.errstate(divide="ignore", invalid="ignore"):
        t_on = np.where(n_on > 0, n_on * np.log(n_on / mu_on), 0.0)
        t_off = np.where(n_off > 0, n_off * np.log(n_off / b), 0.0)
    return float(2.0 * np.sum(mu_on + b - n_on - n_off + t_on + t_off))


@dataclass(frozen=True)
class SpectralFit:
    """Result of :func:`fit_spectrum`.

    Attributes
    ----------
    model : SpectralModel
        The model at the best fit.
    free : tuple of str
        The fitted parameters.
    errors : dict of str to float
        1-sigma errors from the curvature of ``-2 ln L`` at the maximum; NaN for a pegged
        parameter (``pegged``).
    covariance : ndarray
        Covariance of the free parameters (in the order of ``free``; rows and columns of
        pegged parameters NaN, the others computed with those held).
    pegged : tuple of str
        Parameters that ended at one of the model's search limits
        (:attr:`SpectralModel.limits`, astromodels' min/max): the data do not bound them
        there (a Band ``beta`` at -5 says the spectrum falls faster than any power law the
        data can tell), so they have no curvature error; XSPEC calls such parameters pegged.
    converged : bool
        The optimiser reported success and the curvature of every parameter not pegged is
        positive (errors finite).  False: treat the numbers with care (the errors of the
        parameters concerned are NaN).
    statistic : float
        Cash, W statistic or chi-square at the best fit (``stat_name`` says which).
    stat_name : str
    n_channels : int
    """

    model: SpectralModel
    free: tuple[str, ...]
    errors: dict[str, float]
    covariance: np.ndarray
    statistic: float
    stat_name: str
    n_channels: int
    pegged: tuple[str, ...] = ()
    converged: bool = True


def _objective(spectrum: CountsSpectrum | RateSpectrum, channels: np.ndarray):
    resp = spectrum.response
    if isinstance(spectrum, RateSpectrum):
        r = spectrum.rate[channels]
        sigma = spectrum.error[channels]

        def chi2(model: SpectralModel) -> float:
            mu = resp.fold(model, spectrum.exposure)[channels] / spectrum.exposure
            return float(np.sum(((r - mu) / sigma) ** 2))
        return chi2, "chi2"
    n = spectrum.counts[channels]
    if spectrum.background is None:
        def stat(model: SpectralModel) -> float:
            mu = resp.fold(model, spectrum.exposure)[channels]
            if np.any(mu <= 0) and np.any(n[mu <= 0] > 0):
                return np.inf
            return cash(n, np.maximum(mu, 1e-300))
        return stat, "cash"
    off = spectrum.background.counts[channels]
    alpha = spectrum.background_ratio

    def stat_w(model: SpectralModel) -> float:
        return wstat(n, off, alpha, resp.fold(model, spectrum.exposure)[channels])
    return stat_w, "wstat"


def fit_spectrum(
    spectrum: CountsSpectrum | RateSpectrum,
    model: SpectralModel,
    *,
    free: Sequence[str] | None = None,
    channels: Any = None,
) -> SpectralFit:
    """Fit ``model`` forward-folded through the spectrum's response (Cash, W statistic or
    chi-square).

    Parameters
    ----------
    spectrum : CountsSpectrum or RateSpectrum
        With a response.  Counts are fitted by the Cash statistic, or with a background by
        the W statistic; rates with Gaussian errors by chi-square.
    model : SpectralModel
        The start values; parameters not in ``free`` stay fixed.
    free : sequence of str, optional
        Parameters to fit (default: every parameter but pivots ``piv``).
    channels : slice or array_like of bool or int, optional
        The channels fitted (default all).

    Returns
    -------
    SpectralFit
    """
    if not isinstance(spectrum, CountsSpectrum | RateSpectrum):
        raise ParameterError("spectrum must be a CountsSpectrum or a RateSpectrum, got "
                             f"{type(spectrum).__name__}")
    if spectrum.response is None:
        raise ParameterError("spectrum has no response; fit_spectrum needs one")
    n_c = spectrum.response.n_channels
    try:
        chans = np.arange(n_c)[channels if channels is not None else slice(None)]
    except (IndexError, TypeError):
        raise ParameterError(f"channels must select among the {n_c} "
                             f"channels (a slice, indices or a boolean mask), got "
                             f"{channels!r}") from None
    if chans.size == 0:
        raise ParameterError("channels selects no channel: nothing to fit")
    if not np.any(spectrum.response.area > 0):
        raise ParameterError("spectrum.response.area is 0 everywhere: nothing can be detected")
    if isinstance(spectrum, CountsSpectrum) and not np.any(spectrum.counts[chans]):
        # The likelihood then peaks at K = 0, on the edge of the model's domain, with no
        # curvature to give an error: what such data give is an upper limit.
        raise ParameterError("spectrum has no count in the fitted channels: nothing to fit "
                             "(zero counts give an upper limit, not a fitted spectrum)")
    stat, stat_name = _objective(spectrum, chans)
    if isinstance(free, str):  # one name, not its letters
        free = (free,)
    best = minimise_statistic(lambda models: stat(models[0]), [model],
                              None if free is None else [free])
    return SpectralFit(best.models[0], best.free[0], best.errors[0], best.covariance,
                       best.statistic, stat_name, int(chans.size), best.pegged[0],
                       best.converged)


@dataclass(frozen=True)
class StatisticMinimum:
    """Result of :func:`minimise_statistic`: per model the fitted copy, its free parameters,
    their errors and the pegged ones; the covariance of all free parameters (models in
    order), the statistic at the minimum and whether the minimisation converged (see
    :attr:`SpectralFit.converged`)."""

    models: tuple[SpectralModel, ...]
    free: tuple[tuple[str, ...], ...]
    errors: tuple[dict[str, float], ...]
    pegged: tuple[tuple[str, ...], ...]
    covariance: np.ndarray
    statistic: float
    converged: bool


def minimise_statistic(
    statistic: Callable[[list[SpectralModel]], float],
    models: Sequence[SpectralModel],
    free: Sequence[Sequence[str]] | None = None,
) -> StatisticMinimum:
    """Minimise ``statistic(models)`` (``-2 ln L`` up to a constant) over the models' free
    parameters; errors from its curvature.

    Positive parameters are searched in log (the optimiser never leaves their domain), every
    parameter within its model's :attr:`~rotmod.spectral.models.SpectralModel.limits`;
    Nelder-Mead then Powell (which finishes long valleys Nelder-Mead stalls in).  The
    covariance is ``2 H^-1`` of the statistic's Hessian in the natural parameters
    (central differences), with pegged parameters (at a limit) held.  Every spectral fit of
    rotmod -- a counts spectrum (:func:`fit_spectrum`) or sources on the modulator's counts
    (:func:`rotmod.sources.spectra.fit_spectra`) -- is this minimisation of its own
    statistic.

    Parameters
    ----------
    statistic : callable
        ``statistic(list of models) -> float``; may return ``inf`` where the models cannot
        describe the data.
    models : sequence of SpectralModel
        Start values.
    free : sequence of sequences of str, optional
        Per model the parameters to fit (default: all but the pivots ``piv``).
    """
    models = list(models)
    if not models or not all(isinstance(m, SpectralModel) for m in models):
        raise ParameterError("models must be one or more SpectralModel instances")
    if free is None:
        free = [tuple(p for p in m.parameters if p != "piv") for m in models]
    if len(free) != len(models):
        raise ParameterError(f"free must give one list of parameters per model ({len(models)}),"
                             f" got {len(free)}")
    free = [tuple(f) for f in free]
    for m, f in zip(models, free, strict=True):
        names = list(m.parameters)
        if any(p not in names for p in f) or len(set(f)) != len(f):
            raise ParameterError(f"free must name parameters of {type(m).__name__} ({names}),"
                                 f" got {list(f)}")
    if not any(free):
        raise ParameterError("free names no parameter: nothing to fit")
    owner = [(i, p) for i, f in enumerate(free) for p in f]
    logp = np.array([p in type(models[i])._positive for i, p in owner])
    lims = np.array([type(models[i]).limits.get(p, (-np.inf, np.inf)) for i, p in owner])
    start = np.array([models[i].parameters[p] for i, p in owner], dtype=float)
    start = np.clip(start, lims[:, 0], lims[:, 1])

    def build(vals: np.ndarray) -> list[SpectralModel]:
        out = []
        for i, m in enumerate(models):
            sel = [k for k, (j, _) in enumerate(owner) if j == i]
            out.append(m.with_parameters(**{owner[k][1]: float(vals[k]) for k in sel})
                       if sel else m)
        return out

    def f_natural(vals: np.ndarray) -> float:
        if not np.all(np.isfinite(vals)) or np.any(vals < lims[:, 0]) or np.any(
                vals > lims[:, 1]):
            return np.inf
        try:
            return float(statistic(build(vals)))
        except ParameterError:  # outside the model's domain (Band beta >= alpha, ...)
            return np.inf

    def f(x: np.ndarray) -> float:
        return f_natural(np.where(logp, np.exp(x), x))

    x = _to_fit(start, logp)
    if not np.isfinite(f(x)):
        raise ParameterError("the start models cannot describe the data (the statistic is "
                             "infinite there): give start values that predict counts where "
                             "there are counts")
    # Tolerances: 1e-6 in -2 ln L is far below any statistical meaning (1 is one sigma^2)
    # and above the noise of a statistic that is itself a maximisation (profiled
    # backgrounds, converged to ~1e-10 .. 1e-8), which a tighter ``fatol`` would chase to
    # ``maxfev``.
    best = optimize.minimize(f, x, method="Nelder-Mead",
                             options={"xatol": 1e-8, "fatol": 1e-6, "maxiter": 20000,
                                      "maxfev": 40000, "adaptive": True})
    x = best.x
    with np.errstate(invalid="ignore"):  # Powell's line search meets inf beyond a limit
        polish = optimize.minimize(f, x, method="Powell",
                                   options={"xtol": 1e-10, "ftol": 1e-12})
    success = bool(best.success or polish.success)
    x = polish.x if polish.fun <= f(x) else x
    p_hat = np.where(logp, np.exp(x), x)
    # Pegged: within 1e-4 (of the limit's scale) of a finite limit.
    finite = np.isfinite(lims)
    wall = np.where(finite, lims, 0.0)
    scale = 1e-4 * np.maximum(np.abs(wall), 1.0)
    at = np.any(finite & (np.abs(p_hat[:, None] - wall) <= scale), axis=1)
    inner = np.flatnonzero(~at)
    cov = np.full((len(owner), len(owner)), np.nan)
    if inner.size:

        def f_inner(p: np.ndarray) -> float:
            full = p_hat.copy()
            full[inner] = p
            return f_natural(full)

        # Steps first from the values' scale, then from the curvature that gives: 0.3 of
        # each parameter's conditional error sqrt(2 / H_ii) changes -2 ln L by ~0.1 -- the
        # curvature without the rounding noise of a tiny step or the anharmonicity of a
        # large one (MINUIT's HESSE chooses its steps so).  The conditional, not the
        # marginal, error: along a long, narrow valley (Band's K and xp) marginal steps
        # would cross it and make the cross terms meaningless.
        h = 1e-4 * np.maximum(np.abs(p_hat[inner]), 1e-3)
        for _ in range(2):
            hess = _hessian(f_inner, p_hat[inner], h)
            try:
                c_in = 2.0 * np.linalg.inv(hess)
            except np.linalg.LinAlgError:
                break
            cov[np.ix_(inner, inner)] = c_in
            curv = np.diag(hess)
            if not np.all(np.isfinite(curv) & (curv > 0)):
                break
            # ... but not across a limit.
            room = np.minimum(p_hat[inner] - lims[inner, 0], lims[inner, 1] - p_hat[inner])
            h = np.minimum(0.3 * np.sqrt(2.0 / curv), 0.5 * room)
    var = np.diag(cov)
    positive = np.isfinite(var) & (var > 0)
    err = np.sqrt(np.where(positive, var, np.nan))
    success = success and bool(np.all(positive[inner]))
    fitted = build(p_hat)
    errors = tuple({p: float(err[k]) for k, (j, p) in enumerate(owner) if j == i}
                   for i in range(len(models)))
    pegged = tuple(tuple(p for k, (j, p) in enumerate(owner) if j == i and at[k])
                   for i in range(len(models)))
    return StatisticMinimum(tuple(fitted), tuple(free), errors, pegged, cov,
                            float(f_natural(p_hat)), success)


def _to_fit(p: np.ndarray, logp: np.ndarray) -> np.ndarray:
    """Parameters as the optimiser sees them: the positive ones in log."""
    x = np.array(p, dtype=float)
    with np.errstate(invalid="ignore", divide="ignore"):  # a step below 0 is outside: -> nan
        x[logp] = np.log(x[logp])
    return x


def _hessian(f: Any, x: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Central-difference Hessian of ``f`` at ``x`` with steps ``h``."""
    n = x.size
    out = np.empty((n, n))
    f0 = f(x)
    for i in range(n):
        ei = np.zeros(n)
        ei[i] = h[i]
        out[i, i] = (f(x + ei) - 2.0 * f0 + f(x - ei)) / h[i] ** 2
        for j in range(i):
            ej = np.zeros(n)
            ej[j] = h[j]
            v = (f(x + ei + ej) - f(x + ei - ej) - f(x - ei + ej) + f(x - ei - ej)) / (
                4.0 * h[i] * h[j])
            out[i, j] = out[j, i] = v
    return out

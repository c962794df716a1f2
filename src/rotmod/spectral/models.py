"""Spectral models: photon spectra ``dN/dE`` in photons cm^-2 s^-1 keV^-1, energies in keV.

The functions and parameter names are astromodels' (the threeML ecosystem's standard), so a
fit here and one in threeML or gammapy read the same numbers:

===================  ==========================================================================
model                ``dN/dE``
===================  ==========================================================================
``PowerLaw``         ``K (E/piv)^index``
``CutoffPowerLaw``   ``K (E/piv)^index exp(-E/xc)``
``Band``             ``K (E/piv)^alpha exp(-E/E0)`` for ``E <= (alpha - beta) E0``, else
                     ``K [(alpha - beta) E0 / piv]^(alpha - beta) exp(beta - alpha) (E/piv)^beta``,
                     ``E0 = xp / (2 + alpha)`` (Band et al. 1993, peak-energy form)
``Gaussian``         ``F / (sigma sqrt(2 pi)) exp(-(E - mu)^2 / (2 sigma^2))`` (a line of ``F``
                     photons cm^-2 s^-1)
===================  ==========================================================================

Indices carry their sign, as in astromodels (``index = -2`` is the ``E^-2`` spectrum);
:class:`rotmod.energy.PowerLaw`, the Monte Carlo's sampler of photon energies, takes the
positive photon index of the X-ray literature instead.  Every model integrates over energy
bins (:meth:`SpectralModel.integral`): in closed form where there is one, otherwise by
Gauss-Legendre quadrature on each bin, split where the function has a kink (the Band break)
or a narrow feature (a line), so that a folded spectrum is accurate to ~1e-10 whatever the
binning.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, fields, replace
from typing import Any, ClassVar

import numpy as np
from scipy.special import erf, erfc

from rotmod._validate import as_energy, as_scalar
from rotmod.errors import ParameterError

__all__ = ["Band", "CutoffPowerLaw", "Function", "Gaussian", "PowerLaw", "SpectralModel"]

#: Gauss-Legendre nodes and weights on [-1, 1] for the bin integrals.
_GL_X, _GL_W = np.polynomial.legendre.leggauss(16)
#: Sub-intervals per bin in log energy for the quadrature (smooth functions over a bin).
_SUBDIV = 4


@dataclass(frozen=True)
class SpectralModel(ABC):
    """A photon spectrum ``dN/dE`` (photons cm^-2 s^-1 keV^-1) of energy in keV.

    Subclasses are frozen dataclasses whose fields are the parameters, in astromodels' names.
    """

    #: Parameters that must be > 0 (energies and normalisations).
    _positive: ClassVar[tuple[str, ...]] = ()
    #: Search limits of a fit (astromodels' ``min``/``max``): a fitted value that reaches
    #: one is reported as pegged there (:class:`rotmod.spectral.SpectralFit`).
    limits: ClassVar[dict[str, tuple[float, float]]] = {}

    def __post_init__(self) -> None:
        for f in fields(self):
            name = f"{type(self).__name__}.{f.name}"
            if f.name in self._positive:
                value = as_scalar(getattr(self, f.name), name, lo=0.0, lo_open=True)
            else:
                value = as_scalar(getattr(self, f.name), name)
            object.__setattr__(self, f.name, value)

    @property
    def parameters(self) -> dict[str, float]:
        """The parameters by name, in the class's order."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def with_parameters(self, **values: float) -> SpectralModel:
        """A copy with some parameters changed (validated again)."""
        unknown = set(values) - set(self.parameters)
        if unknown:
            raise ParameterError(
                f"{type(self).__name__} has no parameter {sorted(unknown)[0]!r}; its parameters "
                f"are {list(self.parameters)}"
            )
        return replace(self, **values)

    def __call__(self, energy: Any) -> np.ndarray:
        """``dN/dE`` at ``energy`` (keV, > 0): photons cm^-2 s^-1 keV^-1."""
        e = as_energy(energy, "energy")
        if np.any(e <= 0):
            raise ParameterError("energy must be > 0 keV")
        return self._finite(self._evaluate, "dN/dE", e)

    def _finite(self, f: Any, what: str, *args: Any) -> np.ndarray:
        """``f(*args)``, refused when a value is not finite: parameters whose spectrum
        overflows float64 at these energies (an index of -1000, K of 1e308) are outside what
        the model can represent, not a spectrum of infinite flux.  A fit sees the
        :class:`~rotmod.errors.ParameterError` as the edge of the model's domain."""
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            out = f(*args)
        if not np.all(np.isfinite(out)):
            raise ParameterError(
                f"{self!r}: {what} is not finite (overflows float64) at these energies; "
                "the parameters are outside what the model can represent")
        return out

    @abstractmethod
    def _evaluate(self, e: np.ndarray) -> np.ndarray:
        """``dN/dE`` at energies ``e`` (keV, > 0, validated)."""

    def _breaks(self) -> np.ndarray:
        """Energies (keV) where the function is not smooth or varies on a scale finer than a
        bin could resolve; bins are split there for the quadrature."""
        return np.empty(0)

    def integral(self, e_lo: Any, e_hi: Any) -> np.ndarray:
        """Photons cm^-2 s^-1 in each bin ``[e_lo, e_hi]`` (keV; ``0 < e_lo < e_hi``).

        The default integrates by 16-point Gauss-Legendre on ``_SUBDIV`` log-spaced pieces of
        each bin, the bins first split at :meth:`_breaks`.
        """
        lo, hi = _bins(e_lo, e_hi)
        return self._finite(self._integral, "the bin integral", lo, hi)

    def _integral(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """Photons in each bin (validated ``0 < lo < hi``); the default by quadrature."""
        return _quadrature(self._evaluate, self._breaks(), lo, hi)

    def node_weights(self, nodes: Any) -> np.ndarray:
        """Photons cm^-2 s^-1 attributed to each node energy for a response known at the
        nodes and linear in ``ln E`` between them.

        ``sum_i w_i R(E_i) = ∫ dN/dE R(E) dE`` for every such ``R``: the photons between two
        nodes are split between them by the hat functions of ``ln E``.  This is second order
        in the node spacing, where counting a bin's photons at its centre is first order for
        a sloped spectrum (its photons are not centred in the bin); docs/spectra.md measures
        both.  Photons outside ``[nodes[0], nodes[-1]]`` are not counted.

        Parameters
        ----------
        nodes : array_like
            Increasing energies (keV), two or more, > 0.
        """
        x = np.asarray(as_energy(nodes, "nodes"), dtype=float)
        if x.ndim != 1 or x.size < 2 or np.any(~(x > 0)) or np.any(np.diff(x) <= 0):
            raise ParameterError("nodes must be two or more increasing energies > 0 keV")
        return self._finite(self._node_weights, "the node weights", x)

    def _node_weights(self, x: np.ndarray) -> np.ndarray:
        lo, hi = x[:-1], x[1:]
        inv = 1.0 / np.log(hi / lo)
        total = self._integral(lo, hi)
        # The share of each interval's photons that goes to its upper node:
        # ∫ N(E) ln(E / lo) / ln(hi / lo) dE.
        upper = np.zeros(lo.size)
        cuts = self._breaks()
        split = np.array([np.any((cuts > a) & (cuts < b)) for a, b in zip(lo, hi, strict=True)],
                         dtype=bool) if cuts.size else np.zeros(lo.size, dtype=bool)
        k = np.flatnonzero(~split)
        upper[k] = _gauss_legendre(
            lambda e: self._evaluate(e) * np.log(e / lo[k, None, None]) * inv[k, None, None],
            lo[k], hi[k])
        for j in np.flatnonzero(split):
            inner = np.sort(cuts[(cuts > lo[j]) & (cuts < hi[j])])
            edges = np.concatenate(([lo[j]], inner, [hi[j]]))
            upper[j] = _gauss_legendre(
                lambda e, j=j: self._evaluate(e) * np.log(e / lo[j]) * inv[j],
                edges[:-1], edges[1:]).sum()
        w = np.zeros(x.size)
        w[:-1] += total - upper
        w[1:] += upper
        return w

    def energy_flux(self, e_lo: Any, e_hi: Any) -> np.ndarray:
        """Energy flux ``∫ E dN/dE dE`` in each bin, keV cm^-2 s^-1 (by quadrature)."""
        lo, hi = _bins(e_lo, e_hi)
        return self._finite(_quadrature, "the energy flux", lambda e: e * self._evaluate(e),
                            self._breaks(), lo, hi)


def _quadrature(f: Any, cuts: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """``∫ f`` over each bin ``[lo, hi]``: the bin split at ``cuts``, each piece in
    ``_SUBDIV`` log-spaced sub-pieces of 16-point Gauss-Legendre."""
    split = np.array([np.any((cuts > a) & (cuts < b)) for a, b in zip(lo, hi, strict=True)],
                     dtype=bool) if cuts.size else np.zeros(lo.shape, dtype=bool)
    out = np.zeros(lo.shape)
    out[~split] = _gauss_legendre(f, lo[~split], hi[~split])
    for k in np.flatnonzero(split):
        inner = np.sort(cuts[(cuts > lo[k]) & (cuts < hi[k])])
        edges = np.concatenate(([lo[k]], inner, [hi[k]]))
        out[k] = _gauss_legendre(f, edges[:-1], edges[1:]).sum()
    return out


def _gauss_legendre(f: Any, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``∫_a^b f`` for each pair, on ``_SUBDIV`` log-spaced sub-pieces (all pairs at once)."""
    if a.size == 0:
        return np.zeros(0)
    t = np.linspace(0.0, 1.0, _SUBDIV + 1)
    p = a[:, None] * (b / a)[:, None] ** t
    p[:, -1] = b  # exact ends
    lo, hi = p[:, :-1, None], p[:, 1:, None]
    x = 0.5 * (hi - lo) * _GL_X + 0.5 * (hi + lo)
    return np.sum(0.5 * (hi - lo) * _GL_W * f(x), axis=(1, 2))


def _bins(e_lo: Any, e_hi: Any) -> tuple[np.ndarray, np.ndarray]:
    lo = np.atleast_1d(as_energy(e_lo, "e_lo")).astype(float)
    hi = np.atleast_1d(as_energy(e_hi, "e_hi")).astype(float)
    if lo.shape != hi.shape:
        raise ParameterError(f"e_lo and e_hi must have one shape, got {lo.shape} and {hi.shape}")
    if np.any(~(lo > 0)) or np.any(~(hi > lo)):
        raise ParameterError("energy bins must satisfy 0 < e_lo < e_hi (keV)")
    return lo, hi


@dataclass(frozen=True)
class PowerLaw(SpectralModel):
    """``K (E/piv)^index`` (astromodels' ``Powerlaw``).

    Parameters
    ----------
    K : float
        ``dN/dE`` at ``piv`` (photons cm^-2 s^-1 keV^-1), > 0.
    index : float
        Photon index with its sign (-2: ``E^-2``).
    piv : float
        Pivot energy (keV), > 0; not fitted.
    """

    K: float = 1.0
    index: float = -2.0
    piv: float = 100.0
    _positive: ClassVar[tuple[str, ...]] = ("K", "piv")
    limits: ClassVar[dict[str, tuple[float, float]]] = {"index": (-10.0, 10.0)}

    def _evaluate(self, e: np.ndarray) -> np.ndarray:
        return self.K * (e / self.piv) ** self.index

    def _integral(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        g = self.index + 1.0
        # ln(hi/lo) as log1p of the exact difference, and the bracket [(hi/piv)^g -
        # (lo/piv)^g] as expm1: a narrow bin keeps its digits.
        log_ratio = np.log1p((hi - lo) / lo)
        if abs(g) < 1e-10:
            return self.K * self.piv * log_ratio
        return self.K * self.piv / g * (lo / self.piv) ** g * np.expm1(g * log_ratio)


@dataclass(frozen=True)
class CutoffPowerLaw(SpectralModel):
    """``K (E/piv)^index exp(-E/xc)`` (astromodels' ``Cutoff_powerlaw``).

    Parameters
    ----------
    K : float
        Normalisation (photons cm^-2 s^-1 keV^-1 at ``piv`` without the cutoff), > 0.
    index : float
        Photon index with its sign.
    xc : float
        Cutoff energy (keV), > 0; ``E^2 dN/dE`` peaks at ``(2 + index) xc``.
    piv : float
        Pivot energy (keV), > 0.
    """

    K: float = 1.0
    index: float = -1.0
    xc: float = 300.0
    piv: float = 100.0
    _positive: ClassVar[tuple[str, ...]] = ("K", "xc", "piv")
    limits: ClassVar[dict[str, tuple[float, float]]] = {"index": (-10.0, 10.0),
                                                        "xc": (1.0, np.inf)}

    def _evaluate(self, e: np.ndarray) -> np.ndarray:
        return self.K * (e / self.piv) ** self.index * np.exp(-e / self.xc)


@dataclass(frozen=True)
class Band(SpectralModel):
    """The Band et al. (1993) function in its peak-energy form (astromodels' ``Band``).

    Parameters
    ----------
    K : float
        Normalisation at ``piv`` (photons cm^-2 s^-1 keV^-1), > 0.
    alpha : float
        Low-energy index (with sign), > -2 for ``xp`` to be a peak.
    xp : float
        Peak energy of ``E^2 dN/dE`` (keV), > 0.
    beta : float
        High-energy index (with sign), < ``alpha``.
    piv : float
        Pivot energy (keV), > 0.
    """

    K: float = 1.0
    alpha: float = -1.0
    xp: float = 500.0
    beta: float = -2.3
    piv: float = 100.0
    _positive: ClassVar[tuple[str, ...]] = ("K", "xp", "piv")
    # astromodels' limits: beta stops at -5 (steeper is indistinguishable from a cutoff).
    limits: ClassVar[dict[str, tuple[float, float]]] = {
        "alpha": (-1.5, 3.0), "xp": (10.0, np.inf), "beta": (-5.0, -1.6)}

    def __post_init__(self) -> None:
        super().__post_init__()
        if not self.alpha > -2.0:
            raise ParameterError(f"Band.alpha must be > -2 (xp is then a peak), got {self.alpha}")
        if not self.beta < self.alpha:
            raise ParameterError(
                f"Band.beta must be < Band.alpha, got beta = {self.beta}, alpha = {self.alpha}"
            )

    @property
    def break_energy(self) -> float:
        """``(alpha - beta) E0`` (keV), where the two power laws join smoothly."""
        return (self.alpha - self.beta) * self.xp / (2.0 + self.alpha)

    def _evaluate(self, e: np.ndarray) -> np.ndarray:
        e0 = self.xp / (2.0 + self.alpha)
        eb = self.break_energy
        d = self.alpha - self.beta
        low = self.K * (e / self.piv) ** self.alpha * np.exp(-e / e0)
        # The high branch written as one power so that it does not overflow for large d.
        high = self.K * np.exp(d * math.log(eb / self.piv) - d) * (e / self.piv) ** self.beta
        return np.where(e <= eb, low, high)

    def _breaks(self) -> np.ndarray:
        return np.array([self.break_energy])


@dataclass(frozen=True)
class Gaussian(SpectralModel):
    """A Gaussian line of ``F`` photons cm^-2 s^-1 at ``mu`` (astromodels' ``Gaussian``).

    Parameters
    ----------
    F : float
        Line flux (photons cm^-2 s^-1), > 0.
    mu : float
        Centre (keV), > 0.
    sigma : float
        Width (keV), > 0 (the detector's resolution is the response's, not the line's).
    """

    F: float = 1.0
    mu: float = 511.0
    sigma: float = 1.0
    _positive: ClassVar[tuple[str, ...]] = ("F", "mu", "sigma")

    def _evaluate(self, e: np.ndarray) -> np.ndarray:
        z = (e - self.mu) / self.sigma
        return self.F / (self.sigma * math.sqrt(2.0 * math.pi)) * np.exp(-0.5 * z * z)

    def _integral(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        s = self.sigma * math.sqrt(2.0)
        za, zb = (lo - self.mu) / s, (hi - self.mu) / s
        # In a tail the difference of erfc keeps the digits that one of erf (near +-1) loses.
        above = 0.5 * self.F * (erfc(za) - erfc(zb))
        below = 0.5 * self.F * (erfc(-zb) - erfc(-za))
        across = 0.5 * self.F * (erf(zb) - erf(za))
        return np.where(za >= 0, above, np.where(zb <= 0, below, across))

    def _breaks(self) -> np.ndarray:
        # The line's core, for energy fluxes by quadrature.
        return self.mu + self.sigma * np.arange(-8.0, 9.0)


@dataclass(frozen=True)
class Function(SpectralModel):
    """A spectrum given as a function of energy, with no parameters of its own.

    For spectra defined elsewhere: an astromodels function or point source (threeML's fit
    sets its parameters, :class:`rotmod.sources.threeml.RotmodLike`), a tabulated spectrum
    interpolated by the caller.  It folds like any model (bin integrals and node weights by
    Gauss-Legendre quadrature on log-spaced pieces, split at ``breaks``); a fit here has
    nothing to vary in it.

    Parameters
    ----------
    function : callable
        ``dN/dE`` (photons cm^-2 s^-1 keV^-1) of a 1-D array of energies in keV, returning
        an array of the same length.
    breaks : tuple of float
        Energies (keV) where it has a kink or a feature narrower than a bin: the quadrature
        splits there.  Default none, right for smooth functions and for a kink at which the
        value and slope are continuous (Band's costs ~1e-9 of a node weight); a line of width
        ``sigma`` below ~1 keV needs breaks across its core, e.g. ``mu + sigma * k`` for
        ``k = -8 ... 8`` as :class:`Gaussian` has (a 0.2 keV line's weights are otherwise
        off by 10 %, with its centre alone by 7e-4; tests/spectral/test_models.py).
    """

    function: Any = None
    breaks: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        if not callable(self.function):
            raise ParameterError(f"Function.function must be callable (dN/dE of energies in "
                                 f"keV), got {self.function!r:.80}")
        try:
            cuts = np.asarray(self.breaks, dtype=float).ravel()
        except (TypeError, ValueError):
            cuts = np.array([np.nan])
        if not np.all(np.isfinite(cuts)) or np.any(cuts <= 0):
            raise ParameterError(f"Function.breaks must be energies > 0 keV, got "
                                 f"{self.breaks!r:.80}")
        object.__setattr__(self, "breaks", tuple(np.sort(cuts).tolist()))

    @property
    def parameters(self) -> dict[str, float]:
        """Empty: the function's parameters, if any, are its owner's."""
        return {}

    def _evaluate(self, e: np.ndarray) -> np.ndarray:
        flat = np.ravel(e)
        out = np.asarray(self.function(flat), dtype=float)
        if out.shape != flat.shape:
            raise ParameterError(f"Function.function must return one value per energy "
                                 f"({flat.size}), got shape {out.shape}")
        return out.reshape(np.shape(e))

    def _breaks(self) -> np.ndarray:
        return np.asarray(self.breaks, dtype=float)

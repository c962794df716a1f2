"""Spectra of sources in the field: forward-folded fits on the modulator's counts per channel.

A point source of spectrum ``dN/dE`` (photons cm^-2 s^-1 keV^-1) at instrument zenith
``theta`` puts into detector ``d``, mask-angle bin ``t`` and energy channel ``c``

    mu[d, t, c] = T[d, t] sum_e F_e  (pi R^2 cos theta)  P_d(t; E_e)  M(theta; E_e -> c),

with ``F_e`` the photons cm^-2 s^-1 attributed to node energy ``E_e``
(:meth:`rotmod.spectral.SpectralModel.node_weights`: the photons between two nodes split
between them as a response linear in ``ln E`` would count them),
``pi R^2 cos theta`` the face's projected area, which turns the response's sky unit (photons
per second on one unobstructed face, docs/conventions.md) into a photon flux, ``P_d(t; E)``
the response's column at energy ``E`` (the slats' and the detector's attenuation change with
energy; for a thick detector ``P`` counts interactions), and ``M`` the detector's
redistribution given an interaction (:mod:`rotmod.spectral.detector`).

:func:`fit_spectra` fits every source's spectral parameters at once with a background level
per detector and channel (constant over the mask-angle bins), fitted, not given: for each
trial of the spectral parameters the backgrounds are profiled out exactly
(:func:`rotmod.sources.likelihood.maximise`), and the spectral parameters minimise ``-2 ln L``
(:func:`rotmod.spectral.minimise_statistic`, the one optimiser of every spectral fit).

Approximations, stated: the redistribution of a detector is the one of a uniformly lit face
(the mask's shadow changes which part of the crystal is lit, which changes the escape
probabilities slightly); between nodes the columns and the redistribution are taken as linear
in ``ln E`` (keep the nodes closer than the resolution's FWHM; docs/spectra.md measures the
effect of the spacing).
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import astropy.units as u
import numpy as np

from rotmod.errors import ParameterError
from rotmod.events import EventList, fold
from rotmod.limits import check_memory
from rotmod.response.columns import columns_at, position_grid
from rotmod.response.operator import ResponseOperator
from rotmod.sources.likelihood import Groups, maximise
from rotmod.spectral.detector import DetectorResponse
from rotmod.spectral.models import SpectralModel
from rotmod.spectral.spectrum import check_edges, minimise_statistic

__all__ = [
    "SourceSpectraFit", "SpectralColumns", "expected_counts", "fit_spectra", "fold_channels",
    "spectral_columns",
]


@dataclass(frozen=True, eq=False)
class SpectralColumns:
    """The energy-resolved response of point sources at fixed positions.

    Attributes
    ----------
    columns : ndarray, shape (n_src, n_e, n_det, n_time)
        Counts per second in each detector and bin per photon cm^-2 s^-1 at each node
        energy (the response's column times the face's projected area).
    redistribution : ndarray, shape (n_src, n_e, n_c)
        The detector's redistribution at each source's zenith angle.
    energies : ndarray, shape (n_e,)
        The node energies (keV).
    channel_edges : ndarray, shape (n_c + 1,)
    theta : ndarray, shape (n_src,)
        Zenith angles (deg).
    """

    columns: np.ndarray
    redistribution: np.ndarray
    energies: np.ndarray
    channel_edges: np.ndarray
    theta: np.ndarray

    @property
    def shape(self) -> tuple[int, int, int]:
        """``(n_det, n_time, n_channels)`` of the counts it predicts."""
        return (*self.columns.shape[2:], self.redistribution.shape[2])

    def rates(self, k: int, model: SpectralModel) -> np.ndarray:
        """Counts per second ``(n_det, n_time, n_c)`` of source ``k`` with spectrum ``model``."""
        flux = model.node_weights(self.energies)
        n_det, n_t, n_c = self.shape
        # sum_e F_e col[e, d, t] M[e, c], as one (n_det n_t, n_e) x (n_e, n_c) product.
        m = flux[:, None] * self.redistribution[k]
        return (self.columns[k].reshape(len(flux), -1).T @ m).reshape(n_det, n_t, n_c)


def spectral_columns(
    response: ResponseOperator, positions: Any, detector_response: DetectorResponse, *,
    transmission: Any = None,
) -> SpectralColumns:
    """The energy-resolved response of point sources at ``positions``.

    Parameters
    ----------
    response : ResponseOperator
        A response of the instrument (its binning, model and sky frame are used; its
        energy is replaced by each node energy).  One attitude: a drifting observation's
        sum over attitudes is not supported yet.
    positions : SkyCoord or (theta, phi)
        The sources (:func:`rotmod.response.columns_at`).
    detector_response : DetectorResponse
        The detectors' redistribution, tabulated at the true-energy nodes
        (:func:`rotmod.spectral.detector.tabulate_response`) for the instrument's detectors.
    transmission : array_like, shape (n_src, n_e) or broadcastable, optional
        Fraction of each source's photons at each node energy that reach the instrument: the
        residual atmosphere above a balloon, e.g.
        ``Atmosphere.transmission(nodes[None, :], zenith[:, None], altitude)``
        (:mod:`rotmod.spectral.atmosphere`; ``zenith`` is the source's angle from the local
        vertical, not from the instrument axis).  Default 1: fluxes above the atmosphere are
        then those at the instrument.

    Returns
    -------
    SpectralColumns
    """
    if not isinstance(response, ResponseOperator):
        raise ParameterError(f"response must be a ResponseOperator, got {type(response).__name__}")
    if not isinstance(detector_response, DetectorResponse):
        raise ParameterError("detector_response must be a rotmod.spectral.detector."
                             f"DetectorResponse, got {type(detector_response).__name__}")
    parts = response.components()
    if len(parts) != 1 or parts[0][0] is not None:
        raise ParameterError(
            "response: spectral fits take a response of one attitude; a drifting observation "
            f"({len(parts)} attitude intervals) is not supported yet")
    spec = parts[0][1]
    _check_energy_dependence(spec.instrument, detector_response)
    det = spec.instrument.detectors
    nodes = np.asarray(detector_response.energies, dtype=float)
    if nodes.size < 2:
        raise ParameterError("detector_response must be tabulated at two or more energies")
    theta = np.degrees(position_grid(spec.grid, positions).directions()[0].value)
    n_det, n_t = response.n_det, response.n_time
    check_memory(8.0 * theta.size * nodes.size * n_det * n_t,
                 f"the columns of {theta.size} sources at {nodes.size} energies",
                 hint="tabulate the detector response at fewer energies")
    cols = np.empty((theta.size, nodes.size, n_det, n_t))
    for e, energy in enumerate(nodes):
        cols[:, e] = np.moveaxis(columns_at(response, positions, energy=energy), 2, 0)
    area = np.pi * det.radius**2 * np.cos(np.radians(theta))
    cols *= area[:, None, None, None]
    if transmission is not None:
        try:
            trans = np.broadcast_to(np.asarray(transmission, dtype=float),
                                    (theta.size, nodes.size))
        except ValueError:
            raise ParameterError(f"transmission must broadcast to (n_sources, n_energies) = "
                                 f"{(theta.size, nodes.size)}, got shape "
                                 f"{np.shape(transmission)}") from None
        if not np.all((trans >= 0) & (trans <= 1)):
            raise ParameterError("transmission must lie in [0, 1] (a fraction of photons)")
        cols *= trans[:, :, None, None]
    red = detector_response.matrix_at(theta)
    return SpectralColumns(cols, red, nodes,
                           np.asarray(detector_response.channel_edges, dtype=float), theta)


def _check_energy_dependence(instrument: Any, detector_response: DetectorResponse) -> None:
    """The instrument's response must follow energy as the detector response does: thick
    detectors of the material it was tabulated for, and coefficients from the database (a
    fixed one would make every energy's column the same)."""
    det = instrument.detectors
    if det.thickness <= 0:
        raise ParameterError(
            "response: the instrument's detectors must have a thickness and a material for an "
            "energy response (a flat face counts every photon at every energy)")
    if det.material.mass_attenuation is not None:
        raise ParameterError(
            "response: the detectors' material has a fixed mass_attenuation; an energy "
            "response needs the database's, which depends on energy")
    mask = instrument.mask
    fixed = mask.mu if mask.mu is not None else mask.material.mass_attenuation
    if fixed is not None and (fixed.value if isinstance(fixed, u.Quantity) else fixed) != 0:
        raise ParameterError(
            "response: the mask has a fixed attenuation coefficient; an energy response needs "
            "the database's (only 0, a transparent mask, is the same at every energy)")
    made_for = detector_response.detectors
    if made_for is None:
        raise ParameterError("detector_response does not say which detector it was tabulated "
                             "for; make it with rotmod.spectral.detector.tabulate_response")
    same = (made_for.diameter == det.diameter and made_for.thickness == det.thickness
            and made_for.material == det.material)
    if not same:
        raise ParameterError(
            f"detector_response was tabulated for {made_for.diameter:g} cm x "
            f"{made_for.thickness:g} cm {made_for.material.name}, the instrument has "
            f"{det.diameter:g} cm x {det.thickness:g} cm {det.material.name} detectors")


@dataclass(frozen=True)
class SourceSpectraFit:
    """Result of :func:`fit_spectra`.

    Attributes
    ----------
    models : tuple of SpectralModel
        Each source's spectrum at the best fit.
    errors : tuple of dict
        Per source, 1-sigma errors of its free parameters (curvature of ``-2 ln L`` with the
        backgrounds profiled; NaN for a pegged parameter).
    pegged : tuple of tuple of str
        Per source, parameters at a search limit.
    covariance : ndarray
        Of all free parameters, sources in order.
    background : ndarray, shape (n_det, n_c)
        Background rate (counts/s) per detector and channel at the best fit.
    loglike : float
        ``ln L`` at the maximum (less the data's constant,
        :func:`rotmod.sources.likelihood.log_likelihood`).
    converged : bool
        As :attr:`rotmod.spectral.SpectralFit.converged`.
    """

    models: tuple[SpectralModel, ...]
    errors: tuple[dict[str, float], ...]
    pegged: tuple[tuple[str, ...], ...]
    covariance: np.ndarray
    background: np.ndarray
    loglike: float
    converged: bool


def fit_spectra(
    columns: SpectralColumns,
    counts: Any,
    exposure: Any,
    models: Sequence[SpectralModel],
    *,
    free: Sequence[Sequence[str]] | None = None,
    off_counts: Any = None,
    off_exposure: Any = None,
) -> SourceSpectraFit:
    """Fit the sources' spectra to counts per detector, mask-angle bin and channel.

    The background level of each detector and channel is free.  Where it is measured
    elsewhere -- a burst's background before and after it -- give those counts
    (``off_counts``, ``off_exposure``): they enter the likelihood as Poisson counts of the
    same levels, so the levels are fitted to both.  Without them a short, faint-background
    interval leaves each of the ``n_det x n_c`` levels only the modulation to tell it from the
    source, and the non-negative levels of nearly empty channels bias the spectrum (measured
    in benchmarks/spectra_calibration.py).

    Parameters
    ----------
    columns : SpectralColumns
        The sources' energy-resolved response (:func:`spectral_columns`).
    counts : array_like of int, shape (n_det, n_time, n_c)
        Counts (e.g. events folded per channel, :func:`fold_channels`).
    exposure : array_like, shape (n_time,) or (n_det, n_time)
        Good time (s) per bin.
    models : sequence of SpectralModel
        One per source, the start values.
    free : sequence of sequences of str, optional
        Per source the parameters to fit (default all but ``piv``).
    off_counts : array_like of int, shape (n_det, n_c), optional
        Background counts measured without the sources (or with them outside the field).
    off_exposure : float or array_like, shape (n_det,), optional
        Their good time (s); required with ``off_counts``.

    Returns
    -------
    SourceSpectraFit
    """
    if not isinstance(columns, SpectralColumns):
        raise ParameterError(f"columns must be SpectralColumns, got {type(columns).__name__}")
    n_det, n_t, n_c = columns.shape
    y = np.asarray(counts)
    if y.shape != (n_det, n_t, n_c):
        raise ParameterError(f"counts must have shape (n_det, n_time, n_channels) = "
                             f"{(n_det, n_t, n_c)}, got {y.shape}")
    if not np.all(np.isfinite(y)) or np.any(y < 0) or np.any(y != np.round(y)):
        raise ParameterError("counts must be non-negative integers")
    expo = _exposure(exposure, n_det, n_t)
    if len(models) != columns.columns.shape[0]:
        raise ParameterError(f"models must give one spectrum per source "
                             f"({columns.columns.shape[0]}), got {len(models)}")
    use = np.broadcast_to((expo > 0)[:, :, None], y.shape).ravel()
    yv = y.astype(float).ravel()[use]
    t3 = np.broadcast_to(expo[:, :, None], y.shape).ravel()[use]
    group = (np.arange(n_det)[:, None, None] * n_c + np.arange(n_c)[None, None, :])
    g_index = np.broadcast_to(group, y.shape).ravel()[use]
    n_on = yv.size
    if off_counts is not None:
        off = np.asarray(off_counts)
        if off.shape != (n_det, n_c) or not np.all(np.isfinite(off)) or np.any(
                off < 0) or np.any(off != np.round(off)):
            raise ParameterError(f"off_counts must be non-negative integers of shape "
                                 f"(n_det, n_channels) = {(n_det, n_c)}")
        if off_exposure is None:
            raise ParameterError("off_exposure (s) is required with off_counts")
        try:
            t_off = np.broadcast_to(np.asarray(off_exposure, dtype=float), (n_det,))
        except (TypeError, ValueError):
            t_off = np.array([np.nan])
        if not np.all(np.isfinite(t_off)) or np.any(t_off <= 0):
            raise ParameterError("off_exposure must be finite seconds > 0 (one, or one per "
                                 "detector)")
        # One more bin per level: its off counts, expected level x off time.
        yv = np.concatenate([yv, off.ravel().astype(float)])
        t3 = np.concatenate([t3, np.repeat(t_off, n_c)])
        g_index = np.concatenate([g_index, group.ravel()])
    groups = Groups(g_index, t3, n_det * n_c)
    empty = np.zeros((yv.size, 0))
    state: dict[str, Any] = {"x0": None}

    def profile(ms: list[SpectralModel]) -> tuple[float, Any]:
        m0 = np.zeros(yv.size)
        m0[:n_on] = sum(columns.rates(k, m).ravel()[use] for k, m in enumerate(ms)) * t3[:n_on]
        best = maximise(empty, yv, m0, state["x0"], groups=groups)
        return best.loglike, best

    def statistic(ms: list[SpectralModel]) -> float:
        ll, best = profile(ms)
        if np.isfinite(ll):
            state["x0"] = np.maximum(best.x, 1e-12 * max(yv.mean(), 1.0))
        return -2.0 * ll

    found = minimise_statistic(statistic, models, free)
    ll, best = profile(list(found.models))
    return SourceSpectraFit(found.models, found.errors, found.pegged, found.covariance,
                            best.x.reshape(n_det, n_c), float(ll), found.converged)


def expected_counts(columns: SpectralColumns, exposure: Any, models: Sequence[SpectralModel],
                    background: Any = 0.0) -> np.ndarray:
    """Expected counts ``(n_det, n_time, n_c)`` of the sources' spectra plus a background
    rate per detector and channel (counts/s, broadcast to ``(n_det, n_c)``)."""
    n_det, n_t, n_c = columns.shape
    expo = _exposure(exposure, n_det, n_t)
    if len(models) != columns.columns.shape[0]:
        raise ParameterError(f"models must give one spectrum per source "
                             f"({columns.columns.shape[0]}), got {len(models)}")
    rate = sum(columns.rates(k, m) for k, m in enumerate(models)) + np.broadcast_to(
        np.asarray(background, dtype=float), (n_det, n_c))[:, None, :]
    return rate * expo[:, :, None]



def _exposure(exposure: Any, n_det: int, n_t: int) -> np.ndarray:
    """``exposure`` as ``(n_det, n_t)`` seconds, or a ParameterError naming the rule."""
    try:
        e = np.asarray(exposure, dtype=float)
        expo = np.broadcast_to(e, (n_det, n_t)) if e.ndim <= 2 else None
    except (TypeError, ValueError):
        expo = None
    if expo is None or not np.all(np.isfinite(expo)) or np.any(expo < 0):
        raise ParameterError(f"exposure must be finite seconds >= 0: one value, or of shape "
                             f"({n_t},) or ({n_det}, {n_t})")
    return expo


def fold_channels(events: EventList, time_bins: Any, channel_edges: Any
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Fold an event list per energy channel: counts ``(n_det, n_time, n_c)`` and the
    exposure ``(n_time,)`` or ``(n_det, n_time)`` (s) of :func:`rotmod.events.fold`.

    Channel ``c`` takes ``channel_edges[c] <= ENERGY < channel_edges[c + 1]`` (half-open, so
    an event on an inner edge is counted once).
    """
    edges = check_edges(channel_edges, "channel_edges")
    folded = [fold(events, time_bins, energy_band=(lo, np.nextafter(hi, -np.inf)))
              for lo, hi in itertools.pairwise(edges)]
    return np.stack([f.counts for f in folded], axis=2), folded[0].exposure

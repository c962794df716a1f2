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
(:func:`rotmod.spectral.minimise_statistic`, the one optimiser of every spectral fit).  For a
balloon flight cut into time slices, the sources' transmission through the air is given per
slice -- and for a drifting flight the response too, one per slice (:func:`spectral_columns`)
-- and the background as templates in time and energy (e.g.
:meth:`rotmod.spectral.background.BalloonBackground.flight_components`) whose scales the same
fit frees per component, per detector, or per detector and channel.

:func:`extract_spectrum` makes one source's spectrum as a coded-mask pipeline does: per
channel, its rate fitted with the other sources and the background, its error, and the
response (ARF and RMF) that predicts the extracted rate from a photon spectrum -- a
:class:`rotmod.spectral.RateSpectrum` for chi-square fits and OGIP files (docs/spectra.md
derives the response).

Approximations, stated: the redistribution of a detector is the one of a uniformly lit face
(the mask's shadow changes which part of the crystal is lit, which changes the escape
probabilities slightly); between nodes the columns and the redistribution are taken as linear
in ``ln E`` (keep the nodes closer than the resolution's FWHM; docs/spectra.md measures the
effect of the spacing), and the redistribution as linear in ``theta`` between its tabulated
angles.  A drifting observation, which sees a source at another ``theta`` in each attitude
interval, is a sum over those angles with the same interpolation (:class:`SpectralColumns`;
docs/spectra.md, "A drifting observation").
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import astropy.units as u
import numpy as np

from rotmod._validate import as_int
from rotmod.errors import ParameterError
from rotmod.events import EventList, fold
from rotmod.limits import check_memory
from rotmod.response.columns import component_columns, position_grid
from rotmod.response.operator import ResponseOperator
from rotmod.sources.likelihood import Groups, _schur, maximise
from rotmod.spectral.detector import DetectorResponse, check_energy_detectors
from rotmod.spectral.models import PowerLaw, SpectralModel
from rotmod.spectral.spectrum import (
    RateSpectrum,
    SpectralResponse,
    check_edges,
    minimise_statistic,
)

__all__ = [
    "BACKGROUND_FREE", "SourceSpectraFit", "SpectralColumns", "expected_counts",
    "extract_spectrum", "fit_spectra", "fold_channels", "spectral_columns",
]


@dataclass(frozen=True, eq=False)
class SpectralColumns:
    """The energy-resolved response of point sources at fixed positions.

    Each source's counts are a sum over its angle nodes ``a``: the columns that see the
    redistribution at the node's zenith angle.  For one attitude a source has one node, its
    own angle (the redistribution interpolated there, :meth:`DetectorResponse.matrix_at`);
    for a drifting observation, where each attitude interval sees the source at its own
    angle, its nodes are the tabulated angles it visits and each interval's columns are
    shared between them with the interpolation's own weights (docs/spectra.md: exact with
    respect to that interpolation).  A flight cut into time slices, each folded into
    mask-angle bins of its own, predicts counts with a leading slice axis: the slices share
    one set of columns and differ by their ``transmission`` (a gondola that tracks its
    sources), or each slice has its own columns (a drifting flight: the sources move through
    the field from slice to slice), or both.

    Attributes
    ----------
    columns : ndarray, shape ([n_slice,] n_src, n_a, n_e, n_det, n_time)
        Counts per second in each detector and bin per photon cm^-2 s^-1 at each node
        energy (the response's column times the face's projected area), per angle node
        (a source with fewer nodes than ``n_a`` has columns of 0 in the others); with a
        leading axis, per time slice.
    redistribution : ndarray, shape (n_src, n_a, n_e, n_c)
        The detector's redistribution at each angle node.
    energies : ndarray, shape (n_e,)
        The node energies (keV).
    channel_edges : ndarray, shape (n_c + 1,)
    theta : ndarray, shape (n_src, n_a)
        The angle nodes' zenith angles (deg).
    transmission : ndarray, shape (n_slice, n_src, n_e), optional
        For a flight cut into time slices (each folded into mask-angle bins): the fraction
        of each source's photons at each node energy that reach the instrument in each
        slice (the atmosphere above a balloon changes with its altitude and the source's
        zenith angle).  The counts then gain a leading slice axis.  None: the transmission,
        if any, is part of ``columns``.
    """

    columns: np.ndarray
    redistribution: np.ndarray
    energies: np.ndarray
    channel_edges: np.ndarray
    theta: np.ndarray
    transmission: np.ndarray | None = None

    def __post_init__(self) -> None:
        cols, red = np.shape(self.columns), np.shape(self.redistribution)
        n_e, n_c = np.size(self.energies), np.size(self.channel_edges) - 1
        if len(cols) not in (5, 6) or cols[-3] != n_e:
            raise ParameterError(f"columns must have shape ([n_slice,] n_src, n_angle_nodes, "
                                 f"n_e={n_e}, n_det, n_time), got {cols}")
        src = cols[-5:-2]                                  # (n_src, n_a, n_e)
        if red != (*src, n_c):
            raise ParameterError(f"redistribution must have shape (n_src, n_angle_nodes, n_e, "
                                 f"n_c) = {(*src, n_c)}, got {red}")
        if np.shape(self.theta) != src[:2]:
            raise ParameterError(f"theta must have shape (n_src, n_angle_nodes) = {src[:2]}, "
                                 f"got {np.shape(self.theta)}")
        if self.transmission is not None:
            got = np.shape(self.transmission)
            if len(got) != 3 or got[1:] != (src[0], n_e) or (len(cols) == 6 and
                                                            got[0] != cols[0]):
                n_s = cols[0] if len(cols) == 6 else "n_slice"
                raise ParameterError(f"transmission must have shape (n_slice, n_src, n_e) = "
                                     f"({n_s}, {src[0]}, {n_e}), got {got}")

    @property
    def n_sources(self) -> int:
        """The number of sources."""
        return int(self.columns.shape[-5])

    @property
    def shape(self) -> tuple[int, ...]:
        """``(n_det, n_time, n_channels)`` of the counts it predicts, ``(n_slice, n_det,
        n_time, n_channels)`` for a flight's time slices."""
        one = (*self.columns.shape[-2:], self.redistribution.shape[3])
        if self.columns.ndim == 6:
            return (self.columns.shape[0], *one)
        return one if self.transmission is None else (self.transmission.shape[0], *one)

    def rates(self, k: int, model: SpectralModel) -> np.ndarray:
        """Counts per second (:attr:`shape`) of source ``k`` with spectrum ``model``."""
        flux = model.node_weights(self.energies)
        n_a, n_e, n_det, n_t = self.columns.shape[-4:]
        red = self.redistribution[k]
        if self.columns.ndim == 6:
            # Each slice its own columns: per slice s one (n_det n_t, n_a n_e) x (n_a n_e,
            # n_c) product, with its photons F_e T[s, e].
            n_s = self.columns.shape[0]
            photons = flux if self.transmission is None else self.transmission[:, k] * flux
            m = np.broadcast_to(photons, (n_s, n_e))[:, None, :, None] * red
            cols = self.columns[:, k].reshape(n_s, n_a * n_e, n_det * n_t)
            return (cols.transpose(0, 2, 1) @ m.reshape(n_s, n_a * n_e, -1)).reshape(
                self.shape)
        # The angle nodes and energies as one axis: sum_a sum_e F_e col[a, e, d, t] M[a, e, c]
        # is one (n_det n_t, n_a n_e) x (n_a n_e, n_c) product.
        cols = self.columns[k].reshape(n_a * n_e, -1).T      # (n_det n_t, n_a n_e)
        if self.transmission is None:
            m = (flux[:, None] * red).reshape(n_a * n_e, -1)
            return (cols @ m).reshape(self.shape)
        # Per slice s the photons F_e T[s, e]: one (n_det n_t, n_a n_e) x (n_a n_e, n_s n_c)
        # product.
        m = (self.transmission[:, k] * flux)[:, None, :, None] * red
        n_s, n_c = m.shape[0], m.shape[3]
        out = cols @ m.transpose(1, 2, 0, 3).reshape(n_a * n_e, n_s * n_c)
        return np.moveaxis(out.reshape(n_det, n_t, n_s, n_c), 2, 0)


def spectral_columns(
    response: ResponseOperator, positions: Any, detector_response: DetectorResponse, *,
    transmission: Any = None, interval_transmission: Any = None,
) -> SpectralColumns:
    """The energy-resolved response of point sources at ``positions``.

    Parameters
    ----------
    response : ResponseOperator or sequence of ResponseOperator
        A response of the instrument (its binning, model and sky frame are used; its
        energy is replaced by each node energy): of one attitude, or a drifting
        observation's sum over attitude intervals (:func:`rotmod.response.drift.
        drift_response`; :meth:`~rotmod.response.ResponseOperator.components`), where each
        interval sees a source at its own zenith angle and so with its own redistribution
        (:class:`SpectralColumns`; docs/spectra.md).  A sequence: a flight cut into time
        slices, one response per slice (each folded into its own mask-angle bins, e.g. a
        drift response over the slice's attitude intervals), of one instrument and binning;
        the columns then predict counts ``(n_slice, n_det, n_time, n_c)``.
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
        then those at the instrument.  Three dimensions, ``(n_slice, n_src, n_e)``: a
        flight cut into time slices, one transmission per slice (its altitude and the
        source's zenith angle then; the mean over the slice where they change within it):
        the columns then predict counts ``(n_slice, n_det, n_time, n_c)``.  With one
        response the sources' positions in the instrument are the same in every slice (a
        pointed, tracking gondola; one attitude); with one response per slice, as many
        slices.
    interval_transmission : array_like, shape (n_intervals, n_src, n_e), optional
        For a drifting observation instead of ``transmission``: the fraction per attitude
        interval (one per component of ``response``, in order; for time slices the
        intervals of every slice, slice after slice), e.g. a zenith-pointed balloon, where
        each source's zenith angle changes through the flight.  Each interval's columns are
        multiplied by it before the sum over intervals.

    Returns
    -------
    SpectralColumns
    """
    sliced = isinstance(response, Sequence)
    responses = list(response) if sliced else [response]
    if not responses or not all(isinstance(r, ResponseOperator) for r in responses):
        raise ParameterError("response must be a ResponseOperator, or a sequence of one or "
                             f"more (one per time slice), got {response!r:.80}")
    first = responses[0]
    for r in responses[1:]:
        if (r.n_det, r.n_time) != (first.n_det, first.n_time):
            raise ParameterError(
                f"response: every time slice's response must have the first's detectors and "
                f"mask-angle bins ({first.n_det}, {first.n_time}), got ({r.n_det}, "
                f"{r.n_time})")
    if not isinstance(detector_response, DetectorResponse):
        raise ParameterError("detector_response must be a rotmod.spectral.detector."
                             f"DetectorResponse, got {type(detector_response).__name__}")
    # Each slice's attitude intervals, in order: (slice, response component).
    specs = [spec for r in responses for _, spec in r.components()]
    owner = np.concatenate([np.full(len(r.components()), s)
                            for s, r in enumerate(responses)])
    for spec in specs:
        _check_energy_dependence(spec.instrument, detector_response)
        if (spec.time_bins != specs[0].time_bins
                or spec.instrument.rotation_period != specs[0].instrument.rotation_period):
            raise ParameterError(
                "response: every attitude interval and time slice must share the first's "
                f"mask-angle bins and rotation period ({specs[0].time_bins}, "
                f"{specs[0].instrument.rotation_period:g} s), got {spec.time_bins}, "
                f"{spec.instrument.rotation_period:g} s")
    det = specs[0].instrument.detectors
    nodes = np.asarray(detector_response.energies, dtype=float)
    if nodes.size < 2:
        raise ParameterError("detector_response must be tabulated at two or more energies")
    # Each interval's zenith angle of each source (deg), (n_intervals, n_src).
    thetas = np.array([np.degrees(position_grid(s.grid, positions).directions()[0].value)
                       for s in specs])
    n_k, n_src = thetas.shape
    trans = None if transmission is None else _transmission(transmission, n_src, nodes.size)
    if trans is not None and trans.ndim == 3 and not sliced and n_k > 1:
        raise ParameterError(
            f"transmission: time slices of {trans.shape[0]} transmissions take a response of "
            f"one attitude each; for a drifting observation ({n_k} attitude intervals) give "
            "interval_transmission, one per interval, or one response per time slice")
    if trans is not None and trans.ndim == 3 and sliced and trans.shape[0] != len(responses):
        raise ParameterError(f"transmission must hold one slice per response "
                             f"({len(responses)}), got {trans.shape[0]}")
    per_k = None
    if interval_transmission is not None:
        if transmission is not None:
            raise ParameterError("give transmission or interval_transmission, not both "
                                 "(fold any common factor into interval_transmission)")
        got = np.shape(interval_transmission)
        if len(got) != 3 or got[0] != n_k:
            raise ParameterError(
                f"interval_transmission must have shape (n_intervals, n_sources, n_energies)"
                f" = {(n_k, n_src, nodes.size)} (one per attitude interval of the response), "
                f"got {got}")
        per_k = _transmission(interval_transmission, n_src, nodes.size,
                              "interval_transmission")
    share, red, node_theta = _angle_nodes(thetas, detector_response)
    n_det, n_t = first.n_det, first.n_time
    n_slice = (len(responses),) if sliced else ()
    check_memory(8.0 * len(responses) * n_src * share.shape[2] * nodes.size * n_det * n_t,
                 f"the columns of {n_src} sources at {share.shape[2]} angle nodes and "
                 f"{nodes.size} energies" + (f" in {len(responses)} time slices" if sliced
                                             else ""),
                 hint="tabulate the detector response at fewer energies")
    cols = np.zeros((*n_slice, n_src, share.shape[2], nodes.size, n_det, n_t))
    area = np.pi * det.radius**2 * np.cos(np.radians(thetas))       # (n_intervals, n_src)
    for e, energy in enumerate(nodes):
        # One interval's columns at a time (a day's flight has thousands of intervals).
        parts = itertools.chain.from_iterable(component_columns(r, positions, energy=energy)
                                              for r in responses)
        for k, part in enumerate(parts):
            at = np.moveaxis(part, 2, 0) * area[k][:, None, None]
            if per_k is not None:
                at = at * per_k[k, :, e][:, None, None]
            into = cols[owner[k]] if sliced else cols
            into[:, :, e] += share[k][:, :, None, None] * at[:, None]
    if trans is not None and trans.ndim == 2:
        cols *= trans[:, None, :, None, None]
    return SpectralColumns(cols, red, nodes,
                           np.asarray(detector_response.channel_edges, dtype=float),
                           node_theta, trans if trans is not None and trans.ndim == 3 else None)


def _angle_nodes(thetas: np.ndarray, detector_response: DetectorResponse
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each source's angle nodes for its zenith angles ``thetas`` (deg, ``(n_intervals,
    n_src)``): the share of each interval's columns in each node ``(n_intervals, n_src,
    n_a)``, the nodes' redistribution ``(n_src, n_a, n_e, n_c)`` and angles ``(n_src, n_a)``.

    A source seen at one angle in every interval has one node there (the redistribution
    interpolated at it); one whose angle changes has the tabulated angles it visits, each
    interval's columns shared between them with the interpolation's weights
    (:meth:`DetectorResponse.angle_weights`), so that ``sum_a share[k, a] matrix[a]`` is
    the interval's ``matrix_at(theta_k)``.  Sources with fewer nodes than ``n_a`` share 0
    with the rest (their redistribution repeats the first node's).
    """
    n_k, n_src = thetas.shape
    shares, mats, angles = [], [], []
    for s in range(n_src):
        th = thetas[:, s]
        if np.all(th == th[0]):
            shares.append(np.ones((n_k, 1)))
            mats.append(detector_response.matrix_at(th[:1]))
            angles.append(th[:1])
            continue
        h = detector_response.angle_weights(th)                # (n_intervals, n_angles)
        seen = np.flatnonzero(np.any(h > 0, axis=0))
        shares.append(h[:, seen])
        mats.append(detector_response.matrix[seen])
        angles.append(detector_response.angles[seen])
    n_a = max(a.size for a in angles)
    share = np.zeros((n_k, n_src, n_a))
    red = np.empty((n_src, n_a, *mats[0].shape[1:]))
    theta = np.empty((n_src, n_a))
    for s, (h, m, a) in enumerate(zip(shares, mats, angles, strict=True)):
        share[:, s, :a.size] = h
        red[s] = m[0]
        red[s, :a.size] = m
        theta[s] = a[0]
        theta[s, :a.size] = a
    return share, red, theta


def _transmission(transmission: Any, n_src: int, n_e: int, name: str = "transmission"
                  ) -> np.ndarray:
    """``transmission`` as ``(n_src, n_e)``, or ``(n_slice, n_src, n_e)`` for time slices;
    a ParameterError names the parameter (``name``) and the rule broken."""
    trans = np.asarray(transmission, dtype=float)
    want = (n_src, n_e)
    try:
        trans = np.broadcast_to(trans, trans.shape[:1] + want if trans.ndim == 3 else want)
    except ValueError:
        raise ParameterError(f"{name} must broadcast to (n_sources, n_energies) = "
                             f"{want}, or be (n_slices, n_sources, n_energies) for a flight's "
                             f"time slices, got shape {np.shape(transmission)}") from None
    if not np.all((trans >= 0) & (trans <= 1)):
        raise ParameterError(f"{name} must lie in [0, 1] (a fraction of photons)")
    if trans.ndim == 3 and trans.shape[0] < 1:
        raise ParameterError(f"{name} must hold one or more time slices")
    return np.array(trans)


def _check_energy_dependence(instrument: Any, detector_response: DetectorResponse) -> None:
    """The instrument's response must follow energy as the detector response does: thick
    detectors of the material it was tabulated for, and coefficients from the database (a
    fixed one would make every energy's column the same)."""
    det = check_energy_detectors(instrument.detectors, "response: instrument.detectors")
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
    background : ndarray, shape (n_det, n_c) or (n_slice, n_det, n_c)
        Background rate (counts/s) per detector and channel at the best fit (the template
        times its fitted scales; per slice where the template changes with time).
    loglike : float
        ``ln L`` at the maximum (less the data's constant,
        :func:`rotmod.sources.likelihood.log_likelihood`).
    converged : bool
        As :attr:`rotmod.spectral.SpectralFit.converged`.
    scales : ndarray
        The background's fitted normalisations: ``(n_det, n_c)`` for
        ``background_free="level"`` (without a template, the levels in counts/s),
        ``(n_det,)`` for ``"detector"``, one per template for ``"component"``.
    scale_errors : ndarray
        Their 1-sigma errors, marginal over the spectral parameters: the conditional
        covariance plus ``J C J^T``, ``C`` the spectral parameters' covariance and ``J`` the
        profiled scales' derivatives with respect to them (the inverse of the joint
        Hessian's block, written with the profile; one-sided derivatives where a step
        leaves a model's domain, NaN where no step stays in it).
    """

    models: tuple[SpectralModel, ...]
    errors: tuple[dict[str, float], ...]
    pegged: tuple[tuple[str, ...], ...]
    covariance: np.ndarray
    background: np.ndarray
    loglike: float
    converged: bool
    scales: np.ndarray
    scale_errors: np.ndarray


#: How :func:`fit_spectra` frees the background's normalisation.
BACKGROUND_FREE = ("level", "detector", "component")


def fit_spectra(
    columns: SpectralColumns,
    counts: Any,
    exposure: Any,
    models: Sequence[SpectralModel],
    *,
    free: Sequence[Sequence[str]] | None = None,
    background: Any = None,
    background_free: str = "level",
    off_counts: Any = None,
    off_exposure: Any = None,
) -> SourceSpectraFit:
    """Fit the sources' spectra to counts per detector, mask-angle bin and channel.

    The counts' expectation is the sources' (:meth:`SpectralColumns.rates`) plus a
    background, unmodulated (the same in every mask-angle bin), whose normalisation is
    fitted with the spectra -- forward-folded, by the Poisson likelihood; for each trial of
    the spectral parameters the background's normalisations are profiled out exactly
    (:func:`rotmod.sources.likelihood.maximise`) and the spectral parameters minimise
    ``-2 ln L`` (:func:`rotmod.spectral.minimise_statistic`).  ``background`` gives the
    background's shape -- in time for a flight's slices (e.g.
    :meth:`rotmod.spectral.background.BalloonBackground.flight_components` at each slice's
    altitude), in energy and across detectors -- and ``background_free`` what of it is
    free:

    * ``"level"``: a scale per detector and channel; the template gives the shape in time
      only.  Without a template, a constant level per detector and channel (counts/s).
    * ``"detector"``: a scale per detector; the template gives the shape in time and energy.
    * ``"component"``: one scale per template (e.g. CXB, atmospheric continuum, 511 keV
      line, internal), shared by every detector.

    Where the background is measured elsewhere -- a burst's background before and after it
    -- give those counts (``off_counts``, ``off_exposure``, constant levels only): they
    enter the likelihood as Poisson counts of the same levels, so the levels are fitted to
    both.  Without them a short, faint-background interval leaves each of the ``n_det x
    n_c`` levels only the modulation to tell it from the source, and the non-negative levels
    of nearly empty channels bias the spectrum (measured in
    benchmarks/spectra_calibration.py).

    Parameters
    ----------
    columns : SpectralColumns
        The sources' energy-resolved response (:func:`spectral_columns`; for a flight's
        time slices, with a transmission or columns per slice).
    counts : array_like, shape (n_det, n_time, n_c) or (n_slice, n_det, n_time, n_c)
        Counts (e.g. events folded per channel, :func:`fold_channels`, per time slice);
        expected counts (an Asimov data set) are accepted too.
    exposure : array_like
        Good time (s) per bin: ``(n_time,)`` or ``(n_det, n_time)``; for time slices also
        ``(n_slice, n_time)`` or ``(n_slice, n_det, n_time)``.  With as many slices as
        detectors a 2-D exposure is ambiguous and refused: give the 3-D shape.
    models : sequence of SpectralModel
        One per source, the start values.
    free : sequence of sequences of str, optional
        Per source the parameters to fit (default all but ``piv``).
    background : array_like or mapping of str to array_like, optional
        The background template(s), counts/s (any scale): ``(n_c,)`` or ``(n_det, n_c)``,
        for time slices ``(n_slice, n_c)`` or ``(n_slice, n_det, n_c)`` (with as many slices
        as detectors only the latter: a 2-D template is then ambiguous and refused); a
        mapping names several components (``background_free="component"``).  Default: flat.
    background_free : {"level", "detector", "component"}
        Which normalisations are free (above).
    off_counts : array_like, shape (n_det, n_c), optional
        Background counts measured without the sources (or with them outside the field).
    off_exposure : float or array_like, shape (n_det,), optional
        Their good time (s); required with ``off_counts``.

    Returns
    -------
    SourceSpectraFit
    """
    lik = _SpectraLikelihood(columns, counts, exposure, models, background, background_free,
                             off_counts, off_exposure)
    found = minimise_statistic(lik.statistic, models, free)
    ll, best = lik.profile(list(found.models))
    scales, yv, groups, tmpl = best.x, lik.bins.y, lik.groups, lik.template
    n_det, n_c = columns.shape[-3], columns.shape[-1]
    # The scales' covariance with the spectral parameters held (the inverse Hessian of
    # -ln L in the scales), then marginal: + J C J^T, J = d(scales)/d(parameters) along the
    # profile (central differences at 0.3 sigma, as the parameters' own Hessian steps;
    # one-sided where a step leaves the model's domain).
    if groups is None:
        cov = best.covariance()
    else:
        h_gg = groups.sum(groups.value**2 * yv / np.where(best.mu > 0, best.mu, np.inf)**2)
        cov = np.diag(np.where(h_gg > 0, 1.0 / np.where(h_gg > 0, h_gg, 1.0), np.inf))
    jac, inner = _scale_derivatives(lik.profile, found, scales)
    if inner.size:
        c = found.covariance[np.ix_(inner, inner)]
        cov = cov + jac @ c @ jac.T
    with np.errstate(invalid="ignore"):
        errs = np.sqrt(np.diag(cov))
    if background_free == "component":
        rate = np.einsum("k...,k->...", tmpl, scales)
    elif tmpl is None:
        rate = scales.reshape(n_det, n_c)
    else:
        rate = tmpl[0] * (scales.reshape(n_det, n_c) if background_free == "level"
                          else scales[:, None])
    return SourceSpectraFit(found.models, found.errors, found.pegged, found.covariance,
                            np.array(rate), float(ll),
                            found.converged, scales.reshape(lik.n_scales),
                            errs.reshape(lik.n_scales))


class _SpectraLikelihood:
    """The Poisson likelihood of :func:`fit_spectra` (and of the threeML plugin,
    :class:`rotmod.sources.threeml.RotmodLike`): the counts laid out as bins with the
    background's columns; :meth:`profile` maximises it over the background's scales for
    given spectra.  The arguments are :func:`fit_spectra`'s, checked here; ``warm_start``
    False starts every profile from the scales of the background alone, so that ``ln L`` is
    a function of the spectra alone, bit for bit (threeML checks its minimum so), at the
    cost of a few more iterations per profile."""

    def __init__(self, columns: SpectralColumns, counts: Any, exposure: Any,
                 models: Sequence[SpectralModel], background: Any, background_free: str,
                 off_counts: Any, off_exposure: Any, *, warm_start: bool = True) -> None:
        bins = _poisson_bins(columns, counts, exposure, models, off_counts, off_exposure)
        names, tmpl = _templates(background, columns.shape, background_free)
        if tmpl is not None and off_counts is not None:
            raise ParameterError("off_counts: a background measured off the source enters as "
                                 "constant levels; with a background template, fit the off "
                                 "interval's counts as time slices of their own")
        n_det, n_c = columns.shape[-3], columns.shape[-1]
        # Each bin's background column: its exposure times the template there.
        value = bins.value.copy()
        if tmpl is not None:
            per_bin = np.broadcast_to(tmpl[..., None, :], (len(names), *columns.shape))
            value = per_bin.reshape(len(names), -1)[:, bins.flat] * value
        self.groups: Groups | None = None
        if background_free == "component":
            self.A = value.T
            self.n_scales: tuple[int, ...] = (len(names),)
        else:
            value = value if tmpl is None else value[0]
            level = background_free == "level"
            index = bins.group if level else bins.group // n_c
            self.groups = Groups(index, value, n_det * n_c if level else n_det)
            self.A = np.zeros((bins.y.size, 0))
            self.n_scales = (n_det, n_c) if level else (n_det,)
        self.columns, self.bins, self.template = columns, bins, tmpl
        self.warm_start = warm_start
        self._x0: np.ndarray | None = None
        if not warm_start:
            # Every profile starts from the background alone, the first one too.
            self._x0 = self._start(maximise(self.A, bins.y, np.zeros(bins.y.size),
                                            groups=self.groups).x)

    def profile(self, models: Sequence[SpectralModel]) -> tuple[float, Any]:
        """``ln L`` maximised over the background's scales for the sources' ``models``, and
        that maximum (:class:`rotmod.sources.likelihood.LinearPoissonFit`)."""
        bins = self.bins
        m0 = np.zeros(bins.y.size)
        m0[:bins.n_on] = sum(self.columns.rates(k, m).ravel()[bins.flat]
                             for k, m in enumerate(models)) * bins.value[:bins.n_on]
        best = maximise(self.A, bins.y, m0, self._x0, groups=self.groups)
        return best.loglike, best

    def statistic(self, models: Sequence[SpectralModel]) -> float:
        """``-2 ln L`` profiled (:meth:`profile`); with ``warm_start`` the next profile
        starts from its scales (a minimiser's trials are close to each other)."""
        ll, best = self.profile(models)
        if np.isfinite(ll) and self.warm_start:
            self._x0 = self._start(best.x)
        return -2.0 * ll

    def _start(self, x: np.ndarray) -> np.ndarray:
        """Scales as a start: kept off 0, where the Poisson iteration could not move them."""
        return np.maximum(x, 1e-12 * max(self.bins.y.mean(), 1.0))


def _scale_derivatives(profile: Any, found: Any, scales: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray]:
    """``d(scales)/d(parameter)`` along the profile at the fit, for the parameters with an
    error (the others are held), by central differences at 0.3 of each one's error; and the
    indices of those parameters in the fit's covariance.

    Where a step leaves the model's domain (a ParameterError: e.g. ``K - h <= 0`` for a
    faint source) the difference is one-sided on the side that stays in it, from the fit's
    own ``scales``; where both do, the step is halved (at most 10 times) until one side is
    in.  A parameter no step can move leaves its column NaN, and so the scales' errors: never
    a derivative silently taken as 0.
    """
    owner = [(i, p) for i, f in enumerate(found.free) for p in f]
    err = np.array([found.errors[i][p] for i, p in owner])
    inner = np.flatnonzero(np.isfinite(err) & (err > 0))
    jac = np.full((scales.size, inner.size), np.nan)
    for col, q in enumerate(inner):
        i, p = owner[q]
        model, v = found.models[i], found.models[i].parameters[p]
        h = 0.3 * err[q]
        for _ in range(11):
            side = {}
            for sign in (1.0, -1.0):
                try:
                    side[sign] = model.with_parameters(**{p: v + sign * h})
                except ParameterError:  # outside the model's domain
                    continue
            if side:
                break
            h /= 2.0
        x = {sign: profile([*found.models[:i], m, *found.models[i + 1:]])[1].x
             for sign, m in side.items()}
        if len(x) == 2:
            jac[:, col] = (x[1.0] - x[-1.0]) / (2.0 * h)
        elif x:
            sign, xs = next(iter(x.items()))
            jac[:, col] = sign * (xs - scales) / h
    return jac, inner


def _templates(background: Any, shape: tuple[int, ...], free: str
               ) -> tuple[list[str], np.ndarray | None]:
    """The background template(s) as ``(n_templates, [n_slice,] n_det, n_c)`` with their
    names (None without a template), or a ParameterError naming the rule broken."""
    if free not in BACKGROUND_FREE:
        raise ParameterError(f"background_free must be one of {BACKGROUND_FREE}, got {free!r}")
    if background is None:
        if free != "level":
            raise ParameterError(f"background_free={free!r} needs a background template "
                                 "(its shape in time and energy)")
        return ["level"], None
    items = (list(background.items()) if isinstance(background, Mapping)
             else [("background", background)])
    if not items:
        raise ParameterError("background must hold at least one template")
    if free != "component" and len(items) > 1:
        raise ParameterError(f"background_free={free!r} takes one template; several "
                             "components need background_free='component' (or give their "
                             "sum)")
    sliced = len(shape) == 4
    n_det, n_c = shape[-3], shape[-1]
    if sliced:
        n_s = shape[0]
        rule = f"({n_s}, {n_c}) or ({n_s}, {n_det}, {n_c}) (n_slice, [n_det,] n_channels)"
    else:
        rule = f"({n_c},) or ({n_det}, {n_c}) ([n_det,] n_channels)"
    out = []
    for name, t in items:
        try:
            a = np.asarray(t, dtype=float)
        except (TypeError, ValueError):
            raise ParameterError(f"background[{name!r}] must be numbers") from None
        if sliced and a.ndim == 2:
            _check_per_slice(a.shape, shape[:-2], f"background[{name!r}]", "n_channels")
        if a.ndim == len(shape) - 2:          # no detector axis: the same in every detector
            a = np.expand_dims(a, -2)
        if a.ndim != len(shape) - 1 or a.shape[-1] != n_c or a.shape[-2] not in (1, n_det) or (
                sliced and a.shape[0] != n_s):
            raise ParameterError(f"background[{name!r}] must have shape {rule}, got "
                                 f"{np.shape(t)}")
        if not np.all(np.isfinite(a)) or np.any(a < 0):
            raise ParameterError(f"background[{name!r}] must be finite rates >= 0 (a "
                                 "template of counts/s)")
        if not np.any(a > 0):
            raise ParameterError(f"background[{name!r}] is 0 everywhere: its scale would be "
                                 "undefined")
        out.append(np.broadcast_to(a, (*shape[:-3], n_det, n_c)))
    return [n for n, _ in items], np.stack(out)


@dataclass(frozen=True)
class _Bins:
    """The counts of :func:`fit_spectra` and :func:`extract_spectrum` as Poisson bins: the
    on bins with exposure (flattened ``(n_det, n_time, n_c)`` indices ``flat``), then the
    off-source bins, one per detector and channel; each bin's background level (``group`` =
    ``d n_c + c``) and that level's column (its exposure, ``value``)."""

    y: np.ndarray
    value: np.ndarray
    group: np.ndarray
    flat: np.ndarray
    n_on: int
    exposure: np.ndarray


def _poisson_bins(columns: Any, counts: Any, exposure: Any, models: Sequence[Any],
                  off_counts: Any, off_exposure: Any) -> _Bins:
    """Check the arguments shared by :func:`fit_spectra` and :func:`extract_spectrum` and
    lay the counts out as :class:`_Bins`; a ParameterError names what is wrong.  Real counts
    are accepted (expected counts as data, an Asimov data set): the Poisson likelihood is
    defined for them."""
    if not isinstance(columns, SpectralColumns):
        raise ParameterError(f"columns must be SpectralColumns, got {type(columns).__name__}")
    shape = columns.shape
    n_det, n_c = shape[-3], shape[-1]
    y = np.asarray(counts)
    if y.shape != shape:
        axes = "(n_det, n_time, n_channels)" if len(shape) == 3 else (
            "(n_slice, n_det, n_time, n_channels)")
        raise ParameterError(f"counts must have shape {axes} = {shape}, got {y.shape}")
    if not np.all(np.isfinite(y)) or np.any(y < 0):
        raise ParameterError("counts must be finite and non-negative")
    expo = _exposure(exposure, shape[:-1])
    if not np.any(expo > 0):
        raise ParameterError("exposure is 0 everywhere: nothing was observed to fit")
    _check_models(models, columns.n_sources)
    use = np.flatnonzero(np.broadcast_to((expo > 0)[..., None], y.shape))
    yv = y.astype(float).ravel()[use]
    t3 = np.broadcast_to(expo[..., None], y.shape).ravel()[use]
    group = (np.arange(n_det)[:, None, None] * n_c + np.arange(n_c)[None, None, :])
    g_index = np.broadcast_to(group, y.shape).ravel()[use]
    n_on = yv.size
    if off_counts is not None:
        off = np.asarray(off_counts)
        if off.shape != (n_det, n_c) or not np.all(np.isfinite(off)) or np.any(off < 0):
            raise ParameterError(f"off_counts must be non-negative values of shape "
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
    return _Bins(yv, t3, g_index, use, n_on, expo)


def extract_spectrum(
    columns: SpectralColumns,
    counts: Any,
    exposure: Any,
    source: int = 0,
    *,
    models: Sequence[SpectralModel] | None = None,
    off_counts: Any = None,
    off_exposure: Any = None,
    subdivide: int = 4,
) -> RateSpectrum:
    """One source's spectrum extracted channel by channel, with the response that predicts it.

    In each channel the folded counts are fitted (Poisson likelihood,
    :func:`rotmod.sources.likelihood.maximise`) by every source's modulation pattern in that
    channel, each with a free amplitude, and a background level per detector; the source's
    amplitude is its rate (counts/s in all detectors, averaged over the rotation).  The
    estimate is written as what it is at the maximum, a linear combination ``w . y`` of the
    channel's counts (the weights ``(A^T V^-1 A)^-1 A^T V^-1`` of the fitted variance ``V``),
    so that its expectation for a photon spectrum is ``sum_e F_e a_c(E_e) M(E_e -> c)``, with
    ``a_c(E) = sum w T P(E)`` the source's column-weighted effective area (cm^2): the response
    returned (docs/spectra.md derives it).  Coded-mask pipelines make such per-source spectra
    (Swift-BAT's mask-weighted spectra, INTEGRAL/ISGRI's); they are fitted by chi-square
    (:func:`rotmod.spectral.fit_spectrum`) and written as OGIP files with ``STAT_ERR`` and
    ``POISSERR = F`` (:func:`rotmod.io.ogip.write_ogip`).

    Parameters
    ----------
    columns : SpectralColumns
        The sources' energy-resolved response (:func:`spectral_columns`).
    counts : array_like, shape (n_det, n_time, n_c)
        Counts per detector, mask-angle bin and channel (:func:`fold_channels`); expected
        counts (an Asimov data set) are accepted too, the extraction being defined for any
        non-negative values.
    exposure : array_like, shape (n_time,) or (n_det, n_time)
        Good time (s) per bin.
    source : int
        Which source's spectrum to extract (index into ``columns``).
    models : sequence of SpectralModel, optional
        One per source: the spectra that shape each source's pattern within a channel (the
        pattern changes with energy across a channel; only the shape matters).  Default
        ``E^-2`` for every source.  The extracted source's own spectrum only weights its
        channels (its response is exact for any spectrum); another source's, if wrong, leaks
        a little of it into the extracted one (second order: its pattern's change across a
        channel, times its overlap with the extracted source's) -- give the other sources'
        fitted spectra (:func:`fit_spectra`) where they are bright.
    off_counts : array_like of int, shape (n_det, n_c), optional
        Background counts measured without the sources (as :func:`fit_spectra`).
    off_exposure : float or array_like, shape (n_det,), optional
        Their good time (s); required with ``off_counts``.
    subdivide : int
        True-energy bins of the response per interval between the nodes (>= 1): the
        response, linear in ``ln E`` between the nodes as the columns are, is tabulated at
        their centres; 4 makes the folded rate of a smooth spectrum exact to ~1e-4.

    Returns
    -------
    RateSpectrum
        ``rate`` and ``error`` (counts/s) per channel, ``exposure`` the mean live time of a
        detector (s), and the response (ARF: the redistribution-weighted mean of the
        column-weighted area, summed over a drift's angle nodes; RMF: redistribution times
        the column-weighted area over it).
    """
    if not isinstance(columns, SpectralColumns):
        raise ParameterError(f"columns must be SpectralColumns, got {type(columns).__name__}")
    n_src = columns.n_sources
    if isinstance(source, bool) or not isinstance(source, int | np.integer) or not (
            0 <= source < n_src):
        raise ParameterError(f"source must be the index of one of the {n_src} sources "
                             f"(0 to {n_src - 1}), got {source!r}")
    subdivide = as_int(subdivide, "subdivide", 1)
    if models is None:
        models = [PowerLaw(1.0, -2.0)] * n_src
    if len(columns.shape) == 4:
        raise ParameterError("columns: a flight's time slices are fitted with fit_spectra; "
                             "extract a spectrum from one slice's columns (spectral_columns "
                             "of its response)")
    bins = _poisson_bins(columns, counts, exposure, models, off_counts, off_exposure)
    n_det, _, n_c = columns.shape
    expo = bins.exposure
    live = float(expo.sum(axis=1).mean())
    if not live > 0:
        raise ParameterError("exposure is 0 everywhere: nothing to extract")
    # Each source's pattern in each channel, scaled so that its amplitude is its rate in
    # counts/s (all detectors): expected counts = amplitude x template x exposure.
    pattern = np.stack([columns.rates(j, m) for j, m in enumerate(models)])
    counted = np.einsum("jdtc,dt->jc", pattern, expo)
    if not np.all(counted > 0):
        j, c = np.argwhere(~(counted > 0))[0]
        raise ParameterError(f"models[{j}] puts no counts of source {j} into channel {c}: "
                             "its pattern there is undefined (give a spectrum with photons "
                             "at the channel's energies)")
    template = pattern * (live / counted)[:, None, None, :]
    n_on = bins.n_on
    design = np.zeros((bins.y.size, n_src))
    design[:n_on] = template.reshape(n_src, -1).T[bins.flat] * bins.value[:n_on, None]
    channel, detector = bins.group % n_c, bins.group // n_c
    n_a, n_e = columns.columns.shape[1:3]
    col = columns.columns[source].reshape(n_a, n_e, -1)
    rate, var = np.empty(n_c), np.empty(n_c)
    area = np.empty((n_a, n_e, n_c))                 # per angle node
    for c in range(n_c):
        sel = np.flatnonzero(channel == c)
        groups = Groups(detector[sel], bins.value[sel], n_det)
        fit = maximise(design[sel], bins.y[sel], groups=groups)
        w, var[c] = _extraction_weights(design[sel], groups, fit.mu, source)
        rate[c] = w @ bins.y[sel]
        on = sel[sel < n_on]                      # the on bins come first
        dt = bins.flat[on] // n_c                 # their (detector, time) index
        for a in range(n_a):
            area[a, :, c] = (col[a][:, dt] * bins.value[on]) @ w[:on.size]
    # Per angle node its area times its redistribution; the ARF is the sum of the nodes'
    # (each the redistribution-weighted mean of its area), the RMF the rest.
    per_node = area * columns.redistribution[source]
    recorded = columns.redistribution[source].sum(axis=2)
    with np.errstate(invalid="ignore", divide="ignore"):
        arf = np.where(recorded > 0, per_node.sum(axis=2) / recorded, 0.0).sum(axis=0)
    response = _response(columns.energies, columns.channel_edges, per_node.sum(axis=0), arf,
                         subdivide)
    return RateSpectrum(rate, np.sqrt(var), live, response, {"OBJECT": f"source {source}"})


def _extraction_weights(design: np.ndarray, groups: Groups, mu: np.ndarray, k: int
                        ) -> tuple[np.ndarray, float]:
    """The row ``k`` of ``(A^T V^-1 A)^-1 A^T V^-1`` with the background levels eliminated
    (``A``: the sources' columns and the groups' levels), and its variance ``w V w^T``.

    ``V`` is the fitted expectation ``mu``, at least half a count per detector and channel
    (spread over its bins as its exposure): where a level and every source fit 0, ``mu`` is 0
    and would give bins that saw nothing an infinite weight; half a count is the mean of
    Jeffreys' posterior for a Poisson rate that saw none.
    """
    floor = 0.5 * groups.value / groups.sum(groups.value)[groups.index]
    v = np.maximum(mu, floor)
    S, Hdg, inv = _schur(design, groups, 1.0 / v, np.ones(groups.size, bool))
    try:
        cov = np.linalg.inv(S)
    except np.linalg.LinAlgError:
        raise ParameterError("the sources' patterns cannot be told apart in a channel (two "
                             "sources at one position?)") from None
    # A^T V^-1 less each level's projection: the columns with the background removed.
    reduced = design - (Hdg * inv)[:, groups.index].T * groups.value[:, None]
    return cov[k] @ (reduced / v[:, None]).T, float(cov[k, k])


def _response(nodes: np.ndarray, channel_edges: np.ndarray, node: np.ndarray,
              arf: np.ndarray, subdivide: int) -> SpectralResponse:
    """The response ``node[e, c]`` (cm^2 per photon at node ``e`` into channel ``c``) as an
    ARF and an RMF on ``subdivide`` bins per interval between nodes, linear in ``ln E`` as the
    columns are (so a model folded through them gives ``sum_e F_e node[e]`` with
    ``F_e = node_weights``, to the bins' midpoint rule).  ``arf[e]``: the area at the nodes
    (the RMF is ``node / arf``)."""
    if np.any(node < 0):
        e, c = np.argwhere(node < 0)[0]
        raise ParameterError(
            f"the extracted source's column-weighted area is negative at {nodes[e]:g} keV in "
            f"channel {c} ({node[e, c]:.3g} cm2): its pattern at that energy is unlike its "
            "pattern in the channel; give its spectrum in models")
    n_bins, n_c = (nodes.size - 1) * subdivide, node.shape[1]
    # The RMF and the interpolated areas it is made from, and a few vectors per bin.
    check_memory(8.0 * n_bins * (2 * n_c + 8), f"a response of {n_bins} energy bins x "
                 f"{n_c} channels", hint="a smaller subdivide")
    ln = np.log(nodes)
    frac = np.arange(subdivide + 1)[:-1] / subdivide
    edges = np.exp(np.append((ln[:-1, None] + np.diff(ln)[:, None] * frac).ravel(), ln[-1]))
    u = np.tile((np.arange(subdivide) + 0.5) / subdivide, nodes.size - 1)
    lo = np.repeat(np.arange(nodes.size - 1), subdivide)
    full = (1.0 - u)[:, None] * node[lo] + u[:, None] * node[lo + 1]
    a = (1.0 - u) * arf[lo] + u * arf[lo + 1]
    rmf = np.where(a[:, None] > 0, full / np.where(a > 0, a, 1.0)[:, None], 0.0)
    return SpectralResponse(edges, channel_edges, rmf, a)


def expected_counts(columns: SpectralColumns, exposure: Any, models: Sequence[SpectralModel],
                    background: Any = 0.0) -> np.ndarray:
    """Expected counts (:attr:`SpectralColumns.shape`) of the sources' spectra plus a
    background rate per detector and channel (counts/s, broadcast to ``(n_det, n_c)``; for
    a flight's time slices to ``(n_slice, n_det, n_c)``, where a 2-D rate is ``(n_slice,
    n_c)``, the same in every detector -- refused as ambiguous when there are as many slices
    as detectors, as a 2-D exposure is: give the 3-D shape)."""
    shape = columns.shape
    expo = _exposure(exposure, shape[:-1])
    _check_models(models, columns.n_sources)
    b = np.asarray(background, dtype=float)
    if len(shape) == 4 and b.ndim == 2:
        _check_per_slice(b.shape, shape[:-2], "background", "n_channels")
        b = b[:, None, :]
    want = (*shape[:-3], shape[-3], shape[-1])
    try:
        b = np.broadcast_to(b, want)
    except ValueError:
        raise ParameterError(f"background must broadcast to {want}, got shape "
                             f"{np.shape(background)}") from None
    rate = sum(columns.rates(k, m) for k, m in enumerate(models)) + b[..., None, :]
    return rate * expo[..., None]


def _check_models(models: Any, n_src: int) -> None:
    """``models``: a sequence of one :class:`SpectralModel` per source."""
    if isinstance(models, SpectralModel | str) or not isinstance(models, Sequence) or not all(
            isinstance(m, SpectralModel) for m in models):
        raise ParameterError(f"models must be a list of spectral models, one per source "
                             f"({n_src}), got {models!r}")
    if len(models) != n_src:
        raise ParameterError(f"models must give one spectrum per source ({n_src}), got "
                             f"{len(models)}")


def _check_per_slice(got: tuple[int, ...], shape: tuple[int, ...], name: str, last: str
                     ) -> None:
    """For a flight's time slices (``shape`` = ``(n_slice, n_det, ...)``) a 2-D array is read
    as ``(n_slice, last)``, the same in every detector; when there are as many slices as
    detectors it could as well be ``(n_det, last)``: a ParameterError asks for the full
    shape rather than guessing."""
    n_s, n_det = shape[0], shape[1]
    if n_s == n_det > 1 and got[0] == n_s:
        raise ParameterError(
            f"{name} of shape {got} is ambiguous: with {n_s} time slices and {n_det} "
            f"detectors it could be (n_slice, {last}) or (n_det, {last}); give the full "
            f"(n_slice, n_det, {last}) shape")


def _exposure(exposure: Any, shape: tuple[int, ...]) -> np.ndarray:
    """``exposure`` as ``shape`` = ``([n_slice,] n_det, n_t)`` seconds, or a ParameterError
    naming the rule: one value, ``(n_t,)`` or ``(n_det, n_t)``; for time slices also
    ``(n_slice, n_t)`` or ``(n_slice, n_det, n_t)``."""
    n_det, n_t = shape[-2:]
    try:
        e = np.asarray(exposure, dtype=float)
        if len(shape) == 3 and e.ndim == 2:
            _check_per_slice(e.shape, shape, "exposure", "n_time")
        if len(shape) == 3 and e.ndim == 2 and e.shape == (shape[0], n_t):
            e = e[:, None, :]                  # per slice and bin, the same in every detector
        expo = np.broadcast_to(e, shape) if e.ndim <= len(shape) else None
    except ParameterError:
        raise
    except (TypeError, ValueError):
        expo = None
    if expo is None or not np.all(np.isfinite(expo)) or np.any(expo < 0):
        rule = f"({n_t},) or ({n_det}, {n_t})"
        if len(shape) == 3:
            rule += f" or ({shape[0]}, {n_t}) or {shape}"
        raise ParameterError(f"exposure must be finite seconds >= 0: one value, or of shape "
                             f"{rule}")
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

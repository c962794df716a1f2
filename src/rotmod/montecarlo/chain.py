"""The whole chain photon by photon: counts per detector, mask-angle bin and energy channel.

A photon of a point source at infinity crosses the rotating mask (its path in the slats, the
instrument Monte Carlo :func:`~rotmod.montecarlo.simulate_profiles`), interacts in a thick
detector or not (the same Monte Carlo: ``1 - exp(-mu l)`` along its chord in the cylinder),
and, if it was counted, deposits energy in the crystal (the detector transport of
:func:`rotmod.spectral.detector.draw_deposits`: photoabsorption, Compton scattering, pair
production, escapes); the deposit is smeared by the detector's resolution and binned into a
channel.  Every photon has its own energy and its own histories; none of the energy-resolved
response's tabulation enters (:func:`rotmod.sources.spectra.spectral_columns`: node
energies, columns and redistribution linear in ``ln E`` between them, the exact model's
columns, the redistribution histogrammed, folded and interpolated in angle), so the counts
are an independent check of it.  Shared with it: the cross-sections (the transport's own
table, 1000 points a decade), the transport's physics and the resolution's law.

*One approximation is shared with the response*: the instrument Monte Carlo reports which
detector counted a photon and in which bin, not where the photon entered the crystal, so the
deposit is that of a photon of the same energy and direction that interacts in the
uniformly lit detector (the mask's shadow, which changes which part of the crystal is lit
and with it the escape probabilities slightly, is not followed into the crystal).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from rotmod._rng import seed_sequence
from rotmod._validate import as_angle, as_angle_scalar, as_int
from rotmod.energy import EnergyResolution
from rotmod.errors import ParameterError
from rotmod.geometry import Instrument
from rotmod.montecarlo.simulate import simulate_profiles
from rotmod.spectral.detector import (
    check_energies,
    check_energy_detectors,
    draw_deposits,
)
from rotmod.spectral.spectrum import check_edges

__all__ = ["ChannelCounts", "simulate_channel_counts"]

#: Energies (photons per cell) per call of the instrument Monte Carlo: its counts, one int64
#: per detector, bin and energy, stay below ~20 MB for 37 detectors x 30 bins.
DEFAULT_BATCH = 2048


@dataclass(frozen=True, eq=False)
class ChannelCounts:
    """Counts of :func:`simulate_channel_counts`.

    Attributes
    ----------
    counts : ndarray of int64, shape (n_det, n_time, n_c)
        Photons recorded in each detector, mask-angle bin and channel.
    face_photons : ndarray, shape (n_det,)
        Photons of the source that crossed each detector's unobstructed face (its top face's
        area ``pi R^2`` seen along the source's direction) in each bin: the simulated
        photons per cell over the Monte Carlo's generation-disc scale
        (:attr:`MCProfiles.scale <rotmod.montecarlo.MCProfiles.scale>`).  The expected
        counts per photon on a face are ``counts / face_photons[:, None, None]``.
    n_photons : int
        Photons simulated per detector and bin (one per energy given).
    interacting : int
        Photons that crossed the mask and interacted in a detector (before the channels).
    """

    counts: np.ndarray
    face_photons: np.ndarray
    n_photons: int
    interacting: int


def simulate_channel_counts(
    instrument: Instrument,
    theta: Any,
    phi: Any,
    energies: Any,
    channel_edges: Any,
    *,
    xi: Any = None,
    xi_edges: Any = None,
    resolution: EnergyResolution | None = None,
    rayleigh: str = "thomson",
    batch: int = DEFAULT_BATCH,
    seed: Any = None,
) -> ChannelCounts:
    """Counts per detector, mask-angle bin and channel of a point source, photon by photon.

    For each true energy ``energies[k]`` one photon reaches each detector at each mask angle
    ``xi`` or in each mask-angle bin ``xi_edges`` (its point on the detector plane, and its
    angle within a bin, drawn uniformly, as :func:`~rotmod.montecarlo.simulate_profiles`
    draws them, with the slats' and the crystal's attenuation at that energy).  Each photon
    counted (it crossed the mask and interacted in the crystal) gets a deposit of its own
    from the detector transport
    (:func:`rotmod.spectral.detector.draw_deposits`, a photon of its energy interacting in
    the uniformly lit crystal: the module's one shared approximation), smeared by
    ``resolution`` (:meth:`EnergyResolution.smear`) and binned: channel ``c`` takes
    ``channel_edges[c] <= E < channel_edges[c + 1]``; a deposit of 0 (scattered out) is not
    recorded.  Draw ``energies`` from the source's spectrum for a continuum, or repeat one
    energy for a line.  The photons of one energy in different detectors and bins are
    independent histories that share the energy: each cell's counts are binomial (its
    photons' energies are independent draws), but a sum over cells is not, its variance
    holding the energy draws' -- estimate a summed count's error from independent runs.

    Parameters
    ----------
    instrument : Instrument
        Detectors with a thickness and a material (a detector transport needs them).
    theta, phi : float or Quantity
        The source's zenith (``0 <= theta < 90``) and azimuth (deg if plain numbers); at
        infinity.
    energies : array_like or Quantity, shape (n,)
        True photon energies (keV): ``n`` photons per detector and bin.
    channel_edges : array_like
        Increasing measured-energy channel edges (keV).
    xi, xi_edges : array_like or Quantity
        Mask angles (a response's bin centres, ``TimeBinning`` "center" mode) or increasing
        mask-angle bin edges (its bins, "average" mode), deg if plain numbers: give exactly
        one (:func:`~rotmod.montecarlo.simulate_profiles`).
    resolution : EnergyResolution, optional
        The detector's resolution (None: deposits binned as they are).
    rayleigh : {"thomson", "forward"}
        Angular law of Rayleigh scattering in the crystal
        (:func:`~rotmod.spectral.detector.simulate_deposits`).
    batch : int
        Energies per call of the instrument Monte Carlo (bounds memory; results depend on
        it, as on the seed).
    seed : None, int, SeedSequence or Generator

    Returns
    -------
    ChannelCounts
    """
    if not isinstance(instrument, Instrument):
        raise ParameterError(f"instrument must be an Instrument, got {type(instrument)}")
    th = as_angle_scalar(theta, "theta", lo=0.0, hi=90.0, hi_open=True)
    ph = as_angle_scalar(phi, "phi")
    if (xi is None) == (xi_edges is None):
        raise ParameterError("give exactly one of xi (angles) and xi_edges (angle bins)")
    angles = np.degrees(as_angle(xi if xi_edges is None else xi_edges,
                                 "xi" if xi_edges is None else "xi_edges", ndim=1))
    where_xi = {"xi": angles} if xi_edges is None else {"xi_edges": angles}
    # The transport's range, checked here: inside draw_deposits it would come after a
    # batch of the instrument Monte Carlo, and never for a batch with no photon counted.
    e = np.asarray(check_energies(energies, "energies"), dtype=float)
    if e.size == 0:
        raise ParameterError("energies must hold at least one photon energy, got none")
    ch = check_edges(channel_edges, "channel_edges")
    if resolution is not None and not isinstance(resolution, EnergyResolution):
        raise ParameterError(
            f"resolution must be an EnergyResolution or None, got {type(resolution).__name__}")
    if rayleigh not in ("thomson", "forward"):
        raise ParameterError(f"rayleigh must be 'thomson' or 'forward', got {rayleigh!r}")
    batch = as_int(batch, "batch", 1)
    det = check_energy_detectors(instrument.detectors, "instrument.detectors")
    n_det, n_c = len(det), ch.size - 1
    n_t = angles.size - (xi_edges is not None)
    counts = np.zeros(n_det * n_t * n_c, dtype=np.int64)
    scale = np.ones(n_det)
    interacting = 0
    starts = range(0, e.size, batch)
    streams = seed_sequence(seed).spawn(3 * len(starts))
    th_deg, ph_deg = np.degrees(th), np.degrees(ph)
    for j, s in enumerate(starts):
        eb = e[s:s + batch]
        prof = simulate_profiles(instrument, np.full(eb.size, th_deg), np.full(eb.size, ph_deg),
                                 energy=eb, n_photons=1, seed=streams[3 * j], **where_xi)
        scale = np.broadcast_to(np.asarray(prof.scale, dtype=float), (n_det, 1, eb.size))[:, 0, 0]
        hits = prof.counts.ravel()
        where = np.repeat(np.arange(hits.size), hits)     # one entry per counted photon
        cell, k = np.divmod(where, eb.size)                # cell = d n_t + t
        interacting += where.size
        if where.size == 0:
            continue
        dep = draw_deposits(det, eb[k], th_deg, rayleigh=rayleigh, seed=streams[3 * j + 1])
        seen = dep > 0
        cell, dep = cell[seen], dep[seen]
        if resolution is not None and dep.size:
            dep = resolution.smear(dep, np.random.default_rng(streams[3 * j + 2])).astype(float)
        c = np.searchsorted(ch, dep, side="right") - 1
        ok = (c >= 0) & (c < n_c)
        counts += np.bincount(cell[ok] * n_c + c[ok], minlength=counts.size)
    return ChannelCounts(counts.reshape(n_det, n_t, n_c), e.size / scale, int(e.size),
                         interacting)

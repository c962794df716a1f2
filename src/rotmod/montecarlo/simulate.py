"""Public entry points of the Monte Carlo: profiles and observations."""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import astropy.units as u
import numba
import numpy as np

from rotmod._rng import chunk_states, seed_sequence
from rotmod._validate import (
    as_angle,
    as_angle_scalar,
    as_array,
    as_distance,
    as_energy,
    as_energy_scalar,
    as_scalar,
)
from rotmod.conventions import source_direction
from rotmod.energy import EnergyResolution
from rotmod.errors import ParameterError
from rotmod.events import EventList, check_gti
from rotmod.geometry import Instrument, disc_flux
from rotmod.limits import check_memory, check_time
from rotmod.montecarlo import _transport as tr
from rotmod.progress import ProgressArg, progress_callbacks
from rotmod.sky.sources import PointSources

__all__ = [
    "MCProfiles", "chord_lengths", "simulate_drift", "simulate_observation", "simulate_profiles",
]

log = logging.getLogger(__name__)

#: Default photons per parallel chunk (about 40 ms of work on one core).
DEFAULT_CHUNK = 2**20
#: Chunks whose random streams are drawn at once (the streams' layout: results depend on it).
_BATCH_CHUNKS = 256
#: Incident photons per observation batch (bounds memory: 16 bytes each; the streams of its
#: chunks are drawn at once, so results depend on it too).
_OBS_BATCH_PHOTONS = 2**23
#: Photons per numba thread in one kernel call.  Compiled code never sees Ctrl-C, so a
#: batch is handed to numba a few chunks at a time (:func:`_per_call`) and a
#: KeyboardInterrupt stops the run between calls: about 0.1 s of profiles and 0.4 s of an
#: observation per call on one core (docs/reliability.md).  The streams stay the batch's,
#: so the results do not depend on it.
_CALL_PHOTONS = 2**20


def _per_call(chunk_size: int) -> int:
    """Chunks of ``chunk_size`` photons per kernel call: :data:`_CALL_PHOTONS` for each of
    numba's threads (at least one chunk each)."""
    return numba.get_num_threads() * max(1, _CALL_PHOTONS // chunk_size)



def _column(a: np.ndarray, j: int) -> np.ndarray:
    """Column ``j`` of ``a`` as a new, writable, contiguous array.

    A copy, not ``np.ascontiguousarray``: one detector's column is already contiguous and
    would be passed through read-only (a detector array's positions are), and numba compiles
    a kernel again for every read-only argument (seconds more of a first run).
    """
    return np.array(a[:, j], dtype=np.float64)


def _check_instrument(instrument: Any) -> Instrument:
    if not isinstance(instrument, Instrument):
        raise ParameterError(f"instrument must be an Instrument, got {type(instrument)}")
    return instrument


def _check_count(value: Any, name: str, lo: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < lo:
        raise ParameterError(f"{name} must be an integer >= {lo}, got {value!r}")
    return int(value)


def _mask_params(instrument: Instrument) -> tuple[float, float, float, float, bool]:
    m = instrument.mask
    return m.slat_width, m.slat_gap, m.height, m.thickness, m.thickness == 0.0


def _mu_for(instrument: Instrument, energies: np.ndarray) -> np.ndarray:
    cache: dict[float, float] = {}
    out = np.empty(energies.size)
    for i, e in enumerate(energies):
        key = float(e)
        if key not in cache:
            cache[key] = instrument.mask.linear_attenuation(key)
        out[i] = cache[key]
    return out


@dataclass(frozen=True, eq=False)
class MCProfiles:
    """Monte Carlo characteristic profiles with their binomial errors.

    Attributes
    ----------
    counts : ndarray of int64, shape (n_det, n_angle, n_src)
        Photons transmitted unattenuated to each detector face.
    n_photons : int
        Photons simulated per (detector, angle, source) cell, sampled uniformly on the
        detector face (the unobstructed flux).
    theta, phi : Quantity, shape (n_src,)
        Source directions (rad).
    xi : Quantity, shape (n_angle,)
        Mask angles (rad): the points simulated, or the bin centres.
    xi_edges : Quantity, shape (n_angle + 1,) or None
        Mask-angle bin edges (rad) when angles were sampled uniformly within bins.
    energy : float, ndarray of shape (n_src,) or None
        Photon energy (keV) used for the attenuation; one per source when several were
        given.
    instrument : Instrument
    scale : float or ndarray, shape (n_det, 1, n_src)
        Simulated photons per photon crossing one unobstructed detector face: 1 when
        photons are drawn on the face (flat detectors); for thick detectors they are drawn
        on a larger disc holding the detector's shadow, and ``scale`` (>= 1) is the ratio of
        the flux through that disc to the flux through the face.  ``P = counts / n_photons
        * scale`` (compare a model with ``counts`` through ``P / scale``).
    distance : ndarray, shape (n_src,)
        Source distances (cm; ``inf``: at infinity).
    poisson : bool
        Whether each cell's number of photons was Poisson of mean ``n_photons`` (as in a
        measurement) rather than exactly ``n_photons``.
    """

    counts: np.ndarray
    n_photons: int
    theta: u.Quantity
    phi: u.Quantity
    xi: u.Quantity
    xi_edges: u.Quantity | None
    energy: float | None
    instrument: Instrument
    scale: Any = 1.0
    distance: Any = None
    poisson: bool = False

    def __repr__(self) -> str:
        d, t, n = self.counts.shape
        return (
            f"<MCProfiles {d} detectors x {t} angles x {n} sources, "
            f"{self.n_photons} photons per cell>"
        )

    @property
    def fraction(self) -> np.ndarray:
        """Counts per photon of an unobstructed face, ``P[d, t, n] = counts / n_photons *
        scale`` (the transmitted fraction for flat detectors)."""
        return self.counts / self.n_photons * self.scale

    @property
    def error(self) -> np.ndarray:
        """Binomial 1-sigma error of :attr:`fraction`, ``scale sqrt(f (1 - f) / n_photons)``
        with ``f = counts / n_photons``.

        Zero where ``f`` is 0 or 1; use the model's ``P (1 - P) / n`` for chi-square tests.
        """
        f = self.counts / self.n_photons
        return self.scale * np.sqrt(f * (1.0 - f) / self.n_photons)


def _chunks(n_cells: int, n_photons: int, chunk: int) -> tuple[np.ndarray, ...]:
    """Chunk layout: (cell_lo, cell_hi, part, nphot) arrays and the number of parts."""
    if n_photons >= chunk:
        m = math.ceil(n_photons / chunk)
        base, extra = divmod(n_photons, m)
        sizes = base + (np.arange(m) < extra)
        q = np.repeat(np.arange(n_cells), m)
        part = np.tile(np.arange(m), n_cells)
        return q, q + 1, part, np.tile(sizes, n_cells), m
    g = max(1, chunk // n_photons)
    lo = np.arange(0, n_cells, g)
    hi = np.minimum(lo + g, n_cells)
    return lo, hi, np.zeros(lo.size, np.int64), np.full(lo.size, n_photons), 1


def simulate_profiles(
    instrument: Instrument,
    theta: Any,
    phi: Any,
    xi: Any = None,
    *,
    xi_edges: Any = None,
    energy: Any = None,
    n_photons: int = 100_000,
    seed: Any = None,
    chunk_size: int = DEFAULT_CHUNK,
    progress: ProgressArg = None,
    distance: Any = None,
    poisson: bool = False,
) -> MCProfiles:
    """Monte Carlo characteristic profiles ``P[d, t, n]`` with binomial errors.

    For every detector ``d``, mask angle ``t`` and source ``n``, ``n_photons`` photons are
    sampled uniformly on the detector face, traced back along the source direction through
    the 3-D slat boxes, and survive with probability ``exp(-mu * chord)``.

    The instrument as built (``Instrument.is_ideal`` false) and sources at a finite
    ``distance`` take a second kernel: the mask in its own (offset, tilted) frame with any
    slat pattern and outline, photons drawn on the face with the flux density of a point
    source (``cos(incidence) / r^2``), and thick detectors counting photons that interact
    in the cylinder (drawn on a disc that holds the detector's shadow; see
    :attr:`MCProfiles.scale`).

    Parameters
    ----------
    instrument : Instrument
    theta, phi : array_like or Quantity, shape (n_src,)
        Source zenith (0 <= theta < 90 deg) and azimuth; deg if plain numbers.
    xi : array_like or Quantity, shape (n_angle,), optional
        Mask angles at which to simulate (deg if plain numbers).  Give exactly one of
        ``xi``, ``xi_edges``.
    xi_edges : array_like or Quantity, shape (n_angle + 1,), optional
        Increasing mask-angle bin edges (deg if plain numbers); each photon's angle is
        uniform in its bin.
    energy : float, array_like or Quantity, optional
        Photon energy (keV); needed unless the mask's attenuation is fixed.  An array gives
        one energy per source (shape ``(n_src,)``): e.g. the same direction repeated with
        energies drawn from a spectrum, each with its own photons (the mask's and the
        detectors' attenuation are then those of each source's energy).
    n_photons : int
        Photons per (detector, angle, source) cell, >= 1.
    seed : None, int, SeedSequence or numpy Generator
        Randomness; results depend on ``seed`` and ``chunk_size``, not on the thread count.
    chunk_size : int
        Photons per parallel chunk (each with its own random stream), >= 1.
    progress : bool or callable, optional
        ``True`` shows a tqdm bar; a callable is called as ``progress(done, total)``.
    distance : float, array_like or Quantity, optional
        Distance of each source from the origin (the array centre in the detector plane)
        along its direction (cm); ``None`` or ``inf``: at infinity.
    poisson : bool
        Draw each cell's number of photons from a Poisson law of mean ``n_photons`` (the
        counts of a measurement, for likelihood fits) instead of exactly ``n_photons``.

    Returns
    -------
    MCProfiles

    Raises
    ------
    ParameterError
        Bad geometry, directions, angles, distances or counts.
    """
    inst = _check_instrument(instrument)
    th = as_angle(theta, "theta", lo=0.0, hi=90.0, hi_open=True, ndim=1)
    ph = as_angle(phi, "phi", ndim=1)
    if th.shape != ph.shape:
        if ph.size == 1:
            ph = np.full(th.shape, ph[0])
        elif th.size == 1:
            th = np.full(ph.shape, th[0])
        else:
            raise ParameterError(
                f"theta and phi must have the same length, got {th.size} and {ph.size}"
            )
    if th.size == 0:
        raise ParameterError("theta must contain at least one source direction, got none")
    if (xi is None) == (xi_edges is None):
        raise ParameterError("give exactly one of xi (angles) and xi_edges (angle bins)")
    if xi is not None:
        xs = as_angle(xi, "xi", ndim=1)
        if xs.size == 0:
            raise ParameterError("xi must contain at least one mask angle, got none")
        xi_lo, xi_w, binned, edges = xs, np.zeros_like(xs), False, None
    else:
        edges = as_angle(xi_edges, "xi_edges", ndim=1)
        if edges.size < 2 or np.any(np.diff(edges) <= 0):
            raise ParameterError(
                "xi_edges must hold at least 2 strictly increasing mask angles, "
                f"got {edges.size} values"
            )
        xi_lo, xi_w, binned = edges[:-1], np.diff(edges), True
        xs = 0.5 * (edges[1:] + edges[:-1])
    n_photons = _check_count(n_photons, "n_photons", 1)
    chunk_size = _check_count(chunk_size, "chunk_size", 1)
    e = None if energy is None else _energies(energy, th.size)
    dist = as_distance(distance, th.size)
    if not isinstance(poisson, bool | np.bool_):
        raise ParameterError(f"poisson must be True or False, got {poisson!r}")
    mu = np.broadcast_to(inst.mask.linear_attenuation(e), (th.size,)).astype(float)
    a, b, L, h, thin = _mask_params(inst)
    if thin and np.isinf(mu).any() and not np.isinf(mu).all():
        raise ParameterError("a thin opaque mask needs mu = inf at every source energy")
    thin_opaque = thin and bool(np.isinf(mu[0]))
    det = inst.detectors
    n_det, n_t, n_n = len(det), xs.size, th.size
    n_cells = n_det * n_t * n_n
    check_memory(8.0 * n_cells * (1 + math.ceil(n_photons / chunk_size)),
                 f"a Monte Carlo of {n_det} detectors x {n_t} angles x {n_n} sources",
                 hint="simulate fewer angles or sources at a time")
    check_time(float(n_cells) * n_photons, "mc_photons",
               f"a Monte Carlo of n_photons = {n_photons} photons in each of {n_cells} cells "
               f"({n_det} detectors x {n_t} angles x {n_n} sources)",
               hint="simulate fewer photons per cell, or fewer angles or sources")
    as_built = not inst.is_ideal or bool(np.isfinite(dist).any()) or poisson
    scale: Any = 1.0
    if as_built:
        kernel = tr.profile_kernel_asbuilt
        *args, scale = _asbuilt_args(inst, th, ph, dist, mu, e, xi_lo, xi_w, binned,
                                     thin_opaque, n_t, n_n)
        args_geom = (bool(poisson), *args)
    else:
        kernel = tr.profile_kernel
        args_geom = (
            _column(det.positions, 0), _column(det.positions, 1),
            det.radius, np.sin(th), np.cos(th), np.cos(ph), np.sin(ph), mu,
            np.ascontiguousarray(xi_lo), np.ascontiguousarray(xi_w), binned,
            a, b, L, h, thin_opaque, n_t, n_n,
        )
    lo, hi, part, nphot, m = _chunks(n_cells, n_photons, chunk_size)
    counts = np.zeros((m, n_cells), dtype=np.int64)
    root = seed_sequence(seed)
    total = n_cells * n_photons
    update, close = progress_callbacks(progress, total, "MC profiles", "photon")
    done = 0
    lo, hi, part, nphot = (x.astype(np.int64) for x in (lo, hi, part, nphot))
    step = _per_call(chunk_size)
    try:
        for s in range(0, lo.size, _BATCH_CHUNKS):
            states = chunk_states(root, min(_BATCH_CHUNKS, lo.size - s))
            for c in range(0, states.shape[0], step):  # a few chunks per call (_CALL_PHOTONS)
                sl = slice(s + c, s + min(c + step, states.shape[0]))
                kernel(lo[sl], hi[sl], part[sl], nphot[sl], states[c : c + step], *args_geom,
                       counts)
                done += int(np.sum((hi[sl] - lo[sl]) * nphot[sl]))
                update(done, total)
    finally:
        close()
    log.debug("simulate_profiles: %d photons in %d chunks", total, lo.size)
    return MCProfiles(
        counts.sum(axis=0).reshape(n_det, n_t, n_n), n_photons, th * u.rad, ph * u.rad,
        xs * u.rad, None if edges is None else edges * u.rad, e, inst, scale, dist,
        bool(poisson),
    )


def _energies(energy: Any, n_src: int) -> float | np.ndarray:
    """``energy`` (keV) as one float, or as one energy per source (shape ``(n_src,)``)."""
    if np.ndim(energy) == 0:
        return as_energy_scalar(energy, "energy")
    e = as_energy(energy, "energy", ndim=1)
    if e.shape != (n_src,):
        raise ParameterError(f"energy must be one value or one per source ({n_src}), got "
                             f"{e.size} values")
    return np.array(e, dtype=float)


def _asbuilt_args(inst: Instrument, th: np.ndarray, ph: np.ndarray, dist: np.ndarray,
                  mu: np.ndarray, energy: float | np.ndarray | None, xi_lo: np.ndarray,
                  xi_w: np.ndarray, binned: bool, thin_opaque: bool, n_t: int, n_n: int) -> tuple:
    """Arguments of :func:`~rotmod.montecarlo._transport.profile_kernel_asbuilt` (after
    ``poisson_counts``), with the :attr:`MCProfiles.scale` last."""
    det, mask = inst.detectors, inst.mask
    pos = det.positions
    R, H = det.radius, det.thickness
    n_det = len(det)
    S = inst.source_positions(th, ph, dist)
    finite = np.isfinite(dist)
    dirs = source_direction(th, ph)
    src = np.where(finite[:, None], S, dirs)
    gen = np.empty((n_det, n_n, 3))
    wmax = np.ones((n_det, n_n))
    scale = np.ones((n_det, 1, n_n))
    # Sources repeated at one position (e.g. one direction at many energies) share the
    # geometry of the first of them.
    _, first, inverse = np.unique(np.stack([th, ph, dist], axis=1), axis=0,
                                  return_index=True, return_inverse=True)
    rep = first[inverse.ravel()]
    for n in range(n_n):
        if rep[n] != n:
            gen[:, n], wmax[:, n], scale[:, 0, n] = (gen[:, rep[n]], wmax[:, rep[n]],
                                                     scale[:, 0, rep[n]])
            continue
        for d in range(n_det):
            c = pos[d]
            if finite[n]:
                # The bottom face's shadow from S: a disc of radius R / (1 + H / z_s) centred
                # on (c + S_xy H / z_s) / (1 + H / z_s) (docs/physics.md, thick detectors).
                k = 1.0 + H / S[n, 2]
                cb = (c + S[n, :2] * H / S[n, 2]) / k
            else:
                cb = c + H * np.tan(th[n]) * np.array([np.cos(ph[n]), np.sin(ph[n])])
            g = 0.5 * (c + cb)
            gr = R + 0.5 * float(np.hypot(*(cb - c)))
            gen[d, n] = (g[0], g[1], gr)
            if finite[n]:
                near = max(0.0, float(np.hypot(*(S[n, :2] - g))) - gr)
                wmax[d, n] = S[n, 2] / (near**2 + S[n, 2] ** 2) ** 1.5
                if H > 0:
                    scale[d, 0, n] = disc_flux(S[n], g, gr) / disc_flux(S[n], c, R)
            elif H > 0:
                scale[d, 0, n] = (gr / R) ** 2
    mu_det = (np.broadcast_to(det.linear_attenuation(energy), (n_n,)).astype(float)
              if H > 0 else np.zeros(n_n))
    Q, cm = mask.frame()
    e0, W, _, p = mask.pattern()
    kind = {None: 0, "circle": 1, "square": 2}[mask.outline]
    size = 0.0 if mask.outline_size is None else mask.outline_size
    return (
        _column(pos, 0), _column(pos, 1), R, H, mu_det,
        gen, wmax, np.ascontiguousarray(src), finite, mu,
        np.ascontiguousarray(xi_lo), np.ascontiguousarray(xi_w), binned,
        Q, cm, mask.thickness, e0, W, p, kind, size, thin_opaque, n_t, n_n,
        scale if H > 0 else 1.0,
    )


def chord_lengths(
    instrument: Instrument, x: Any, y: Any, theta: Any, phi: Any, xi: Any
) -> np.ndarray:
    """Path length (cm) in slat material of rays ending at detector-plane points.

    The ray ending at lab point ``(x, y, 0)`` is traced back toward the source at
    ``(theta, phi)`` through the mask at angle ``xi`` (all broadcast together).

    Parameters
    ----------
    instrument : Instrument
    x, y : array_like or Quantity
        Lab coordinates of the rays' end points in the detector plane (cm).
    theta, phi, xi : array_like or Quantity
        Source zenith (< 90 deg), azimuth and mask angle (deg if plain numbers).

    Returns
    -------
    numpy.ndarray
        Chord lengths with the broadcast shape.
    """
    inst = _check_instrument(instrument)
    xx = as_array(x, "x", u.cm)
    yy = as_array(y, "y", u.cm)
    th = as_angle(theta, "theta", lo=0.0, hi=90.0, hi_open=True)
    ph = as_angle(phi, "phi")
    xv = as_angle(xi, "xi")
    xx, yy, th, ph, xv = np.broadcast_arrays(xx, yy, th, ph, xv)
    shape = xx.shape
    a, b, L, h, _ = _mask_params(inst)
    out = tr.chords_many(
        xx.ravel().copy(), yy.ravel().copy(), np.sin(th).ravel(), np.cos(th).ravel(),
        np.cos(ph).ravel(), np.sin(ph).ravel(), xv.ravel().copy(), a, b, L, h,
    )
    return out.reshape(shape)


def simulate_observation(
    instrument: Instrument,
    sources: PointSources,
    *,
    t_start: Any = 0.0,
    t_stop: Any = None,
    gti: Any = None,
    start_phase: Any = 0.0,
    background: Any = 0.0,
    background_energy: Any = None,
    seed: Any = None,
    chunk_size: int = DEFAULT_CHUNK,
    progress: ProgressArg = None,
    meta: dict[str, Any] | None = None,
    attitude: Any = None,
    resolution: Any = None,
) -> EventList:
    """Simulate a time-tagged observation with the mask rotating.

    Photons of each source arrive on each detector face as a Poisson process of the source's
    rate during the good time; at arrival time ``t`` the mask angle is
    ``xi = 2 pi t / rotation_period + start_phase``, and each photon is transported through
    the 3-D mask as in :func:`simulate_profiles`.  A flat (unmodulated) background adds
    Poisson events on each detector.

    Parameters
    ----------
    instrument : Instrument
    sources : PointSources
        Directions, rates (photons/s on each detector face with no mask) and energies.
    t_start, t_stop : float or Quantity
        Exposure bounds (s); ``t_stop`` is required unless ``gti`` is given.
    gti : array_like, shape (k, 2), optional
        Good-time intervals inside ``[t_start, t_stop]``; default the whole exposure.
    start_phase : float or Quantity
        Mask angle at ``t = 0`` (deg if a plain number).
    background : float or array_like, shape (n_det,)
        Flat background rate per detector (1/s), >= 0.
    background_energy : float or Quantity, optional
        Energy (keV) given to background events; default the sources' energy when they
        all share one.
    seed : None, int, SeedSequence or numpy Generator
        Randomness; results depend on ``seed`` and ``chunk_size``, not on the thread count.
    chunk_size : int
        Expected incident photons per parallel chunk (each with its own random streams).
    progress : bool or callable, optional
        ``True`` shows a tqdm bar; a callable is called as ``progress(done, total)`` with the
        simulated time (ms) done and total.
    meta : dict, optional
        Header metadata for the event list (``telescop``, ``mjdref``, ...).
    attitude : rotmod.sky.Attitude, optional
        Where the instrument pointed, recorded with the events (sources given on the sky go
        through :meth:`PointSources.from_sky` with the same attitude).
    resolution : rotmod.energy.EnergyResolution, optional
        Detector energy resolution: recorded energies are the lines smeared by it (default:
        the true energies).

    Returns
    -------
    EventList
        Detected events sorted by time, with the Monte Carlo truth in ``source``.
    """
    inst = _check_instrument(instrument)
    if not isinstance(sources, PointSources):
        raise ParameterError(f"sources must be PointSources, got {type(sources)}")
    if not inst.is_ideal:
        raise ParameterError(
            "simulate_observation transports photons through the ideal instrument only, got "
            f"one as built ({', '.join(inst.as_built_features())}); simulate folded counts "
            "with simulate_profiles(..., xi_edges=..., poisson=True)"
        )
    t0 = as_scalar(t_start, "t_start", u.s)
    t1 = None if t_stop is None else as_scalar(t_stop, "t_stop", u.s)
    if gti is None and t1 is None:
        raise ParameterError("t_stop is required unless gti is given")
    g = check_gti(gti, t0, t1)
    if t1 is None:
        t1 = float(g[-1, 1])
    phase = as_angle_scalar(start_phase, "start_phase")
    n_det = len(inst.detectors)
    bkg = as_array(background, "background", 1 / u.s, lo=0.0, ndim=1)
    if bkg.size == 1:
        bkg = np.full(n_det, bkg[0])
    if bkg.shape != (n_det,):
        raise ParameterError(
            f"background must be a scalar or one rate per detector ({n_det}), got {bkg.shape}"
        )
    if background_energy is None:
        uniq = np.unique(sources.energy)
        if np.any(bkg > 0) and uniq.size > 1:
            raise ParameterError(
                "background_energy is required when the sources have different energies"
            )
        e_bkg = float(uniq[0])
    else:
        e_bkg = as_energy_scalar(background_energy, "background_energy")
    chunk_size = _check_count(chunk_size, "chunk_size", 1)
    mu = _mu_for(inst, sources.energy)
    a, b, L, h, thin = _mask_params(inst)
    thin_opaque_arr = thin & np.isinf(mu)
    if thin_opaque_arr.any() and not thin_opaque_arr.all():
        raise ParameterError("a thin opaque mask needs mu = inf at every source energy")
    thin_opaque = bool(thin_opaque_arr.any())

    # Time pieces of at most chunk_size expected incident photons each.
    total_rate = n_det * float(sources.rate.sum()) + float(bkg.sum())
    duration = float(np.sum(g[:, 1] - g[:, 0]))
    # Every incident photon may become an event (TIME 8 B, DET_ID, ENERGY, SRC_ID 4 B each),
    # held twice while the pieces are joined and sorted.
    check_memory(2 * 20.0 * total_rate * duration + 16.0 * duration * total_rate / chunk_size,
                 f"an observation of {duration:g} s at {total_rate:g} photons/s",
                 hint="simulate a shorter time (or in several pieces) and fold each")
    check_time(total_rate * duration, "mc_photons",
               f"an observation of {duration:g} s at {total_rate:g} photons/s",
               hint="simulate a shorter time (or in several pieces) and fold each")
    max_dt = np.inf if total_rate == 0 else chunk_size / total_rate
    pieces = []
    for s_, e_ in g:
        k = max(1, math.ceil((e_ - s_) / max_dt)) if np.isfinite(max_dt) else 1
        edges = np.linspace(s_, e_, k + 1)
        pieces.append(np.stack([edges[:-1], edges[1:]], axis=1))
    pc = np.concatenate(pieces)
    root = seed_sequence(seed)
    det = inst.detectors
    src_th, src_ph = sources.theta.to_value(u.rad), sources.phi.to_value(u.rad)
    geom = (
        _column(det.positions, 0), _column(det.positions, 1),
        det.radius, np.sin(src_th), np.cos(src_th), np.cos(src_ph), np.sin(src_ph), mu,
        np.array(sources.rate), bkg,
        inst.angular_speed, phase, a, b, L, h, thin_opaque,
    )
    per_batch = max(1, _OBS_BATCH_PHOTONS // max(chunk_size, 1))
    step = _per_call(chunk_size)
    out_t, out_d, out_s = [], [], []
    total_ms = round(1e3 * float(np.sum(g[:, 1] - g[:, 0])))
    update, close = progress_callbacks(progress, total_ms, "MC observation", "photon")
    done = 0.0
    try:
        for s in range(0, pc.shape[0], per_batch):
            p = pc[s : s + per_batch]
            st_n = chunk_states(root, p.shape[0])
            st_p = chunk_states(root, p.shape[0])
            tot = np.zeros(p.shape[0], np.int64)
            tr.observation_count_kernel(
                p[:, 0].copy(), p[:, 1].copy(), st_n, np.array(sources.rate), bkg, n_det, tot
            )
            offset = np.concatenate([[0], np.cumsum(tot)[:-1]]).astype(np.int64)
            n_tot = int(tot.sum())
            bt = np.empty(n_tot)
            bd = np.empty(n_tot, np.int32)
            bs = np.empty(n_tot, np.int32)
            n_out = np.zeros(p.shape[0], np.int64)
            t_lo, t_hi = p[:, 0].copy(), p[:, 1].copy()
            for c in range(0, p.shape[0], step):  # a few pieces per call (_CALL_PHOTONS)
                sl = slice(c, c + step)
                tr.observation_kernel(t_lo[sl], t_hi[sl], st_n[sl], st_p[sl], offset[sl],
                                      *geom, bt, bd, bs, n_out[sl])
            keep = np.concatenate(
                [np.arange(o, o + k) for o, k in zip(offset, n_out, strict=True)]
            ) if p.shape[0] else np.zeros(0, np.int64)
            out_t.append(bt[keep])
            out_d.append(bd[keep])
            out_s.append(bs[keep])
            done += float(np.sum(p[:, 1] - p[:, 0]))
            update(round(1e3 * done), total_ms)
    finally:
        close()
    time = np.concatenate(out_t)
    order = np.argsort(time, kind="stable")
    src = np.concatenate(out_s)[order]
    energy = np.where(src >= 0, sources.energy[np.maximum(src, 0)], e_bkg).astype(np.float32)
    if sources.spectrum is not None and np.any(src >= 0):
        # True energies within each source's band (the attenuation used its centre); a
        # stream of its own, spawned after the transport's.
        s = src[src >= 0]
        energy[src >= 0] = sources.spectrum.draw(
            sources.band[s, 0], sources.band[s, 1], np.random.default_rng(root.spawn(1)[0])
        ).astype(np.float32)
    if resolution is not None:
        if not isinstance(resolution, EnergyResolution):
            raise ParameterError(f"resolution must be an EnergyResolution, got {resolution!r}")
        # Its own stream (spawned after the transport's): the same seed gives the same
        # events with or without smearing, only their recorded energies differ.
        energy = resolution.smear(energy, np.random.default_rng(root.spawn(1)[0]))
    log.debug("simulate_observation: %d events in %d time pieces", time.size, pc.shape[0])
    return EventList(
        time[order], np.concatenate(out_d)[order], energy, inst, g, phase * u.rad, t0, t1,
        src, sources, dict(meta or {}), attitude,
    )


def simulate_drift(
    instrument: Instrument,
    coords: Any,
    intervals: list[tuple[float, float, Any]],
    *,
    rate: Any = 1.0,
    energy: Any = 662.0,
    background: Any = 0.0,
    background_energy: Any = None,
    seed: Any = None,
    resolution: Any = None,
    meta: dict[str, Any] | None = None,
    progress: Callable[[int, int], Any] | None = None,
) -> EventList:
    """An observation of sky sources while the attitude drifts.

    Each interval ``(t_lo, t_hi, attitude)`` (e.g. from
    :meth:`rotmod.sky.AttitudeTable.intervals`) is simulated with the sources where that
    attitude sees them; the events are joined into one list over the whole time.

    Parameters
    ----------
    instrument : Instrument
    coords : astropy.coordinates.SkyCoord
        Source positions.
    intervals : list of (float, float, Attitude)
        Contiguous, increasing pieces of time (s) and the attitude in each.
    rate, energy, background, background_energy, resolution, meta
        As for :class:`PointSources` and :func:`simulate_observation`.
    seed : int or SeedSequence, optional
        One seed for the whole observation (each interval gets its own stream).
    progress : callable, optional
        Called as ``progress(done, total)`` with the intervals simulated and their number.

    Returns
    -------
    EventList
        With the attitude of the middle interval (the file's nominal pointing).
    """
    if not intervals:
        raise ParameterError("intervals must hold at least one (t_lo, t_hi, attitude)")
    streams = seed_sequence(seed).spawn(len(intervals))
    parts = []
    for (lo, hi, att), ss in zip(intervals, streams, strict=True):
        src = PointSources.from_sky(coords, att, rate=rate, energy=energy)
        parts.append(simulate_observation(instrument, src, t_start=lo, t_stop=hi,
                                          background=background,
                                          background_energy=background_energy, seed=ss,
                                          resolution=resolution, meta=meta))
        if progress is not None:
            progress(len(parts), len(intervals))
    gti = np.concatenate([p.gti for p in parts])
    mid = intervals[len(intervals) // 2][2]
    return EventList(
        np.concatenate([p.time for p in parts]), np.concatenate([p.detector for p in parts]),
        np.concatenate([p.energy for p in parts]), instrument, gti, 0.0,
        intervals[0][0], intervals[-1][1], np.concatenate([p.source for p in parts]),
        parts[0].sources, dict(meta or {}), mid,
    )

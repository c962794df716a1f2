"""Calibrating the instrument as built from lab measurements of known sources.

A measurement is the folded counts ``k[d, t]`` (detector, mask-angle bin) of one source at a
known position (direction and distance) and energy.  Its expected counts are

    mu[d, t] = A * omega_d * Pbar[d, t](p) + b,

``Pbar`` the exact model's profile averaged over the bin (counts per photon crossing a
detector's face), ``omega_d`` the solid angle of face ``d`` relative to a face at the
array's centre (1 at infinity; it carries the ``1 / r^2`` of a nearby source across the
array), ``A`` the source's photons per bin through that central face, a nuisance
parameter of each measurement, and ``b`` the known background per bin (measured without
the source; it also keeps ``mu > 0`` where an opaque mask shadows a detector for a whole
bin).  :func:`fit_calibration` maximises the Poisson likelihood
``sum k log mu - mu`` over the instrument parameters ``p`` (axis offset and tilt, the mask's
height, an offset common to the source distances) and the amplitudes by Fisher scoring
(Gauss–Newton for Poisson data, with a Levenberg damping that only ever accepts steps that
raise the likelihood), the derivatives of ``Pbar`` by central differences.  The
uncertainties are the inverse Fisher matrix at the optimum, amplitudes marginalised (the
pull distribution over seeds checks them: ``scripts/calibration.py``).

:func:`simulate_measurement` makes such data with the Monte Carlo (``poisson=True``: the
counts of a measurement), from an instrument whose misalignment the analyst does not know.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass, field
from typing import Any

import astropy.units as u
import numpy as np

from rotmod._validate import (
    as_angle_scalar,
    as_array,
    as_distance,
    as_energy_scalar,
    as_int,
    as_integers,
    as_scalar,
)
from rotmod.binning import TimeBinning
from rotmod.errors import ParameterError
from rotmod.geometry import Instrument, disc_flux
from rotmod.montecarlo import seed_sequence, simulate_profiles
from rotmod.profiles import DEFAULT_MODEL, get_model

__all__ = [
    "PARAMETERS",
    "CalibrationResult",
    "LabMeasurement",
    "bins",
    "fit_calibration",
    "relative_flux",
    "simulate_measurement",
]

log = logging.getLogger(__name__)

#: Parameters a calibration can fit: (unit, finite-difference step).  Offsets and the
#: mask's height are :class:`~rotmod.geometry.Mask` fields; ``distance_offset`` is added to
#: every source's distance (the tape measure's zero).
PARAMETERS: dict[str, tuple[str, float]] = {
    "axis_offset_x": ("cm", 0.02),
    "axis_offset_y": ("cm", 0.02),
    "tilt_x": ("deg", 0.02),
    "tilt_y": ("deg", 0.02),
    "height": ("cm", 0.1),
    "distance_offset": ("cm", 1.0),
}


def bins(n_bins: int) -> TimeBinning:
    """``n_bins`` bins per rotation, each averaged over midpoint sub-angles at most 1 deg
    apart (and at least 4).

    Opaque slats (lead at 122 keV) give profiles with kinks, where the midpoint rule
    converges slowly: for the lab prototype at 2 m and 2e4 counts per bin the deviance/dof
    at the truth is 1.31 with 1.9 deg sub-intervals, 1.11 with 0.94 deg and 1.094 with
    0.12 deg (docs/physics.md).
    """
    n = as_int(n_bins, "time_bins", 1)
    return TimeBinning(n, "average", max(4, math.ceil(360.0 / n)))


@dataclass(frozen=True)
class LabMeasurement:
    """Folded counts of one source at a known position.

    Parameters
    ----------
    theta, phi : float or Quantity
        Direction of the source from the array's centre (deg if plain numbers; held as
        Quantities in rad).
    distance : float or Quantity
        Distance from the array's centre (cm); ``inf`` for a source at infinity.
    energy : float or Quantity
        Photon energy (keV).
    counts : array_like, shape (n_det, n_bins)
        Counts per detector and mask-angle bin (integers >= 0).
    time_bins : TimeBinning or int
        The binning of one rotation; the model averages each bin over its ``n_sub``
        midpoint sub-angles.  An int is that many bins with sub-angles at most 1 deg apart
        (:func:`bins`): coarser ones misfit bright sources.
    background : float or array_like, shape (n_det,) or (n_det, n_bins)
        Known background counts per bin (>= 0), e.g. from a run without the source.
    """

    theta: Any
    phi: Any
    distance: Any
    energy: Any
    counts: Any
    time_bins: Any
    background: Any = 0.0

    def __post_init__(self) -> None:
        # Angles held as Quantities (rad), so that dataclasses.replace keeps them.
        object.__setattr__(self, "theta", as_angle_scalar(self.theta, "theta", lo=0.0,
                                                          hi=90.0, hi_open=True) * u.rad)
        object.__setattr__(self, "phi", as_angle_scalar(self.phi, "phi") * u.rad)
        if self.distance is None:  # as_distance would read None as infinity: say it
            raise ParameterError("distance must be > 0 cm (inf: at infinity), got None")
        d = float(as_distance(self.distance, 1, "distance")[0])
        object.__setattr__(self, "distance", d)
        object.__setattr__(self, "energy", as_energy_scalar(self.energy, "energy"))
        k = as_integers(self.counts, "counts", lo=0).astype(float)
        if k.ndim != 2:
            raise ParameterError(f"counts must be 2-dimensional (n_det, n_bins), got shape "
                                 f"{k.shape}")
        tb = self.time_bins
        tb = tb if isinstance(tb, TimeBinning) else bins(tb)
        if k.shape[1] != tb.n_bins:
            raise ParameterError(
                f"counts must have one column per time bin ({tb.n_bins}), got {k.shape[1]}"
            )
        object.__setattr__(self, "counts", k)
        object.__setattr__(self, "time_bins", tb)
        b = np.asarray(as_array(self.background, "background", lo=0.0), dtype=float)
        if b.ndim == 1:
            b = b[:, None]
        try:
            b = np.broadcast_to(b, k.shape).copy()
        except ValueError:
            raise ParameterError(f"background must be a scalar, one value per detector or "
                                 f"one per (detector, bin) {k.shape}, got {b.shape}") from None
        object.__setattr__(self, "background", b)


@dataclass
class CalibrationResult:
    """The fitted instrument parameters.

    Attributes
    ----------
    names : tuple of str
        Fitted parameters (see :data:`PARAMETERS`).
    values, errors : dict of str to Quantity
        Best values and 1-sigma uncertainties (inverse Fisher matrix, amplitudes
        marginalised).
    covariance : ndarray
        Covariance of the fitted parameters, in their units (cm, deg).
    amplitudes, amplitude_errors : ndarray
        Photons per bin through the central face, per measurement.
    instrument : Instrument
        The instrument with the fitted parameters.
    distance_offset : float
        The fitted distance offset (cm; 0 if not fitted).
    log_likelihood : float
    deviance : float
        Poisson deviance ``2 sum k log(k / mu) - (k - mu)``: about ``dof`` for a good fit.
    dof : int
        Counts minus fitted parameters (amplitudes included).
    n_iter : int
    converged : bool
    """

    names: tuple[str, ...]
    values: dict[str, u.Quantity]
    errors: dict[str, u.Quantity]
    covariance: np.ndarray
    amplitudes: np.ndarray
    amplitude_errors: np.ndarray
    instrument: Instrument
    distance_offset: float
    log_likelihood: float
    deviance: float
    dof: int
    n_iter: int
    converged: bool
    history: list[dict[str, float]] = field(default_factory=list)

    def __repr__(self) -> str:
        body = ", ".join(f"{n} = {self.values[n].value:.5g} +- {self.errors[n].value:.2g} "
                         f"{self.values[n].unit}" for n in self.names)
        return f"<CalibrationResult {body}; deviance/dof = {self.deviance / self.dof:.3f}>"


def _with(instrument: Instrument, p: dict[str, float]) -> tuple[Instrument, float]:
    """The instrument with the mask parameters of ``p`` (cm, deg) and the distance offset."""
    mask_changes = {k: v for k, v in p.items() if k != "distance_offset"}
    mask = dataclasses.replace(instrument.mask, **mask_changes) if mask_changes else \
        instrument.mask
    return Instrument(mask, instrument.detectors, instrument.rotation_period), \
        p.get("distance_offset", 0.0)


def relative_flux(instrument: Instrument, theta: float, phi: float, distance: float
                  ) -> np.ndarray:
    """``omega_d``: each detector face's solid angle seen from the source over that of a face
    at the array's centre (1 for a source at infinity).

    Parameters
    ----------
    instrument : Instrument
    theta, phi : float
        Source direction (rad).
    distance : float
        Source distance (cm), ``inf`` at infinity.

    Returns
    -------
    numpy.ndarray, shape (n_det,)
    """
    det = instrument.detectors
    if not np.isfinite(distance):
        return np.ones(len(det))
    S = instrument.source_positions(np.array([theta]), np.array([phi]),
                                    np.array([distance]))[0]
    ref = disc_flux(S, (0.0, 0.0), det.radius)
    return np.array([disc_flux(S, c, det.radius) for c in det.positions]) / ref


def _profiles(instrument: Instrument, m: LabMeasurement, distance_offset: float,
              model: Any) -> np.ndarray:
    """``omega_d Pbar[d, t]`` of one measurement (bin averages over the sub-angles)."""
    tb = m.time_bins
    xi = tb.sub_angles().ravel()  # rad, sub-sample k of every bin, then the next k
    D = m.distance + distance_offset if np.isfinite(m.distance) else None
    P = get_model(model).profile(instrument, u.Quantity([m.theta]), u.Quantity([m.phi]),
                                 xi * u.rad, m.energy, distance=D)[:, :, 0]
    Pbar = P.reshape(P.shape[0], tb.n_sub, tb.n_bins).mean(axis=1)
    return Pbar * relative_flux(instrument, m.theta.to_value(u.rad), m.phi.to_value(u.rad),
                                 m.distance + distance_offset)[:, None]


def simulate_measurement(
    instrument: Instrument,
    theta: Any,
    phi: Any,
    *,
    distance: Any = np.inf,
    energy: Any = 662.0,
    time_bins: Any = 32,
    photons: float = 1e4,
    background: float = 0.0,
    seed: Any = None,
) -> LabMeasurement:
    """A lab measurement simulated with the Monte Carlo.

    Each detector's face receives Poisson photons of mean ``photons * omega_d`` per bin (a
    source emitting isotropically: ``omega_d`` of :mod:`rotmod.calibration`), transported
    through ``instrument`` (offsets, tilts, thick detectors... which the analyst may not
    know) at mask angles uniform within each bin.

    Parameters
    ----------
    instrument : Instrument
        The instrument as built (the truth).
    theta, phi : float or Quantity
        Source direction (deg if plain numbers).
    distance : float or Quantity
        Source distance (cm; ``inf`` at infinity).
    energy : float or Quantity
        Photon energy (keV).
    time_bins : TimeBinning or int
        Binning of one rotation.
    photons : float
        Mean photons per bin through a face at the array's centre, > 0.
    background : float
        Mean background counts per bin and detector (Poisson, flat), >= 0; the measurement
        records it as known.
    seed : None, int, SeedSequence or numpy Generator

    Returns
    -------
    LabMeasurement
    """
    n = as_scalar(photons, "photons", lo=0.0, lo_open=True)
    tb = time_bins if isinstance(time_bins, TimeBinning) else bins(time_bins)
    det = instrument.detectors
    bkg = as_scalar(background, "background", lo=0.0)
    m0 = LabMeasurement(theta, phi, distance, energy, np.zeros((len(det), tb.n_bins)), tb, bkg)
    D = m0.distance if np.isfinite(m0.distance) else None
    src = (u.Quantity([m0.theta]), u.Quantity([m0.phi]))
    omega = relative_flux(instrument, m0.theta.to_value(u.rad), m0.phi.to_value(u.rad),
                           m0.distance)
    # The Monte Carlo draws photons on each face, or on a disc around a thick detector's
    # shadow, ``scale_d`` drawn photons per face photon: each detector draws
    # photons * omega_d * scale_d of them (the scale is geometry: one photon finds it).
    scale = np.broadcast_to(np.asarray(simulate_profiles(
        instrument, *src, [0.0], energy=m0.energy, n_photons=1, distance=D, seed=0).scale,
        dtype=float), (len(det), 1, 1))[:, 0, 0]
    edges = tb.edges() * u.rad
    counts = np.empty((len(det), tb.n_bins))
    root = seed_sequence(seed)
    counts_bkg = np.random.default_rng(root.spawn(1)[0]).poisson(bkg, counts.shape)
    for d, ss in enumerate(root.spawn(len(det))):
        one = Instrument(instrument.mask, det.with_positions(det.positions[d:d + 1]),
                         instrument.rotation_period)
        mc = simulate_profiles(one, *src, xi_edges=edges, energy=m0.energy,
                               n_photons=max(1, round(n * omega[d] * scale[d])), distance=D,
                               seed=ss, poisson=True)
        counts[d] = mc.counts[0, :, 0]
    return dataclasses.replace(m0, counts=counts + counts_bkg)


def fit_calibration(
    instrument: Instrument,
    measurements: list[LabMeasurement],
    *,
    parameters: tuple[str, ...] = ("axis_offset_x", "axis_offset_y", "tilt_x", "tilt_y"),
    start: dict[str, Any] | None = None,
    model: Any = DEFAULT_MODEL,
    max_iter: int = 30,
    tol: float = 1e-3,
) -> CalibrationResult:
    """Fit the instrument's parameters to lab measurements by maximum likelihood.

    Parameters
    ----------
    instrument : Instrument
        The instrument as designed (or the last calibration); its other parameters are
        held fixed.
    measurements : list of LabMeasurement
        Known sources; use several distances and directions: an axis offset shifts every
        shadow alike, a tilt turns the mask about its centre (a shift that grows with the
        source's distance), so sources at one distance cannot tell them apart.
    parameters : tuple of str
        Names from :data:`PARAMETERS`.
    start : dict, optional
        Starting values (cm, deg; Quantities accepted); default the instrument's.
    model : str or ProfileModel
        Profile model (default :data:`~rotmod.profiles.DEFAULT_MODEL`, ``"exact"``: the only
        one that describes the instrument as built).
    max_iter : int
        Most Fisher-scoring iterations.
    tol : float
        Converged when every parameter's step is below ``tol`` of its uncertainty.

    Returns
    -------
    CalibrationResult

    Raises
    ------
    ParameterError
        Unknown parameter names, no measurements, or a singular Fisher matrix (parameters
        the measurements cannot tell apart).
    """
    names = tuple(parameters)
    bad = [n for n in names if n not in PARAMETERS]
    if bad or not names:
        raise ParameterError(f"parameters must be names from {sorted(PARAMETERS)}, got "
                             f"{list(names)}")
    if not measurements or not all(isinstance(m, LabMeasurement) for m in measurements):
        raise ParameterError("measurements must be a non-empty list of LabMeasurement")
    max_iter = as_int(max_iter, "max_iter", 1)
    m0 = instrument.mask
    current = {"axis_offset_x": m0.axis_offset_x, "axis_offset_y": m0.axis_offset_y,
               "tilt_x": float(np.rad2deg(m0.tilt_rad[0])),
               "tilt_y": float(np.rad2deg(m0.tilt_rad[1])), "height": m0.height,
               "distance_offset": 0.0}
    for k, v in (start or {}).items():
        if k not in PARAMETERS:
            raise ParameterError(f"start: unknown parameter {k!r}")
        current[k] = as_scalar(v, f"start[{k!r}]", u.Unit(PARAMETERS[k][0]))
    n_det = len(instrument.detectors)
    for i, m in enumerate(measurements):
        if m.counts.shape[0] != n_det:  # one row per detector, never broadcast
            raise ParameterError(
                f"measurements[{i}].counts must have one row per detector of the instrument "
                f"({n_det}), got {m.counts.shape[0]}")
    theta = np.array([current[n] for n in names])
    k_obs = [m.counts for m in measurements]
    b_obs = [m.background for m in measurements]
    n_m, n_p = len(measurements), len(names)

    def shapes(vec: np.ndarray) -> list[np.ndarray]:
        inst, doff = _with(instrument, {**current, **dict(zip(names, vec, strict=True))})
        return [_profiles(inst, m, doff, model) for m in measurements]

    def best_amplitudes(F: list[np.ndarray], A0: np.ndarray | None = None) -> np.ndarray:
        # For fixed shapes the likelihood's maximum in A solves sum f (k / (A f + b) - 1)
        # = 0: sum(k - b) / sum(f) without background, else a few Newton steps from there.
        out = []
        for i, (k, f, b) in enumerate(zip(k_obs, F, b_obs, strict=True)):
            a = max((k - b).sum(), 1.0) / max(f.sum(), 1e-300) if A0 is None else A0[i]
            for _ in range(50 if b.any() else 0):
                mu = a * f + b
                g = float(np.sum(f * (k / mu - 1.0)))
                h = float(np.sum(f * f * k / mu**2))
                step = g / h if h > 0 else 0.0
                a = max(a + step, 0.5 * a)
                if abs(step) <= 1e-12 * a:
                    break
            out.append(a)
        return np.array(out)

    def loglike(F: list[np.ndarray], A: np.ndarray) -> float:
        total = 0.0
        for k, f, b, a in zip(k_obs, F, b_obs, A, strict=True):
            mu = a * f + b
            if np.any((mu <= 0) & (k > 0)):
                return -np.inf
            with np.errstate(divide="ignore", invalid="ignore"):
                total += float(np.sum(np.where(k > 0, k * np.log(mu), 0.0) - mu))
        return total

    def jacobian(vec: np.ndarray, F: list[np.ndarray]) -> list[np.ndarray]:
        """dF/dp by central differences: list over parameters of per-measurement arrays."""
        out = []
        for j, name in enumerate(names):
            step = PARAMETERS[name][1]
            up, dn = vec.copy(), vec.copy()
            up[j] += step
            dn[j] -= step
            Fu, Fd = shapes(up), shapes(dn)
            out.append([(a - b) / (2 * step) for a, b in zip(Fu, Fd, strict=True)])
        return out

    def fisher(F: list[np.ndarray], A: np.ndarray, dF: list[list[np.ndarray]]
               ) -> tuple[np.ndarray, np.ndarray]:
        """Fisher matrix and score in (parameters, amplitudes)."""
        n = n_p + n_m
        fim = np.zeros((n, n))
        g = np.zeros(n)
        for i, (k, f, b, a) in enumerate(zip(k_obs, F, b_obs, A, strict=True)):
            mu = np.maximum(a * f + b, 1e-300)
            cols = [a * dF[j][i] for j in range(n_p)]
            cols += [f if q == i else np.zeros_like(f) for q in range(n_m)]
            resid = k / mu - 1.0
            for r in range(n):
                g[r] += float(np.sum(cols[r] * resid))
                for c in range(r, n):
                    fim[r, c] += float(np.sum(cols[r] * cols[c] / mu))
        fim = fim + np.triu(fim, 1).T
        return fim, g

    F = shapes(theta)
    A = best_amplitudes(F)
    ll = loglike(F, A)
    if not np.isfinite(ll):
        raise ParameterError(
            "measurements: the model expects no counts in some bins that have counts (an "
            "opaque mask shadowing a detector for a whole bin): give the measured "
            "background (LabMeasurement.background) or start closer to the truth (start=)"
        )
    lam = 1e-3
    history: list[dict[str, float]] = []
    converged = False
    it = 0
    cov = np.full((n_p + n_m, n_p + n_m), np.nan)
    for it in range(1, max_iter + 1):
        dF = jacobian(theta, F)
        fim, g = fisher(F, A, dF)
        try:
            cov = np.linalg.inv(fim)
        except np.linalg.LinAlgError:
            raise ParameterError(
                f"the measurements cannot tell the parameters {list(names)} apart (singular "
                "Fisher matrix); add sources at other distances and directions"
            ) from None
        while True:
            D = np.diag(np.diag(fim))
            step = np.linalg.solve(fim + lam * D, g)
            t_new = theta + step[:n_p]
            try:
                F_new = shapes(t_new)
            except ParameterError:  # a step outside the parameters' domain (e.g. tilt)
                ll_new = -np.inf
            else:
                A_new = best_amplitudes(F_new, A)
                ll_new = loglike(F_new, A_new)
            if ll_new >= ll - 1e-9 * abs(ll):
                break
            if lam > 1e8:
                t_new, F_new, A_new, ll_new = theta, F, A, ll  # no better point nearby
                break
            lam *= 10.0
        sig = np.sqrt(np.abs(np.diag(cov)[:n_p]))
        small = bool(np.all(np.abs(t_new - theta) <= tol * sig))
        theta, F, A, ll = t_new, F_new, A_new, ll_new
        lam = max(lam / 10.0, 1e-6)
        history.append({"loglike": ll, **dict(zip(names, theta.tolist(), strict=True))})
        log.debug("calibration iteration %d: %s, log L = %.6f", it, theta, ll)
        if small:
            converged = True
            break
    # Uncertainties at the optimum.
    fim, _ = fisher(F, A, jacobian(theta, F))
    cov = np.linalg.inv(fim)
    sig = np.sqrt(np.diag(cov))
    dev = 0.0
    n_counts = 0
    for k, f, b, a in zip(k_obs, F, b_obs, A, strict=True):
        mu = a * f + b
        with np.errstate(divide="ignore", invalid="ignore"):
            term = np.where(k > 0, k * np.log(k / mu), 0.0)
        dev += float(2 * np.sum(term - (k - mu)))
        n_counts += k.size
    values = {n: theta[j] * u.Unit(PARAMETERS[n][0]) for j, n in enumerate(names)}
    errors = {n: sig[j] * u.Unit(PARAMETERS[n][0]) for j, n in enumerate(names)}
    inst, doff = _with(instrument, {**current, **dict(zip(names, theta, strict=True))})
    return CalibrationResult(
        names, values, errors, cov[:n_p, :n_p], A, sig[n_p:], inst, doff, ll, dev,
        n_counts - n_p - n_m, it, converged, history,
    )

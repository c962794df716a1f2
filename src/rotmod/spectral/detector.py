"""The energy redistribution of a detector cylinder: what a photon of true energy ``E``
deposits, by Monte Carlo photon transport, folded with the energy resolution.

A photon of energy ``E`` crossing a detector cylinder (:class:`rotmod.geometry.DetectorArray`:
radius ``R``, thickness ``H``, its material; ``-H <= z <= 0``) interacts with probability
``1 - exp(-mu l)``; what it then deposits is a distribution: the full-energy peak, the Compton
continuum, escape peaks.  :func:`simulate_deposits` transports photons of one energy from a
parallel beam at zenith angle ``theta`` (or a point source on the axis) and returns a
:class:`DepositSpectrum`; :func:`tabulate_response` tabulates them on a grid of angles and
energies, folded with :class:`rotmod.energy.EnergyResolution` into channels, as a
:class:`DetectorResponse`.

Normalisation (``docs/detector_response.md``): the *interaction probability* counts
interactions per photon crossing the top face's area with no mask (side entry included, so it
can exceed 1): the ``E0`` of rotmod's thick-detector profile (``docs/physics.md``, "Thick
detectors"), and ``effective_area = pi R^2 cos(theta) E0``.  The *redistribution* is the
distribution of the deposited energy given an interaction; its rows sum to at most 1, the
deficit being interactions that leave nothing in the channels (scattered out with no deposit,
or below the first channel).  Counts per channel = profile x redistribution.

Physics (each approximation with its size in ``docs/detector_response.md``):

* Cross-sections: NIST XCOM partials (:func:`rotmod.materials.partial_attenuation`), on a grid
  uniform in ``ln E`` (1000 points a decade from 1 keV), interpolated linearly in ``ln E``.
* Photoabsorption deposits locally, except a K x-ray of a fluorescing element (table
  :data:`K_FLUORESCENCE`), emitted isotropically and transported, with probability (share of
  that element in the photoabsorption) x (K-shell share ``1 - 1/J``, ``J`` the K-edge jump
  ratio of the XCOM table) x (fluorescence yield).  L-shell x-rays are absorbed locally.
* Compton scattering: free-electron Klein–Nishina angles (Butcher–Messel sampler) at XCOM's
  incoherent rate (which includes binding); no Doppler broadening.
* Pair production (nuclear and electron field): ``E - 2 m c^2`` deposited locally, then two
  511 keV photons back to back, isotropic, from the interaction point.
* Rayleigh scattering: turns the photon with the Thomson law ``(1 + cos^2)``, no form factor
  (too wide; ``rayleigh="forward"``, no deflection, is too narrow: the two bracket it).
* Electrons and positrons deposit their kinetic energy where they are made (no range, no
  bremsstrahlung escape).  Photons below 1 keV are absorbed.
* The crystal is bare: no housing, window or reflector.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import astropy.units as u
import numpy as np
from scipy.special import ndtr

from rotmod._rng import chunk_states, seed_sequence
from rotmod._validate import as_angle, as_angle_scalar, as_energy, as_int, as_scalar
from rotmod.energy import FWHM_PER_SIGMA, EnergyResolution
from rotmod.errors import ParameterError
from rotmod.geometry import DetectorArray
from rotmod.limits import check_time
from rotmod.materials import DATABASE_RANGE_KEV, mass_fractions, partial_attenuation
from rotmod.spectral import _detector_kernels as _k
from rotmod.spectral.spectrum import check_edges

__all__ = [
    "ENERGY_RANGE_KEV",
    "K_FLUORESCENCE",
    "MAX_PHOTONS",
    "DepositSpectrum",
    "DetectorResponse",
    "check_energies",
    "check_energy_detectors",
    "draw_deposits",
    "sample_klein_nishina",
    "simulate_deposits",
    "tabulate_response",
]

#: True photon energies (keV) the transport accepts: below 2 keV every photon is absorbed at
#: the surface; above 30 MeV the local deposit of electrons (no bremsstrahlung escape) is
#: too poor (docs/detector_response.md).
ENERGY_RANGE_KEV = (2.0, 3.0e4)

#: Photons per energy and angle accepted by one call (a guard against typos: 1e9 photons
#: take hours).
MAX_PHOTONS = 200_000_000

#: K-shell fluorescence data of the elements whose K x-rays can escape a detector:
#: symbol -> (fluorescence yield omega_K, ((line energy keV, relative intensity), ...)) for
#: the lines K alpha2, K alpha1, K beta3, K beta1, K beta2 (the K beta1,3 blend for Zn).
#: Energies and intensities (per 100 of K alpha1): X-ray Data Booklet (A. C. Thompson et al.,
#: LBNL, 2009), Tables 1-2 and 1-3, as transcribed in puglet5/XRFViewer
#: (src/data/emission_lines_data.ts); except germanium's K beta1, which the transcription
#: gives as 60 (an outlier: its neighbours As and Se have 13), taken as 13.  Yields: M. O.
#: Krause, J. Phys. Chem. Ref. Data 8, 307 (1979); compilations differ by <= 0.005.
K_FLUORESCENCE: dict[str, tuple[float, tuple[tuple[float, float], ...]]] = {
    "Zn": (0.474, ((8.6158, 51.0), (8.6389, 100.0), (9.5720, 17.0))),
    "Ge": (0.535, ((9.8553, 51.0), (9.8864, 100.0), (10.9780, 6.0), (10.9821, 13.0))),
    "Br": (0.618, ((11.8776, 52.0), (11.9242, 100.0), (13.2845, 7.0), (13.2914, 14.0),
                   (13.4695, 1.0))),
    "Cd": (0.843, ((22.9841, 53.0), (23.1736, 100.0), (26.0612, 9.0), (26.0955, 17.0),
                   (26.6438, 4.0))),
    "Te": (0.875, ((27.2017, 54.0), (27.4723, 100.0), (30.9443, 9.0), (30.9957, 18.0),
                   (31.7004, 5.0))),
    "I": (0.882, ((28.3172, 54.0), (28.6120, 100.0), (32.2394, 9.0), (32.2947, 18.0),
                  (33.0420, 5.0))),
    "Cs": (0.895, ((30.6251, 54.0), (30.9728, 100.0), (34.9194, 9.0), (34.9869, 18.0),
                   (35.8220, 6.0))),
    "La": (0.905, ((33.0341, 54.0), (33.4418, 100.0), (37.7202, 10.0), (37.8010, 19.0),
                   (38.7299, 6.0))),
    "Bi": (0.961, ((74.8148, 60.0), (77.1079, 100.0), (86.834, 12.0), (87.343, 23.0),
                   (89.830, 9.0))),
}

#: Approximate K-edge energies (keV; X-ray Data Booklet Table 1-1) where the XCOM table's
#: jump is looked for.
_K_EDGE_GUESS = {"Zn": 9.6586, "Ge": 11.1031, "Br": 13.4737, "Cd": 26.7112, "Te": 31.8138,
                 "I": 33.1694, "Cs": 35.9846, "La": 38.9246, "Bi": 90.526}

_GRID_PER_DECADE = 1000
_N_CHUNKS = 16


@dataclass(frozen=True)
class _Medium:
    """The tables a transport needs: linear coefficients (1/cm) per process and the
    cumulative K-fluorescence probabilities on the ``ln E`` grid, and the K lines."""

    table: np.ndarray
    ln0: float
    inv_dln: float
    lines: np.ndarray
    elements: tuple[str, ...]
    edges: tuple[float, ...]
    jumps: tuple[float, ...]

    def total(self, energy: np.ndarray) -> np.ndarray:
        """Total linear coefficient (1/cm) at ``energy`` (keV): the kernels' ``_mu_total``
        (the processes' columns interpolated linearly on the ``ln E`` grid, held at its
        ends), for many energies at once."""
        x = (np.log(energy) - self.ln0) * self.inv_dln
        return np.interp(x, np.arange(self.table.shape[0]), self.table[:, :4].sum(axis=1))


def _elements(name: str) -> list[str]:
    """Element symbols of the material ``name`` (a formula, an element or an alias such as
    ``"germanium"``), from the mixture rule's own mass fractions."""
    return sorted(mass_fractions(name))


def _k_edge(symbol: str) -> tuple[float, float]:
    """The K edge (keV) and jump ratio ``J`` of ``symbol``'s XCOM photoabsorption, found as
    the largest ratio of neighbours on a grid 1e-5 apart (relative) around the guess."""
    e = _K_EDGE_GUESS[symbol] * np.geomspace(0.99, 1.01, 2001)
    tau = partial_attenuation(symbol, e)[:, 2]
    ratio = tau[1:] / tau[:-1]
    i = int(np.argmax(ratio))
    return float(e[i + 1]), float(ratio[i])


def _medium(det: DetectorArray, e_max: float) -> _Medium:
    mat = det.material
    assert mat is not None
    lo = DATABASE_RANGE_KEV[0]
    n = math.ceil(math.log10(e_max * 1.01 / lo) * _GRID_PER_DECADE) + 1
    ln0 = math.log(lo)
    dln = math.log(10.0) / _GRID_PER_DECADE
    grid = np.exp(ln0 + dln * np.arange(n))
    grid[-1] = min(grid[-1], DATABASE_RANGE_KEV[1])
    part = partial_attenuation(mat.name, grid) * mat.density
    tau = part[:, 2]
    fl = [s for s in _elements(mat.name) if s in K_FLUORESCENCE]
    cols, lines, edges, jumps = [], [], [], []
    if fl:
        # The mixture rule's weights: the material's photoabsorption is sum_j w_j tau_j.
        frac = mass_fractions(mat.name)
        cum = np.zeros(n)
        for s in fl:
            edge, jump = _k_edge(s)
            omega, ls = K_FLUORESCENCE[s]
            tau_s = frac[s] * partial_attenuation(s, grid)[:, 2] * mat.density
            with np.errstate(divide="ignore", invalid="ignore"):
                share = np.where(tau > 0, tau_s / tau, 0.0)
            p = np.where(grid >= edge, share * (1.0 - 1.0 / jump) * omega, 0.0)
            cum = cum + p
            cols.append(cum.copy())
            inten = np.array([i for _, i in ls])
            cp = np.cumsum(inten) / inten.sum()
            cp[-1] = 1.0
            lines.append([v for (en, _), c in zip(ls, cp, strict=True) for v in (en, c)])
            edges.append(edge)
            jumps.append(jump)
    table = np.ascontiguousarray(np.column_stack([part, *cols]) if cols else part)
    width = max((len(r) for r in lines), default=2)
    # Rows padded with their last line at cumulative probability 1.
    line_arr = np.array([r + r[-2:] * ((width - len(r)) // 2) for r in lines],
                        dtype=float).reshape(len(lines), width)
    return _Medium(table, ln0, 1.0 / dln, line_arr, tuple(fl), tuple(edges), tuple(jumps))


def check_energy_detectors(detectors: Any, name: str = "detectors") -> DetectorArray:
    """``detectors`` if they can have an energy response (the checks every transport of
    photons in the crystal shares), else a :class:`~rotmod.errors.ParameterError` that names
    ``name`` and the rule.

    Parameters
    ----------
    detectors : DetectorArray
    name : str
        What the caller calls them (``"instrument.detectors"``), for the message.

    Returns
    -------
    DetectorArray
        ``detectors``: thick, with a material from the attenuation database.
    """
    if not isinstance(detectors, DetectorArray):
        raise ParameterError(f"{name} must be a DetectorArray, got {type(detectors).__name__}")
    if detectors.thickness <= 0:
        raise ParameterError(
            f"{name}.thickness must be > 0 cm for an energy response (a flat face "
            f"absorbs every photon and has no redistribution), got {detectors.thickness:g} cm"
        )
    if detectors.material is None:
        raise ParameterError(f"{name}.material is required for an energy response")
    if detectors.material.mass_attenuation is not None:
        raise ParameterError(
            f"{name}.material.mass_attenuation must be None for an energy response: a fixed "
            "coefficient has no split into photoabsorption, scattering and pair production"
        )
    return detectors


def check_energies(energy: Any, name: str = "energy") -> np.ndarray:
    """``energy`` (keV) as a 1-D array if every value lies in :data:`ENERGY_RANGE_KEV` (the
    attenuation database's range that photons are transported in), else a
    :class:`~rotmod.errors.ParameterError` that names ``name`` and the rule.

    Parameters
    ----------
    energy : float, array_like or Quantity
    name : str
        What the caller calls it, for the message.

    Returns
    -------
    numpy.ndarray
        The energies in keV, at least 1-D.
    """
    lo, hi = ENERGY_RANGE_KEV
    return as_energy(energy, name, lo=lo, hi=hi, ndim=1)


def _batch_error(num: np.ndarray, den: np.ndarray) -> float:
    """Jackknife standard error of ``sum(num) / sum(den)`` over batches."""
    n = num.size
    tn, td = num.sum(), den.sum()
    if n < 2 or td <= 0:
        return math.nan
    with np.errstate(divide="ignore", invalid="ignore"):
        loo = (tn - num) / (td - den)
    loo = loo[np.isfinite(loo)]
    if loo.size < 2:
        return math.nan
    return float(np.sqrt((loo.size - 1) / loo.size * np.sum((loo - loo.mean()) ** 2)))


@dataclass(frozen=True, eq=False)
class DepositSpectrum:
    """Energy deposits of photons of one true energy in a detector cylinder.

    Attributes
    ----------
    energy : float
        True photon energy (keV).
    theta : float
        Zenith angle of the parallel beam (deg); NaN for a point source.
    distance : float or None
        Height (cm) of the on-axis point source above the top face; None for a parallel beam.
    interaction : float
        Interactions per photon crossing the top face's area (parallel beam: side entry
        included, as rotmod's thick-detector ``E0``; point source: per photon crossing the top
        face, every ray of the cone entering through it).
    interaction_error : float
        Its Monte Carlo standard error.
    edges : numpy.ndarray
        Fine deposit bin edges (keV), ``n_fine + 1`` points on ``[0, energy]``.
    continuum : numpy.ndarray
        Probability, given an interaction, of a deposit in each fine bin below the full
        energy (shape ``(n_fine,)``).
    full_energy : float
        Probability, given an interaction, of depositing the whole energy (the photofraction).
    no_deposit : float
        Probability, given an interaction, of depositing nothing (Rayleigh scattered out).
    n_photons : int
        Primary photons simulated.
    batches : numpy.ndarray
        Per-batch weights ``(n_batches, n_fine + 3)``: continuum bins, full energy, no deposit,
        all interactions (for :meth:`error`).
    solid_angle : float
        Point source: the fraction of 4 pi that crosses the top face; 1 for a parallel beam.
    overflow : float
        Probability, given an interaction, of a deposit above ``energy`` (energy
        conservation: 0; kept as a check).
    """

    energy: float
    theta: float
    distance: float | None
    interaction: float
    interaction_error: float
    edges: np.ndarray
    continuum: np.ndarray
    full_energy: float
    no_deposit: float
    n_photons: int
    batches: np.ndarray = field(repr=False)
    solid_angle: float = 1.0
    overflow: float = 0.0

    @property
    def centres(self) -> np.ndarray:
        """Fine bin centres (keV)."""
        return 0.5 * (self.edges[1:] + self.edges[:-1])

    def above(self, threshold: Any) -> float:
        """Probability, given an interaction, of a deposit ``>= threshold`` keV (fine bins
        counted by their centres; the full-energy peak included)."""
        t = as_scalar(threshold, "threshold", u.keV, lo=0.0)
        return float(self.continuum[self.centres >= t].sum() + self.full_energy)

    def peak_to_total(self, threshold: Any = 0.0, window: Any = 0.0) -> float:
        """Peak deposits over all deposits ``>= threshold`` keV; the peak is the full energy
        plus, with ``window`` > 0, the fine bins within ``window`` keV below it (the K-escape
        lines that a scintillator's resolution merges with the photopeak)."""
        return self.peak_fraction(window) / self.above(threshold)

    def peak_fraction(self, window: Any = 0.0) -> float:
        """Probability, given an interaction, of a deposit in ``[energy - window, energy]``
        (fine bins by their centres; ``window = 0``: the full energy alone)."""
        w = as_scalar(window, "window", u.keV, lo=0.0)
        near = self.centres >= self.energy - w if w > 0 else np.zeros(self.centres.size, bool)
        return float(self.full_energy + self.continuum[near].sum())

    def error(self, what: str, threshold: Any = 0.0, window: Any = 0.0) -> float:
        """Jackknife standard error (over batches) of ``"full_energy"`` (with ``window``:
        :meth:`peak_fraction`), ``"peak_to_total"`` or ``"interaction"``."""
        t = as_scalar(threshold, "threshold", u.keV, lo=0.0)
        w = as_scalar(window, "window", u.keV, lo=0.0)
        b = self.batches
        n_fine = self.continuum.size
        allw = b[:, n_fine + 2]
        near = self.centres >= self.energy - w if w > 0 else np.zeros(n_fine, bool)
        peak = b[:, n_fine] + b[:, :n_fine][:, near].sum(axis=1)
        cont = b[:, :n_fine][:, (self.centres >= t) & ~near].sum(axis=1)
        if what == "full_energy":
            return _batch_error(peak, allw)
        if what == "peak_to_total":
            return _batch_error(peak, peak + cont)
        if what == "interaction":
            return self.interaction_error
        raise ParameterError(
            f"what must be 'full_energy', 'peak_to_total' or 'interaction', got {what!r}"
        )

    def fold(self, channel_edges: Any, resolution: EnergyResolution | None = None) -> np.ndarray:
        """Probability per channel given an interaction.

        Parameters
        ----------
        channel_edges : array_like
            Increasing measured-energy edges (keV), ``n_ch + 1`` of them, the first >= 0.
        resolution : EnergyResolution, optional
            Gaussian resolution; each fine bin (at its centre) and the full-energy line
            spread as ``N(E, FWHM(E)/2.355)``, integrated over each channel exactly
            (``ndtr`` differences).  None: the fine bins' centres are binned as they are.

        Returns
        -------
        numpy.ndarray
            Shape ``(n_ch,)``; sums to at most 1.
        """
        ch = check_edges(channel_edges, "channel_edges")
        return _fold(self.centres, self.continuum, self.energy, self.full_energy, ch,
                     resolution)


def _fold(centres: np.ndarray, cont: np.ndarray, energy: float, full: float, ch: np.ndarray,
          resolution: EnergyResolution | None) -> np.ndarray:
    keep = cont > 0
    c = np.append(centres[keep], energy)
    m = np.append(cont[keep], full)
    if resolution is None:
        out, _ = np.histogram(c, bins=ch, weights=m)
        return out
    sig = resolution.fwhm(np.maximum(c, 1e-6)) / FWHM_PER_SIGMA
    cdf = ndtr((ch[None, :] - c[:, None]) / sig[:, None])
    return m @ np.diff(cdf, axis=1)


def simulate_deposits(
    detectors: DetectorArray,
    energy: Any,
    theta: Any = 0.0,
    *,
    distance: Any = None,
    n_photons: int = 100_000,
    n_fine: int = 1024,
    forced: bool = True,
    rayleigh: str = "thomson",
    seed: Any = None,
) -> DepositSpectrum:
    """Monte Carlo of the energy deposits of photons of one energy in one detector.

    Parameters
    ----------
    detectors : DetectorArray
        Gives the cylinder: diameter, thickness (> 0) and material (with a density; the
        database's partial cross-sections, no fixed coefficient).
    energy : float or Quantity
        True photon energy (keV), within :data:`ENERGY_RANGE_KEV`.
    theta : float or Quantity
        Zenith angle of the parallel beam (deg), ``0 <= theta < 90``.
    distance : float or Quantity, optional
        Instead of a parallel beam, a point source on the axis this far above the top face
        (cm, > 0); ``theta`` must then be 0.
    n_photons : int
        Primary photons (each crossing the shadow of the cylinder, or the top face for a
        point source), 100 to :data:`MAX_PHOTONS`.
    n_fine : int
        Fine deposit bins on ``[0, energy]`` (16 to 65536).
    forced : bool
        Force the first interaction (each ray weighted by ``1 - exp(-mu l)``: the
        interaction probability then has only the rays' geometric variance).  False: analog.
    rayleigh : {"thomson", "forward"}
        Angular law of Rayleigh scattering: Thomson's ``1 + cos^2`` (no form factor: too
        wide) or no deflection (too narrow); the two bracket the truth (docs).
    seed : None, int, SeedSequence or Generator

    Returns
    -------
    DepositSpectrum
    """
    det = check_energy_detectors(detectors)
    e = float(check_energies(energy)[0]) if np.ndim(energy) == 0 else None
    if e is None:
        raise ParameterError("energy must be a scalar for simulate_deposits; use "
                             "tabulate_response for a grid")
    th = as_angle_scalar(theta, "theta", lo=0.0, hi=90.0, hi_open=True)
    n = as_int(n_photons, "n_photons", 100, MAX_PHOTONS)
    nf = as_int(n_fine, "n_fine", 16, 65536)
    if not isinstance(forced, bool | np.bool_):
        raise ParameterError(f"forced must be True or False, got {forced!r}")
    if rayleigh not in ("thomson", "forward"):
        raise ParameterError(f"rayleigh must be 'thomson' or 'forward', got {rayleigh!r}")
    dist = None
    if distance is not None:
        dist = as_scalar(distance, "distance", u.cm, lo=0.0, lo_open=True)
        if th != 0.0:
            raise ParameterError(
                f"theta must be 0 with a point source (distance), got {math.degrees(th):g} deg"
            )
    med = _medium(det, e)
    return _run(det, med, e, th, dist, n, nf, bool(forced), seed_sequence(seed),
                rayleigh == "thomson")


def _run(det: DetectorArray, med: _Medium, e: float, th: float, dist: float | None, n: int,
         nf: int, forced: bool, root: np.random.SeedSequence,
         thomson: bool = True) -> DepositSpectrum:
    m = min(_N_CHUNKS, n)
    nphot = np.full(m, n // m, dtype=np.int64)
    nphot[: n % m] += 1
    states = chunk_states(root, m)
    hist = np.zeros((m, nf))
    tally = np.zeros((m, 5))
    R, H = det.radius, det.thickness
    _k.deposit_kernel(states, nphot, e, np.int64(0 if dist is None else 1), math.sin(th),
                      math.cos(th), 1.0 if dist is None else dist, R, H, forced, med.table,
                      med.ln0, med.inv_dln, np.int64(med.lines.shape[0]), med.lines, 1.0,
                      thomson, hist, tally)
    if dist is None:
        # Rays were drawn uniformly over the shadow; per photon crossing the top face's
        # area, scale by shadow area / face area.
        geom = 1.0 + 2.0 * H * math.tan(th) / (math.pi * R)
        solid = 1.0
    else:
        geom = 1.0
        solid = 0.5 * (1.0 - dist / math.hypot(dist, R))
    sw, sw2 = tally[:, 0].sum(), tally[:, 1].sum()
    mean = sw / n
    var = max(sw2 / n - mean * mean, 0.0) / max(n - 1, 1)
    total = sw if sw > 0 else 1.0
    batches = np.column_stack([hist, tally[:, 2], tally[:, 3], tally[:, 0]])
    return DepositSpectrum(
        energy=e, theta=math.nan if dist is not None else math.degrees(th), distance=dist,
        interaction=geom * mean, interaction_error=geom * math.sqrt(var),
        edges=np.linspace(0.0, e, nf + 1), continuum=hist.sum(axis=0) / total,
        full_energy=float(tally[:, 2].sum() / total), no_deposit=float(tally[:, 3].sum() / total),
        n_photons=n, batches=batches, solid_angle=solid,
        overflow=float(tally[:, 4].sum() / total),
    )


@dataclass(frozen=True, eq=False)
class DetectorResponse:
    """A detector's energy response tabulated on zenith angles and true energies.

    ``interaction[a, i]`` are interactions per photon crossing the top face's area (the
    thick-detector ``E0``) at ``angles[a]``, ``energies[i]``; ``matrix[a, i, c]`` the
    probability, given an interaction, of a count in channel ``c`` (rows sum to <= 1).  The
    expected counts per channel of a photon flux are ``profile x matrix`` (profile on the
    same normalisation, see :mod:`rotmod.spectral.detector`).

    Attributes
    ----------
    angles : numpy.ndarray
        Zenith angles (deg), increasing.
    energies : numpy.ndarray
        True energies (keV), increasing.
    channel_edges : numpy.ndarray
        Measured-energy channel edges (keV).
    interaction, interaction_error : numpy.ndarray
        Shape ``(n_angles, n_energies)``.
    matrix : numpy.ndarray
        Shape ``(n_angles, n_energies, n_channels)``.
    full_energy : numpy.ndarray
        Photofraction (full-energy deposits per interaction), ``(n_angles, n_energies)``.
    resolution : EnergyResolution or None
    n_photons : int
        Photons per (angle, energy).
    detectors : DetectorArray or None
        The detector it was tabulated for (its diameter, thickness and material; a response
        of the modulator checks it against the instrument's).
    """

    angles: np.ndarray
    energies: np.ndarray
    channel_edges: np.ndarray
    interaction: np.ndarray
    interaction_error: np.ndarray
    matrix: np.ndarray
    full_energy: np.ndarray
    resolution: EnergyResolution | None
    n_photons: int
    detectors: DetectorArray | None = None

    @property
    def energy_edges(self) -> np.ndarray:
        """True-energy bins around the nodes :attr:`energies`: the geometric midpoints, the
        outer edges as far (in log) beyond the end nodes as the nearest midpoints: where a
        diffuse background's photons in bin ``i`` are counted with the response at node ``i``
        (:mod:`rotmod.spectral.background`; a source's spectrum is split between nodes,
        :meth:`rotmod.spectral.SpectralModel.node_weights`)."""
        if self.energies.size < 2:
            raise ParameterError("a detector response needs two or more energies for bins")
        ln = np.log(self.energies)
        mid = 0.5 * (ln[1:] + ln[:-1])
        return np.exp(np.concatenate([[2 * ln[0] - mid[0]], mid, [2 * ln[-1] - mid[-1]]]))

    def _weights(self, theta: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Grid neighbours ``i, j``, the fraction in theta and the angles (deg)."""
        deg = np.degrees(as_angle(theta, "theta", lo=float(self.angles[0]),
                                  hi=float(self.angles[-1]), ndim=1))
        if self.angles.size == 1:
            z = np.zeros(deg.size, dtype=int)
            return z, z, np.zeros(deg.size), deg
        i = np.clip(np.searchsorted(self.angles, deg, side="right") - 1, 0,
                    self.angles.size - 2)
        f = (deg - self.angles[i]) / (self.angles[i + 1] - self.angles[i])
        return i, i + 1, f, deg

    def interaction_at(self, theta: Any) -> np.ndarray:
        """Interaction probability at zenith angles ``theta`` (deg): shape
        ``(n_theta, n_energies)``, linear in ``tan(theta)`` between grid angles (exact for
        the side-entry term ``2 H tan(theta) / (pi R)`` of a black detector)."""
        i, j, _, deg = self._weights(theta)
        if self.angles.size == 1:
            return self.interaction[i]
        ti, tj = np.tan(np.radians(self.angles[i])), np.tan(np.radians(self.angles[j]))
        f = ((np.tan(np.radians(deg)) - ti) / (tj - ti))[:, None]
        return (1 - f) * self.interaction[i] + f * self.interaction[j]

    def matrix_at(self, theta: Any) -> np.ndarray:
        """Redistribution at zenith angles ``theta`` (deg), linear in ``theta`` between grid
        angles: shape ``(n_theta, n_energies, n_channels)``."""
        i, j, f, _ = self._weights(theta)
        f = f[:, None, None]
        return (1 - f) * self.matrix[i] + f * self.matrix[j]

    def angle_weights(self, theta: Any) -> np.ndarray:
        """The weights of the tabulated angles in :meth:`matrix_at`: ``h[n, a]`` with
        ``matrix_at(theta)[n] = sum_a h[n, a] matrix[a]`` (the hat functions of linear
        interpolation in ``theta``: two non-zero weights summing to 1 per angle), shape
        ``(n_theta, n_angles)``."""
        i, j, f, _ = self._weights(theta)
        h = np.zeros((f.size, self.angles.size))
        rows = np.arange(f.size)
        np.add.at(h, (rows, i), 1.0 - f)
        np.add.at(h, (rows, j), f)
        return h

    def counts_per_photon(self, theta: Any) -> np.ndarray:
        """Expected counts per channel per photon crossing the top face's area with no mask:
        ``interaction_at x matrix_at``, shape ``(n_theta, n_energies, n_channels)``."""
        return self.interaction_at(theta)[:, :, None] * self.matrix_at(theta)


def tabulate_response(
    detectors: DetectorArray,
    energies: Any,
    angles: Any,
    channel_edges: Any,
    *,
    resolution: EnergyResolution | None = None,
    n_photons: int = 20_000,
    n_fine: int = 1024,
    rayleigh: str = "thomson",
    seed: Any = None,
) -> DetectorResponse:
    """Tabulate a detector's response (interaction probability and redistribution).

    Parameters
    ----------
    detectors : DetectorArray
        The cylinder (see :func:`simulate_deposits`).
    energies : array_like or Quantity
        True energies (keV), increasing, within :data:`ENERGY_RANGE_KEV`.
    angles : array_like or Quantity
        Zenith angles (deg), increasing, in ``[0, 90)``.
    channel_edges : array_like
        Measured-energy channel edges (keV), increasing.
    resolution : EnergyResolution, optional
        Gaussian resolution to fold with (None: none).
    n_photons : int
        Photons per (angle, energy).
    n_fine : int
        Fine deposit bins per energy.
    rayleigh : {"thomson", "forward"}
        See :func:`simulate_deposits`.
    seed : None, int, SeedSequence or Generator

    Returns
    -------
    DetectorResponse
    """
    det = check_energy_detectors(detectors)
    e = check_energies(energies, "energies")
    if np.any(np.diff(e) <= 0):
        raise ParameterError("energies must increase strictly")
    ang = np.degrees(as_angle(angles, "angles", lo=0.0, hi=90.0, hi_open=True, ndim=1))
    if np.any(np.diff(ang) <= 0):
        raise ParameterError("angles must increase strictly")
    ch = check_edges(channel_edges, "channel_edges")
    if resolution is not None and not isinstance(resolution, EnergyResolution):
        raise ParameterError(
            f"resolution must be an EnergyResolution or None, got {type(resolution).__name__}"
        )
    n = as_int(n_photons, "n_photons", 100, MAX_PHOTONS)
    nf = as_int(n_fine, "n_fine", 16, 65536)
    if rayleigh not in ("thomson", "forward"):
        raise ParameterError(f"rayleigh must be 'thomson' or 'forward', got {rayleigh!r}")
    med = _medium(det, float(e[-1]))
    roots = seed_sequence(seed).spawn(ang.size * e.size)
    inter = np.empty((ang.size, e.size))
    err = np.empty_like(inter)
    full = np.empty_like(inter)
    mat = np.empty((ang.size, e.size, ch.size - 1))
    for a, t in enumerate(ang):
        for i, ei in enumerate(e):
            s = _run(det, med, float(ei), math.radians(t), None, n, nf, True,
                     roots[a * e.size + i], rayleigh == "thomson")
            inter[a, i] = s.interaction
            err[a, i] = s.interaction_error
            full[a, i] = s.full_energy
            mat[a, i] = _fold(s.centres, s.continuum, s.energy, s.full_energy, ch, resolution)
    return DetectorResponse(ang, e, ch, inter, err, mat, full, resolution, n, det)


def draw_deposits(
    detectors: DetectorArray,
    energies: Any,
    theta: Any = 0.0,
    *,
    rayleigh: str = "thomson",
    seed: Any = None,
) -> np.ndarray:
    """The energy each of a list of interacting photons deposits, photon by photon.

    For each true energy ``energies[i]``, primaries of that energy in a parallel beam at
    zenith angle ``theta`` (the detector's face lit uniformly, as :func:`simulate_deposits`)
    are transported, analog, until one interacts; its deposit (keV, its secondaries
    included) is returned.  So the deposits follow the redistribution *given an
    interaction*, with no histogram and no table: a photon-by-photon Monte Carlo hands the
    photons it counted in a detector (e.g. :func:`rotmod.montecarlo.simulate_profiles`) to
    it.  A deposit of 0 is an interaction that left nothing (Rayleigh scattered out).

    Parameters
    ----------
    detectors : DetectorArray
        The cylinder (see :func:`simulate_deposits`).
    energies : array_like or Quantity, shape (n,)
        True energies (keV) of the interacting photons, within :data:`ENERGY_RANGE_KEV`;
        at most :data:`MAX_PHOTONS`.
    theta : float or Quantity
        Zenith angle of the beam (deg), ``0 <= theta < 90``.
    rayleigh : {"thomson", "forward"}
        See :func:`simulate_deposits`.
    seed : None, int, SeedSequence or Generator
        Results depend on the seed, not on the number of threads.

    Returns
    -------
    numpy.ndarray
        Deposited energies (keV), shape ``(n,)``, each in ``[0, energies[i]]``.
    """
    det = check_energy_detectors(detectors)
    # A copy: a read-only array (e.g. PointSources.energy) is another type to numba, and
    # would compile the kernel a second time.
    e = np.array(check_energies(energies, "energies"), dtype=np.float64, order="C")
    if e.size > MAX_PHOTONS:
        raise ParameterError(f"energies must hold at most {MAX_PHOTONS} photons, got {e.size}")
    th = as_angle_scalar(theta, "theta", lo=0.0, hi=90.0, hi_open=True)
    if rayleigh not in ("thomson", "forward"):
        raise ParameterError(f"rayleigh must be 'thomson' or 'forward', got {rayleigh!r}")
    out = np.zeros(e.size)
    if e.size == 0:
        return out
    med = _medium(det, float(e.max()))
    # Each photon costs ~1/P primaries (analog: drawn until one interacts), P = 1 -
    # exp(-mu l) with l the mean chord of the lit cylinder (volume / projected area,
    # Cauchy); by Jensen that P is an upper bound, so the estimate is a lower bound.  A
    # primary that does not interact costs about one Monte Carlo photon through a geometry.
    # mu is the transport's own (its table, interpolated as the kernel does: cheap beside
    # the database's, on the chain's every batch).
    chord = (det.radius * det.thickness * math.pi
             / (math.pi * det.radius * math.cos(th) + 2.0 * det.thickness * math.sin(th)))
    p_hit = -np.expm1(-med.total(e) * chord)
    check_time(float(np.sum(1.0 / np.maximum(p_hit, 1e-300))), "mc_photons",
               f"energies: {e.size} photons interacting in a detector {det.thickness:g} cm "
               f"thick (down to {float(p_hit.min()):.2g} of the primaries interact, so each "
               "photon needs up to "
               f"{1.0 / max(float(p_hit.min()), 1e-300):.3g} primaries)",
               hint="fewer photons, or a thicker detector")
    m = min(_N_CHUNKS, e.size)
    bounds = np.linspace(0, e.size, m + 1).round().astype(np.int64)
    _k.draw_kernel(chunk_states(seed_sequence(seed), m), bounds, e, math.sin(th),
                   math.cos(th), det.radius, det.thickness, med.table, med.ln0, med.inv_dln,
                   np.int64(med.lines.shape[0]), med.lines, 1.0, rayleigh == "thomson", out)
    return out


def sample_klein_nishina(energy: Any, n: int, seed: Any = None) -> tuple[np.ndarray, np.ndarray]:
    """``n`` Compton scatterings of photons of ``energy`` (keV) by the transport's sampler:
    ``(E'/E, cos theta)`` (for checks against the Klein–Nishina cross-section)."""
    e = float(as_energy(energy, "energy"))
    n = as_int(n, "n", 1, MAX_PHOTONS)
    eps = np.empty(n)
    cos = np.empty(n)
    _k.compton_many(chunk_states(seed_sequence(seed), 4), e / _k.ME_KEV, n, eps, cos)
    return eps, cos

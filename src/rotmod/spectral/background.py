"""The background of a balloon-borne instrument: diffuse photon intensities and their counts.

Components (docs/background.md gives every formula with its source and validity):

* **Cosmic diffuse background** (CXB/CGB), isotropic above the atmosphere: the analytic fit of
  Gruber et al. (1999, ApJ 520, 124), 3 keV - 100 GeV, attenuated along each direction by the
  air above the balloon (:meth:`rotmod.spectral.atmosphere.Atmosphere.transmission`).
* **Atmospheric continuum**, downward and upward (albedo), and the **511 keV annihilation
  line**: the balloon-altitude parameterisation of Mizuno et al. (2004, ApJ 614, 1113) for
  Palestine, Texas (cutoff rigidity 4.46 GV), with the zenith-angle dependence based on
  Schoenfelder et al. (1977), as transcribed in the Fermi-LAT CRflux code
  (``CrGammaSecondaryDownward.cxx``/``CrGammaSecondaryUpward.cxx``).  Depth dependence,
  derived (docs): downward intensity proportional to the depth ``X`` (valid for thin
  overburdens, ``X`` well below the cascade's ~100 g/cm^2 attenuation length), upward
  intensity independent of ``X``.
* **Detector-internal** background: a user-set counts spectrum (e.g. a power law plus
  activation lines) whose normalisation is fitted; no universal value exists.

Folding (:func:`diffuse_rates`): a diffuse intensity ``I(E, z)`` (photons cm^-2 s^-1 sr^-1
keV^-1, azimuth-symmetric in the local vertical frame) gives in one bare cylinder (radius
``R``, thickness ``H``) the counts per second in channel ``c``

    r_c = int dOmega int dE  I(E, z)  A(theta)  q(theta, E)  M(theta; E -> c),

``theta = z`` for ``z < 90`` (top face) and ``180 - z`` for ``z > 90`` (bottom face: a bare
cylinder is symmetric), ``A = pi R^2 cos(theta) + 2 R H sin(theta)`` the projected area and
``q = E0 / (1 + 2 H tan(theta) / (pi R))`` the interactions per photon crossing the shadow
(``E0`` the response's interactions per photon crossing the top face's area), ``M`` the
redistribution.  The mask's modulation of a diffuse background is ignored (unmodulated to
first order); its mean opacity reduces the downward part by an optional factor.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import minimize
from scipy.special import erf

from rotmod._validate import as_angle, as_array, as_energy, as_scalar
from rotmod.errors import ParameterError
from rotmod.geometry import DetectorArray, Mask
from rotmod.spectral.atmosphere import Atmosphere
from rotmod.spectral.detector import DetectorResponse
from rotmod.spectral.models import SpectralModel
from rotmod.spectral.spectrum import check_edges

__all__ = [
    "ANNIHILATION_DOWN",
    "ANNIHILATION_UP",
    "CXB_RANGE_KEV",
    "MIZUNO_DEPTH",
    "MIZUNO_RANGE_KEV",
    "BalloonBackground",
    "angular_shape_downward",
    "angular_shape_upward",
    "annihilation_line",
    "atmospheric_continuum",
    "cxb_intensity",
    "diffuse_rates",
    "fit_normalisations",
    "internal_rates",
    "mask_transmission",
]

#: Energies (keV) of Gruber et al. (1999)'s fit: 3 keV to 100 GeV.
CXB_RANGE_KEV = (3.0, 1.0e8)
#: Energies (keV) of Mizuno et al. (2004)'s atmospheric gamma-ray model: 30 keV to 100 GeV.
MIZUNO_RANGE_KEV = (30.0, 1.0e8)
#: Atmospheric depth (g/cm^2) at which the Mizuno et al. (2004) balloon model applies.  The
#: GLAST balloon flight engineering model's float depth, 3.8 g/cm^2, is recalled, not read in
#: the paper here: check Mizuno et al. 2004, Sect. 2, before relying on it (a parameter).
MIZUNO_DEPTH = 3.8
#: 511 keV line at 3.8 g/cm^2 (Mizuno et al. 2004): vertically downward and vertically
#: upward intensities, photons cm^-2 s^-1 sr^-1 (70.5 and 470 per m^2).
ANNIHILATION_DOWN = 70.5e-4
ANNIHILATION_UP = 470.0e-4
#: m^-2 MeV^-1 -> cm^-2 keV^-1.
_PER_M2_MEV = 1.0e-7
#: Relative intensity of the upward component at the nadir (Schoenfelder-based shape).
_NADIR = 20.0 / 3.0
_GL_X, _GL_W = np.polynomial.legendre.leggauss(16)
_GLE_X, _GLE_W = np.polynomial.legendre.leggauss(6)
#: Zenith-angle breaks of the angular shapes (deg), where the quadrature is split.
_THETA_BREAKS = (0.0, 40.0, 60.0, 65.0, 80.0, 86.0, 90.0)


# -- the cosmic diffuse background ---------------------------------------------------------


def cxb_intensity(energy: Any) -> np.ndarray:
    """Cosmic diffuse X- and gamma-ray intensity above the atmosphere (Gruber et al. 1999).

    ``E I(E)`` (keV cm^-2 s^-1 sr^-1 keV^-1) is ``7.877 E^-0.29 exp(-E/41.13)`` for
    ``3 <= E <= 60`` keV and ``0.0259 (E/60)^-5.5 + 0.504 (E/60)^-1.58 + 0.0288 (E/60)^-1.05``
    above; this returns the photon intensity ``I(E)``.

    Parameters
    ----------
    energy : float, array_like or Quantity
        keV, within :data:`CXB_RANGE_KEV`.

    Returns
    -------
    numpy.ndarray
        photons cm^-2 s^-1 sr^-1 keV^-1.
    """
    e = as_energy(energy, "energy", lo=CXB_RANGE_KEV[0], hi=CXB_RANGE_KEV[1], lo_open=False)
    return _cxb(e)


def _cxb(e: np.ndarray) -> np.ndarray:
    x = e / 60.0
    low = 7.877 * e**-0.29 * np.exp(-e / 41.13)
    high = 0.0259 * x**-5.5 + 0.504 * x**-1.58 + 0.0288 * x**-1.05
    return np.where(e <= 60.0, low, high) / e


# -- the atmosphere's own gamma rays -------------------------------------------------------


def angular_shape_downward(zenith: Any) -> np.ndarray:
    """Zenith dependence of the downward atmospheric intensity, 1 at the zenith
    (Mizuno et al. 2004 after Schoenfelder et al. 1977): ``1/cos z`` to 60 deg, then
    ``0.1676 exp(2.368 z)`` (z in rad) to 90 deg; 0 below the horizon."""
    z = as_angle(zenith, "zenith", lo=0.0, hi=180.0)
    return _down_shape(z)


def _down_shape(z: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore", over="ignore"):
        near = 1.0 / np.cos(np.minimum(z, np.pi / 3))
    far = 0.1676 * np.exp(2.368 * z)
    return np.where(z <= np.pi / 3, near, np.where(z <= np.pi / 2, far, 0.0))


def angular_shape_upward(zenith: Any) -> np.ndarray:
    """Zenith dependence of the upward (albedo) intensity, 1 at the nadir (Mizuno et al.
    2004 after Schoenfelder et al. 1977): ``g(z) / (20/3)`` with ``g = 0.2067 exp(2.263 z)``
    for 90-115 deg, ``2590.67 exp(-2.441 z)`` for 115-140 deg and ``20/3`` beyond (z in rad,
    breaks at 2.007 and 2.443 rad); 0 above the horizon."""
    z = as_angle(zenith, "zenith", lo=0.0, hi=180.0)
    return _up_shape(z)


def _up_shape(z: np.ndarray) -> np.ndarray:
    g = np.where(z <= 2.007, 0.2067 * np.exp(2.263 * z),
                 np.where(z <= 2.443, 2590.67 * np.exp(-2.441 * z), _NADIR))
    return np.where(z > np.pi / 2, g / _NADIR, 0.0)


def _down_spectrum(e: np.ndarray) -> np.ndarray:
    """Vertically downward continuum at the reference depth, photons cm^-2 s^-1 sr^-1 keV^-1."""
    m = e / 1000.0
    low = 250.0 * m**-1.34
    with np.errstate(over="ignore"):
        mid = 250.0 * m**-1.70 + 1.14e5 * m**-2.5 * np.exp(-((m / 120.0) ** -1.5))
    high = 2.15e4 * m**-2.20
    return _PER_M2_MEV * np.where(m <= 1.0, low, np.where(m <= 1000.0, mid, high))


def _up_spectrum(e: np.ndarray) -> np.ndarray:
    """Vertically upward continuum, photons cm^-2 s^-1 sr^-1 keV^-1."""
    m = e / 1000.0
    low = 1670.0 * m**-1.34
    mid = 1670.0 * m**-1.70
    high = 5.29e4 * m**-2.20
    return _PER_M2_MEV * np.where(m <= 1.0, low, np.where(m <= 1000.0, mid, high))


def _depth(depth: Any, reference_depth: Any) -> tuple[np.ndarray, float]:
    x = as_array(depth, "depth", lo=0.0)
    x0 = as_scalar(reference_depth, "reference_depth", lo=0.0, lo_open=True)
    if np.any(x > 30.0):
        raise ParameterError(
            f"depth must be <= 30 g/cm2 (the thin-overburden scaling of the atmospheric "
            f"model), got {float(np.max(x)):g} g/cm2")
    return x, x0


def atmospheric_continuum(energy: Any, zenith: Any, depth: Any, *,
                          reference_depth: Any = MIZUNO_DEPTH) -> np.ndarray:
    """Atmospheric gamma-ray continuum intensity at a balloon (Mizuno et al. 2004).

    Downward (``z < 90``): ``S_down(E) f_down(z) X / X_ref``; upward: ``S_up(E) f_up(z)``.

    Parameters
    ----------
    energy : float, array_like or Quantity
        keV, within :data:`MIZUNO_RANGE_KEV`.
    zenith : float, array_like or Quantity
        Arrival direction's zenith angle (deg if plain), 0-180 (above 90: from below).
    depth : float or array_like
        Atmospheric depth above the balloon (g/cm^2), 0-30.
    reference_depth : float
        Depth of the parameterisation (g/cm^2; :data:`MIZUNO_DEPTH`).

    Returns
    -------
    numpy.ndarray
        photons cm^-2 s^-1 sr^-1 keV^-1, broadcast over the three inputs.
    """
    e = as_energy(energy, "energy", lo=MIZUNO_RANGE_KEV[0], hi=MIZUNO_RANGE_KEV[1],
                  lo_open=False)
    z = as_angle(zenith, "zenith", lo=0.0, hi=180.0)
    x, x0 = _depth(depth, reference_depth)
    try:
        return (_down_spectrum(e) * _down_shape(z) * (x / x0)
                + _up_spectrum(e) * _up_shape(z))
    except ValueError as exc:
        raise ParameterError("energy, zenith and depth must broadcast together") from exc


def annihilation_line(zenith: Any, depth: Any, *,
                      reference_depth: Any = MIZUNO_DEPTH) -> np.ndarray:
    """Intensity of the atmospheric 511 keV line (photons cm^-2 s^-1 sr^-1), Mizuno et al.
    (2004): ``70.5e-4 f_down(z) X / X_ref`` downward and ``470e-4 f_up(z)`` upward."""
    z = as_angle(zenith, "zenith", lo=0.0, hi=180.0)
    x, x0 = _depth(depth, reference_depth)
    return ANNIHILATION_DOWN * _down_shape(z) * (x / x0) + ANNIHILATION_UP * _up_shape(z)


# -- the mask's mean transmission of a diffuse field ------------------------------------------


def mask_transmission(mask: Mask, zenith: Any) -> np.ndarray:
    """Mean geometric transmission of a rotating mask of *opaque* slats for photons arriving
    from zenith angle ``z`` (< 90 deg), averaged over azimuth (the mask turns).

    A ray at ``z`` crossing the slat pattern at azimuth ``phi`` to the slats' normal is
    shadowed over ``h tan(z) |cos phi|`` of each gap (``h`` the slats' thickness), so a gap of
    width ``g`` passes ``max(0, g - c |cos phi|)`` with ``c = h tan z``.  Averaged over
    ``phi``: ``g - 2c/pi`` for ``c <= g``, else ``(2/pi) [g (pi/2 - phi0) - c (1 - sin phi0)]``
    with ``cos phi0 = g/c``.  Summed over the gaps of one period and divided by the period.
    The slats' own transparency (their material at high energy), the mask's outline and tilt
    are ignored: an upper bound on the opacity.

    Parameters
    ----------
    mask : Mask
    zenith : float, array_like or Quantity
        deg if plain, 0-180; 0 returned from 90 deg on (the mask is above the detectors).
    """
    if not isinstance(mask, Mask):
        raise ParameterError(f"mask must be a Mask, got {type(mask).__name__}")
    z = as_angle(zenith, "zenith", lo=0.0, hi=180.0)
    return _mask_transmission(mask, z)


def _mask_transmission(mask: Mask, z: np.ndarray) -> np.ndarray:
    edges = mask.edges
    period = float(mask.period)
    starts, ends = edges[0::2], edges[1::2]
    gaps = np.append(starts[1:] - ends[:-1], starts[0] + period - ends[-1])
    zz = np.minimum(z, np.pi / 2 - 1e-12)
    c = float(mask.thickness) * np.tan(zz)[..., None]
    g = gaps[gaps > 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        phi0 = np.arccos(np.clip(g / np.maximum(c, 1e-300), -1.0, 1.0))
    wide = g - 2.0 * c / np.pi
    narrow = (2.0 / np.pi) * (g * (np.pi / 2 - phi0) - c * (1.0 - np.sin(phi0)))
    out = np.where(c <= g, wide, narrow).sum(axis=-1) / period
    return np.where(z < np.pi / 2, out, 0.0)


# -- folding through a detector -------------------------------------------------------------


def _theta_nodes() -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Legendre nodes in theta (rad) on [0, 90 deg] split at the shapes' breaks, and
    weights including ``2 pi sin(theta)``."""
    b = np.radians(_THETA_BREAKS)
    lo, hi = b[:-1, None], b[1:, None]
    t = (0.5 * (hi - lo) * _GL_X + 0.5 * (hi + lo)).ravel()
    w = (0.5 * (hi - lo) * _GL_W).ravel() * 2.0 * np.pi * np.sin(t)
    return t, w


def _kernel(response: DetectorResponse, detectors: DetectorArray,
            theta: np.ndarray) -> np.ndarray:
    """``A(theta) q(theta, E) M(theta; E -> c)``: counts per (photon cm^-2) per direction,
    shape ``(n_theta, n_e, n_c)``.  Beyond the response's last angle ``q`` and ``M`` are held
    at their last values (the projected area keeps its exact form)."""
    R, H = float(detectors.radius), float(detectors.thickness)
    deg = np.degrees(theta)
    lim = np.clip(deg, response.angles[0], response.angles[-1])
    tl = np.radians(lim)
    shadow = 1.0 + 2.0 * H * np.tan(tl) / (np.pi * R)
    q = response.interaction_at(lim) / shadow[:, None]
    area = np.pi * R * R * np.cos(theta) + 2.0 * R * H * np.sin(theta)
    return (area[:, None] * q)[:, :, None] * response.matrix_at(lim)


def diffuse_rates(intensity: Callable[[np.ndarray, np.ndarray], np.ndarray],
                  response: DetectorResponse, detectors: DetectorArray, *,
                  downward_factor: float | Callable[[np.ndarray], np.ndarray] = 1.0,
                  upward: bool = True,
                  line: tuple[float, float] | None = None) -> np.ndarray:
    """Counts per second per channel in one bare detector from a diffuse intensity.

    Parameters
    ----------
    intensity : callable
        ``intensity(energy, zenith)`` with ``energy`` (keV) of shape ``(1, n)`` and ``zenith``
        (rad) of shape ``(m, 1)``, returning photons cm^-2 s^-1 sr^-1 keV^-1 of shape
        ``(m, n)``; with ``line``, photons cm^-2 s^-1 sr^-1 of shape ``(m, 1)``.
    response : DetectorResponse
        The detector's tabulated response (angles from 0 deg; true-energy bins between the
        geometric midpoints of its nodes).
    detectors : DetectorArray
        The cylinder the response belongs to (radius, thickness).
    downward_factor : float or callable
        Multiplies the downward half (the mask's mean transmission), in [0, 1]; or a function
        of the zenith angle (rad, array) giving it per direction (:func:`mask_transmission`).
    upward : bool
        Include the directions from below (the bottom face).
    line : (mu, sigma), optional
        The intensity is a Gaussian line at ``mu`` keV of width ``sigma`` keV: its photons
        are shared among the true-energy bins exactly.

    Returns
    -------
    numpy.ndarray
        Shape ``(n_channels,)``, counts s^-1.
    """
    if not isinstance(response, DetectorResponse):
        raise ParameterError(
            f"response must be a DetectorResponse, got {type(response).__name__}")
    if not isinstance(detectors, DetectorArray):
        raise ParameterError(
            f"detectors must be a DetectorArray, got {type(detectors).__name__}")
    if not callable(downward_factor) and not 0.0 <= downward_factor <= 1.0:
        raise ParameterError(f"downward_factor must be in [0, 1], got {downward_factor!r}")
    if response.angles[0] != 0.0:
        raise ParameterError("response.angles must start at 0 deg for a diffuse background")
    theta, w = _theta_nodes()
    kern = _kernel(response, detectors, theta)  # (t, e, c)
    edges = response.energy_edges
    lo, hi = edges[:-1], edges[1:]
    out = np.zeros(response.channel_edges.size - 1)
    down = (np.asarray(downward_factor(theta), dtype=float) if callable(downward_factor)
            else np.full(theta.shape, float(downward_factor)))
    if np.any(~((down >= 0) & (down <= 1))):
        raise ParameterError("downward_factor must give values in [0, 1]")
    halves = [(theta, down)]
    if upward:
        halves.append((np.pi - theta, np.ones(theta.shape)))
    for zen, factor in halves:
        if not np.any(factor):
            continue
        if line is None:
            # 6-point Gauss-Legendre in ln E on each true-energy bin.
            a, b = np.log(lo)[:, None], np.log(hi)[:, None]
            ln = 0.5 * (b - a) * _GLE_X + 0.5 * (b + a)
            en = np.exp(ln)
            wt = 0.5 * (b - a) * _GLE_W * en
            val = intensity(en.reshape(1, -1), zen[:, None]).reshape(zen.size, *en.shape)
            flux = np.einsum("tek,ek->te", val, wt)  # (t, e): photons cm^-2 s^-1 sr^-1
        else:
            mu, sig = line
            share = 0.5 * (erf((hi - mu) / (sig * math.sqrt(2.0)))
                           - erf((lo - mu) / (sig * math.sqrt(2.0))))
            flux = intensity(np.array([[mu]]), zen[:, None]).reshape(-1, 1) * share[None, :]
        out += np.einsum("t,te,tec->c", w * factor, flux, kern)
    return out


def internal_rates(model: SpectralModel, channel_edges: Any) -> np.ndarray:
    """A detector-internal background given as a counts spectrum in measured energy
    (counts s^-1 keV^-1 per detector; e.g. a :class:`~rotmod.spectral.models.PowerLaw`
    plus :class:`~rotmod.spectral.models.Gaussian` activation lines already broadened by the
    resolution): counts s^-1 per channel."""
    if not isinstance(model, SpectralModel):
        raise ParameterError(f"model must be a SpectralModel, got {type(model).__name__}")
    ch = check_edges(channel_edges, "channel_edges")
    if ch[0] <= 0:  # a spectrum's integral starts above 0 keV
        raise ParameterError(f"channel_edges must start above 0 keV, got {ch[0]:g}")
    return model.integral(ch[:-1], ch[1:])


@dataclass(frozen=True, eq=False)
class BalloonBackground:
    """The diffuse background at a balloon: CXB through the air, atmospheric continuum and
    511 keV line, as counts per channel in one detector.

    Parameters
    ----------
    atmosphere : Atmosphere
        Gives the depth above the balloon and the CXB's transmission.
    reference_depth : float
        Depth of the atmospheric parameterisation (g/cm^2).
    line_sigma : float
        Intrinsic width of the 511 keV line (keV), user-set (default 1 keV, far below a
        scintillator's resolution; no published value is used).
    mask_opacity : float
        Mean fraction of downward photons the mask stops, in [0, 1], given by the user (0: no
        mask).
    mask : Mask, optional
        Or compute it: the downward intensity is multiplied by :func:`mask_transmission` (opaque
        slats, per zenith angle) and by ``1 - mask_opacity``.
    """

    atmosphere: Atmosphere
    reference_depth: float = MIZUNO_DEPTH
    line_sigma: float = 1.0
    mask_opacity: float = 0.0
    mask: Mask | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.atmosphere, Atmosphere):
            raise ParameterError(
                f"atmosphere must be an Atmosphere, got {type(self.atmosphere).__name__}")
        object.__setattr__(self, "reference_depth", as_scalar(
            self.reference_depth, "reference_depth", lo=0.0, lo_open=True))
        object.__setattr__(self, "line_sigma", as_scalar(
            self.line_sigma, "line_sigma", lo=0.0, lo_open=True))
        object.__setattr__(self, "mask_opacity", as_scalar(
            self.mask_opacity, "mask_opacity", lo=0.0, hi=1.0))
        if self.mask is not None and not isinstance(self.mask, Mask):
            raise ParameterError(f"mask must be a Mask or None, got {type(self.mask).__name__}")

    def _downward(self, z: np.ndarray) -> np.ndarray:
        """The mask's mean transmission of downward photons at zenith ``z`` (rad)."""
        t = np.full(np.shape(z), 1.0 - self.mask_opacity)
        if self.mask is not None:
            t = t * _mask_transmission(self.mask, np.asarray(z, dtype=float))
        return t

    def depth(self, altitude: Any) -> np.ndarray:
        """Vertical column above the balloon (g/cm^2) at ``altitude`` (km)."""
        return self.atmosphere.column_depth(altitude, 0.0)

    def cxb(self, energy: Any, zenith: Any, altitude: Any) -> np.ndarray:
        """CXB intensity at the balloon: ``I_Gruber(E) T(E, z, h)`` (0 where the line of
        sight meets the ground)."""
        e = as_energy(energy, "energy", lo=CXB_RANGE_KEV[0], hi=CXB_RANGE_KEV[1], lo_open=False)
        return _cxb(e) * self.atmosphere.transmission(e, zenith, altitude)

    def intensity(self, energy: Any, zenith: Any, altitude: Any) -> np.ndarray:
        """Continuum intensity at the balloon, CXB plus atmospheric (photons cm^-2 s^-1 sr^-1
        keV^-1; the 511 keV line is :func:`annihilation_line`), with the mask's mean opacity
        applied to the downward half: what a Monte Carlo draws background photons from.

        Parameters
        ----------
        energy : float, array_like or Quantity
            keV, within :data:`MIZUNO_RANGE_KEV`.
        zenith : float, array_like or Quantity
            Arrival direction (deg if plain), 0-180.
        altitude : float
            Balloon altitude (km).
        """
        e = as_energy(energy, "energy", lo=MIZUNO_RANGE_KEV[0], hi=MIZUNO_RANGE_KEV[1],
                      lo_open=False)
        z = as_angle(zenith, "zenith", lo=0.0, hi=180.0)
        h = as_scalar(altitude, "altitude", lo=0.0)
        x = float(self.depth(h))
        down = np.where(z < np.pi / 2, self._downward(z), 1.0)
        total = (_cxb(e) * self.atmosphere.transmission(e, np.degrees(z), h)
                 + atmospheric_continuum(e, np.degrees(z), x,
                                         reference_depth=self.reference_depth))
        return down * total

    def components(self, response: DetectorResponse, detectors: DetectorArray,
                   altitude: Any) -> dict[str, np.ndarray]:
        """Counts s^-1 per channel of each component at one altitude (km): ``"cxb"``,
        ``"continuum"`` and ``"line"``.

        The line's photons are counted with the response at the node of the true-energy bin
        holding 511 keV: include 511 keV among the response's energies, or the peak appears
        at the nearest node."""
        h = as_scalar(altitude, "altitude", lo=0.0)
        x = float(self.depth(h))
        x0 = self.reference_depth
        down = self._downward
        atm = self.atmosphere

        def cxb(e: np.ndarray, z: np.ndarray) -> np.ndarray:
            inside = (e >= CXB_RANGE_KEV[0]) & (e <= CXB_RANGE_KEV[1])
            ee = np.clip(e, *CXB_RANGE_KEV)
            return np.where(inside, _cxb(ee) * atm.transmission(ee, np.degrees(z), h), 0.0)

        def cont(e: np.ndarray, z: np.ndarray) -> np.ndarray:
            inside = (e >= MIZUNO_RANGE_KEV[0]) & (e <= MIZUNO_RANGE_KEV[1])
            val = (_down_spectrum(e) * _down_shape(z) * (x / x0)
                   + _up_spectrum(e) * _up_shape(z))
            return np.where(inside, val, 0.0)

        def line(e: np.ndarray, z: np.ndarray) -> np.ndarray:
            return (ANNIHILATION_DOWN * _down_shape(z) * (x / x0)
                    + ANNIHILATION_UP * _up_shape(z))

        return {
            "cxb": diffuse_rates(cxb, response, detectors, downward_factor=down),
            "continuum": diffuse_rates(cont, response, detectors, downward_factor=down),
            "line": diffuse_rates(line, response, detectors, downward_factor=down,
                                  line=(511.0, self.line_sigma)),
        }

    def rates(self, response: DetectorResponse, detectors: DetectorArray,
              altitude: Any) -> np.ndarray:
        """Total counts s^-1 per channel at one altitude (km)."""
        return sum(self.components(response, detectors, altitude).values())

    def flight_components(self, response: DetectorResponse, detectors: DetectorArray,
                          altitudes: Any, *, step: float = 0.1) -> dict[str, np.ndarray]:
        """Counts s^-1 per channel of each component along a flight: ``"cxb"``,
        ``"continuum"`` and ``"line"`` (as :meth:`components`), each of shape
        ``(n_times, n_channels)``.

        The components are tabulated every ``step`` km over the flight's altitude range and
        interpolated linearly to each altitude (km).  They are the time-variable
        background's templates: shapes in time and energy whose normalisations a fit frees
        (:func:`rotmod.sources.spectra.fit_spectra`, ``background_free="component"``).
        """
        h = as_array(altitudes, "altitudes", lo=0.0, ndim=1)
        st = as_scalar(step, "step", lo=0.001, hi=5.0)
        n = max(int(np.ceil((h.max() - h.min()) / st)), 1)
        grid = np.linspace(h.min(), h.min() + n * st, n + 1)
        tabs = [self.components(response, detectors, g) for g in grid]
        i = np.clip(np.searchsorted(grid, h, side="right") - 1, 0, n - 1)
        f = ((h - grid[i]) / st)[:, None]
        return {k: (1.0 - f) * tab[i] + f * tab[i + 1]
                for k, tab in ((k, np.array([t[k] for t in tabs])) for k in tabs[0])}

    def flight_rates(self, response: DetectorResponse, detectors: DetectorArray,
                     altitudes: Any, *, step: float = 0.1) -> np.ndarray:
        """Counts s^-1 per channel along a flight, shape ``(n_times, n_channels)``: the sum
        of :meth:`flight_components` (a time-variable background = this shape x the
        flight's profile).  The interpolation is linear, so summing the interpolated
        components is interpolating the summed rates, to rounding (tested at 1e-13)."""
        return sum(self.flight_components(response, detectors, altitudes, step=step).values())


def fit_normalisations(counts: Any, exposure: float,
                       templates: Mapping[str, Any]) -> dict[str, float]:
    """Fit one non-negative scale factor per background component to counts per channel.

    Maximises the Poisson likelihood of ``counts_c`` with mean
    ``exposure * sum_k a_k r_k,c`` (``r_k`` the templates in counts s^-1 per channel, e.g.
    :meth:`BalloonBackground.components` and :func:`internal_rates`), ``a_k >= 0``.

    Returns
    -------
    dict
        The scale factors by template name.
    """
    n = as_array(counts, "counts", lo=0.0, ndim=1)
    t = as_scalar(exposure, "exposure", lo=0.0, lo_open=True)
    if not templates:
        raise ParameterError("templates must hold at least one component")
    names = list(templates)
    r = np.array([as_array(templates[k], f"templates[{k!r}]", lo=0.0, ndim=1)
                  for k in names]) * t
    if r.shape[1] != n.size:
        raise ParameterError(
            f"templates must have one value per channel ({n.size}), got {r.shape[1]}")
    scale = np.maximum(r.sum(axis=1), 1e-300)
    a0 = np.full(len(names), n.sum() / max(scale.sum(), 1e-300))

    def nll(b: np.ndarray) -> tuple[float, np.ndarray]:
        a = b / scale
        mu = np.maximum(a @ r, 1e-300)
        val = float(np.sum(mu - n * np.log(mu)))
        grad = (r @ (1.0 - n / mu)) / scale
        return val, grad

    res = minimize(nll, a0 * scale, jac=True, method="L-BFGS-B",
                   bounds=[(0.0, None)] * len(names),
                   options={"ftol": 1e-14, "gtol": 1e-10, "maxiter": 2000})
    return dict(zip(names, (res.x / scale).tolist(), strict=True))

"""The residual atmosphere above a balloon: density profile, slant column depth, transmission.

A rotating modulator flown on a balloon at 30-40 km sees every source through the air above
it.  The direct (unscattered) beam of a source at zenith angle ``z`` seen from altitude ``h`` is
transmitted with probability

    T(E, z, h) = exp(-(mu/rho)_air(E) X(h, z)),

where ``X`` is the column depth (g/cm^2) along the line of sight.  ``(mu/rho)`` is the *total*
attenuation coefficient (photoelectric, coherent, incoherent and pair): a photon scattered
even slightly has left the source's beam (it joins the atmospheric background, which is not
modelled here).  Refraction is irrelevant for gamma rays (``n - 1`` is ~1e-10 at 100 keV).

Geometry (docs/atmosphere.md derives it): the atmosphere is a stack of spherical shells
about a sphere of radius ``R`` (the Gaussian mean radius of curvature of the WGS84 ellipsoid
at the flight's latitude), horizontally uniform, with the density ``rho(h)`` of one vertical
profile.  Along the line of sight at distance ``s`` from the balloon (radius
``r0 = R + h``), ``r(s) = sqrt(r0^2 + s^2 + 2 r0 s cos z)``.  With the impact parameter
``p = r0 sin z`` and ``u = sqrt(r^2 - p^2) = s + r0 cos z``, ``ds = du`` and

    X(h, z) = integral from u0 = r0 cos z to u_top of rho(sqrt(u^2 + p^2) - R) du     (z <= 90)

which has no singularity at the horizon.  Below the horizon (``z > 90 deg``) the line of
sight descends to the tangent altitude ``h_t = p - R`` and climbs again; by symmetry about
the tangent point ``X(h, z) = 2 X(h_t, 90) - X(h, 180 - z)``.  When ``h_t <= 0`` the ray
meets the ground: ``X = inf`` and ``T = 0``.

The density profile comes from NRLMSIS 2.1 (Emmert et al. 2021, Earth Space Sci. 8,
e2020EA001321; nitric oxide added in 2.1, Emmert et al. 2022, JGR Space Phys. 127) through
pymsis, always with explicit space-weather indices (pymsis would otherwise download them): the
stratosphere barely depends on them (docs/atmosphere.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import astropy.units as u
import numpy as np
from astropy.coordinates import AltAz, EarthLocation, SkyCoord
from astropy.time import Time
from scipy.interpolate import CubicSpline, RectBivariateSpline

from rotmod._validate import as_angle, as_array, as_energy, as_scalar
from rotmod.errors import ParameterError
from rotmod.materials import DATABASE_RANGE_KEV, mass_attenuation

__all__ = [
    "AIR_MASS_FRACTIONS",
    "DEFAULT_AP",
    "DEFAULT_DATE",
    "DEFAULT_F107",
    "DEFAULT_F107A",
    "DEFAULT_SITE",
    "Atmosphere",
    "air_attenuation",
    "earth_radius",
    "source_zenith",
]

#: Dry air near sea level by mass (CRC Handbook / NIST XCOM's "Air, Dry (near sea level)"
#: composition, also used by the NIST X-ray mass attenuation tables, Hubbell & Seltzer 1996).
#: The stratosphere is well mixed up to ~90 km (homosphere), so the same fractions hold at
#: 30-40 km.
AIR_MASS_FRACTIONS: dict[str, float] = {"N": 0.7553, "O": 0.2318, "Ar": 0.0128, "C": 0.0001}
#: Default flight site: the Columbia Scientific Balloon Facility's launch site at Fort
#: Sumner, New Mexico (latitude deg N, longitude deg E), a mid-latitude site.
DEFAULT_SITE: tuple[float, float] = (34.47, -104.24)
#: Default date (UTC): a Fort Sumner autumn campaign, local noon.
DEFAULT_DATE = "2025-09-15T18:00"
#: Default space weather: moderate solar activity (F10.7 and its 81-day mean, sfu) and a quiet
#: magnetosphere (daily Ap).  Between F10.7 = 70 and 250, or Ap = 4 and 100, the column above
#: 30-40 km changes by < 2e-6 (measured: docs/atmosphere.md), so the defaults serve any flight.
DEFAULT_F107 = 150.0
DEFAULT_F107A = 150.0
DEFAULT_AP = 4.0

_WGS84_A_KM = 6378.137
_WGS84_E2 = 6.69437999014e-3
_BOLTZMANN = 1.380649e-23  # J/K
_GL_NODES, _GL_WEIGHTS = np.polynomial.legendre.leggauss(6)
_CHUNK = 256  # rays per vectorised block (memory ~ CHUNK x levels x 6 doubles)


def earth_radius(latitude: Any) -> float:
    """Gaussian mean radius of curvature of the WGS84 ellipsoid at ``latitude`` (km).

    ``R = a sqrt(1 - e^2) / (1 - e^2 sin^2 phi)``: the radius of the sphere that osculates the
    ellipsoid best on average over azimuth (6356.8 km at the equator, 6399.6 km at the poles,
    6370.4 km at Fort Sumner).
    """
    phi = float(as_angle(latitude, "latitude", lo=-90.0, hi=90.0))
    return _WGS84_A_KM * np.sqrt(1.0 - _WGS84_E2) / (1.0 - _WGS84_E2 * np.sin(phi) ** 2)


def air_attenuation(energy: Any) -> np.ndarray:
    """Total mass attenuation coefficient of dry air (cm^2/g, with coherent scattering).

    Parameters
    ----------
    energy : float, array_like or Quantity
        Photon energy (keV if plain), within the XCOM database's 1 keV to 100 GeV.

    Raises
    ------
    ParameterError
        ``energy`` not finite or outside the database's range.
    """
    lo, hi = DATABASE_RANGE_KEV
    e = as_energy(energy, "energy", lo=lo, hi=hi)
    return mass_attenuation(AIR_MASS_FRACTIONS, e)


@dataclass(frozen=True, eq=False)
class Atmosphere:
    """A horizontally uniform atmosphere in spherical shells: column depths and transmission.

    Build it from NRLMSIS with :meth:`from_msis`, or from any tabulated profile.  Between
    tabulated altitudes ``ln rho`` is linear (exact for an isothermal layer); above the top
    the density is taken as 0 (the column above 150 km is ~1e-6 of the column above 40 km).

    Parameters
    ----------
    altitude : array_like or Quantity, shape (n,)
        Altitudes (km if plain), increasing, from 0 km (the ground), n >= 2.
    density : array_like or Quantity, shape (n,)
        Mass density (g/cm^3 if plain), > 0.
    radius : float or Quantity
        Radius of the spherical Earth (km if plain); :func:`earth_radius` gives the local one.
    max_altitude : float or Quantity
        Highest balloon altitude the fast table covers (km if plain; default 60 km).
    pressure : array_like or Quantity, optional
        Pressure at each altitude (hPa if plain), kept for checks (NRLMSIS: ``n k T``).
    info : dict, optional
        Provenance (model, date, site, indices).
    """

    altitude: Any
    density: Any
    radius: Any = 6371.0
    max_altitude: Any = 60.0
    pressure: Any = None
    info: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        h = as_array(self.altitude, "altitude", u.km, lo=0.0, ndim=1)
        rho = as_array(self.density, "density", u.g / u.cm**3, lo=0.0, lo_open=True, ndim=1)
        if h.size < 2 or h[0] != 0.0 or np.any(np.diff(h) <= 0):
            raise ParameterError("altitude must start at 0 km and increase, with >= 2 values")
        if rho.shape != h.shape:
            raise ParameterError(
                f"density must have one value per altitude ({h.size}), got shape {rho.shape}")
        radius = as_scalar(self.radius, "radius", u.km, lo=1000.0)
        top = as_scalar(self.max_altitude, "max_altitude", u.km, lo=1.0, hi=float(h[-1]))
        object.__setattr__(self, "altitude", h)
        object.__setattr__(self, "density", rho)
        object.__setattr__(self, "radius", radius)
        object.__setattr__(self, "max_altitude", top)
        if self.pressure is not None:
            p = as_array(self.pressure, "pressure", u.hPa, lo=0.0, ndim=1)
            if p.shape != h.shape:
                raise ParameterError("pressure must have one value per altitude")
            object.__setattr__(self, "pressure", p)
        object.__setattr__(self, "info", dict(self.info))
        ln_rho = np.log(rho)
        object.__setattr__(self, "_ln_rho", ln_rho)
        object.__setattr__(self, "_slope", np.diff(ln_rho) / np.diff(h))
        object.__setattr__(self, "_table", None)

    # -- construction -------------------------------------------------------------------------

    @classmethod
    def from_msis(
        cls,
        date: Any = DEFAULT_DATE,
        latitude: Any = DEFAULT_SITE[0],
        longitude: Any = DEFAULT_SITE[1],
        *,
        f107: float = DEFAULT_F107,
        f107a: float = DEFAULT_F107A,
        ap: float = DEFAULT_AP,
        top: Any = 150.0,
        step: Any = 0.25,
        max_altitude: Any = 60.0,
    ) -> Atmosphere:
        """The NRLMSIS 2.1 profile above a site at one date, tabulated once.

        Parameters
        ----------
        date : str, numpy.datetime64 or astropy Time
            Date and time (UTC) of the profile (default :data:`DEFAULT_DATE`).
        latitude, longitude : float or Quantity
            Geodetic site (deg if plain; default Fort Sumner, NM: :data:`DEFAULT_SITE`).
        f107, f107a, ap : float
            Solar radio flux F10.7 of the previous day and its 81-day mean (sfu), daily Ap.
            Always passed to NRLMSIS (no network needed); defaults 150, 150, 4.
        top : float or Quantity
            Top of the tabulated profile (km if plain; default 150 km).
        step : float or Quantity
            Altitude step (km if plain; default 0.25 km, interpolation error < 1e-5 of X).
        max_altitude : float or Quantity
            Highest balloon altitude of the fast column table (km if plain).

        Raises
        ------
        ParameterError
            A parameter out of its range, or a date NRLMSIS cannot take.
        """
        from pymsis import msis  # ~70 ms to import: only when a profile is built

        lat = np.degrees(float(as_angle(latitude, "latitude", lo=-90.0, hi=90.0)))
        lon = np.degrees(float(as_angle(longitude, "longitude", lo=-360.0, hi=360.0)))
        top_km = as_scalar(top, "top", u.km, lo=60.0, hi=1000.0)
        step_km = as_scalar(step, "step", u.km, lo=0.01, hi=2.0)
        f107 = as_scalar(f107, "f107", lo=0.0, lo_open=True)
        f107a = as_scalar(f107a, "f107a", lo=0.0, lo_open=True)
        ap = as_scalar(ap, "ap", lo=0.0)
        try:
            when = Time(date, scale="utc") if not isinstance(date, Time) else date
            stamp = np.datetime64(when.utc.datetime64, "s")
        except (ValueError, TypeError) as exc:
            raise ParameterError(f"date must be a date and time (UTC), got {date!r}") from exc
        n = int(np.ceil(top_km / step_km))
        h = np.linspace(0.0, n * step_km, n + 1)
        out = msis.calculate(np.atleast_1d(stamp), lon, lat, h, [f107], [f107a], [[ap] * 7],
                             version=2.1)
        out = np.asarray(out, dtype=float).reshape(h.size, -1)
        rho = out[:, 0] * 1e-3  # kg/m^3 -> g/cm^3
        # Pressure n k T of every species (N2, O2, O, He, H, Ar, N, anomalous O, NO; NaN where
        # the model does not define one) -> Pa -> hPa.
        n_tot = np.nansum(out[:, 1:10], axis=1)
        pressure = n_tot * _BOLTZMANN * out[:, 10] / 100.0
        info = {"model": "NRLMSIS 2.1 (pymsis)", "date": str(stamp), "latitude": lat,
                "longitude": lon, "f107": f107, "f107a": f107a, "ap": ap}
        return cls(h, rho, radius=earth_radius(lat), max_altitude=max_altitude,
                   pressure=pressure, info=info)

    # -- profile ------------------------------------------------------------------------------

    def density_at(self, altitude: Any) -> np.ndarray:
        """Mass density (g/cm^3) at ``altitude`` (km if plain), log-linear in the table;
        0 above its top."""
        h = as_array(altitude, "altitude", u.km, lo=0.0)
        return self._rho(h)

    def _rho(self, h: np.ndarray) -> np.ndarray:
        grid = self.altitude
        i = np.clip(np.searchsorted(grid, h, side="right") - 1, 0, grid.size - 2)
        out = np.exp(self._ln_rho[i] + self._slope[i] * (h - grid[i]))
        return np.where(h > grid[-1], 0.0, out)

    # -- columns ------------------------------------------------------------------------------

    def _upward(self, p: np.ndarray, u0: np.ndarray) -> np.ndarray:
        """``integral_{u0}^{u_top} rho(sqrt(u^2 + p^2) - R) du`` for rays of impact parameter
        ``p`` (km) from ``u0 >= 0`` (km); g/cm^2.

        The altitude levels cut every ray into segments inside which ``ln rho`` is linear in
        ``h`` and ``h(u)`` is smooth: 6-point Gauss-Legendre on each (error < 1e-9 relative for
        the 0.25 km levels).
        """
        R = self.radius
        r_lev = R + self.altitude
        out = np.empty(p.shape)
        for a in range(0, p.size, _CHUNK):
            pp = p[a:a + _CHUNK, None]
            uu = u0[a:a + _CHUNK, None]
            u_lev = np.sqrt(np.maximum(r_lev[None, :] ** 2 - pp**2, 0.0))
            u_lev = np.maximum(u_lev, uu)  # levels below the start collapse to it
            lo, hi = u_lev[:, :-1], u_lev[:, 1:]
            half = 0.5 * (hi - lo)
            mid = 0.5 * (hi + lo)
            uq = mid[..., None] + half[..., None] * _GL_NODES
            hq = np.sqrt(uq**2 + pp[..., None] ** 2) - R
            i = np.arange(self.altitude.size - 1)[None, :, None]
            ln = self._ln_rho[i] + self._slope[i] * (hq - self.altitude[i])
            seg = np.einsum("rlq,q->rl", np.exp(ln), _GL_WEIGHTS) * half
            out[a:a + _CHUNK] = seg.sum(axis=1)
        return out * 1e5  # km * g/cm^3 -> g/cm^2

    def column_depth_exact(self, altitude: Any, zenith: Any) -> np.ndarray:
        """Column depth X (g/cm^2) along the line of sight, integrated for every ray.

        Parameters
        ----------
        altitude : float, array_like or Quantity
            Balloon altitude (km if plain), ``0 <= h <= top of the profile``.
        zenith : float, array_like or Quantity
            Zenith angle of the source (deg if plain), ``0 <= z <= 180``; broadcast together.

        Returns
        -------
        numpy.ndarray
            X, ``inf`` where the line of sight meets the ground.
        """
        h, z = self._check(altitude, zenith, self.altitude[-1])
        shape = h.shape
        h, z = h.ravel(), z.ravel()
        r0 = self.radius + h
        p = r0 * np.sin(z)
        c = r0 * np.cos(z)
        out = np.full(h.shape, np.inf)
        up = c >= 0
        out[up] = self._upward(p[up], c[up])
        below = ~up & (p > self.radius)
        if np.any(below):
            full = self._upward(p[below], np.zeros(int(below.sum())))
            out[below] = 2.0 * full - self._upward(p[below], -c[below])
        return out.reshape(shape)

    def _check(self, altitude: Any, zenith: Any, hmax: float) -> tuple[np.ndarray, np.ndarray]:
        h = as_array(altitude, "altitude", u.km, lo=0.0, hi=hmax)
        z = as_angle(zenith, "zenith", lo=0.0, hi=180.0)
        try:
            return np.broadcast_arrays(h, z)
        except ValueError as exc:
            raise ParameterError(
                f"altitude and zenith must broadcast together, got shapes {h.shape} "
                f"and {z.shape}") from exc

    def _build_table(self) -> tuple[RectBivariateSpline, CubicSpline]:
        """``ln X`` on an (altitude, zenith) grid for 0 <= z <= 90 deg, and ``ln X(h, 90)``."""
        hg = np.linspace(0.0, self.max_altitude, round(self.max_altitude / 0.5) + 1)
        # Zenith nodes: 2 deg steps to 70 deg, then finer toward the horizon where ln X bends.
        zg = np.unique(np.concatenate([np.arange(0.0, 70.0, 2.0), np.arange(70.0, 84.0, 1.0),
                                       np.arange(84.0, 90.0, 0.5), [90.0]]))
        H, Z = np.meshgrid(hg, zg, indexing="ij")
        x = self.column_depth_exact(H, Z)
        table = RectBivariateSpline(hg, np.radians(zg), np.log(x), kx=3, ky=3)
        horizon = CubicSpline(hg, np.log(x[:, -1]))
        return table, horizon

    def column_depth(self, altitude: Any, zenith: Any) -> np.ndarray:
        """Column depth X (g/cm^2) along the line of sight, interpolated in a table.

        ``ln X`` is tabulated once (0.5 km x 0.5-2 deg) and interpolated by bicubic splines;
        the relative error is < 1e-4 against :meth:`column_depth_exact` (measured in
        docs/atmosphere.md).  Below the horizon ``X = 2 X(h_t, 90) - X(h, 180 - z)``.

        Parameters
        ----------
        altitude : float, array_like or Quantity
            Balloon altitude (km if plain), ``0 <= h <= max_altitude``.
        zenith : float, array_like or Quantity
            Zenith angle of the source (deg if plain), ``0 <= z <= 180``; broadcast together.

        Returns
        -------
        numpy.ndarray
            X, ``inf`` where the line of sight meets the ground.
        """
        h, z = self._check(altitude, zenith, self.max_altitude)
        if self._table is None:
            object.__setattr__(self, "_table", self._build_table())
        table, horizon = self._table
        shape = h.shape
        h, z = h.ravel(), z.ravel()
        zz = np.minimum(z, np.pi - z)  # the table's half: 180 - z below the horizon
        out = np.exp(table.ev(h, zz))
        below = z > 0.5 * np.pi
        if np.any(below):
            ht = (self.radius + h[below]) * np.sin(z[below]) - self.radius
            xb = np.full(ht.shape, np.inf)
            ok = ht > 0
            xb[ok] = 2.0 * np.exp(horizon(ht[ok])) - out[below][ok]
            out[below] = xb
        return out.reshape(shape)

    def transmission(self, energy: Any, zenith: Any, altitude: Any) -> np.ndarray:
        """Transmission of the direct beam, ``exp(-(mu/rho)_air(E) X(h, z))``.

        Parameters
        ----------
        energy : float, array_like or Quantity
            Photon energy (keV if plain), 1 keV to 100 GeV.
        zenith : float, array_like or Quantity
            Zenith angle of the source (deg if plain), 0 to 180.
        altitude : float, array_like or Quantity
            Balloon altitude (km if plain), 0 to ``max_altitude``.

        Returns
        -------
        numpy.ndarray
            T in [0, 1], with the broadcast shape of the three inputs (e.g. ``energy[:, None]``
            against a flight's zenith angles and altitudes gives an (energy, time) table); 0
            where the line of sight meets the ground.

        Raises
        ------
        ParameterError
            An input not finite or outside its range, or shapes that do not broadcast.
        """
        mu = air_attenuation(energy)
        x = self.column_depth(altitude, zenith)
        try:
            mu, x = np.broadcast_arrays(mu, x)
        except ValueError as exc:
            raise ParameterError(
                f"energy must broadcast against zenith and altitude, got shapes {mu.shape} "
                f"and {x.shape}") from exc
        return np.exp(-mu * x)


def source_zenith(coords: SkyCoord, time: Time, latitude: Any, longitude: Any,
                  altitude: Any) -> np.ndarray:
    """Zenith angle (deg) of sources seen from the balloon, without refraction.

    Parameters
    ----------
    coords : SkyCoord
        Source position(s) (any celestial frame).
    time : astropy Time
        Time(s); broadcast with ``coords`` and the location.
    latitude, longitude : float, array_like or Quantity
        Geodetic position of the balloon (deg if plain); arrays follow a flight's track.
    altitude : float, array_like or Quantity
        Height above the WGS84 ellipsoid (km if plain).

    Returns
    -------
    numpy.ndarray
        Zenith angle in degrees, 0 to 180 (above 90: below the astronomical horizon).

    Raises
    ------
    ParameterError
        Wrong types or values out of range.
    """
    if not isinstance(coords, SkyCoord):
        raise ParameterError(f"coords must be an astropy SkyCoord, got {type(coords)}")
    if not isinstance(time, Time):
        raise ParameterError(f"time must be an astropy Time, got {type(time)}")
    lat = as_angle(latitude, "latitude", lo=-90.0, hi=90.0)
    lon = as_angle(longitude, "longitude", lo=-360.0, hi=360.0)
    h = as_array(altitude, "altitude", u.km, lo=-1.0, hi=1000.0)
    loc = EarthLocation.from_geodetic(lon * u.rad, lat * u.rad, h * u.km)
    frame = AltAz(obstime=time, location=loc)  # pressure 0: no refraction (gamma rays)
    alt = coords.transform_to(frame).alt
    return 90.0 - np.asarray(alt.to_value(u.deg))

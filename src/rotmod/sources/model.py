"""The sky model: point sources at continuous positions, an optional diffuse image and a
fitted background -- one object that predicts counts, simulates them and is fitted to them.

Fluxes are in the response's sky unit: photons per second that would reach one detector face
with no mask (:class:`rotmod.sky.PointSources` ``rate``), so ``forward`` of a unit source is
its count rate per detector and bin.  Positions are instrument directions ``(theta, phi)``
for a response in the instrument frame, or sky positions (`~astropy.coordinates.SkyCoord`)
for a response on the sky, which its attitude (or attitudes) place in the instrument frame.

The background of detector ``d`` in bin ``t`` is ``b_d T[d, t]`` (counts per second): a
template ``T`` (default flat, 1/s) times one level per detector, fitted with the sources.  A
background that drifts through a long observation is fitted per time interval by the light
curve (:func:`rotmod.sources.light_curve`), where each interval has its own levels.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import astropy.units as u
import numpy as np
from astropy.coordinates import SkyCoord

from rotmod._validate import as_angle_scalar, as_scalar
from rotmod.conventions import source_angles, source_direction
from rotmod.errors import ParameterError
from rotmod.reconstruction.data import PoissonData
from rotmod.response.columns import columns_at
from rotmod.response.operator import ResponseOperator
from rotmod.sky.attitude import Attitude
from rotmod.sky.sources import PointSources

__all__ = ["PointSource", "SkyModel"]


@dataclass(frozen=True)
class PointSource:
    """A point source.

    Parameters
    ----------
    position : SkyCoord or (theta, phi)
        A sky position (one SkyCoord, any frame; held in ICRS), or an instrument direction
        (zenith ``0 <= theta < 90`` and azimuth, deg if plain numbers).
    flux : float
        Photons per second on one unmasked detector face (the response's sky unit), >= 0.
    name : str
        Label in catalogues.
    free_flux, free_position : bool
        Which parameters a fit adjusts (default: the flux only).
    """

    position: Any
    flux: float = 0.0
    name: str = ""
    free_flux: bool = True
    free_position: bool = False

    def __post_init__(self) -> None:
        pos = self.position
        if isinstance(pos, SkyCoord):
            if not pos.isscalar:
                raise ParameterError(f"position must be one SkyCoord, got {len(pos)} positions")
            icrs = pos.icrs
            if not (np.isfinite(icrs.ra.deg) and np.isfinite(icrs.dec.deg)):
                raise ParameterError(f"position must be finite, got {pos!r}")
            object.__setattr__(self, "position", SkyCoord(icrs.ra, icrs.dec, frame="icrs"))
        else:
            try:
                theta, phi = pos
            except (TypeError, ValueError) as exc:
                raise ParameterError(f"position must be a SkyCoord or a pair (theta, phi), got "
                                     f"{pos!r}") from exc
            th = np.degrees(as_angle_scalar(theta, "theta", lo=0.0, hi=90.0, hi_open=True))
            ph = np.degrees(as_angle_scalar(phi, "phi"))
            object.__setattr__(self, "position", (float(th), float(ph % 360.0)))
        object.__setattr__(self, "flux", as_scalar(self.flux, "flux", 1 / u.s, lo=0.0))
        object.__setattr__(self, "name", str(self.name))

    @property
    def frame(self) -> str:
        """``"celestial"`` (a SkyCoord) or ``"instrument"`` (a direction)."""
        return "celestial" if isinstance(self.position, SkyCoord) else "instrument"

    def vector(self) -> np.ndarray:
        """Unit vector of the position in its frame (ICRS, or the instrument's)."""
        if isinstance(self.position, SkyCoord):
            return np.asarray(self.position.cartesian.xyz.value, dtype=float)
        th, ph = np.radians(self.position)
        return np.asarray(source_direction(th, ph), dtype=float)

    def at_vector(self, v: np.ndarray) -> PointSource:
        """The same source moved to the direction ``v`` (a vector in its frame)."""
        v = np.asarray(v, dtype=float) / np.linalg.norm(v)
        if isinstance(self.position, SkyCoord):
            pos: Any = SkyCoord(x=v[0], y=v[1], z=v[2], representation_type="cartesian",
                                frame="icrs")
            pos = SkyCoord(pos.spherical.lon, pos.spherical.lat, frame="icrs")
        else:
            th, ph = source_angles(v)
            if np.degrees(th) >= 90.0:
                raise ParameterError("position moved below the instrument's horizon")
            pos = (float(np.degrees(th)), float(np.degrees(ph)))
        return dataclasses.replace(self, position=pos)

    def separation(self, other: PointSource) -> float:
        """Angle to another source of the same frame (deg)."""
        c = float(np.clip(self.vector() @ other.vector(), -1.0, 1.0))
        return float(np.degrees(np.arccos(c)))


def positions_of(sources: list[PointSource] | tuple[PointSource, ...]) -> Any:
    """The positions of sources of one frame: a SkyCoord array or ``(theta, phi)`` (deg)."""
    frames = {s.frame for s in sources}
    if len(frames) != 1:
        raise ParameterError(f"sources must all be in one frame, got {sorted(frames)}")
    if frames == {"celestial"}:
        return SkyCoord([s.position.ra for s in sources], [s.position.dec for s in sources],
                        frame="icrs")
    th, ph = np.array([s.position for s in sources], dtype=float).T
    return th, ph


def tangent_basis(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors orthogonal to ``v`` and to each other (the local tangent plane)."""
    ref = np.array([0.0, 0.0, 1.0]) if abs(v[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    e1 = np.cross(ref, v)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(v, e1)


@dataclass(frozen=True)
class SkyModel:
    """Point sources, an optional diffuse image and a per-detector background.

    Parameters
    ----------
    sources : sequence of PointSource
        All in one frame (the frame of the response they are used with).
    background : array_like, shape (n_det,), optional
        Background level of each detector (times ``template``, counts/s).  ``None``: not
        yet known (a fit starts from the counts).
    template : array_like, shape (n_det, n_time), optional
        Shape of the background in each detector (default flat).
    diffuse : array_like, shape (n_sky,), optional
        A sky image on the response's grid (its sky unit), scaled by ``diffuse_norm``.
    diffuse_norm : float
        Scale of ``diffuse``, >= 0.
    free_diffuse : bool
        Whether a fit adjusts ``diffuse_norm``.
    """

    sources: tuple[PointSource, ...] = ()
    background: Any = None
    template: Any = None
    diffuse: Any = None
    diffuse_norm: float = 1.0
    free_diffuse: bool = True

    def __post_init__(self) -> None:
        src = tuple(self.sources)
        for k, s in enumerate(src):
            if not isinstance(s, PointSource):
                raise ParameterError(f"sources[{k}] must be a PointSource, got {type(s)}")
        if src:
            positions_of(src)
        object.__setattr__(self, "sources", src)
        if self.background is not None:
            b = np.atleast_1d(np.asarray(self.background, dtype=float))
            if b.ndim != 1 or not np.all(np.isfinite(b)) or np.any(b < 0):
                raise ParameterError("background must be finite levels >= 0, one per detector")
            object.__setattr__(self, "background", b)
        for name in ("template", "diffuse"):
            v = getattr(self, name)
            if v is not None:
                v = np.asarray(v, dtype=float)
                if not np.all(np.isfinite(v)) or np.any(v < 0):
                    raise ParameterError(f"{name} must be finite and >= 0")
                object.__setattr__(self, name, v)
        object.__setattr__(self, "diffuse_norm",
                           as_scalar(self.diffuse_norm, "diffuse_norm", u.one, lo=0.0))

    def replace(self, **changes: Any) -> SkyModel:
        """A copy with some fields changed."""
        return dataclasses.replace(self, **changes)

    def background_template(self, n_det: int, n_time: int) -> np.ndarray:
        """The template ``T[d, t]`` (flat by default), checked against the data's shape."""
        if self.template is None:
            return np.ones((n_det, n_time))
        if self.template.shape != (n_det, n_time):
            raise ParameterError(f"template must have shape ({n_det}, {n_time}), got "
                                 f"{self.template.shape}")
        return self.template

    def source_columns(self, response: ResponseOperator,
                       cache: dict[Any, np.ndarray] | None = None) -> np.ndarray:
        """Response columns ``c[d, t, k]`` of the sources.

        ``cache`` (a dict the caller keeps for one response) holds columns already computed,
        keyed by position, so that a fit moving one source recomputes one column.
        """
        cache = {} if cache is None else cache
        out = np.zeros((response.n_det, response.n_time, len(self.sources)))
        todo = []
        for k, s in enumerate(self.sources):
            key = (s.frame, *np.round(s.vector(), 15))
            if key in cache:
                out[:, :, k] = cache[key]
            else:
                todo.append((k, key))
        if todo:
            cols = columns_at(response, positions_of([self.sources[k] for k, _ in todo]))
            for j, (k, key) in enumerate(todo):
                out[:, :, k] = cache[key] = cols[:, :, j]
        return out

    def rates(self, response: ResponseOperator) -> np.ndarray:
        """Expected count rates ``(n_det, n_time)`` (1/s): sources, diffuse and background."""
        rate = np.zeros((response.n_det, response.n_time))
        if self.sources:
            rate += self.source_columns(response) @ np.array([s.flux for s in self.sources])
        if self.diffuse is not None:
            rate += self.diffuse_norm * response.forward(self.diffuse)
        if self.background is not None:
            if self.background.shape != (response.n_det,):
                raise ParameterError(f"background must have {response.n_det} levels (one per "
                                     f"detector), got {self.background.size}")
            rate += self.background[:, None] * self.background_template(response.n_det,
                                                                         response.n_time)
        return rate

    def expected_counts(self, response: ResponseOperator, exposure: Any) -> np.ndarray:
        """``exposure * rates`` (counts), ``exposure`` in s per bin (scalar or array)."""
        return np.asarray(exposure, dtype=float) * self.rates(response)

    def point_sources(self, energy: Any, attitude: Attitude | None = None) -> PointSources:
        """The sources as :class:`rotmod.sky.PointSources` for the Monte Carlo
        (:func:`rotmod.montecarlo.simulate_observation`), with ``background`` its flat
        per-detector rate: the same sky injected photon by photon.

        Parameters
        ----------
        energy : float or Quantity
            Photon energy (keV).
        attitude : Attitude, optional
            Places sky positions in the instrument frame (required for SkyCoord sources).
        """
        if not self.sources:
            raise ParameterError("the model has no point sources to simulate")
        if self.sources[0].frame == "celestial":
            if not isinstance(attitude, Attitude):
                raise ParameterError("attitude (an Attitude) is required to place sky "
                                     "positions in the instrument frame")
            theta, phi = attitude.to_instrument(positions_of(self.sources))
        else:
            th, ph = positions_of(self.sources)
            theta, phi = th * u.deg, ph * u.deg
        return PointSources(theta, phi, rate=[s.flux for s in self.sources], energy=energy)

    def simulate(self, response: ResponseOperator, exposure: Any,
                 seed: int | np.random.Generator | None = None) -> PoissonData:
        """Poisson counts drawn from the expected counts: an injection into the model.

        Returns
        -------
        PoissonData
            The counts with ``exposure``.
        """
        ex = np.broadcast_to(np.asarray(exposure, dtype=float),
                             (response.n_det, response.n_time))
        rng = np.random.default_rng(seed)
        return PoissonData(rng.poisson(self.expected_counts(response, ex)).astype(float), ex)

"""Localisation regions from the likelihood surface, with a systematic term.

Around a fitted source the TS of a test source (the source itself removed from the model,
the other sources held at their fitted fluxes, the background refitted) is computed on a
square of points in the source's tangent plane. Its likelihood surface ``L(x) ~ exp(TS(x) /
2)`` is the position's probability density (flat prior on the small patch); a systematic
error -- the attitude's uncertainty, the calibration's -- is a Gaussian of standard
deviation ``systematic`` per axis that the density is convolved with. A region of
containment ``q`` is the highest-density set holding ``q`` of the probability: for a
Gaussian surface the statistical part is the ``2 delta ln L <= chi2_2^-1(q)`` contour (2.30
at 68 %, 4.61 at 90 %), but no formula is assumed -- the surface decides its shape, and
``benchmarks/sources_calibration.py`` counts how often injected sources fall inside.

The square adapts: it widens until the surface has fallen by ``EDGE_DROP`` at its edge, and
narrows while the 90 % region is only a few points across.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import astropy.units as u
import numpy as np
from astropy.coordinates import SkyCoord
from scipy.interpolate import RegularGridInterpolator
from scipy.ndimage import gaussian_filter

from rotmod._validate import as_angle_scalar
from rotmod.conventions import source_angles, source_direction
from rotmod.errors import ParameterError
from rotmod.sources.fitting import SourceFitter, geometric_scale
from rotmod.sources.model import PointSource, SkyModel, tangent_basis
from rotmod.sources.tsmap import null_state, scan_test_source

__all__ = ["Region", "localise"]

#: ``2 delta ln L`` the surface must fall by at the edge of the square (0.1 % of the
#: probability of a Gaussian surface lies beyond ``chi2_2 = 13.8``).
EDGE_DROP = 13.8
#: Points per side of the square (odd: the fitted position is the centre point).
N_SIDE = 41
#: Largest half-width of the square (rad, 20 deg): the gnomonic square stays nearly
#: equal-area (pixel areas within 6 %), and a source too faint to be localised within it is
#: reported as such (``Region.closed`` False), not given an ever larger square.
MAX_HALF = np.radians(20.0)
#: Off-axis angle (deg) beyond which a square's points are not evaluated: a response is
#: defined in front of the detectors only (theta < 90 deg), and a drift's other attitudes
#: may turn a point a little further.
HORIZON = 89.0


def vectors_to_positions(frame: str, v: np.ndarray) -> Any:
    """Unit vectors ``(n, 3)`` as positions of ``frame``: SkyCoord or ``(theta, phi)``."""
    if frame == "celestial":
        c = SkyCoord(x=v[:, 0], y=v[:, 1], z=v[:, 2], representation_type="cartesian",
                     frame="icrs")
        return SkyCoord(c.spherical.lon, c.spherical.lat, frame="icrs")
    th, ph = source_angles(v)
    return np.degrees(th), np.degrees(ph)


@dataclass(frozen=True)
class Region:
    """The position's probability on a square of the tangent plane around a source.

    Attributes
    ----------
    source : PointSource
        The fitted source (the square's centre).
    offsets : ndarray, shape (n,)
        Tangent-plane coordinates of the points along each axis (rad).
    density : ndarray, shape (n, n)
        Probability of each point (sums to 1), indexed ``[i_y, i_x]``.
    ts : ndarray, shape (n, n)
        TS of a test source at each point (before the systematic term).
    systematic : float
        Systematic error per axis (deg) folded in.
    closed : bool
        Whether the surface fell by :data:`EDGE_DROP` at the square's edge.  ``False``:
        the source is too faint to be localised within :data:`MAX_HALF` (TS below ~14),
        so the region's probability beyond the square is missing and its sizes are lower
        bounds.
    levels : dict
        Density threshold of each computed containment.
    """

    source: PointSource
    offsets: np.ndarray
    density: np.ndarray
    ts: np.ndarray
    systematic: float
    closed: bool = True
    levels: dict[float, float] = field(default_factory=dict)

    def _basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        v0 = self.source.vector()
        return (v0, *tangent_basis(v0))

    def level(self, containment: float) -> float:
        """Density above which the points hold ``containment`` of the probability."""
        if not 0.0 < containment < 1.0:
            raise ParameterError(f"containment must be in (0, 1), got {containment!r}")
        if containment not in self.levels:
            p = np.sort(self.density.ravel())[::-1]
            k = int(np.searchsorted(np.cumsum(p), containment))
            self.levels[containment] = float(p[min(k, p.size - 1)])
        return self.levels[containment]

    def tangent(self, positions: Any) -> tuple[np.ndarray, np.ndarray]:
        """Coordinates (rad) of ``positions`` in the region's tangent plane (gnomonic).

        ``positions``: a SkyCoord (scalar or array) for a source on the sky, ``(theta,
        phi)`` (deg; scalars or arrays) for one in the instrument frame.
        """
        v0, e1, e2 = self._basis()
        if self.source.frame == "celestial":
            if not isinstance(positions, SkyCoord):
                raise ParameterError("positions must be a SkyCoord for a source on the sky")
            v = np.atleast_2d(np.asarray(positions.icrs.cartesian.xyz.value).T)
        else:
            if isinstance(positions, SkyCoord):
                raise ParameterError("positions must be (theta, phi) for a source in the "
                                     "instrument frame")
            th, ph = (np.radians(np.atleast_1d(np.asarray(a, dtype=float))) for a in positions)
            v = np.stack(source_direction(th, ph), axis=-1).reshape(-1, 3)
        w = v / (v @ v0)[:, None]  # gnomonic projection onto the tangent plane
        return w @ e1, w @ e2

    def density_at(self, positions: Any) -> np.ndarray:
        """Probability density per unit tangent-plane area (rad^-2) at ``positions`` (linear
        interpolation between the points; 0 outside the square)."""
        x, y = self.tangent(positions)
        o = self.offsets
        step = float(o[1] - o[0])
        inside = (np.abs(x) <= o[-1]) & (np.abs(y) <= o[-1])
        out = np.zeros(x.size)
        if np.any(inside):
            interp = RegularGridInterpolator((o, o), self.density / step**2)
            out[inside] = interp(np.column_stack([y[inside], x[inside]]))
        return out

    def contains(self, position: Any, containment: float = 0.9) -> bool:
        """Whether ``position`` (SkyCoord or ``(theta, phi)``) lies in the region."""
        step = float(self.offsets[1] - self.offsets[0])
        level = self.level(containment) / step**2
        return bool(self.density_at(position)[0] >= level)

    def radius(self, containment: float = 0.9) -> float:
        """Radius (deg) of the circle about the source holding ``containment``."""
        if not 0.0 < containment < 1.0:
            raise ParameterError(f"containment must be in (0, 1), got {containment!r}")
        xx, yy = np.meshgrid(self.offsets, self.offsets)
        r = np.hypot(xx, yy).ravel()
        order = np.argsort(r)
        cum = np.cumsum(self.density.ravel()[order])
        return float(np.degrees(r[order][min(int(np.searchsorted(cum, containment)),
                                             r.size - 1)]))

    def area(self, containment: float = 0.9) -> float:
        """Solid angle of the region (deg^2)."""
        step = float(self.offsets[1] - self.offsets[0])
        n = int(np.count_nonzero(self.density >= self.level(containment)))
        return n * np.degrees(step) ** 2

    def contour(self, containment: float = 0.9) -> list[Any]:
        """The region's outline(s): positions (SkyCoord or ``(theta, phi)``) per polygon."""
        import contourpy  # matplotlib's contour engine

        o = self.offsets
        gen = contourpy.contour_generator(o, o, self.density)
        v0, e1, e2 = self._basis()
        out = []
        for line in gen.lines(self.level(containment)):
            v = v0[None, :] + line[:, :1] * e1[None, :] + line[:, 1:2] * e2[None, :]
            v /= np.linalg.norm(v, axis=1, keepdims=True)
            out.append(vectors_to_positions(self.source.frame, v))
        return out

    def sample_positions(self) -> tuple[Any, np.ndarray]:
        """Every point of the square as positions, with its probability (flat)."""
        v0, e1, e2 = self._basis()
        xx, yy = np.meshgrid(self.offsets, self.offsets)
        v = v0[None, :] + xx.ravel()[:, None] * e1 + yy.ravel()[:, None] * e2
        v /= np.linalg.norm(v, axis=1, keepdims=True)
        return vectors_to_positions(self.source.frame, v), self.density.ravel()


def scan_square(fitter: SourceFitter, state: tuple[np.ndarray, ...], source: PointSource,
                half: float, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """TS of a test source on the ``n x n`` tangent-plane square of half-width ``half``
    (rad) around ``source``, against the null ``state`` (:func:`null_state`).

    Returns ``(offsets, ts, vectors)``: the square's ``n`` offsets (rad), its TS ``(n, n)``
    (``-inf`` at points below the instrument's horizon, where no source can be) and the
    points' unit vectors ``(n * n, 3)``.
    """
    v0 = source.vector()
    e1, e2 = tangent_basis(v0)
    o = np.linspace(-half, half, n)
    xx, yy = np.meshgrid(o, o)
    v = v0[None, :] + xx.ravel()[:, None] * e1 + yy.ravel()[:, None] * e2
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    if source.frame == "celestial":
        theta = fitter.response.grid.attitude.to_instrument(
            vectors_to_positions("celestial", v))[0].to_value(u.deg)
    else:
        theta = np.degrees(np.arccos(np.clip(v[:, 2], -1.0, 1.0)))
    seen = theta < HORIZON
    ts = np.full(v.shape[0], -np.inf)
    if seen.any():
        cols = fitter.columns_on_bins(vectors_to_positions(source.frame, v[seen]))
        # Only the TS is read: no upper limits or sensitivities (most of a scan's cost).
        ts[seen] = np.nan_to_num(scan_test_source(fitter, state, cols, 0.0, 0.0)[:, 0],
                                 nan=0.0)
    return o, ts.reshape(n, n), v


def localise(
    fitter: SourceFitter,
    model: SkyModel,
    k: int,
    *,
    systematic: Any = 0.0,
    n_side: int = N_SIDE,
    dispersion: float = 1.0,
) -> Region:
    """The localisation region of source ``k`` of a fitted ``model``.

    Parameters
    ----------
    fitter : SourceFitter
        The data and response the model was fitted to.
    model : SkyModel
        The fitted model (source ``k`` at its best position).
    k : int
        Index of the source.
    systematic : float or Quantity
        Systematic error per axis (deg if plain), >= 0: the attitude's and the
        calibration's uncertainty, added to the statistical surface.
    n_side : int
        Points per side of the square (odd, >= 11).
    dispersion : float
        >= 1: the square is sized for the surface ``TS / dispersion`` (a surface that will be
        tempered by it, :func:`rotmod.bursts.posterior.tempered`: the data's dispersion
        beyond Poisson), so that this wider surface too falls by :data:`EDGE_DROP` at the
        edge and ``closed`` says so.  The returned region holds the untempered surface.

    Returns
    -------
    Region
    """
    if not 0 <= k < len(model.sources):
        raise ParameterError(f"k must index a source (0..{len(model.sources) - 1}), got {k}")
    sys_rad = as_angle_scalar(systematic, "systematic", lo=0.0)
    if n_side < 11 or n_side % 2 == 0:
        raise ParameterError(f"n_side must be odd and >= 11, got {n_side}")
    if not (np.isfinite(dispersion) and dispersion >= 1.0):
        raise ParameterError(f"dispersion must be finite and >= 1, got {dispersion!r}")
    source = model.sources[k]
    # The others held at their fluxes in the full fit: refitted without source k, they would
    # absorb part of it through their sidelobes and move the surface's peak (measured: 0.1
    # deg, 10 in TS, for a bright source among four).  The background is refitted per point.
    others = tuple(dataclasses.replace(s, free_flux=False)
                   for i, s in enumerate(model.sources) if i != k)
    null = model.replace(sources=others)
    ts_k = max(fitter.source_ts(model, k, fitter.maximise(model)[1].loglike), 1.0)
    # A Gaussian surface has sigma ~ scale / sqrt(TS): start at ~4 sigma, then adapt.
    half = 4.0 * geometric_scale(fitter.response) * np.sqrt(dispersion / ts_k) + 4.0 * sys_rad
    half = min(half, MAX_HALF)
    for _ in range(12):
        o, ts, _ = scan_square(fitter, null_state(fitter, null), source, half, n_side)
        drop = (ts.max() - ts) / dispersion
        edge = np.concatenate([drop[0], drop[-1], drop[:, 0], drop[:, -1]])
        closed = bool(edge.min() >= EDGE_DROP)
        if not closed and half < MAX_HALF:
            half = min(2.0 * half, MAX_HALF)
            continue
        # Too coarse: the 90 % region a few points across, and no systematic needing room.
        inner = np.count_nonzero(drop <= 4.61)
        if inner < 25 and edge.min() > 4 * EDGE_DROP and 8.0 * sys_rad < half:
            half *= 0.5
            continue
        break
    logp = 0.5 * (ts - ts.max())
    density = np.exp(logp)
    if sys_rad > 0:
        step = float(o[1] - o[0])
        density = gaussian_filter(density, sys_rad / step, mode="constant")
    density /= density.sum()
    return Region(source, o, density, ts, float(np.degrees(sys_rad)), closed)

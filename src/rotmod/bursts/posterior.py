"""A burst's position probability over its modes.

A faint burst's likelihood on the sky has several peaks of nearly equal height: the burst's
excess fixes its TS almost wherever it is placed, and only the modulation tells the places
apart (the mirror image of a point-symmetric array, a fringe next to the core).  A 90 %
region drawn around the best peak alone then holds the truth far less than 90 % of the time.
The probability of a position is ``exp(TS / 2)`` (a flat prior on the sky), so each mode's
is its peak likelihood times its surface's integral.  The surfaces are those of
:func:`rotmod.sources.localise` around each mode (the exact TS on a fine square, with the
systematic term); :meth:`Posterior.contains` and :meth:`Posterior.probability_map` take
the highest-density region of their union: the points of highest probability per unit area
that together hold the containment.

What lies outside every mode's square is not counted: a burst whose probability is spread
over more modes than were refitted (``docs/bursts.md``: at sqrt(TS) below ~12) has a region
that is too small.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from astropy.coordinates import SkyCoord
from scipy.ndimage import gaussian_filter

from rotmod.errors import ParameterError
from rotmod.io.regions import HealpixProbability
from rotmod.sources.catalogue import probability_map
from rotmod.sources.localisation import Region

__all__ = ["Posterior", "tempered"]


def _covers(region: Region, positions: SkyCoord) -> np.ndarray:
    """Whether each of ``positions`` lies in ``region``'s square."""
    x, y = region.tangent(positions)
    half = float(region.offsets[-1]) * (1.0 + 1e-9)  # its own edge points, to rounding
    return (np.abs(x) <= half) & (np.abs(y) <= half)


def tempered(region: Region, factor: float) -> Region:
    """``region`` with its TS surface divided by ``factor`` (> 0), its density drawn again.

    A quasi-likelihood: where the model's residuals are ``factor`` times as dispersed as
    Poisson counts (the light curve's misfit, :func:`rotmod.bursts.pulses.inflation`), every
    ``delta ln L`` is ``factor`` times too large, so the surface ``exp(TS / (2 factor))``
    is the position's probability.  A Gaussian surface's radii grow by ``sqrt(factor)``;
    the systematic term is folded in as :func:`rotmod.sources.localise` does.  ``factor``
    1 returns ``region`` itself; ``tempered(tempered(r, f), 1 / f)`` is ``r``.
    """
    if not (np.isfinite(factor) and factor > 0):
        raise ParameterError(f"factor must be finite and > 0, got {factor!r}")
    if factor == 1.0:
        return region
    ts = region.ts / factor
    density = np.exp(0.5 * (ts - ts.max()))
    if region.systematic > 0:
        step = float(region.offsets[1] - region.offsets[0])
        density = gaussian_filter(density, np.radians(region.systematic) / step,
                                  mode="constant")
    return dataclasses.replace(region, density=density / density.sum(), ts=ts, levels={})


@dataclass(frozen=True, eq=False)
class Posterior:
    """The position's probability over the modes' squares.

    Parameters
    ----------
    squares : sequence of Region
        The regions of the modes (the best first); their ``ts`` is the TS of a source at
        each point.

    Attributes
    ----------
    square_probability : ndarray
        Probability of each square (of the part of it no earlier square covers).

    Notes
    -----
    The squares of a faint burst's modes are wide and may overlap: each point of the sky
    belongs to the first square that covers it (the best first), so that no probability is
    counted twice.
    """

    squares: tuple[Region, ...]
    square_probability: np.ndarray = field(init=False)
    #: Each square's density restricted to the points it owns.
    _owned: tuple[np.ndarray, ...] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        squares = tuple(self.squares)
        if not squares or not all(isinstance(r, Region) for r in squares):
            raise ParameterError("squares must be one or more Regions")
        ts0 = max(float(np.nanmax(r.ts)) for r in squares)
        owned, mass = [], []
        for k, r in enumerate(squares):
            mine = np.ones(r.ts.shape, dtype=bool)
            if k:
                points = r.sample_positions()[0]
                for earlier in squares[:k]:
                    mine &= ~_covers(earlier, points).reshape(r.ts.shape)
            step = float(r.offsets[1] - r.offsets[0])
            t = np.where(mine & np.isfinite(r.ts), r.ts, -np.inf)
            owned.append(np.where(mine, r.density, 0.0))
            mass.append(float(np.sum(np.exp(0.5 * (t - ts0)))) * step ** 2)
        object.__setattr__(self, "squares", squares)
        object.__setattr__(self, "square_probability", np.array(mass) / sum(mass))
        object.__setattr__(self, "_owned", tuple(owned))

    def _point_probability(self, k: int) -> np.ndarray:
        """Probability of each point of square ``k`` (0 where an earlier square owns it);
        its density (with the systematic term) restricted to its own points."""
        d = self._owned[k]
        total = d.sum()
        return d * (self.square_probability[k] / total) if total > 0 else d

    @property
    def best_probability(self) -> float:
        """The probability that the burst is in the best mode's square."""
        return float(self.square_probability[0])

    def _elements(self) -> tuple[np.ndarray, np.ndarray]:
        """Probability per unit area (rad^-2) and probability of every point."""
        dens, mass = [], []
        for k, r in enumerate(self.squares):
            step = float(r.offsets[1] - r.offsets[0])
            m = np.ravel(self._point_probability(k))
            dens.append(m / step ** 2)
            mass.append(m)
        return np.concatenate(dens), np.concatenate(mass)

    def level(self, containment: float = 0.9) -> float:
        """Probability per unit area (rad^-2) above which the points hold
        ``containment`` of the probability (the highest-density region)."""
        if not 0.0 < containment < 1.0:
            raise ParameterError(f"containment must be in (0, 1), got {containment!r}")
        dens, mass = self._elements()
        order = np.argsort(dens)[::-1]
        k = int(np.searchsorted(np.cumsum(mass[order]), containment))
        return float(dens[order][min(k, dens.size - 1)])

    def density_at(self, position: SkyCoord) -> float:
        """Probability per unit area (rad^-2) at ``position``."""
        for k, r in enumerate(self.squares):
            if _covers(r, position)[0]:
                # The square's density (linear between its points, as Region.contains),
                # restricted to the points it owns.
                owned = float(self._owned[k].sum())
                return float(self.square_probability[k] * r.density_at(position)[0] / owned) \
                    if owned > 0 else 0.0
        return 0.0

    def contains(self, position: SkyCoord, containment: float = 0.9) -> bool:
        """Whether ``position`` lies in the highest-density region of ``containment``."""
        if not isinstance(position, SkyCoord) or not position.isscalar:
            raise ParameterError(f"position must be one SkyCoord, got {position!r}")
        return self.density_at(position) >= self.level(containment)

    def area(self, containment: float = 0.9) -> float:
        """Solid angle of the highest-density region (deg^2)."""
        dens, mass = self._elements()
        keep = dens >= self.level(containment)
        return float(np.sum(mass[keep] / dens[keep]) * np.degrees(1.0) ** 2)

    def probability_map(self, nside: int | None = None, order: str = "nested"
                        ) -> HealpixProbability:
        """The probability on HEALPix pixels (ICRS): every square's density at the pixel
        centres, weighted by its probability (``nside`` default: see
        :func:`rotmod.sources.catalogue.probability_map`, from the best square)."""
        own = tuple(dataclasses.replace(r, density=o, levels={})
                    for r, o in zip(self.squares, self._owned, strict=True))
        return probability_map(own, nside=nside, order=order,
                               weights=[p / max(float(r.density.sum()), 1e-300) for p, r in
                                        zip(self.square_probability, own, strict=True)])

    def describe(self) -> dict[str, Any]:
        """Plain numbers: the modes' probabilities and the 90 % region's area."""
        return {"modes": [float(p) for p in self.square_probability],
                "area90_deg2": self.area(0.9)}

"""Shared fixtures: a tiny paper instrument, a seeded RNG and the brute-force reference profile.

Other test modules keep their own fixtures in their own files; only fixtures that several
physics test modules share live here.  Plain helpers are imported as
``from tests.conftest import rad`` (tests/ is a package: see tests/__init__.py); what a
user's tests could share too (dot test, test operator, tiny instrument) is in
:mod:`rotmod.testing`.
"""

from __future__ import annotations

import itertools
import math
import warnings
from collections.abc import Callable

import astropy.units as u
import numpy as np
import pytest
from scipy.integrate import IntegrationWarning, quad

from rotmod.geometry import DetectorArray, Instrument, Mask
from rotmod.materials import PAPER_SIGMA_662, Material


@pytest.fixture
def rng() -> np.random.Generator:
    """A fixed-seed generator, so every randomised check is reproducible."""
    return np.random.default_rng(20240531)


@pytest.fixture
def paper_instrument() -> Instrument:
    """The paper's simulation set-up with its fixed 662 keV attenuation (sigma = 0.103 cm2/g):
    lead, a = b = c = 4 cm, h = 2 cm, L = 100 cm, one detector on the axis."""
    return Instrument.paper(sigma=PAPER_SIGMA_662)


@pytest.fixture
def make_instrument() -> Callable[..., Instrument]:
    """Factory for small instruments with an explicit linear attenuation ``mu`` (1/cm)."""

    def make(
        a: float, b: float, c: float, h: float, mu: float, positions=((0.0, 0.0),), L=100.0
    ) -> Instrument:
        mask = Mask(a, b, h, L, Material("Pb"), mu=mu)
        return Instrument(mask, DetectorArray(np.asarray(positions, dtype=float), c))

    return make


def _path_in_slats(u: float, s: float, a: float, b: float) -> float:
    """``|[u, u + s] ∩ slats|`` by explicit interval overlaps (exactly 0 inside a gap)."""
    lo, hi = (u, u + s) if s >= 0 else (u + s, u)
    p = a + b
    total = 0.0
    for k in range(math.floor((lo - b / 2) / p) - 1, math.floor((hi - b / 2) / p) + 2):
        e1 = b / 2 + k * p
        total += max(0.0, min(hi, e1 + a) - max(lo, e1))
    return total


def reference_profile(uc: float, s: float, radius: float, a: float, b: float, tau: float) -> float:
    """Brute-force profile: adaptive quadrature of the chord-weighted 1-D integral.

    ``P = (2/pi) ∫ T(uc - R cos phi) sin^2 phi dphi`` over ``0..pi`` (``u = uc - R cos phi``
    turns the chord weight ``2 sqrt(R^2 - (u-uc)^2)/(pi R^2) du`` into ``(2/pi) sin^2 phi
    dphi``).  ``scipy.integrate.quad`` runs separately between every breakpoint of ``T``
    (slat edges ``e`` and ``e - s``) and, inside clip regions, at a few multiples of the
    exponential's decay length ``|s|/tau`` so that steep exponentials are resolved.
    """
    p = a + b

    def transmission(u: float) -> float:
        if s == 0.0:
            inside = (u - b / 2) % p <= a
            if not inside:
                return 1.0
            return 0.0 if math.isinf(tau) else math.exp(-tau)
        g = _path_in_slats(u, s, a, b)
        if g <= 0.0:
            return 1.0
        return 0.0 if math.isinf(tau) else math.exp(-tau * g / abs(s))

    lo, hi = uc - radius, uc + radius
    points = {lo, hi}
    for shift in (0.0, -s):
        k0 = math.floor((lo - shift - b / 2) / p) - 1
        k1 = math.floor((hi - shift - b / 2) / p) + 1
        for k in range(k0, k1 + 1):
            for e in (b / 2 + k * p + shift, b / 2 + k * p + a + shift):
                if lo < e < hi:
                    points.add(e)
    if s != 0.0 and 0.0 < tau < math.inf:
        ell = abs(s) / tau
        for e in list(points):
            for j in (0.5, 2.0, 8.0, 30.0):
                for x in (e - j * ell, e + j * ell):
                    if lo < x < hi:
                        points.add(x)
    phis = [math.acos(min(max((uc - x) / radius, -1.0), 1.0)) for x in sorted(points)]
    total = 0.0
    for f1, f2 in itertools.pairwise(phis):
        if f2 > f1:
            with warnings.catch_warnings():
                # Round-off warnings at epsabs = 1e-14 are harmless; the error estimate
                # below is what we rely on.
                warnings.simplefilter("ignore", IntegrationWarning)
                val, err = quad(
                    lambda f: transmission(uc - radius * math.cos(f)) * math.sin(f) ** 2,
                    f1, f2, epsabs=1e-14, epsrel=1e-13, limit=200,
                )
            assert err < 1e-11, f"reference quadrature did not converge ({err:g})"
            total += val
    return total * 2.0 / math.pi


@pytest.fixture
def reference() -> Callable[[float, float, float, float, float, float], float]:
    """The brute-force :func:`reference_profile` (uc, s, radius, a, b, tau) -> P."""
    return reference_profile


def rad(value):
    """Angles the tests compute in radians, as Quantities (a plain public angle means deg)."""
    return u.Quantity(value, u.rad)

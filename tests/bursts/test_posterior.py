"""A burst's position probability over its modes and the cone, against closed forms."""

from __future__ import annotations

import astropy.units as u
import numpy as np
import pytest
from astropy.coordinates import SkyCoord

from rotmod.bursts.posterior import Posterior, tempered
from rotmod.errors import ParameterError
from rotmod.sources.localisation import Region
from rotmod.sources.model import PointSource

pytest.importorskip("astropy_healpix")

A = SkyCoord(10.0 * u.deg, 20.0 * u.deg)
B = SkyCoord(30.0 * u.deg, 20.0 * u.deg)
SIGMA_A, SIGMA_B = 0.5, 1.0  # deg
TS_A, TS_B = 100.0, 96.0


def square(centre: SkyCoord, sigma: float, peak: float, n: int = 41) -> Region:
    """A circular Gaussian likelihood surface of width ``sigma`` (deg) and peak TS ``peak``
    on ``n x n`` points over +-4.5 sigma (mass beyond: exp(-10))."""
    s = np.radians(sigma)
    o = np.linspace(-4.5 * s, 4.5 * s, n)
    xx, yy = np.meshgrid(o, o)
    logp = -0.5 * (xx**2 + yy**2) / s**2
    density = np.exp(logp) / np.exp(logp).sum()
    return Region(PointSource(centre), o, density, peak + 2.0 * logp, 0.0)


def test_modes_are_weighted_by_peak_likelihood_times_width() -> None:
    # A mode's probability is exp(TS_max / 2) times its surface's integral, 2 pi sigma^2
    # for a Gaussian: B / A = exp(-2) (1.0 / 0.5)^2.  The sampled sums are Riemann sums of
    # Gaussians at 0.225 sigma, exact to ~1e-9; truncation at 4.5 sigma loses exp(-10).
    post = Posterior((square(A, SIGMA_A, TS_A), square(B, SIGMA_B, TS_B)))
    p_a, p_b = post.square_probability
    assert p_b / p_a == pytest.approx(np.exp(-2.0) * 4.0, rel=1e-4)
    assert post.best_probability == pytest.approx(1.0 / (1.0 + 4.0 * np.exp(-2.0)), rel=1e-4)
    # The 90 % highest-density region in closed form: with densities rho_A, rho_B at the
    # peaks, the level lam solves sum_i p_i (1 - lam / rho_i) = 0.9, and each disc has area
    # 2 pi sigma_i^2 ln(rho_i / lam).
    rho = np.array([p_a / SIGMA_A**2, p_b / SIGMA_B**2])  # (per 2 pi deg^2)
    lam = 0.1 / np.sum(np.array([p_a, p_b]) / rho)
    assert lam < rho.min()  # both discs are in the region
    area = 2.0 * np.pi * np.sum(np.array([SIGMA_A, SIGMA_B]) ** 2 * np.log(rho / lam))
    # Discretised at 0.225 sigma: the boundary moves by up to half a step.
    assert post.area(0.9) == pytest.approx(area, rel=0.05)
    assert post.contains(A) and post.contains(B)
    r = SIGMA_A * np.sqrt(2.0 * np.log(rho[0] / lam))  # the 90 % disc's radius around A
    assert post.contains(A.directional_offset_by(0.0, 0.8 * r * u.deg))
    assert not post.contains(A.directional_offset_by(0.0, 1.25 * r * u.deg))
    assert not post.contains(SkyCoord(20.0 * u.deg, 35.0 * u.deg))
    m = post.probability_map()
    assert m.prob.sum() == pytest.approx(1.0, abs=1e-12)


def test_overlapping_squares_count_once() -> None:
    a = square(A, SIGMA_A, TS_A)
    twice = Posterior((a, square(A, SIGMA_A, TS_A)))
    assert twice.square_probability[1] == 0.0
    assert twice.best_probability == pytest.approx(1.0, abs=1e-15)
    # A wide square around a narrow one: it owns only what the narrow one does not cover.
    wide = square(A.directional_offset_by(0.0 * u.deg, 1.0 * u.deg), 1.0, TS_A)
    post = Posterior((a, wide))
    alone = Posterior((wide,))
    assert post.square_probability[1] < alone.square_probability[0]
    # On HEALPix: what lies in the narrow square is its own probability only (the wide
    # square's density there is not added), up to the wide square's probability within one
    # of its grid steps of the narrow square's edge (the linear interpolation of its density
    # blends its owned and unowned points across that band).
    m = post.probability_map()
    assert m.prob.sum() == pytest.approx(1.0, abs=1e-12)
    hp = pytest.importorskip("astropy_healpix")
    centres = hp.HEALPix(m.nside, "nested", frame="icrs").healpix_to_skycoord(m.pixels)
    x, y = a.tangent(centres)
    inside = (np.abs(x) < a.offsets[-1]) & (np.abs(y) < a.offsets[-1])
    pts, dens = wide.sample_positions()
    px, py = a.tangent(pts)
    edge = np.maximum(np.abs(px), np.abs(py))
    step = wide.offsets[1] - wide.offsets[0]
    band = post.square_probability[1] * dens[np.abs(edge - a.offsets[-1]) <= step].sum() / \
        dens[edge > a.offsets[-1]].sum()
    assert m.prob[inside].sum() == pytest.approx(post.square_probability[0], abs=band)


def test_a_posterior_refuses_what_it_cannot_hold() -> None:
    with pytest.raises(ParameterError, match="one or more Regions"):
        Posterior(())
    post = Posterior((square(A, SIGMA_A, TS_A),))
    with pytest.raises(ParameterError, match="containment"):
        post.level(1.5)
    with pytest.raises(ParameterError, match="one SkyCoord"):
        post.contains("here")


def test_tempering_widens_a_gaussian_by_the_root_of_the_factor() -> None:
    # A Gaussian surface exp(TS / 2) of width sigma, its TS divided by f, is a Gaussian of
    # width sigma sqrt(f): the 90 % radius sigma sqrt(2 ln 10) grows by sqrt(f), to the
    # 41-point grid's resolution (0.225 sigma, so 5 %; the square spans 4.5 sigma, which
    # holds the 90 % region up to f = 3: 2.15 sqrt 3 = 3.7 sigma).  The growth is monotone
    # in f, f = 1 changes nothing, and 1 / f undoes f.  Modes' weights are tempered too:
    # B / A = exp(-(TS_A - TS_B) / (2 f)) (1.0 / 0.5)^2.
    base = square(A, SIGMA_A, TS_A)
    r0 = base.radius(0.9)
    assert r0 == pytest.approx(SIGMA_A * np.sqrt(2.0 * np.log(10.0)), rel=0.05)
    radii = [tempered(base, f).radius(0.9) for f in (1.0, 1.3, 1.7, 2.2, 3.0)]
    assert np.all(np.diff(radii) > 0)
    for f, r in zip((1.3, 1.7, 2.2, 3.0), radii[1:], strict=True):
        assert r / r0 == pytest.approx(np.sqrt(f), rel=0.05)
    assert tempered(base, 1.0) is base
    back = tempered(tempered(base, 2.0), 0.5)
    np.testing.assert_allclose(back.density, base.density, rtol=1e-10, atol=1e-300)
    np.testing.assert_allclose(back.ts, base.ts, rtol=1e-12)
    f = 2.0
    post = Posterior((tempered(base, f), tempered(square(B, SIGMA_B, TS_B), f)))
    p_a, p_b = post.square_probability
    # The surfaces are truncated at 4.5 / sqrt(2) sigma of the tempered width (mass beyond
    # exp(-5) = 0.7 %, a little more from B's wider tails).
    assert p_b / p_a == pytest.approx(np.exp(-2.0 / f) * 4.0, rel=0.02)
    with pytest.raises(ParameterError, match="factor must be"):
        tempered(base, 0.0)

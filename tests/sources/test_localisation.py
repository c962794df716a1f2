"""Localisation regions: scaling with exposure, the systematic term's Rayleigh radii,
outlines that enclose the region."""

from __future__ import annotations

import numpy as np
import pytest

from rotmod.bursts.posterior import tempered
from rotmod.errors import ParameterError
from rotmod.reconstruction import PoissonData
from rotmod.sources import PointSource, SkyModel, SourceFitter, fit, localise
from rotmod.sources.localisation import EDGE_DROP

BKG = 2.0
TRUTH = PointSource((3.3, 47.0), flux=0.08)


def _region(field, exposure, **kw):
    model = SkyModel([TRUTH], background=np.full(7, BKG))
    data = PoissonData(model.expected_counts(field, exposure), exposure)  # Asimov
    fitter = SourceFitter(field, data)
    res = fit(field, data, SkyModel([PointSource(TRUTH.position)]), errors=False)
    return localise(fitter, res.model, 0, **kw)


def test_regions_shrink_as_one_over_root_exposure(field):
    # Asimov data: every ln L difference is proportional to the exposure, so 4x the
    # exposure halves a locally quadratic surface's radii (5 %: the surface's curvature
    # changes over the region and the square is discrete).
    r1, r4 = _region(field, 2000.0), _region(field, 8000.0)
    assert r1.closed and r4.closed
    for q in (0.68, 0.9):
        assert r4.radius(q) / r1.radius(q) == pytest.approx(0.5, rel=0.05)
    assert r1.contains(TRUTH.position, 0.68)
    assert r1.area(0.9) > r1.area(0.68)


def test_a_square_sized_for_a_tempered_surface_holds_it(field):
    # Asimov data: TS / 4 at 4x the exposure is the surface at 1x.  Sized for it
    # (dispersion=4), the square holds the tempered surface as the 1x square holds its own:
    # the edge falls by EDGE_DROP and the radii agree (5 %, as above).  Sized for the
    # untempered surface, the tempered one would run past the edge (drop ~14 / 4).
    r1 = _region(field, 2000.0)
    r4 = tempered(_region(field, 8000.0, dispersion=4.0), 4.0)
    drop = r4.ts.max() - r4.ts
    edge = np.concatenate([drop[0], drop[-1], drop[:, 0], drop[:, -1]])
    assert r4.closed and edge.min() >= EDGE_DROP
    for q in (0.68, 0.9):
        assert r4.radius(q) / r1.radius(q) == pytest.approx(1.0, rel=0.05)


def test_a_dominant_systematic_gives_rayleigh_radii(field):
    sigma = 3.0  # deg per axis, ~20x the statistical size of this source
    reg = _region(field, 8000.0, systematic=sigma)
    # Radius holding q of a circular Gaussian: sigma sqrt(-2 ln(1 - q)) (Rayleigh); the
    # statistical part adds ~1 % in quadrature, the grid ~2 %.
    for q in (0.68, 0.9):
        assert reg.radius(q) == pytest.approx(sigma * np.sqrt(-2 * np.log(1 - q)), rel=0.04)


def test_the_outline_encloses_the_regions_area(field):
    reg = _region(field, 4000.0)
    (theta, phi), = reg.contour(0.9)
    # Polygon area in the source's tangent plane (small region: plane geometry, deg).
    x = theta * np.cos(np.radians(phi))
    y = theta * np.sin(np.radians(phi))
    area = 0.5 * abs(np.dot(x, np.roll(y, 1)) - np.dot(y, np.roll(x, 1)))
    # 10 %: the pixel count of the region against the interpolated contour of 41^2 points.
    assert area == pytest.approx(reg.area(0.9), rel=0.1)


def test_a_faint_source_is_reported_as_not_localised(field):
    model = SkyModel([PointSource((3.3, 47.0), flux=0.004)], background=np.full(7, BKG))
    data = PoissonData(model.expected_counts(field, 1000.0), 1000.0)
    fitter = SourceFitter(field, data)
    reg = localise(fitter, fitter.maximise(SkyModel([PointSource((3.3, 47.0))]))[0], 0)
    assert not reg.closed


def test_bad_arguments_are_refused(field):
    model = SkyModel([TRUTH], background=np.full(7, BKG))
    fitter = SourceFitter(field, PoissonData(model.expected_counts(field, 100.0), 100.0))
    with pytest.raises(ParameterError, match="k must index a source"):
        localise(fitter, model, 3)
    with pytest.raises(ParameterError, match="systematic"):
        localise(fitter, model, 0, systematic=-1.0)
    with pytest.raises(ParameterError, match="n_side"):
        localise(fitter, model, 0, n_side=10)
    with pytest.raises(ParameterError, match="dispersion must be finite and >= 1"):
        localise(fitter, model, 0, dispersion=0.5)

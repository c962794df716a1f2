"""Coarse-to-fine reconstruction (issue 24): the restricted operator, the coarse grid, and
the refined image against the full-resolution solve on a case where both run."""

from __future__ import annotations

import numpy as np
import pytest

from rotmod import DetectorArray, Instrument, Mask
from rotmod.errors import ParameterError
from rotmod.reconstruction import MLEM, Refinement, StoppingRule, reconstruct
from rotmod.reconstruction.data import as_data
from rotmod.reconstruction.multires import _refine, _screen_start, coarse_grid
from rotmod.reconstruction.sgp import SGP
from rotmod.response import MaterialisedResponse, RadonResponse, TimeBinning
from rotmod.response.subset import PixelSubset
from rotmod.sky import SkyGrid
from rotmod.testing import dot_test

INST = Instrument(Mask(1.0, 1.0, 1.0, 114.0), DetectorArray.hexagonal(1.0, rings=1))


@pytest.fixture(scope="module")
def case():
    """16 x 16 pixels of 0.3 deg, 7 detectors, 180 bins (1260 data for 256 unknowns, so the
    maximum-likelihood image is unique and SGP converges to it), two sources."""
    resp = RadonResponse(INST, SkyGrid((16, 16), 0.3), TimeBinning(180), 662.0,
                         dtype=np.float64)
    truth = np.zeros((16, 16))
    truth[6, 7], truth[12, 3] = 40.0, 20.0
    counts = np.random.default_rng(5).poisson(400.0 * (resp.forward(truth.ravel()) + 1.0))
    return resp, counts.astype(float)


def test_pixel_subset_is_the_parents_columns(case) -> None:
    resp, _ = case
    pix = np.array([3, 40, 41, 200, 255])
    sub = PixelSubset(resp, pix)
    x = np.random.default_rng(1).random(pix.size)
    full = np.zeros(resp.n_sky)
    full[pix] = x
    # The same values as the parent's products (float64: rounding only).
    np.testing.assert_allclose(sub.forward(x), resp.forward(full), rtol=1e-12, atol=1e-14)
    y = np.random.default_rng(2).random((resp.n_det, resp.n_time))
    np.testing.assert_allclose(sub.adjoint(y), resp.adjoint(y)[pix], rtol=1e-12)
    dot_test(sub, rng=np.random.default_rng(3), rtol=1e-12)
    # A grown subset reuses the columns it has and computes the others.
    grown = PixelSubset(resp, np.array([41, 7, 3]), reuse=sub)
    np.testing.assert_array_equal(grown.columns([0, 1, 2]), resp.columns([41, 7, 3]))
    with pytest.raises(ParameterError, match="distinct"):
        PixelSubset(resp, [1, 1])


def test_coarse_pixels_are_the_means_of_their_fine_pixels() -> None:
    fine = SkyGrid((7, 9), 0.2, center=(1.0, -2.0))
    coarse = coarse_grid(fine, 3)
    assert coarse.shape == (3, 3) and coarse.pixel_size == pytest.approx(0.6)

    def plane(g):  # tangent-plane coordinates (axis-tangent grids: tan(theta) e^(i phi))
        th, ph = (a.to_value("rad").reshape(g.shape) for a in g.directions())
        return np.tan(th) * np.cos(ph), np.tan(th) * np.sin(ph)

    fx, fy = plane(fine)
    cx, cy = plane(coarse)
    # Coarse pixel (1, 1) covers fine rows 3-5 and columns 3-5 (wholly inside the field).
    assert cx[1, 1] == pytest.approx(fx[3:6, 3:6].mean(), abs=1e-12)
    assert cy[1, 1] == pytest.approx(fy[3:6, 3:6].mean(), abs=1e-12)


def test_refined_image_is_the_full_resolution_maximum(case) -> None:
    """Started from a support that misses the second source, the full-resolution check
    (``ts_cut = 0``: the optimality condition) must bring it in, and the result must be the
    full solve's maximum of the likelihood."""
    radon, counts = case
    resp = radon.materialise()  # the same values; BLAS products make the 2 solves quick
    data = as_data(counts, exposure=400.0, background=1.0)
    stop = StoppingRule(max_iter=20000, chi2_dof=None, rel_tol=1e-13)
    full = SGP(resp, data, stopping=stop).run()
    support = np.zeros((16, 16), dtype=bool)
    support[4:9, 5:10] = True  # the first source only
    res, rounds = _refine(resp, data, SGP, support, Refinement(factor=4, ts_cut=0.0),
                          stopping=stop)
    assert len(rounds) >= 2 and rounds[0].added > 0
    assert support[12, 3] and rounds[-1].max_ts_outside == 0.0
    # Both are converged maxima of one concave likelihood, which on 1260 data for 256
    # unknowns is strictly concave: the deviances agree to the stopping rule's 1e-13 per
    # iteration summed over the last iterations (measured 3e-9 relative), the images to
    # its flux scale (measured 4e-5 of a 40-unit peak).
    assert res.deviance == pytest.approx(full.deviance, rel=1e-6)
    image = np.zeros(resp.n_sky)
    image[support.ravel()] = res.image.ravel()
    np.testing.assert_allclose(image, full.image.ravel(), atol=1e-2)
    # Independent of the check: the gradient from the materialised columns is >= 0 at every
    # pixel held at 0 (no flux can be added there), up to rounding of the converged solve.
    p = resp.matrix.reshape(-1, resp.n_sky)
    mu = 400.0 * (p @ image + 1.0)
    grad = p.T @ (400.0 * (1.0 - counts.ravel() / mu))
    assert grad[~support.ravel()].min() > -1e-3 * np.abs(grad).max()


def test_default_method_coarse_to_fine_puts_sources_on_their_pixels(case) -> None:
    resp, counts = case
    res = reconstruct(resp, counts, exposure=400.0, background=1.0, seed=1, coarse=4)
    assert res.image.shape == (16, 16) and res.grid == resp.grid
    assert res.method == "ncar" and res.extras["support"][6, 7]
    img = res.image
    assert np.unravel_index(int(np.argmax(img)), img.shape) == (6, 7)
    assert np.unravel_index(int(np.argmax(img[9:, :7])), (7, 7)) == (3, 3)
    assert res.extras["max_ts_outside"] <= 25.0
    assert res.extras["layers"].shape[-2:] == (16, 16)


def test_an_empty_sky_is_solved_not_refused(case) -> None:
    # Nothing significant at the coarse scale: the solve starts from the most significant
    # coarse pixel (it crashed on an empty support), and the check finds nothing to add.
    resp, _ = case
    counts = np.random.default_rng(6).poisson(400.0 * (resp.forward(np.zeros(256)) + 1.0))
    counts = counts.astype(float)
    res = reconstruct(resp, counts, exposure=400.0, background=1.0, seed=1, coarse=4)
    assert res.extras["support"].sum() == 16  # one coarse pixel of 4 x 4
    assert res.extras["max_ts_outside"] <= 25.0
    # Flux is a few counts' worth at most: background fluctuations, no source.
    assert res.image.sum() * 400.0 < 3.0 * np.sqrt(counts.sum())


def test_refinement_refusals(case) -> None:
    resp, counts = case
    with pytest.raises(ParameterError, match=r"coarse\.factor"):
        Refinement(factor=1)
    with pytest.raises(ParameterError, match="uncertainty"):
        reconstruct(resp, counts, exposure=400.0, coarse=4, uncertainty="bootstrap")
    bare = MaterialisedResponse(np.ones((2, 4, 3)))  # a matrix from elsewhere: no grid
    with pytest.raises(ParameterError, match="SkyGrid"):
        reconstruct(bare, np.ones((2, 4)), coarse=2)


def test_screening_grows_the_support_and_leaves_the_result_to_the_method(case) -> None:
    """Short SGP fits grow the support from one that misses the second source; the result
    is then exactly the method's (here MLEM, so the two cannot be confused) on the grown
    support, and its own check passes."""
    radon, counts = case
    resp = radon.materialise()
    data = as_data(counts, exposure=400.0, background=1.0)
    support = np.zeros((16, 16), dtype=bool)
    support[4:9, 5:10] = True  # the first source only
    stop = StoppingRule(max_iter=300, chi2_dof=None, rel_tol=None)
    res, rounds = _refine(resp, data, MLEM, support,
                          Refinement(factor=4, screen_iterations=30), stopping=stop)
    kinds = [r.kind for r in rounds]
    assert kinds[0] == "screen" and rounds[0].added > 0 and support[12, 3]
    assert kinds[-1] == "solve" and "screen" not in kinds[kinds.index("solve"):]
    assert rounds[-1].max_ts_outside <= 25.0 and res.method == "mlem" and res.n_iter == 300
    # The same solve started afresh on the final support: bit for bit (MLEM is deterministic).
    alone = MLEM(PixelSubset(resp, np.flatnonzero(support.ravel())), data, stopping=stop).run()
    np.testing.assert_array_equal(res.image, alone.image)
    # Without screening every round is the method's, and it ends on the same sources.
    support0 = np.zeros((16, 16), dtype=bool)
    support0[4:9, 5:10] = True
    _, rounds0 = _refine(resp, data, MLEM, support0,
                         Refinement(factor=4, screen_iterations=0), stopping=stop)
    assert {r.kind for r in rounds0} == {"solve"} and support0[12, 3]
    # One screening fit allowed, and it adds pixels: the method solves the grown support,
    # and the support returned is the one it solved (the image is scattered onto it).
    support1 = np.zeros((16, 16), dtype=bool)
    support1[4:9, 5:10] = True
    res1, rounds1 = _refine(resp, data, MLEM, support1,
                            Refinement(factor=4, screen_iterations=30, max_rounds=1),
                            stopping=stop)
    assert [r.kind for r in rounds1] == ["screen", "solve"] and rounds1[0].added > 0
    assert rounds1[1].pixels == support1.sum() == 25 + rounds1[0].added
    assert res1.image.size == support1.sum()
    with pytest.raises(ParameterError, match=r"coarse\.screen_iterations"):
        Refinement(screen_iterations=-1)


def test_a_screening_fit_starts_where_the_last_one_ended() -> None:
    """The warm start maps each old pixel's flux to its place among the new, sorted pixels,
    sets the new ones to 0 and carries the background amplitudes over."""
    old_pix = np.array([3, 10, 11, 40])
    z_old = np.array([1.0, 2.0, 3.0, 4.0, 7.0, 8.0])  # 4 pixels, 2 background amplitudes
    pix = np.array([0, 3, 5, 10, 11, 12, 40, 41])
    z = _screen_start((old_pix, z_old), pix, 2)
    np.testing.assert_array_equal(z, [0.0, 1.0, 0.0, 2.0, 3.0, 0.0, 4.0, 0.0, 7.0, 8.0])
    assert _screen_start(None, pix, 2) is None

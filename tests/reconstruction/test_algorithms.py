"""Reconstruction algorithms on small dense problems: correctness, invariants, errors."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rotmod import RotmodError, get_model
from rotmod.reconstruction import (
    ALGORITHMS,
    MLEM,
    NCAR,
    SGP,
    PoissonData,
    Reconstructor,
    StoppingRule,
    get_algorithm,
    log_likelihood,
    reconstruct,
    register_algorithm,
)
from rotmod.reconstruction.data import as_data
from rotmod.reconstruction.metrics import (
    find_peaks,
    localization_errors,
    peak_fwhm,
    recovered_flux,
    spurious_peak_level,
    two_source_dip,
)
from rotmod.sky.grid import SkyGrid
from rotmod.testing import MatrixOperator, tiny_grid, tiny_instrument
from tests.conftest import rad


@pytest.fixture(scope="module")
def small() -> MatrixOperator:
    inst = tiny_instrument()  # lead a = b = c = 4, h = 2, L = 100 cm, 7 detectors
    grid = tiny_grid()  # 11 x 11 pixels of 0.6 deg
    th, ph = grid.directions()
    xi = (np.arange(90) + 0.5) * 2 * np.pi / 90
    return MatrixOperator(get_model("standard").profile(inst, rad(th), rad(ph), rad(xi)), grid)


def _point(R: MatrixOperator, iy: int, ix: int, flux: float = 5.0) -> np.ndarray:
    s = np.zeros(R.n_sky)
    s[iy * R.grid.shape[1] + ix] = flux
    return s


@pytest.mark.parametrize(
    "method", ["backprojection", "mlem", "mart", "sirt", "ncar", "osem", "sgp", "sparse"]
)
def test_noiseless_point_source_lands_on_its_pixel(small: MatrixOperator, method: str) -> None:
    E = 50.0
    y = E * (small.forward(_point(small, 3, 7)) + 2.0)
    res = reconstruct(small, y, method, exposure=E, background=2.0, seed=0, max_iter=300)
    # Exact pixel: noiseless data, source on a pixel centre.
    assert np.unravel_index(np.argmax(res.image), res.image.shape) == (3, 7)
    assert res.image.shape == small.grid.shape
    assert res.run_time >= 0 and res.method == method


@settings(max_examples=15, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    n_src=st.integers(1, 3),
    bkg=st.one_of(st.just(0.0), st.floats(0.1, 5.0)),
)
def test_mlem_likelihood_never_decreases_and_stays_nonnegative(seed: int, n_src: int,
                                                               bkg: float) -> None:
    rng = np.random.default_rng(seed)
    P = rng.uniform(0, 1, size=(2, 15, 12))
    s = np.zeros(12)
    s[rng.choice(12, n_src, replace=False)] = rng.uniform(1, 10, n_src)
    y = rng.poisson(3.0 * (P @ s + bkg)).astype(float)
    data = PoissonData(y, 3.0, background=bkg if bkg > 0 else None, fit_background=bkg > 0)
    solver = MLEM(MatrixOperator(P), data, max_iter=60, chi2_dof=None, rel_tol=None)
    solver.setup()
    ll = [log_likelihood(y, solver.mu)]
    for _ in range(60):
        solver.step()
        assert np.all(solver.z >= 0)
        ll.append(log_likelihood(y, solver.mu))
    # EM is monotone; allow float64 round-off relative to |ll| (1e-12).
    assert np.all(np.diff(ll) >= -1e-12 * np.abs(ll[:-1]).max())


def test_mart_images_nonnegative(small: MatrixOperator) -> None:
    rng = np.random.default_rng(4)
    y = rng.poisson(10.0 * (small.forward(_point(small, 5, 5)) + 1.0))
    for ns in (1, 3):
        res = reconstruct(small, y, "mart", exposure=10.0, background=1.0, n_subsets=ns,
                          max_iter=50)
        assert np.all(res.image >= 0)


def test_stopping_rule_triggers_at_the_stated_fit_level(small: MatrixOperator) -> None:
    rng = np.random.default_rng(5)
    y = rng.poisson(20.0 * (small.forward(_point(small, 5, 5, 20.0)) + 3.0))
    for target in (1.2, 1.05):
        res = reconstruct(small, y, "mlem", exposure=20.0, background=3.0, chi2_dof=target,
                          max_iter=5000, rel_tol=None)
        h = res.history["chi2_dof"]
        assert res.stop_reason.startswith("chi2/dof")
        # Stops at the first iteration at or below the target, not before.
        assert h[-1] <= target and np.all(h[:-1] > target)
    res = reconstruct(small, y, "mlem", exposure=20.0, background=3.0, chi2_dof=None,
                      rel_tol=1e-3, max_iter=5000)
    d = res.history["deviance"]
    assert abs(d[-2] - d[-1]) / d[-2] < 1e-3 and res.stop_reason.startswith("relative")
    res = reconstruct(small, y, "mlem", exposure=20.0, background=3.0, chi2_dof=None,
                      rel_tol=None, max_iter=7)
    assert res.n_iter == 7 and res.stop_reason.startswith("max_iter")


def test_callback_can_stop(small: MatrixOperator) -> None:
    y = 10.0 * (small.forward(_point(small, 5, 5)) + 1.0)
    res = reconstruct(small, y, "mlem", exposure=10.0, background=1.0,
                      callbacks=[lambda s, i: i >= 3])
    assert res.n_iter == 3 and "callback" in res.stop_reason


def test_bootstrap_uncertainty_scales_like_sqrt_counts(small: MatrixOperator) -> None:
    s = _point(small, 5, 5, 10.0)
    sig = []
    for E in (10.0, 160.0):
        y = np.round(E * (small.forward(s) + 2.0))
        res = reconstruct(small, y, "mlem", exposure=E, background=2.0, uncertainty="bootstrap",
                          n_boot=30, seed=1, max_iter=40, chi2_dof=None, rel_tol=None)
        assert res.uncertainty is not None and res.uncertainty.shape == small.grid.shape
        sig.append(res.uncertainty[5, 5])
    # 16x the counts: the rate uncertainty should drop by 4 (sqrt); 30 replicas give the
    # std to ~13 % each, so the ratio to ~20 %: accept 3.0 .. 5.3.
    assert 3.0 < sig[0] / sig[1] < 5.3


def test_bootstrap_is_seeded(small: MatrixOperator) -> None:
    y = np.round(20.0 * (small.forward(_point(small, 5, 5)) + 2.0))
    kw = dict(exposure=20.0, background=2.0, uncertainty="bootstrap", n_boot=3, max_iter=5)
    a = reconstruct(small, y, "mlem", seed=7, **kw).uncertainty
    b = reconstruct(small, y, "mlem", seed=7, **kw).uncertainty
    np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("method", sorted(ALGORITHMS))
def test_bootstrap_works_for_every_method(small: MatrixOperator, method: str) -> None:
    # NCAR (randomised: its own seed) used to raise TypeError "multiple values for 'seed'".
    y = np.round(20.0 * (small.forward(_point(small, 5, 5)) + 2.0))
    kw = dict(exposure=20.0, background=2.0, uncertainty="bootstrap", n_boot=3, max_iter=5)
    a = reconstruct(small, y, method, seed=3, **kw)
    b = reconstruct(small, y, method, seed=3, **kw)
    assert a.uncertainty.shape == small.grid.shape
    assert np.all(np.isfinite(a.uncertainty)) and np.all(a.uncertainty >= 0)
    np.testing.assert_array_equal(a.uncertainty, b.uncertainty)  # seeded, replicas included


def test_ncar_noise_layers_seeded_and_consistent(small: MatrixOperator) -> None:
    rng = np.random.default_rng(2)
    y = rng.poisson(20.0 * (small.forward(_point(small, 4, 6, 10.0)) + 3.0))
    kw = dict(exposure=20.0, background=3.0, n_layers=3)
    a = reconstruct(small, y, "ncar", seed=11, **kw)
    b = reconstruct(small, y, "ncar", seed=11, **kw)
    np.testing.assert_array_equal(a.image, b.image)
    assert a.extras["layers"].shape == (3, *small.grid.shape)
    assert np.all(a.image >= 0)
    # The refit restores consistency with the data (same rule as the plain solve); 0.1 is
    # the one-sigma width sqrt(2/dof) of chi2/dof for 630 bins times ~2.
    assert a.chi2_dof <= a.extras["unlayered_chi2_dof"] + 0.1


def test_ncar_honours_a_warm_start(small: MatrixOperator) -> None:
    """NCAR's core solve starts where ``warm_start`` says (it used to start flat whatever
    it was given): one iteration from a converged SGP solution stays at it."""
    rng = np.random.default_rng(4)
    data = as_data(rng.poisson(20.0 * (small.forward(_point(small, 4, 6, 10.0)) + 3.0)),
                   exposure=20.0, background=3.0)
    best = SGP(small, data).run()
    one = StoppingRule(max_iter=1, chi2_dof=None, rel_tol=None)
    warm = NCAR(small, data, n_layers=0, stopping=one)
    warm.warm_start(np.concatenate([best.image.ravel(), np.zeros(warm.model.size
                                                                  - small.n_sky)]))
    cold = NCAR(small, data, n_layers=0, stopping=one).run()
    res = warm.run()
    # From the maximum one SGP step changes the likelihood by ~nothing; from the flat start
    # it is one MLEM step, hundreds of deviance units away.
    assert res.deviance == pytest.approx(best.deviance, rel=1e-6)
    assert cold.deviance > best.deviance + 50.0


def test_bad_input_raises_naming_the_parameter(small: MatrixOperator) -> None:
    y = np.ones((small.n_det, small.n_time))
    with pytest.raises(RotmodError, match="counts must have shape"):
        reconstruct(small, np.ones((2, 3)), "mlem")
    with pytest.raises(RotmodError, match="counts must be >= 0"):
        reconstruct(small, -y, "mlem")
    with pytest.raises(RotmodError, match="method must be one of"):
        reconstruct(small, y, "clean")
    with pytest.raises(RotmodError, match="max_iter must be an integer >= 1"):
        reconstruct(small, y, "mlem", max_iter=0)
    with pytest.raises(RotmodError, match="exposure must be"):
        reconstruct(small, y, "mlem", exposure=np.ones(3))
    with pytest.raises(RotmodError, match="unknown parameter"):
        reconstruct(small, y, "mlem", relax=0.5)
    with pytest.raises(RotmodError, match="relax must be"):
        reconstruct(small, y, "mart", relax=1.5)
    with pytest.raises(RotmodError, match="n_boot must be"):
        reconstruct(small, y, "mlem", uncertainty="bootstrap", n_boot=1)
    with pytest.raises(RotmodError, match="n_layers must be"):
        reconstruct(small, y, "ncar", n_layers=-1)
    with pytest.raises(RotmodError, match="max_iter"):
        StoppingRule(max_iter=0)


def test_registry_has_the_four_methods() -> None:
    assert {"backprojection", "mlem", "mart", "ncar"} <= set(ALGORITHMS)


class _FluxScale(Reconstructor):
    """A toy algorithm, one class and its registration: a flat image scaled to the counts."""

    def _initial(self) -> np.ndarray:
        return np.ones(self.model.size)

    def _update(self) -> None:
        self.z = self.z * (self.y.sum() / self.mu.sum())
        self.mu = self.model.forward(self.z)


def test_a_new_algorithm_is_one_registered_class(small: MatrixOperator) -> None:
    # What an algorithm's module does when imported (the same class again is a no-op).
    name = "test-flux-scale"
    register_algorithm(name)(_FluxScale)
    assert name in ALGORITHMS.names() and get_algorithm(name) is _FluxScale
    y = np.round(20.0 * (small.forward(_point(small, 5, 5)) + 2.0))
    res = reconstruct(small, y, name, exposure=20.0, max_iter=3)
    assert res.method == name and 1 <= res.n_iter <= 3 and res.image.shape == small.grid.shape
    # A flat image fitted to the total counts.
    assert np.ptp(res.image) == 0 and res.model_counts.sum() == pytest.approx(y.sum())
    boot = reconstruct(small, y, name, exposure=20.0, max_iter=3, uncertainty="bootstrap",
                       n_boot=2, seed=1)
    assert boot.uncertainty.shape == small.grid.shape
    with pytest.raises(RotmodError, match=r"got 'mlme'; did you mean 'mlem'\?"):
        reconstruct(small, y, "mlme")


def test_metrics_on_synthetic_images() -> None:
    grid = SkyGrid((21, 21), 0.2)
    px, py = grid.pixel_centers()
    src = grid.from_tangent(np.array([-0.6, 0.6]), np.array([0.0, 0.0]))

    def gauss(x0: float, fwhm: float) -> np.ndarray:
        s = fwhm / 2.3548
        return np.exp(-((px - x0) ** 2 + py**2) / (2 * s * s))

    img = gauss(-0.6, 0.5) + gauss(0.6, 0.5)
    # The other source's tail (~1e-5 of the peak at 1 deg) pulls the centroid by ~1e-6 deg.
    assert np.all(localization_errors(img, grid, src, radius=0.4) < 1e-5)
    assert two_source_dip(img, grid, src, radius=0.4) < 0.1
    merged = gauss(-0.6, 2.0) + gauss(0.6, 2.0)
    assert two_source_dip(merged, grid, src, radius=0.4) > 0.9
    one = grid.from_tangent(np.array([0.0]), np.array([0.0]))
    g1 = gauss(0.0, 1.0)
    # Equivalent-disc FWHM of a pixelised Gaussian: within one pixel (0.2 deg) of 1 deg.
    assert abs(peak_fwhm(g1, grid, one, radius=0.5) - 1.0) < 0.2
    spiky = g1.copy()
    spiky[2, 2] = 0.3
    assert spurious_peak_level(spiky, grid, one, radius=0.5) == pytest.approx(0.3)
    assert find_peaks(spiky)[0].tolist() == [10, 10]
    delta = np.zeros(grid.shape)
    delta[10, 10] = 4.0
    assert recovered_flux(delta, grid, one, [4.0], radius=0.3) == pytest.approx(1.0)

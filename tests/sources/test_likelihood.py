"""The bounded Poisson maximiser against an independent optimiser and the KKT conditions."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import minimize

from rotmod.sources.likelihood import Groups, log_likelihood, maximise


def _problem(rng, n_bins=300, n_par=6):
    A = rng.random((n_bins, n_par)) * (rng.random((n_bins, n_par)) < 0.6)
    x_true = rng.random(n_par) * 5
    x_true[[1, 4]] = 0.0  # two amplitudes on the bound
    m0 = np.full(n_bins, 0.5)
    return A, rng.poisson(m0 + A @ x_true).astype(float), m0


def test_maximum_matches_an_independent_optimiser(rng):
    for _ in range(5):
        A, y, m0 = _problem(rng)
        res = maximise(A, y, m0)

        def neg(x, A=A, y=y, m0=m0):
            mu = m0 + A @ x
            return -(np.sum(y * np.log(mu) - mu)), -(A.T @ (y / mu - 1.0))

        ref = minimize(neg, np.ones(A.shape[1]), jac=True, method="L-BFGS-B",
                       bounds=[(0, None)] * A.shape[1], options={"ftol": 1e-15, "gtol": 1e-12})
        # Same maximum: the two ln L differ only by the data's constant (log_likelihood's).
        const = float(np.sum(y * np.log(np.where(y > 0, y, 1.0)) - y))
        assert res.loglike + const == pytest.approx(-ref.fun, abs=1e-6)
        # KKT: zero gradient where x > 0, non-positive where x sits on the bound.
        g = A.T @ (y / res.mu - 1.0)
        free = res.x > 1e-9
        assert np.all(np.abs(g[free]) < 1e-5 * np.abs(A.T @ (y / res.mu)).max())
        assert np.all(g[~free] <= 1e-6)
        assert np.all(res.x >= 0)


def test_held_amplitudes_stay_and_the_rest_are_optimal(rng):
    A, y, m0 = _problem(rng)
    x0 = np.ones(A.shape[1])
    fixed = np.zeros(A.shape[1], bool)
    fixed[0] = True
    res = maximise(A, y, m0, x0, fixed=fixed)
    assert res.x[0] == 1.0
    free = ~fixed & (res.x > 1e-9)
    g = A.T @ (y / res.mu - 1.0)
    assert np.all(np.abs(g[free]) < 1e-6 * y.sum())


def test_log_likelihood_differences_keep_their_digits():
    # 1e8 counts: sum(y ln mu) ~ 1e9, whose rounding (1e-7) would swamp a TS of 1e-6.
    y = np.full(10_000, 1e4)
    mu = y * (1 + 1e-7)
    exact = float(np.sum(y * np.log1p(1e-7) - y * 1e-7))
    assert log_likelihood(y, mu) - log_likelihood(y, y) == pytest.approx(exact, rel=1e-6)
    assert log_likelihood(np.array([1.0]), np.array([0.0])) == -np.inf


def test_group_amplitudes_are_the_same_as_their_columns(rng):
    # Background-like amplitudes given as groups (one per block of bins) or as explicit
    # indicator columns: one likelihood, one maximum.
    A, y, m0 = _problem(rng, n_bins=240, n_par=6)
    index = np.repeat(np.arange(4), 60)
    value = rng.random(240) + 0.5
    cols = np.zeros((240, 4))
    cols[np.arange(240), index] = value
    dense = maximise(np.hstack([A, cols]), y, m0)
    k = A.shape[1]
    grouped = maximise(A, y, m0, groups=Groups(index, value, 4))
    np.testing.assert_allclose(grouped.x, dense.x, rtol=1e-6, atol=1e-9)
    assert grouped.loglike == pytest.approx(dense.loglike, abs=1e-8)
    # The grouped information is the Schur complement: its inverse is the column block of
    # the full covariance.
    full_cov = np.linalg.inv((np.hstack([A, cols]) * (y / dense.mu**2)[:, None]).T
                             @ np.hstack([A, cols]))
    free = dense.x[:k] > 1e-9
    np.testing.assert_allclose(grouped.covariance()[np.ix_(free, free)],
                               full_cov[:k, :k][np.ix_(free, free)], rtol=1e-4)

"""The Poisson likelihood of a linear model with non-negative amplitudes, maximised exactly.

Every source product is a fit of this one model to counts ``y`` in bins ``i``:

    mu_i = m0_i + sum_j A_ij x_j,    x_j >= 0,

``m0`` the fixed part (counts), ``A`` the columns of the free amplitudes (a source's response
column times the exposure, a detector's background template times the exposure) and ``x``
the amplitudes (fluxes, background levels).  The log-likelihood ``l = sum_i y_i ln mu_i -
mu_i`` (the Cash statistic is ``-2 l``) is concave in ``x``, so the maximum on the
non-negative orthant is unique and a projected Newton method (Bertsekas 1982) finds it:
variables at the bound whose gradient pushes outward are held there, the rest take the
Newton step of the exact Hessian ``-A^T diag(y / mu^2) A``, and a backtracking line search
keeps every step an ascent.  The boundary is part of the statistics: a flux fitted at 0
makes a likelihood ratio whose null distribution is ``1/2 chi2_0 + 1/2 chi2_1`` (Chernoff
1954), which is what :mod:`rotmod.sources` quotes and ``benchmarks/sources_calibration.py``
measures.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rotmod.errors import ParameterError

__all__ = ["LinearPoissonFit", "log_likelihood", "maximise"]

#: Newton decrement (in units of ln L) below which a fit has converged; 1e-9 makes the TS
#: (twice a difference of two maxima) exact to ~1e-8, far below its statistical spread of 1.
TOL = 1e-9
MAX_ITER = 200


def log_likelihood(y: np.ndarray, mu: np.ndarray) -> float:
    """``ln L = sum(y ln mu - mu)`` less the constant ``sum(y ln y - y)``.

    Summed as ``y ln(mu / y) + y - mu`` (the logarithm as ``log1p((mu - y) / y)``), terms
    that are small near a fit, so that the differences a TS is made of keep their digits
    (``sum y ln mu`` of a large data set is ~1e8 and would leave ~1e-8 of them).
    ``-inf`` where some ``mu <= 0`` has counts.
    """
    if np.any((mu <= 0) & (y > 0)):
        return -np.inf
    # ln(mu / y) as log1p((mu - y) / y): exact to rounding of the small difference.
    pos = y > 0
    excess = np.where(pos, (np.maximum(mu, 1e-300) - y) / np.where(pos, y, 1.0), 0.0)
    return float(np.sum(np.where(pos, y * np.log1p(excess) - (mu - y), -mu)))


@dataclass(frozen=True)
class LinearPoissonFit:
    """The maximum of the likelihood (see the module notes).

    Attributes
    ----------
    x : ndarray
        Amplitudes at the maximum (>= 0).
    loglike : float
        ``ln L`` there (:func:`log_likelihood`: less the data's constant).
    mu : ndarray
        Expected counts there.
    hessian : ndarray
        ``A^T diag(y / mu^2) A``, the observed information of the amplitudes.
    n_iter : int
        Newton steps taken.
    """

    x: np.ndarray
    loglike: float
    mu: np.ndarray
    hessian: np.ndarray
    n_iter: int

    def covariance(self) -> np.ndarray:
        """Inverse of the information (pseudo-inverse where it is singular)."""
        return np.linalg.pinv(self.hessian)


def maximise(
    A: np.ndarray,
    y: np.ndarray,
    m0: np.ndarray | None = None,
    x0: np.ndarray | None = None,
    *,
    fixed: np.ndarray | None = None,
) -> LinearPoissonFit:
    """Maximise the Poisson likelihood of ``mu = m0 + A x`` over ``x >= 0``.

    Parameters
    ----------
    A : ndarray, shape (n_bins, n_par)
        Non-negative columns of the amplitudes.
    y : ndarray, shape (n_bins,)
        Counts (>= 0).
    m0 : ndarray, shape (n_bins,), optional
        Fixed expected counts (default 0).
    x0 : ndarray, shape (n_par,), optional
        Start (default: every column scaled to share the counts).
    fixed : ndarray of bool, shape (n_par,), optional
        Amplitudes held at their start value (a profile likelihood).

    Returns
    -------
    LinearPoissonFit
    """
    A = np.asarray(A, dtype=float)
    y = np.asarray(y, dtype=float)
    n_bins, n_par = A.shape
    m0 = np.zeros(n_bins) if m0 is None else np.asarray(m0, dtype=float)
    hold = np.zeros(n_par, bool) if fixed is None else np.asarray(fixed, bool)
    col = A.sum(axis=0)
    if x0 is None:
        share = max(float(y.sum() - m0.sum()), 1e-3 * max(float(y.sum()), 1.0))
        x = np.where(col > 0, share / max(n_par, 1) / np.where(col > 0, col, 1.0), 0.0)
    else:
        x = np.array(x0, dtype=float)
    if np.any(x < 0) or not np.all(np.isfinite(x)):
        raise ParameterError("x0 must be finite and >= 0")
    # A column that touches no bin is not constrained by the data: its amplitude stays 0.
    dead = col <= 0
    x[dead & ~hold] = 0.0
    mu = m0 + A @ x
    ll = log_likelihood(y, mu)
    if not np.isfinite(ll):
        # Counts where the start predicts none: lift every free amplitude a little.
        x[~hold & ~dead] += max(float(y.sum()), 1.0) / max(float(col[~hold & ~dead].sum()), 1e-300)
        mu = m0 + A @ x
        ll = log_likelihood(y, mu)
        if not np.isfinite(ll):
            raise ParameterError("the model predicts no counts in bins that have counts, "
                                 "whatever its amplitudes")
    n_iter = 0
    while n_iter < MAX_ITER:
        n_iter += 1
        r = y / np.where(mu > 0, mu, np.inf)
        g = A.T @ (r - 1.0)
        H = (A * (r / np.where(mu > 0, mu, np.inf))[:, None]).T @ A
        # Free: not held, not a dead column, and not at the bound being pushed outward.
        free = ~hold & ~dead & ~((x <= 0) & (g <= 0))
        if not free.any():
            break
        Hf = H[np.ix_(free, free)]
        # A tiny ridge keeps a column seen only by empty bins (H = 0) solvable.
        ridge = 1e-12 * max(float(np.max(np.diag(Hf))), 1e-300)
        try:
            d = np.linalg.solve(Hf + ridge * np.eye(Hf.shape[0]), g[free])
        except np.linalg.LinAlgError:
            d = g[free] / np.maximum(np.diag(Hf), 1e-300)
        decrement = float(g[free] @ d)
        # Converged: the remaining gain is below TOL or the rounding of ln L itself.
        if decrement < TOL + 1e-13 * abs(ll):
            break
        step = 1.0
        while True:
            xn = x.copy()
            xn[free] = np.maximum(x[free] + step * d, 0.0)
            mun = m0 + A @ xn
            lln = log_likelihood(y, mun)
            # Armijo on the projected step; the projection can only shorten it.
            if lln >= ll + 1e-4 * float(g[free] @ (xn[free] - x[free])) or step < 1e-9:
                break
            step *= 0.5
        if lln < ll:
            break
        gained = lln - ll
        x, mu, ll = xn, mun, lln
        if gained < 0.1 * TOL and step < 1.0:
            break
    r = y / np.where(mu > 0, mu, np.inf)
    H = (A * (r / np.where(mu > 0, mu, np.inf))[:, None]).T @ A
    return LinearPoissonFit(x, ll, mu, H, n_iter)

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
keeps every step an ascent.  Amplitudes that each touch one group of bins only -- a
detector's background level -- are given as ``groups`` (each bin's group and its column
value) rather than as columns: their block of the Hessian is diagonal, so a Newton step
eliminates them through the Schur complement of the other amplitudes in one pass over the
bins, and no ``n_bins x n_detectors`` matrix is formed (nor a large BLAS product, whose
threads stall on a loaded machine).  The boundary is part of the statistics: a flux fitted
at 0 makes a likelihood ratio whose null distribution is ``1/2 chi2_0 + 1/2 chi2_1`` (Chernoff
1954), which is what :mod:`rotmod.sources` quotes and ``benchmarks/sources_calibration.py``
measures.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import sparse

from rotmod.errors import ParameterError

__all__ = ["Groups", "LinearPoissonFit", "log_likelihood", "maximise"]

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
    # A mu so small that mu / y rounds to 0 gives log1p(-1) = -inf: the answer for counts
    # where nothing is expected, as for mu = 0 above, not a numerical accident to warn of.
    with np.errstate(divide="ignore"):
        return float(np.sum(np.where(pos, y * np.log1p(excess) - (mu - y), -mu)))


@dataclass(frozen=True)
class LinearPoissonFit:
    """The maximum of the likelihood (see the module notes).

    Attributes
    ----------
    x : ndarray
        Amplitudes at the maximum (>= 0): the columns' first, then the groups'.
    loglike : float
        ``ln L`` there (:func:`log_likelihood`: less the data's constant).
    mu : ndarray
        Expected counts there.
    information : ndarray, shape (k, k)
        Observed information of the column amplitudes with the group amplitudes profiled
        out (the Schur complement): its inverse is their covariance.
    n_iter : int
        Newton steps taken.
    """

    x: np.ndarray
    loglike: float
    mu: np.ndarray
    information: np.ndarray
    n_iter: int

    def covariance(self) -> np.ndarray:
        """Covariance of the column amplitudes (pseudo-inverse of :attr:`information`)."""
        return np.linalg.pinv(self.information)


@dataclass(frozen=True)
class Groups:
    """Amplitudes that each multiply one group of bins: ``mu_i += x_{g_i} t_i``.

    Parameters
    ----------
    index : ndarray of int, shape (n_bins,)
        Group of each bin (``0 <= g < size``).
    value : ndarray, shape (n_bins,)
        The group column's value in each bin (>= 0).
    size : int
        Number of groups.
    """

    index: np.ndarray
    value: np.ndarray
    size: int
    indicator: sparse.csr_matrix = field(init=False, repr=False)

    def __post_init__(self) -> None:
        n = len(self.index)
        # Sums over groups as one sparse product (no BLAS threads, no (n_bins, size) array).
        object.__setattr__(self, "indicator", sparse.csr_matrix(
            (np.ones(n), (np.asarray(self.index), np.arange(n))), shape=(self.size, n)))

    def sum(self, v: np.ndarray) -> np.ndarray:
        """Per-group sums of ``v`` (one value per bin, or ``(n_bins, k)``: ``(size, k)``)."""
        return np.asarray(self.indicator @ v)


def _state(A, groups, y, m0, x, k):
    mu = m0 + A @ x[:k]
    if groups is not None:
        mu = mu + x[k:][groups.index] * groups.value
    return mu


def maximise(
    A: np.ndarray,
    y: np.ndarray,
    m0: np.ndarray | None = None,
    x0: np.ndarray | None = None,
    *,
    fixed: np.ndarray | None = None,
    groups: Groups | None = None,
) -> LinearPoissonFit:
    """Maximise the Poisson likelihood of ``mu = m0 + A x + x_g[groups] t`` over ``x >= 0``.

    Parameters
    ----------
    A : ndarray, shape (n_bins, k)
        Non-negative columns of the first ``k`` amplitudes.
    y : ndarray, shape (n_bins,)
        Counts (>= 0).
    m0 : ndarray, shape (n_bins,), optional
        Fixed expected counts (default 0).
    x0 : ndarray, shape (k + n_groups,), optional
        Start (default: every amplitude scaled to share the counts).
    fixed : ndarray of bool, shape (k + n_groups,), optional
        Amplitudes held at their start value (a profile likelihood).
    groups : Groups, optional
        Amplitudes of one group of bins each (after the ``k`` column amplitudes).

    Returns
    -------
    LinearPoissonFit
    """
    A = np.asarray(A, dtype=float).reshape(len(y), -1)
    y = np.asarray(y, dtype=float)
    n_bins, k = A.shape
    n_g = 0 if groups is None else groups.size
    n_par = k + n_g
    m0 = np.zeros(n_bins) if m0 is None else np.asarray(m0, dtype=float)
    hold = np.zeros(n_par, bool) if fixed is None else np.asarray(fixed, bool)
    col = np.concatenate([A.sum(axis=0), groups.sum(groups.value) if n_g else []])
    if x0 is None:
        share = max(float(y.sum() - m0.sum()), 1e-3 * max(float(y.sum()), 1.0))
        x = np.where(col > 0, share / max(n_par, 1) / np.where(col > 0, col, 1.0), 0.0)
    else:
        x = np.array(x0, dtype=float)
    if x.shape != (n_par,) or np.any(x < 0) or not np.all(np.isfinite(x)):
        raise ParameterError(f"x0 must be {n_par} finite values >= 0")
    # A column that touches no bin is not constrained by the data: its amplitude stays 0.
    dead = col <= 0
    x[dead & ~hold] = 0.0
    mu = _state(A, groups, y, m0, x, k)
    ll = log_likelihood(y, mu)
    if not np.isfinite(ll):
        # Counts where the start predicts none: lift every free amplitude a little.
        lift = ~hold & ~dead
        x[lift] += max(float(y.sum()), 1.0) / max(float(col[lift].sum()), 1e-300)
        mu = _state(A, groups, y, m0, x, k)
        ll = log_likelihood(y, mu)
        if not np.isfinite(ll):
            raise ParameterError("the model predicts no counts in bins that have counts, "
                                 "whatever its amplitudes")
    n_iter = 0
    while n_iter < MAX_ITER:
        n_iter += 1
        r = y / np.where(mu > 0, mu, np.inf)
        w = r / np.where(mu > 0, mu, np.inf)
        g = np.concatenate([A.T @ (r - 1.0),
                            groups.sum(groups.value * (r - 1.0)) if n_g else []])
        # Free: not held, not a dead column, and not at the bound being pushed outward.
        free = ~hold & ~dead & ~((x <= 0) & (g <= 0))
        fd, fg = free[:k], free[k:]
        S, Hdg, inv = _schur(A, groups, w, fg)
        rhs = g[:k] - Hdg @ (inv * g[k:]) if n_g else g[:k]
        d = np.zeros(n_par)
        if fd.any():
            Sf = S[np.ix_(fd, fd)]
            # A tiny ridge keeps a column seen only by empty bins (H = 0) solvable.
            ridge = 1e-12 * max(float(np.max(np.abs(np.diag(Sf)))), 1e-300)
            try:
                d[:k][fd] = np.linalg.solve(Sf + ridge * np.eye(Sf.shape[0]), rhs[fd])
            except np.linalg.LinAlgError:
                d[:k][fd] = rhs[fd] / np.maximum(np.diag(Sf), 1e-300)
        if n_g:
            d[k:] = inv * (g[k:] - Hdg.T @ d[:k])
        decrement = float(g[free] @ d[free])
        # Converged: the remaining gain is below TOL or the rounding of ln L itself.
        if not free.any() or decrement < TOL + 1e-13 * abs(ll):
            break
        step = 1.0
        while True:
            xn = x.copy()
            xn[free] = np.maximum(x[free] + step * d[free], 0.0)
            mun = _state(A, groups, y, m0, xn, k)
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
    # The information where the fit ended (every group profiled out).
    w = y / np.where(mu > 0, mu, np.inf) ** 2
    info = _schur(A, groups, w, np.ones(n_g, bool))[0]
    return LinearPoissonFit(x, ll, mu, info, n_iter)


def _schur(A: np.ndarray, groups: Groups | None, w: np.ndarray, free_groups: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(S, H_dg, 1 / H_gg)``: the Hessian of the column amplitudes with the free groups
    eliminated (Schur complement), the cross block and the inverse diagonal of the groups'
    block (0 for held groups)."""
    Hdd = (A * w[:, None]).T @ A
    if groups is None:
        return Hdd, np.zeros((A.shape[1], 0)), np.zeros(0)
    Hdg = groups.sum(A * (groups.value * w)[:, None]).T       # (k, n_groups)
    Hgg = groups.sum(groups.value**2 * w)                      # the diagonal block
    inv = np.where(free_groups & (Hgg > 0), 1.0 / np.where(Hgg > 0, Hgg, 1.0), 0.0)
    return Hdd - (Hdg * inv) @ Hdg.T, Hdg, inv

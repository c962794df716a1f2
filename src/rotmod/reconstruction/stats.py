"""Fit statistics of Poisson counts against a model: deviance (Cash) and Pearson chi-square.

Both are summed over bins with exposure.  ``deviance = 2 sum(mu - y + y ln(y / mu))``
(``0 ln 0 = 0``) is the Cash statistic minus its saturated value, so it is >= 0 and, like
``chi2 = sum((y - mu)^2 / mu)``, has expectation close to the number of bins for a correct
model with enough counts (exactly, for chi2).  Bins whose model is <= 0 (possible only for
signed images such as back-projections) use ``max(y, 1)`` as the variance in chi2 and a
floor of ``1e-12`` counts in the deviance.
"""

from __future__ import annotations

import numpy as np
from scipy.special import xlogy

__all__ = ["chi2", "deviance", "deviance_terms", "log_likelihood"]

_MU_FLOOR = 1e-12


def deviance_terms(y: np.ndarray, mu: np.ndarray, valid: np.ndarray | None = None) -> np.ndarray:
    """Per-bin Poisson deviance ``2 (mu - y + y ln(y / mu))`` of the ``valid`` bins (flat)."""
    y = np.asarray(y, dtype=float)
    m = np.maximum(np.asarray(mu, dtype=float), _MU_FLOOR)
    if valid is not None:
        y, m = y[valid], m[valid]
    # xlogy is 0 where y == 0 (0 ln 0 = 0), with no log(0) evaluated.
    return 2.0 * (m - y + xlogy(y, y / m))


def deviance(y: np.ndarray, mu: np.ndarray, valid: np.ndarray | None = None) -> float:
    """Poisson deviance ``2 sum(mu - y + y ln(y / mu))`` over ``valid`` bins."""
    return float(np.sum(deviance_terms(y, mu, valid)))


def log_likelihood(y: np.ndarray, mu: np.ndarray, valid: np.ndarray | None = None) -> float:
    """Poisson log-likelihood without the ``ln y!`` term: ``sum(y ln mu - mu)``."""
    y = np.asarray(y, dtype=float)
    m = np.maximum(np.asarray(mu, dtype=float), _MU_FLOOR)
    if valid is not None:
        y, m = y[valid], m[valid]
    return float(np.sum(xlogy(y, m) - m))


def chi2(y: np.ndarray, mu: np.ndarray, valid: np.ndarray | None = None) -> float:
    """Pearson chi-square ``sum((y - mu)^2 / mu)`` over ``valid`` bins (see module notes)."""
    y = np.asarray(y, dtype=float)
    m = np.asarray(mu, dtype=float)
    if valid is not None:
        y, m = y[valid], m[valid]
    var = np.where(m > 0, m, np.maximum(y, 1.0))
    return float(np.sum((y - m) ** 2 / var))

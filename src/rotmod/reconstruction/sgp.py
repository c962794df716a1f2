"""Fast Poisson maximum likelihood: scaled gradient projection, and its sparse (l1) prior.

``sgp`` minimises the Poisson negative log-likelihood over ``z >= 0`` by the scaled
gradient projection method of Bonettini, Zanella & Zanni (2009, Inverse Problems 25,
015002): the EM scaling ``D = z / K^T 1`` (its first step with unit step length *is* an
MLEM step), Barzilai-Borwein step lengths alternated adaptively (ABB), projection on the
positive orthant and a non-monotone Armijo line search along the projected direction.
Because the model is linear, ``mu(z + theta d) = mu + theta K d``: one forward and one
adjoint per iteration, as MLEM, and the line search is free.

``sparse`` adds the penalty ``lambda sum_j s_j S_j`` (``s = K^T 1``, the sensitivity: the
penalty is ``lambda`` times the expected sky counts, so ``lambda`` is dimensionless and the
same for any exposure), which on ``S >= 0`` is the l1 norm of the expected counts of each
pixel, as in SPIRAL-TAP (Harmany, Marcia & Willett 2012).  ``lambda`` is chosen from the
data by two-fold cross-validation between Poisson-thinned halves (:func:`select_weight`).
"""

from __future__ import annotations

import logging
import time
from collections import deque
from typing import Any, ClassVar

import numpy as np

from rotmod._validate import as_int
from rotmod.errors import ParameterError
from rotmod.reconstruction.base import (
    ReconstructionResult,
    Reconstructor,
    StoppingRule,
    _check_float,
    _safe_div,
    register_algorithm,
)
from rotmod.reconstruction.data import ForwardModel, PoissonData
from rotmod.reconstruction.stats import deviance_terms

__all__ = ["SGP", "Sparse", "select_weight", "thin_counts"]

log = logging.getLogger(__name__)

# SGP constants (Bonettini et al. 2009, Sec. 4): Armijo fraction, backtracking factor,
# non-monotone memory, step-length bounds, ABB memory.  Scaling floor: a pixel at 0 is
# scaled as if it held 1 % of the flat start's level, so that the gradient can switch it
# on (measured on the thin-mask pair, sparse path: floors of 1e-8 and 1e-4 left the true
# pixels off and noise pixels on, spurious 1.1 and 0.7 of the peak; 1e-2: 0.03).
_BETA, _SHRINK, _M_NONMONO = 1e-4, 0.4, 10
_ALPHA_MIN, _ALPHA_MAX, _M_ALPHA = 1e-5, 1e5, 3
_D_FLOOR = 1e-2


def thin_counts(
    counts: np.ndarray, rng: np.random.Generator, fraction: float = 0.5
) -> tuple[np.ndarray, np.ndarray]:
    """Split counts into two independent Poisson data sets by binomial thinning.

    ``y_a ~ Binomial(y, f)``, ``y_b = y - y_a``: for Poisson ``y`` with mean ``mu`` the
    two are independent Poisson with means ``f mu`` and ``(1 - f) mu``.  Non-integer
    (noiseless) counts are split deterministically.

    Parameters
    ----------
    counts : ndarray
    rng : numpy.random.Generator
    fraction : float
        ``f`` in (0, 1).

    Returns
    -------
    (ndarray, ndarray)
    """
    y = np.asarray(counts, dtype=float)
    if np.all(y == np.round(y)):
        ya = rng.binomial(y.astype(np.int64), fraction).astype(float)
    else:
        ya = fraction * y
    return ya, y - ya


@register_algorithm("sgp")
class SGP(Reconstructor):
    """Poisson maximum likelihood by scaled gradient projection (accelerated EM).

    Minimises ``f(z) = sum_i (mu_i - y_i ln mu_i) + lambda w.z`` over ``z >= 0``
    (``lambda = 0`` here: plain maximum likelihood; see :class:`Sparse`).

    Notes
    -----
    Iteration ``k`` (``g`` the gradient ``K^T 1 + lambda w - K^T(y / mu)``):
    ``D = max(z, eps) / K^T 1`` (EM scaling), ``u = max(0, z - alpha D g)``,
    ``d = u - z``, ``z <- z + theta d`` with the largest ``theta = 0.4^m`` such that
    ``f(z + theta d) <= max(last 10 f) + 1e-4 theta g.d``.  ``alpha`` alternates the two
    scaled Barzilai-Borwein lengths (``s = z_k - z_{k-1}``, ``r = g_k - g_{k-1}``:
    ``alpha1 = s.D^-2 s / s.D^-1 r`` and ``alpha2 = s.D r / r.D^2 r``) by the adaptive rule
    of Frassoldati, Zanghirati & Zanni (2008), in [1e-5, 1e5]; the first step has
    ``alpha = 1``, which is exactly an MLEM step.  The limit points are maxima of the
    likelihood on ``z >= 0`` (Bonettini et al. 2009, Thm 2.1); every iterate is >= 0.
    Stopping (:class:`StoppingRule`): by default when the relative deviance change per
    iteration is below 1e-10 (converged), or after 1000 iterations; the discrepancy
    principle (``chi2_dof=1.0``) is available but off by default, because on low-contrast
    data it stops before close pairs separate (docs/reconstruction.md).
    """

    defaults: ClassVar[dict[str, Any]] = {}
    # Converge as far as 1000 iterations go: on low-contrast data chi2/dof <= 1 is reached
    # (within its +-sqrt(2/dof) noise) long before close pairs separate, and the deviance
    # settles (changes < 1e-8 per iteration) while the pair is still sharpening (measured,
    # NCAR on SGP, thin-mask pair: dip 0.91 at the 1e-8 stop, 0.62 at 1000 iterations); so the
    # discrepancy principle is opt-in (chi2_dof=1.0) and the relative-change rule is 1e-10.
    default_stopping: ClassVar[StoppingRule] = StoppingRule(
        max_iter=1000, chi2_dof=None, rel_tol=1e-10
    )
    #: Penalty weight ``lambda`` of ``lambda sum_j s_j S_j`` (0: maximum likelihood).
    _lam: float = 0.0

    def _penalty_weights(self) -> np.ndarray:
        w = self.model.sensitivity().copy()
        w[self.model.n_sky :] = 0.0  # the background amplitudes are not penalised
        return w

    def _objective(self, mu: np.ndarray, z: np.ndarray) -> float:
        y, v = self._yv, self._valid
        m = mu[v]
        pos = y > 0
        if np.any(m[pos] <= 0):
            return np.inf
        return float(np.sum(m) - np.sum(y[pos] * np.log(m[pos])) + self._lam * (self._w @ z))

    def _gradient(self, mu: np.ndarray) -> np.ndarray:
        return self._sens + self._lam * self._w - self.model.adjoint(_safe_div(self.y, mu))

    def _scaling(self, z: np.ndarray) -> np.ndarray:
        # EM scaling z / s, with z floored at a fraction of the flat start's level so that
        # a pixel at 0 can still be switched on by the gradient.
        return np.where(self._live, _safe_div(np.maximum(z, self._z_floor), self._sens), 0.0)

    def _initial(self) -> np.ndarray:
        m = self.model
        self._sens = m.sensitivity()
        self._live = self._sens > 0
        self._w = self._penalty_weights()
        self._valid = self.data.valid
        self._yv = self.y[self._valid]
        z0 = m.initial()
        self._z_floor = _D_FLOOR * np.where(self._live, z0, 0.0)
        return z0

    def setup(self) -> None:
        """Initialise the estimate, the gradient and the step-length state."""
        super().setup()
        self._pen_dev: list[float] = []
        self.z = np.where(self._live, np.maximum(self.z, 0.0), 0.0)
        self.mu = self.model.forward(self.z)
        self._g = self._gradient(self.mu)
        self._alpha = 1.0
        self._tau = 0.5
        self._alpha2: deque[float] = deque(maxlen=_M_ALPHA)
        self._f = deque([self._objective(self.mu, self.z)], maxlen=_M_NONMONO)
        if not np.isfinite(self._f[0]):
            raise ParameterError(
                "data: counts in bins whose expected count is 0 at the start (no sky "
                "sensitivity and no background there); give a background"
            )

    def _convergence_series(self) -> list[float]:
        # The penalised deviance D + 2 lambda w.z (= 2 (f - f_saturated)): for lambda > 0
        # the penalty can still fall while the deviance has settled.
        return self._pen_dev

    def _record(self) -> None:
        super()._record()
        pen = 2.0 * self._lam * float(self._w @ self.z)
        self._pen_dev.append(self.history["deviance"][-1] + pen)

    @property
    def objective(self) -> float:
        """Current value of the minimised objective ``f(z)``."""
        return self._f[-1]

    def _update(self) -> None:
        z, g, mu = self.z, self._g, self.mu
        D = self._scaling(z)
        u = np.where(self._live, np.maximum(z - self._alpha * D * g, 0.0), 0.0)
        d = u - z
        gd = float(g @ d)
        if not gd < 0:  # projected gradient is zero: stationary point
            return
        Kd = self.model.forward(d) - self.model.fixed
        f_ref = max(self._f)
        theta = 1.0
        while True:
            f_new = self._objective(mu + theta * Kd, z + theta * d)
            if f_new <= f_ref + _BETA * theta * gd:
                break
            theta *= _SHRINK
            if theta < 1e-12:
                return  # no decrease representable in float: stay (the deviance rule stops)
        z_new = z + theta * d
        mu_new = np.maximum(mu + theta * Kd, 0.0)
        g_new = self._gradient(mu_new)
        # Scaled Barzilai-Borwein step lengths at the new point, adaptive alternation.
        s, r = z_new - z, g_new - g
        Dn = self._scaling(z_new)
        live = self._live
        sD, rD = s[live] / Dn[live], r[live] * Dn[live]
        bk, ck = float(sD @ r[live]), float(rD @ s[live])
        a1 = float(sD @ sD) / bk if bk > 0 else _ALPHA_MAX
        rr = float(rD @ rD)
        a2 = ck / rr if ck > 0 and rr > 0 else _ALPHA_MAX
        self._alpha2.append(min(max(a2, _ALPHA_MIN), _ALPHA_MAX))
        if a2 / a1 < self._tau:
            alpha, self._tau = min(self._alpha2), self._tau * 0.9
        else:
            alpha, self._tau = a1, self._tau * 1.1
        self._alpha = min(max(alpha, _ALPHA_MIN), _ALPHA_MAX)
        self.z, self.mu, self._g = z_new, mu_new, g_new
        self._f.append(f_new)


def _background_only(model: Any, y: np.ndarray) -> np.ndarray:
    """``z`` with no sky and the background amplitudes of maximum likelihood."""
    z = np.zeros(model.size)
    if model.template is not None:
        # mu = beta_d T_d (no fixed term when the background is fitted): closed form.
        z[model.n_sky :] = y.sum(axis=1) / model.template.sum(axis=1)
    return z


def _weight_max(model: Any, y: np.ndarray) -> float:
    """The smallest ``lambda`` at which the empty sky is optimal (the lasso's lambda_max).

    At ``S = 0`` (background at its maximum likelihood) the KKT condition
    ``K_j^T (y / mu) <= (1 + lambda) s_j`` holds for every pixel iff ``lambda`` is at least
    ``max_j K_j^T(y / mu0) / s_j - 1``.
    """
    z0 = _background_only(model, y)
    mu0 = model.forward(z0)
    sens = model.sensitivity()[: model.n_sky]
    back = model.adjoint(_safe_div(y, mu0))[: model.n_sky]
    lam = float(np.max(_safe_div(back, sens))) - 1.0
    return max(lam, 1e-6)


def _one_standard_error(terms: list[np.ndarray]) -> int:
    """Index of the largest weight whose held-out deviance is within one standard error
    of the minimum (weights in decreasing order).

    The standard error of the difference of two held-out deviances is that of a sum of
    independent per-bin differences, ``sqrt(n) std(d_k - d_min)`` (the held-out bins are
    independent Poisson counts): the "one-standard-error rule" of cross-validation
    (Hastie, Tibshirani & Friedman, *Elements of Statistical Learning*, Sec. 7.10).
    """
    scores = np.array([t.sum() for t in terms])
    k_min = int(np.argmin(scores))
    for k in range(k_min + 1):
        diff = terms[k] - terms[k_min]
        if scores[k] - scores[k_min] <= np.sqrt(diff.size) * float(np.std(diff)):
            return k
    return k_min


def select_weight(
    response: Any,
    data: PoissonData,
    *,
    rng: np.random.Generator,
    n_weights: int = 13,
    span: float = 1e-6,
    inner_iter: int = 200,
    n_folds: int = 2,
    grid: Any = None,
) -> tuple[float, dict[str, Any]]:
    """The sparsity weight ``lambda`` of :class:`Sparse` by cross-validation of thinned halves.

    The counts are split by binomial thinning into two independent Poisson halves (each
    with half the exposure).  For trial values of ``lambda`` from ``lambda_max`` (where the
    empty sky is optimal) down to ``span * lambda_max`` (``n_weights`` log-spaced values),
    the penalised fit to one half, warm-started from the previous ``lambda`` (a
    continuation path), is scored by the Poisson deviance of the *other* half; with
    ``n_folds = 2`` the roles are swapped and the scores added.  The ``lambda`` of the
    smallest held-out deviance is returned: the one whose image best predicts independent
    data.  The path stops early once the held-out deviance has risen at two successive
    weights.

    Parameters
    ----------
    response : ResponseOperator
    data : PoissonData
    rng : numpy.random.Generator
        Randomness of the thinning.
    n_weights : int
        Number of trial weights (>= 2).
    span : float
        Smallest over largest trial weight, in (0, 1).
    inner_iter : int
        Most SGP iterations per trial weight (>= 1); each fit also stops when the
        relative deviance change per iteration is below 1e-8.
    n_folds : {1, 2}
        One held-out half, or both.
    grid : SkyGrid, optional

    Returns
    -------
    lam : float
    info : dict
        ``weights`` (those tried), ``cv_deviance`` (held-out deviance of each),
        ``lambda_max``, ``iterations`` (SGP iterations spent) and ``half_start`` (the mean
        of the half-data estimates at ``lam``, to warm-start the fit of all the data).
    """
    n_weights = as_int(n_weights, "n_weights", 2)
    n_folds = as_int(n_folds, "n_folds", 1, 2)
    inner_iter = as_int(inner_iter, "inner_iter", 1)
    span = _check_float(span, "span", 0.0, hi=1.0)
    y = np.where(data.valid, data.counts, 0.0)
    ya, yb = thin_counts(y, rng)
    halves = [data.with_counts(ya, 0.5), data.with_counts(yb, 0.5)]
    lam_max = _weight_max(ForwardModel(response, data), y)
    weights = lam_max * np.logspace(0.0, np.log10(span), n_weights)
    rule = StoppingRule(max_iter=inner_iter, chi2_dof=None, rel_tol=1e-8)
    solvers = [
        Sparse(response, halves[k], stopping=rule, grid=grid, weight=float(weights[0]))
        for k in range(n_folds)
    ]
    terms: list[np.ndarray] = []
    path: list[list[np.ndarray]] = []
    iters = 0
    for lam in weights:
        score, zs = 0.0, []
        for k, solver in enumerate(solvers):
            solver._lam = float(lam)
            if path:
                solver.warm_start(path[-1][k])
            solver.setup()
            solver.run_from_setup()
            iters += solver.iteration
            test = halves[1 - k]
            # Both halves have the exposure E/2: the trained model predicts the other half.
            score = score + deviance_terms(test.counts, solver.mu, test.valid)
            zs.append(solver.z.copy())
        terms.append(score)
        path.append(zs)
        if len(terms) - int(np.argmin([t.sum() for t in terms])) > 2:
            break
    scores = np.array([t.sum() for t in terms])
    best = _one_standard_error(terms)
    info = {
        "weights": weights[: len(scores)],
        "cv_deviance": scores,
        "lambda_max": lam_max,
        "iterations": iters,
        "half_start": np.mean(path[best], axis=0),
    }
    log.debug("sparse: lambda %.3g (%d of %d tried), lambda_max %.3g, %d SGP iterations",
              weights[best], best + 1, len(scores), lam_max, iters)
    return float(weights[best]), info


@register_algorithm("sparse")
class Sparse(SGP):
    """Sparse (l1) penalised Poisson maximum likelihood, weight chosen by cross-validation.

    Minimises ``sum_i (mu_i - y_i ln mu_i) + lambda sum_j s_j S_j`` over ``S >= 0`` by
    :class:`SGP` (``s = K^T 1``: the penalty is ``lambda`` times the expected sky counts).

    Parameters
    ----------
    weight : float or "cv"
        ``lambda`` (>= 0; 0 is maximum likelihood), or ``"cv"`` (default): chosen by
        :func:`select_weight` (two-fold cross-validation between Poisson-thinned halves).
    n_weights, span, inner_iter, n_folds
        The cross-validation's trial weights and effort (see :func:`select_weight`).
    seed : None, int, SeedSequence or Generator
        Randomness of the thinning.

    Notes
    -----
    Why l1: the scenes are point sources on a known or fitted background, and positivity
    plus sparsity is the prior that both resolves close pairs (two points explain the data
    with less l1 mass than a blob) and removes the weak noise peaks that plain maximum
    likelihood fits.  On ``S >= 0`` the penalty is linear, so the projected gradient step
    sets pixels exactly to 0.  The KKT condition of a pixel that stays on,
    ``K_j^T(y / mu) = (1 + lambda) s_j``, shows that ``lambda`` is a relative level,
    independent of the exposure: the value found on half the data applies to all of it.
    The penalty biases fluxes low by about ``lambda`` relative to the background-dominated
    counts; the chosen ``lambda`` is reported in ``params["lambda"]`` and the CV curve in
    ``extras``.  The final fit starts from the half-data solutions at the chosen weight.
    """

    defaults: ClassVar[dict[str, Any]] = {
        "weight": "cv",
        "n_weights": 13,
        "span": 1e-6,
        "inner_iter": 200,
        "n_folds": 2,
        "seed": None,
    }
    default_stopping: ClassVar[StoppingRule] = StoppingRule(
        max_iter=1000, chi2_dof=None, rel_tol=1e-8
    )

    def _check_params(self) -> None:
        p = self.params
        if isinstance(p["weight"], str):
            if p["weight"] != "cv":
                raise ParameterError(f"weight must be a number >= 0 or 'cv', got {p['weight']!r}")
        else:
            p["weight"] = _check_float(p["weight"], "weight", 0.0, lo_open=False)
        p["n_weights"] = as_int(p["n_weights"], "n_weights", 2)
        p["span"] = _check_float(p["span"], "span", 0.0, hi=1.0)
        p["inner_iter"] = as_int(p["inner_iter"], "inner_iter", 1)
        p["n_folds"] = as_int(p["n_folds"], "n_folds", 1, 2)
        if not isinstance(p["weight"], str):
            self._lam = p["weight"]

    def run(self) -> ReconstructionResult:
        """Choose the weight (if ``"cv"``), then fit all the data; return the result."""
        t0 = time.perf_counter()
        extras: dict[str, Any] = {}
        if self.params["weight"] == "cv":
            seed = self.params["seed"]
            rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
            p = self.params
            lam, info = select_weight(
                self.response, self.data, rng=rng, n_weights=p["n_weights"], span=p["span"],
                inner_iter=p["inner_iter"], n_folds=p["n_folds"], grid=self.grid,
            )
            self._lam = lam
            if self._warm is None:
                self.warm_start(info.pop("half_start"))
            else:
                info.pop("half_start")
            extras.update({f"cv_{k}" if not k.startswith("cv") else k: v
                           for k, v in info.items()})
        self.setup()
        reason = self.run_from_setup()
        res = self.finalise(reason, extras)
        res.params["lambda"] = self._lam
        res.run_time = time.perf_counter() - t0
        return res

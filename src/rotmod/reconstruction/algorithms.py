"""The reconstruction algorithms: back-projection, MLEM, MART/SMART, SIRT and NCAR.

All act on the augmented model ``mu = K z`` of :class:`~rotmod.reconstruction.data.ForwardModel`
(``z`` = sky pixels plus fitted per-detector background amplitudes), through its forward,
adjoint and sensitivity only.  ``docs/reconstruction.md`` gives the design and the maths.
"""

from __future__ import annotations

import logging
import time
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
from rotmod.reconstruction.sgp import SGP
from rotmod.reconstruction.stats import chi2, deviance

__all__ = ["MART", "MLEM", "NCAR", "OSEM", "SIRT", "BackProjection"]

log = logging.getLogger(__name__)


@register_algorithm("backprojection")
class BackProjection(Reconstructor):
    """Cross-correlation (back-projection) map, normalised by the sensitivity.

    Notes
    -----
    With ``r = y - E B_fixed`` the background-subtracted counts, the per-detector mean rate
    is removed (``r'[d, t] = r - E c_d``, ``c_d = sum_t r / sum_t E``): this is the flat
    background, and it makes the back-projection a correlation with zero-mean profiles
    (``sum_t P (r - E c) = sum_t (P - <P>) (r - E c)``).  The map is
    ``m = P^T(E r') / P^T(E)`` and, with ``scale="fit"``, it is multiplied by the scalar
    ``k`` that best fits the data in least squares (``k = <A m, r'> / <A m', A m'>``, the
    primes marking per-detector mean removal), which puts it in sky units.  The map is
    signed (side lobes are negative).  One forward and two adjoints; no iterations.
    """

    iterative = False
    defaults: ClassVar[dict[str, Any]] = {"scale": "fit"}

    def _check_params(self) -> None:
        if self.params["scale"] not in ("fit", "none"):
            raise ParameterError(f"scale must be 'fit' or 'none', got {self.params['scale']!r}")

    def _initial(self) -> np.ndarray:
        return np.zeros(self.model.size)

    def _update(self) -> None:  # pragma: no cover - direct method
        raise NotImplementedError

    def _demean(self, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        E = self.model.E
        c = _safe_div(r.sum(axis=1), E.sum(axis=1))
        return r - E * c[:, None], c

    def run(self) -> ReconstructionResult:
        """Compute the map (no iterations) and return the result."""
        self.setup()
        m_ = self.model
        E = m_.E
        r, _ = self._demean(self.y - m_.fixed)
        sens = m_.sensitivity()[: m_.n_sky]
        m = _safe_div(m_.response.adjoint(E * r), sens)
        if self.params["scale"] == "fit":
            am, _ = self._demean(E * m_.response.forward(m))
            den = float(np.sum(am * am))
            m = m * (float(np.sum(am * r)) / den if den > 0 else 0.0)
        sky_counts = E * m_.response.forward(m)
        _, c = self._demean(self.y - m_.fixed - sky_counts)
        self.z = np.zeros(m_.size)
        self.z[: m_.n_sky] = m
        self.mu = sky_counts + m_.fixed + E * c[:, None]
        self._record()
        res = self.finalise("direct method (no iterations)")
        res.background = (m_.fixed + E * c[:, None]) / np.where(E > 0, E, 1.0)
        return res


@register_algorithm("mlem")
class MLEM(Reconstructor):
    """Maximum-likelihood expectation maximisation (Richardson–Lucy) for Poisson data.

    Notes
    -----
    ``z <- z / K^T 1 * K^T (y / K z)`` with ``K z = E (P S + B)``; the background amplitudes
    (when fitted) are updated by the same EM step, so the Poisson likelihood never decreases
    and ``z`` stays >= 0.  A known background enters ``K z`` as a fixed term.
    """

    defaults: ClassVar[dict[str, Any]] = {}
    default_stopping: ClassVar[StoppingRule] = StoppingRule(max_iter=500)

    def _initial(self) -> np.ndarray:
        return self.model.initial()

    def _update(self) -> None:
        ratio = _safe_div(self.y, self.mu)
        self.z = self.z * _safe_div(self.model.adjoint(ratio), self.model.sensitivity())
        self.mu = self.model.forward(self.z)


@register_algorithm("osem")
class OSEM(Reconstructor):
    """Ordered-subsets EM (Hudson & Larkin 1994) over blocks of detectors.

    Parameters
    ----------
    n_subsets : int
        Number of detector blocks (detector ``d`` is in block ``d mod n_subsets``), from 1
        (= MLEM) to the number of detectors (default 4).  One iteration visits every block
        once and costs about one forward and one adjoint product in all, like one MLEM
        iteration, when the response computes blocks of rows cheaply
        (:meth:`~rotmod.response.operator.ResponseOperator.forward_detectors`).

    Notes
    -----
    Sub-step for block ``b``: ``z <- z / K_b^T 1 * K_b^T (y_b / K_b z)``.  Each detector of
    the array sees the whole field through the full rotation, so every block alone images
    the sky and the early iterations progress about ``n_subsets`` times faster than MLEM.
    On consistent (noise-free) data the fixed point is MLEM's (the data are fitted
    exactly); on noisy data OS-EM does not converge to the maximum likelihood but settles
    into a cycle near it, so the discrepancy principle is the stop that matters.
    """

    defaults: ClassVar[dict[str, Any]] = {"n_subsets": 4}
    default_stopping: ClassVar[StoppingRule] = StoppingRule(max_iter=500)

    def _check_params(self) -> None:
        n_det = self.data.shape[0]
        self.params["n_subsets"] = as_int(self.params["n_subsets"], "n_subsets", 1, n_det)

    def _initial(self) -> np.ndarray:
        n_det, ns = self.data.shape[0], self.params["n_subsets"]
        self._blocks = [np.arange(k, n_det, ns) for k in range(ns)]
        m = self.model
        self._sens = [m.adjoint_detectors(np.where(self.data.valid[b], 1.0, 0.0), b)
                      for b in self._blocks]
        return m.initial()

    def _update(self) -> None:
        m, y = self.model, self.y
        for b, sens in zip(self._blocks, self._sens, strict=True):
            ratio = _safe_div(y[b], m.forward_detectors(self.z, b))
            self.z = self.z * _safe_div(m.adjoint_detectors(ratio, b), sens)
        self.mu = m.forward(self.z)


@register_algorithm("mart")
class MART(Reconstructor):
    """Multiplicative ART in its simultaneous / block form (SMART; positivity built in).

    Parameters
    ----------
    relax : float
        Relaxation ``lambda`` in (0, 1] (default 1).
    n_subsets : int
        Blocks of time bins (bin ``t`` is in block ``t mod n_subsets``) visited in turn
        within one iteration; 1 is SMART, ``n_time`` is a row-block MART (one mask angle,
        all detectors, per sub-step).  Each block costs one forward and one adjoint.
    delta : float
        Counts added to data and model in the ratio ``(y + delta) / (mu + delta)``
        (> 0): keeps the logarithm finite in empty bins without moving the fixed point
        ``mu = y``.

    Notes
    -----
    ``z_j <- z_j exp(lambda sum_{i in block} K_ij ln((y_i + delta)/(mu_i + delta))
    / sum_{i in block} K_ij)``.
    """

    defaults: ClassVar[dict[str, Any]] = {"relax": 1.0, "n_subsets": 1, "delta": 0.5}
    default_stopping: ClassVar[StoppingRule] = StoppingRule(max_iter=500)

    def _check_params(self) -> None:
        p = self.params
        p["relax"] = _check_float(p["relax"], "relax", 0.0, hi=1.0)
        p["n_subsets"] = as_int(p["n_subsets"], "n_subsets", 1)
        if p["n_subsets"] > self.data.shape[1]:
            raise ParameterError(
                f"n_subsets must be <= the number of time bins ({self.data.shape[1]}), "
                f"got {p['n_subsets']}"
            )
        p["delta"] = _check_float(p["delta"], "delta", 0.0)

    def _initial(self) -> np.ndarray:
        ns = self.params["n_subsets"]
        t = np.arange(self.data.shape[1])
        self._masks = [np.broadcast_to(t % ns == k, self.data.shape) for k in range(ns)]
        if ns == 1:
            self._sens = [self.model.sensitivity()]
        else:
            self._sens = [self.model.adjoint(m.astype(float)) for m in self._masks]
        return self.model.initial()

    def _update(self) -> None:
        lam, d = self.params["relax"], self.params["delta"]
        for mask, sens in zip(self._masks, self._sens, strict=True):
            logr = np.where(mask, np.log((self.y + d) / (np.maximum(self.mu, 0.0) + d)), 0.0)
            expo = np.clip(lam * _safe_div(self.model.adjoint(logr), sens), -50.0, 50.0)
            self.z = self.z * np.exp(expo)
            self.mu = self.model.forward(self.z)


@register_algorithm("sirt")
class SIRT(Reconstructor):
    """Non-negative SIRT: projected, preconditioned Landweber on the weighted data.

    Minimises ``phi(z) = 1/2 sum_i w_i (y_i - (K z)_i)^2`` over ``z >= 0`` with
    ``w_i = 1 / max(y_i, 1)`` (Neyman weights: each residual in units of its Poisson error).

    Parameters
    ----------
    relax : float
        Step ``lambda`` in (0, 2) in units of the diagonal majoriser (default 1).
    accelerate : bool
        Nesterov momentum with adaptive restart (FISTA; default True).

    Notes
    -----
    Step: ``z <- max(0, z + lambda K^T(w (y - K z)) / D)`` with
    ``D = K^T (w K 1)``, a diagonal majoriser of ``K^T W K`` for ``K >= 0`` (the SIRT /
    separable-quadratic-surrogate preconditioner), so ``lambda <= 1`` never increases
    ``phi``.  Non-negativity is the projection; consistency with the data is the
    stopping rule (discrepancy principle, ``chi2/dof <= 1`` by default).
    """

    defaults: ClassVar[dict[str, Any]] = {"relax": 1.0, "accelerate": True}
    default_stopping: ClassVar[StoppingRule] = StoppingRule(max_iter=1000, rel_tol=1e-7)

    def _check_params(self) -> None:
        self.params["relax"] = _check_float(self.params["relax"], "relax", 0.0, hi=1.999)
        self.params["accelerate"] = bool(self.params["accelerate"])

    def _initial(self) -> np.ndarray:
        m = self.model
        self._w = np.where(self.data.valid, 1.0 / np.maximum(self.y, 1.0), 0.0)
        ones = np.ones(m.size)
        k1 = m.forward(ones) - m.fixed
        self._D = m.adjoint(self._w * k1)
        self._live = self._D > 0
        z0 = m.initial()
        self._x_prev = z0.copy()
        self._tk = 1.0
        self._phi = np.inf
        return z0

    def _grad_step(self, v: np.ndarray, mu_v: np.ndarray) -> np.ndarray:
        g = self.model.adjoint(self._w * (self.y - mu_v))
        step = self.params["relax"] * _safe_div(g, self._D)
        return np.where(self._live, np.maximum(v + step, 0.0), 0.0)

    def _update(self) -> None:
        if not self.params["accelerate"]:
            self.z = self._grad_step(self.z, self.mu)
            self.mu = self.model.forward(self.z)
            return
        # FISTA on the momentum point v; restart the momentum when phi goes up.
        t_next = 0.5 * (1 + np.sqrt(1 + 4 * self._tk**2))
        v = self.z + ((self._tk - 1) / t_next) * (self.z - self._x_prev)
        mu_v = self.model.forward(v) if self._tk > 1 else self.mu
        x_new = self._grad_step(v, mu_v)
        mu_new = self.model.forward(x_new)
        phi = 0.5 * float(np.sum(self._w * (self.y - mu_new) ** 2))
        if phi > self._phi:
            self._tk = 1.0
            x_new = self._grad_step(self.z, self.mu)
            mu_new = self.model.forward(x_new)
            phi = 0.5 * float(np.sum(self._w * (self.y - mu_new) ** 2))
        else:
            self._tk = t_next
        self._x_prev, self.z, self.mu, self._phi = self.z, x_new, mu_new, phi


@register_algorithm("ncar")
class NCAR(SIRT):
    """Noise-compensating algebraic reconstruction (our design from the seed paper's outline).

    The core solver enforces the physical constraint (a non-negative sky) and stops when
    the counts are consistent with the data within their noise (discrepancy principle) or
    the fit no longer improves.  Noise compensation: ``n_layers`` randomised noise layers,
    each a reconstruction of a random re-sampling of the counts; the layer images are
    combined pixel by pixel so that only structure reproduced in independent noise
    realisations survives.

    Parameters
    ----------
    n_layers : int
        Number of noise layers ``K`` (>= 0; 0 = the plain constrained solution).
    core : {"sgp", "sirt"}
        The solver of the full data, of every layer and of the refit.  ``"sgp"`` (default):
        Poisson maximum likelihood by scaled gradient projection (:class:`SGP`); the
        layers start from the full-data solution.  ``"sirt"``: the algebraic
        :class:`SIRT` (weighted least squares, Nesterov momentum), each layer from a flat
        start, a SMART refit and SIRT's stopping rule (the design before issue 11; about
        5-10x slower).
    layer_mode : {"split", "redraw"}
        ``"split"`` (default): binomial thinning of the counts into two halves
        ``y = y_a + y_b`` with ``y_a ~ Binomial(y, 1/2)``; for Poisson data the halves are
        *independent* Poisson data sets with half the exposure, reconstructed separately.
        ``"redraw"``: ``y_k ~ Poisson(y)`` (noise added on top of the data's own).
    combine : {"geomean", "median", "mean", "min"}
        How layer images are combined.  In split mode each layer gives
        ``geomean: sqrt(x_a x_b)`` (``min``: ``min(x_a, x_b)``, ``mean``: the average), and
        the layers are averaged; in redraw mode the pixel-wise ``median``/``mean``/``min``
        over the ``K`` images (``geomean`` = the geometric mean).
    seed : None, int, SeedSequence or Generator
        Randomness of the layers.
    refit : bool
        After combining, restore consistency with the full data by iterations of the core
        (``"sirt"``: multiplicative SMART) started from the combined image, with the same
        stopping rule (default True).  Both scale each pixel's step by its value, so they
        cannot create structure where the combined image is ~0: suppressed spurious peaks
        stay suppressed.
    layer_iter : int
        Most iterations of each layer solve and of the refit with the SGP core (>= 1;
        default 150): they start from the full-data solution, so they only adapt it to
        their data.  With the defaults the total is at most 1000 + 7 x 150 = 2050 SGP
        iterations, about 4 MLEM runs of 500.  The SIRT core uses the stopping rule
        throughout.
    relax, accelerate
        As for :class:`SIRT` (``core="sirt"`` only).

    Notes
    -----
    Counts that are not integers (noiseless expectations) are split deterministically
    in halves.  Callbacks are called by every solve (full data, layers, refit).
    ``extras`` holds ``"unlayered"`` (the plain solution of the full data),
    ``"layers"`` (``(K, ny, nx)``; in split mode the per-layer combination) and the
    iteration counts.  Cost: ``2K + 1`` solves plus the refit; with the SGP core the
    layers are warm-started and capped (``layer_iter``), which keeps the total within 5
    MLEM runs (docs/reconstruction.md).
    """

    defaults: ClassVar[dict[str, Any]] = {
        **SIRT.defaults,
        "n_layers": 3,
        "core": "sgp",
        "layer_mode": "split",
        "combine": "geomean",
        "seed": None,
        "refit": True,
        "layer_iter": 150,
    }
    # As SGP's: converge (the discrepancy principle stops short of separating close pairs).
    default_stopping: ClassVar[StoppingRule] = StoppingRule(
        max_iter=1000, chi2_dof=None, rel_tol=1e-10
    )

    def __init__(self, response: Any, data: Any, **kwargs: Any) -> None:
        # The SIRT core keeps SIRT's own stopping rule (discrepancy principle first), so that
        # core="sirt" is the NCAR of before issue 11.
        if kwargs.get("core") == "sirt":
            self.default_stopping = SIRT.default_stopping  # type: ignore[misc]
        super().__init__(response, data, **kwargs)

    def _check_params(self) -> None:
        super()._check_params()
        p = self.params
        p["n_layers"] = as_int(p["n_layers"], "n_layers", 0)
        p["layer_iter"] = as_int(p["layer_iter"], "layer_iter", 1)
        if p["core"] not in ("sgp", "sirt"):
            raise ParameterError(f"core must be 'sgp' or 'sirt', got {p['core']!r}")
        if p["layer_mode"] not in ("split", "redraw"):
            raise ParameterError(
                f"layer_mode must be 'split' or 'redraw', got {p['layer_mode']!r}"
            )
        if p["combine"] not in ("geomean", "median", "mean", "min"):
            raise ParameterError(
                f"combine must be 'geomean', 'median', 'mean' or 'min', got {p['combine']!r}"
            )
        if p["layer_mode"] == "split" and p["combine"] == "median":
            raise ParameterError("combine='median' needs layer_mode='redraw'")

    def _layer_stopping(self) -> StoppingRule:
        """The rule of the layer solves and the refit (capped by ``layer_iter``, SGP core)."""
        st = self.stopping
        if self.params["core"] != "sgp":
            return st
        return StoppingRule(min(st.max_iter, self.params["layer_iter"]), st.chi2_dof,
                            st.rel_tol, min(st.min_iter, self.params["layer_iter"]))

    def _solve(self, data: Any, start: np.ndarray | None = None,
               stopping: StoppingRule | None = None) -> Reconstructor:
        stopping = self.stopping if stopping is None else stopping
        if self.params["core"] == "sgp":
            solver: Reconstructor = SGP(self.response, data, stopping=stopping,
                                        grid=self.grid, callbacks=self.callbacks)
        else:
            solver = SIRT(
                self.response, data, stopping=stopping, grid=self.grid,
                relax=self.params["relax"], accelerate=self.params["accelerate"],
                callbacks=self.callbacks,
            )
        if start is not None:
            solver.warm_start(start)
        solver.setup()
        solver.run_from_setup()
        return solver

    def _inner(self, counts: np.ndarray, exposure_scale: float,
               start: np.ndarray | None = None) -> Reconstructor:
        return self._solve(self.data.with_counts(counts, exposure_scale), start,
                           self._layer_stopping())

    def run(self) -> ReconstructionResult:
        """Plain constrained solution, then the noise layers; return the combined result."""
        t0 = time.perf_counter()
        if self.params["core"] == "sirt":
            full = super().run()
        else:
            # A warm start (warm_start) is the core solve's start; the layers then start
            # from the core's solution as always.
            solver = self._solve(self.data, self._warm)
            self._t0, self.z, self.mu = t0, solver.z, solver.mu
            self.iteration, self.history = solver.iteration, solver.history
            full = self.finalise(solver.stopping.check(
                solver.iteration, solver.history["chi2_dof"], solver.history["deviance"]
            ) or "stopped")
        K = self.params["n_layers"]
        if K == 0:
            return full
        # SGP layers start from the full solution (they converge to the halves' own maxima
        # of the likelihood; SIRT stops early, so it keeps its flat start).
        start = self.z.copy() if self.params["core"] == "sgp" else None
        seed = self.params["seed"]
        rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
        y = self.data.counts
        integer = bool(np.all(y == np.round(y)))
        if not integer:
            log.info("ncar: non-integer counts, splitting deterministically in halves")
        mode, comb = self.params["layer_mode"], self.params["combine"]
        skies, betas, iters = [], [], []
        for _ in range(K):
            if mode == "split":
                ya = rng.binomial(y.astype(np.int64), 0.5).astype(float) if integer else y / 2
                sa, sb = self._inner(ya, 0.5, start), self._inner(y - ya, 0.5, start)
                xa, ba = self.model.split(sa.z)
                xb, bb = self.model.split(sb.z)
                if comb == "geomean":
                    skies.append(np.sqrt(xa * xb))
                elif comb == "min":
                    skies.append(np.minimum(xa, xb))
                else:
                    skies.append(0.5 * (xa + xb))
                betas.append(0.5 * (ba + bb))
                iters.append((sa.iteration, sb.iteration))
            else:
                yk = rng.poisson(y).astype(float) if integer else y.copy()
                s = self._inner(yk, 1.0, start)
                x, b = self.model.split(s.z)
                skies.append(x)
                betas.append(b)
                iters.append((s.iteration,))
        stack = np.asarray(skies)
        if mode == "split" or comb == "mean":
            sky = stack.mean(axis=0)
        elif comb == "median":
            sky = np.median(stack, axis=0)
        elif comb == "min":
            sky = stack.min(axis=0)
        else:
            sky = np.exp(np.mean(np.log(np.maximum(stack, 1e-300)), axis=0))
            sky[np.any(stack <= 0, axis=0)] = 0.0
        self.z = np.concatenate([sky, np.mean(betas, axis=0)])
        self.mu = self.model.forward(self.z)
        reason, n_refit = "noise layers combined (no refit)", 0
        if self.params["refit"]:
            if self.params["core"] == "sgp":
                ref: Reconstructor = SGP(self.response, self.data,
                                         stopping=self._layer_stopping(), grid=self.grid,
                                         callbacks=self.callbacks)
            else:
                ref = MART(self.response, self.data, stopping=self.stopping, grid=self.grid,
                           callbacks=self.callbacks)
            ref.warm_start(self.z)
            ref.setup()
            ref._record()
            reason = ref.stopping.check(
                max(ref.stopping.min_iter, 1), ref.history["chi2_dof"], [np.inf]
            ) or None
            if reason is None:
                reason, n_refit = ref.run_from_setup(), ref.iteration
            else:
                reason = "combined layers already " + reason
            self.z, self.mu = ref.z, ref.mu
        res = self.finalise(reason)
        res.run_time = time.perf_counter() - t0
        res.extras.update(
            unlayered=full.image,
            unlayered_chi2_dof=full.chi2_dof,
            layers=stack.reshape((K, *self.image_shape)),
            layer_iterations=iters,
            refit_iterations=n_refit,
        )
        v = self.data.valid
        log.debug(
            "ncar: %d layers; chi2/dof %.3f (unlayered %.3f), deviance %.1f",
            K, chi2(y, self.mu, v) / self.dof, full.chi2_dof, deviance(y, self.mu, v),
        )
        return res

"""Per-pixel uncertainty of any algorithm by a Poisson bootstrap."""

from __future__ import annotations

import logging
import time
from typing import Any

import numpy as np

from rotmod._validate import as_int
from rotmod.errors import ParameterError
from rotmod.limits import check_memory, check_time
from rotmod.reconstruction.base import get_algorithm
from rotmod.reconstruction.data import as_data

__all__ = ["bootstrap_images", "check_bootstrap"]

log = logging.getLogger(__name__)


def _replica_seconds(wall: float, result: Any) -> float:
    """One replica's wall time, bounded from a measured run of ``wall`` s: an iterative
    method may go on to ``max_iter`` on a replica's noisier data where the measured run
    stopped early (the discrepancy rule often stops the data's own run after a few)."""
    n, most = result.n_iter, result.params.get("max_iter")
    if n > 0 and isinstance(most, int) and most > n:
        return wall * most / n
    return wall


def check_bootstrap(n_boot: int, n_sky: int, seconds_each: float | None = None) -> None:
    """Refuse a bootstrap of ``n_boot`` replicas before it starts: its images (``n_boot x
    n_sky`` float64, held twice while stacked) against the memory budget, and, given the
    measured wall time of one reconstruction, its time against the time budget.

    Raises
    ------
    rotmod.limits.MemoryBudgetError, rotmod.limits.TimeBudgetError
        With the estimate, naming ``n_boot``.
    """
    what = f"a bootstrap of n_boot = {n_boot} replicas of {n_sky} pixels"
    # The relative error of a standard deviation from n draws is ~1 / sqrt(2 (n - 1)).
    hint = "ask for fewer replicas (20 to 100 give a one-sigma map to 16-7 %)"
    check_memory(2 * 8.0 * n_boot * n_sky, what, hint=hint)
    if seconds_each is not None:
        check_time(n_boot, 1.0 / max(seconds_each, 1e-9), what, unit="replicas", hint=hint)


def bootstrap_images(
    response: Any,
    data: Any,
    method: Any,
    *,
    n_boot: int = 20,
    seed: Any = None,
    redraw: str = "data",
    model_counts: np.ndarray | None = None,
    seconds_each: float | None = None,
    **params: Any,
) -> np.ndarray:
    """Reconstructions of ``n_boot`` Poisson re-draws of the data.

    Parameters
    ----------
    response : ResponseOperator
    data : PoissonData, FoldedProfiles or ndarray
    method : str or Reconstructor subclass
    n_boot : int
        Number of re-draws (>= 1).
    seed : None, int or SeedSequence
        Each replica gets its own spawned stream (replica ``k`` is reproducible alone).
    redraw : {"data", "model"}
        ``y* ~ Poisson(y)`` (non-parametric) or ``y* ~ Poisson(model_counts)``.
    model_counts : ndarray, optional
        The fitted model, required for ``redraw="model"``.
    seconds_each : float, optional
        The wall time of one replica (s), to estimate the bootstrap's time before it starts
        (:func:`check_bootstrap`); default: the first replica's, measured, set-up included,
        scaled to ``max_iter`` iterations if it stopped before.
    **params
        Solver parameters (as for :func:`~rotmod.reconstruction.reconstruct`).

    Returns
    -------
    ndarray, shape (n_boot, ny, nx)

    Raises
    ------
    rotmod.limits.MemoryBudgetError, rotmod.limits.TimeBudgetError
        ``n_boot`` replicas would not fit the memory or time budget (refused before the
        first replica for memory, and before the second for time unless ``seconds_each``
        is given).
    """
    cls = get_algorithm(method)
    n_boot = as_int(n_boot, "n_boot", 1)
    keys = ("exposure", "background", "fit_background")
    d = as_data(data, **{k: params.pop(k) for k in keys if k in params})
    if redraw == "data":
        lam = d.counts
    elif redraw == "model":
        if model_counts is None:
            raise ParameterError("model_counts is required for redraw='model'")
        lam = np.maximum(np.asarray(model_counts, dtype=float), 0.0)
    else:
        raise ParameterError(f"redraw must be 'data' or 'model', got {redraw!r}")
    check_bootstrap(n_boot, response.n_sky, seconds_each)
    ss = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
    out = []
    for k in range(n_boot):
        # One child at a time: the same streams as ss.spawn(n_boot), without making them
        # all first (1e5 of them take a second, before any check of the time).
        gen_ss, alg_ss = ss.spawn(1)[0].spawn(2)
        rng = np.random.default_rng(gen_ss)
        p = dict(params)
        if "seed" in cls.defaults:
            p["seed"] = alg_ss
        t0 = time.perf_counter()
        res = cls(response, d.with_counts(rng.poisson(lam).astype(float)), **p).run()
        out.append(res.image)
        if k == 0 and seconds_each is None:  # the rest, at the first replica's measured time
            check_bootstrap(n_boot - 1, response.n_sky,
                            _replica_seconds(time.perf_counter() - t0, res))
    log.debug("bootstrap: %d replicas of %s", n_boot, cls.name)
    return np.asarray(out)

"""Per-pixel uncertainty of any algorithm by a Poisson bootstrap."""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from rotmod._validate import as_int
from rotmod.errors import ParameterError
from rotmod.reconstruction.base import get_algorithm
from rotmod.reconstruction.data import as_data

__all__ = ["bootstrap_images"]

log = logging.getLogger(__name__)


def bootstrap_images(
    response: Any,
    data: Any,
    method: Any,
    *,
    n_boot: int = 20,
    seed: Any = None,
    redraw: str = "data",
    model_counts: np.ndarray | None = None,
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
    **params
        Solver parameters (as for :func:`~rotmod.reconstruction.reconstruct`).

    Returns
    -------
    ndarray, shape (n_boot, ny, nx)
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
    ss = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
    out = []
    for child in ss.spawn(n_boot):
        gen_ss, alg_ss = child.spawn(2)
        rng = np.random.default_rng(gen_ss)
        p = dict(params)
        if "seed" in cls.defaults:
            p["seed"] = alg_ss
        res = cls(response, d.with_counts(rng.poisson(lam).astype(float)), **p).run()
        out.append(res.image)
    log.debug("bootstrap: %d replicas of %s", n_boot, cls.name)
    return np.asarray(out)

"""``reconstruct``: one call from a response and folded counts to an image (and its errors).

It sits above the solvers (:mod:`rotmod.reconstruction.base`, the registry) and the
bootstrap (:mod:`rotmod.reconstruction.bootstrap`), which both stand on the registry alone.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from rotmod._validate import as_int
from rotmod.errors import ParameterError
from rotmod.reconstruction.base import ReconstructionResult, Reconstructor, get_algorithm
from rotmod.reconstruction.bootstrap import _replica_seconds, bootstrap_images, check_bootstrap
from rotmod.reconstruction.multires import Refinement, coarse_to_fine
from rotmod.response.operator import ResponseOperator

__all__ = ["DEFAULT_METHOD", "reconstruct"]

#: The method :func:`reconstruct` uses when none is named (the choice and its evidence:
#: docs/reconstruction.md, "Choosing the default").
DEFAULT_METHOD = "ncar"


def reconstruct(
    response: ResponseOperator,
    data: Any,
    method: str | type[Reconstructor] | None = None,
    *,
    uncertainty: str | None = None,
    n_boot: int = 20,
    redraw: str = "data",
    seed: Any = None,
    coarse: Refinement | int | None = None,
    **params: Any,
) -> ReconstructionResult:
    """Reconstruct a sky image in one line.

    Parameters
    ----------
    response : ResponseOperator
    data : PoissonData, FoldedProfiles or ndarray
        Folded counts (and exposure, background; see :class:`Reconstructor`).
    method : str or Reconstructor subclass, optional
        A name in :data:`~rotmod.reconstruction.base.ALGORITHMS` (``ALGORITHMS.names()``
        lists them) or a solver class; default :data:`DEFAULT_METHOD`.
    uncertainty : {None, "bootstrap"}
        ``"bootstrap"`` adds a per-pixel one-sigma map from ``n_boot`` reconstructions of
        Poisson re-draws of the data (same method and parameters).
    n_boot : int
        Bootstrap replicas (>= 2).
    redraw : {"data", "model"}
        Re-draw from the observed counts (``y* ~ Poisson(y)``) or from the fitted model.
    seed : None, int or numpy.random.SeedSequence
        Seeds the bootstrap and, for randomised methods (NCAR), the method.
    coarse : Refinement or int, optional
        Solve coarse-to-fine (:func:`~rotmod.reconstruction.multires.coarse_to_fine`): a
        coarse grid first, then the method at full resolution on the pixels with flux,
        checked at full resolution by a score test.  An int is the coarse factor.  Not
        with ``uncertainty``.
    **params
        Passed to the solver class (stopping rule, callbacks, grid, exposure, background,
        fit_background and the algorithm's own parameters).

    Returns
    -------
    ReconstructionResult

    Raises
    ------
    ParameterError
        Unknown method or parameter, bad data or shapes.
    """
    cls = get_algorithm(DEFAULT_METHOD if method is None else method)
    ss = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
    own, boot_ss = ss.spawn(2)
    if "seed" in cls.defaults and "seed" not in params:
        params["seed"] = own
    if uncertainty not in (None, "bootstrap"):
        raise ParameterError(f"uncertainty must be None or 'bootstrap', got {uncertainty!r}")
    if coarse is not None:
        if uncertainty is not None:
            raise ParameterError("coarse: a coarse-to-fine solve has no bootstrap yet; "
                                 "pass uncertainty=None")
        return coarse_to_fine(response, data, cls, coarse, **params)
    if uncertainty == "bootstrap":  # the replicas' memory, before the main run
        n_boot = as_int(n_boot, "n_boot", 2)
        check_bootstrap(n_boot, response.n_sky)
    t0 = time.perf_counter()
    result = cls(response, data, **params).run()
    seconds = time.perf_counter() - t0  # a replica's cost: the solver's set-up and its run
    if uncertainty == "bootstrap":
        # A randomised method's own seed stays with the main run: each replica gets one
        # drawn from the bootstrap's stream instead (passing both was issue 11's TypeError).
        shared = {k: v for k, v in params.items() if k != "seed"}
        imgs = bootstrap_images(
            response, data, cls, n_boot=n_boot, seed=boot_ss, redraw=redraw,
            model_counts=result.model_counts,
            seconds_each=_replica_seconds(seconds, result), **shared,
        )
        result.uncertainty = imgs.std(axis=0, ddof=1)
        result.params.update({"uncertainty": "bootstrap", "n_boot": n_boot, "redraw": redraw})
        result.extras["bootstrap_mean"] = imgs.mean(axis=0)
    return result

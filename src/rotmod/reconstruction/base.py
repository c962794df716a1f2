"""One interface for every reconstruction algorithm: solver classes, result, stopping rule.

Pattern: ``solver = get_algorithm(name)(response, data, **params)``; ``solver.setup()``;
``solver.step()`` as often as wanted; ``solver.run()`` does both until the
:class:`StoppingRule` fires and returns a :class:`ReconstructionResult`.  The one-line
:func:`reconstruct` wraps it, and adds a bootstrap uncertainty map on request.

Algorithms see the response only through ``forward``, ``adjoint`` and ``sensitivity``
(wrapped with exposure and background in :class:`~rotmod.reconstruction.data.ForwardModel`).
"""

from __future__ import annotations

import logging
import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from rotmod._validate import as_int
from rotmod.errors import ParameterError
from rotmod.reconstruction.data import ForwardModel, PoissonData, as_data
from rotmod.reconstruction.stats import chi2, deviance
from rotmod.registry import Registry
from rotmod.response.operator import ResponseOperator

__all__ = [
    "ALGORITHMS",
    "ReconstructionResult",
    "Reconstructor",
    "StoppingRule",
    "get_algorithm",
    "register_algorithm",
]

log = logging.getLogger(__name__)

Callback = Callable[["Reconstructor", int], Any]


def _check_float(value: Any, name: str, lo: float, *, lo_open: bool = True,
                 hi: float | None = None) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"{name} must be a number, got {value!r}") from exc
    if not np.isfinite(v) or (v <= lo if lo_open else v < lo) or (hi is not None and v > hi):
        rule = f"{'>' if lo_open else '>='} {lo:g}" + (f" and <= {hi:g}" if hi is not None else "")
        raise ParameterError(f"{name} must be {rule}, got {value!r}")
    return v


def _safe_div(num: np.ndarray, den: np.ndarray) -> np.ndarray:
    """``num / den`` where ``den > 0``, else 0 (ratios of counts to models, of
    back-projections to sensitivities)."""
    out = np.zeros(np.broadcast(num, den).shape)
    np.divide(num, den, out=out, where=den > 0)
    return out


@dataclass(frozen=True)
class StoppingRule:
    """When an iterative reconstruction stops (the first rule that holds, checked in order).

    Parameters
    ----------
    max_iter : int
        Hard limit on iterations (>= 1).
    chi2_dof : float or None
        Discrepancy principle: stop as soon as the Pearson chi-square per degree of freedom
        of the model to the data is <= ``chi2_dof`` (``None`` disables).  A correct model
        with Poisson noise has chi2/dof = 1 +- sqrt(2/dof); iterating further fits noise.
    rel_tol : float or None
        Stop when the relative change of the Poisson deviance over one iteration is below
        ``rel_tol`` (the fit no longer improves; ``None`` disables).
    min_iter : int
        Iterations always done before the fit-based rules are checked (>= 1).

    Notes
    -----
    ``dof`` is the number of bins with exposure minus the number of fitted background
    amplitudes (the sky pixels are not counted: with positivity their effective number is
    far below their count and unknown).
    """

    max_iter: int = 200
    chi2_dof: float | None = 1.0
    rel_tol: float | None = 1e-5
    min_iter: int = 1

    def __post_init__(self) -> None:
        as_int(self.max_iter, "max_iter", 1)
        as_int(self.min_iter, "min_iter", 1)
        if self.chi2_dof is not None:
            _check_float(self.chi2_dof, "chi2_dof", 0.0)
        if self.rel_tol is not None:
            _check_float(self.rel_tol, "rel_tol", 0.0, lo_open=False)

    def check(self, n_iter: int, chi2_per_dof: Sequence[float], dev: Sequence[float]) -> str | None:
        """The stop reason after ``n_iter`` iterations, or ``None`` to go on."""
        if n_iter >= self.min_iter:
            if self.chi2_dof is not None and chi2_per_dof[-1] <= self.chi2_dof:
                return f"chi2/dof {chi2_per_dof[-1]:.4g} <= {self.chi2_dof:g} (discrepancy)"
            if self.rel_tol is not None and len(dev) >= 2:
                change = abs(dev[-2] - dev[-1]) / max(abs(dev[-2]), 1e-300)
                if change < self.rel_tol:
                    return f"relative deviance change {change:.3g} < {self.rel_tol:g}"
        if n_iter >= self.max_iter:
            return f"max_iter {self.max_iter} reached"
        return None


@dataclass(eq=False)
class ReconstructionResult:
    """What every algorithm returns.

    Attributes
    ----------
    image : ndarray, shape (ny, nx)
        The sky in the response's sky units (rate per pixel on one unobstructed detector).
    uncertainty : ndarray, shape (ny, nx) or None
        One-sigma per-pixel uncertainty (bootstrap or the method's own), if computed.
    history : dict of str to ndarray
        Per iteration: ``deviance`` (Poisson), ``chi2`` (Pearson) and ``chi2_dof``.
    params : dict
        The parameters used (defaults filled in).
    n_iter : int
        Iterations done (0 for direct methods).
    stop_reason : str
    run_time : float
        Wall time (s) of the reconstruction (without the bootstrap).
    method : str
    background : ndarray, shape (n_det, n_time) or None
        The background rate (1/s) of the final model (fitted or given).
    model_counts : ndarray, shape (n_det, n_time)
        Expected counts of the final image.
    deviance, chi2, dof : float, float, int
        Fit of the final image to the data.
    grid : SkyGrid or None
        The sky grid (for the WCS) when the response has one.
    extras : dict
        Method-specific products (e.g. NCAR's layer images).
    """

    image: np.ndarray
    uncertainty: np.ndarray | None
    history: dict[str, np.ndarray]
    params: dict[str, Any]
    n_iter: int
    stop_reason: str
    run_time: float
    method: str
    background: np.ndarray | None
    model_counts: np.ndarray
    deviance: float
    chi2: float
    dof: int
    grid: Any = None
    extras: dict[str, Any] = field(default_factory=dict)

    def __repr__(self) -> str:
        ny, nx = self.image.shape
        return (
            f"<ReconstructionResult {self.method} {ny}x{nx}, {self.n_iter} iterations "
            f"({self.stop_reason}), chi2/dof {self.chi2_dof:.3g}, {self.run_time:.3g} s>"
        )

    @property
    def chi2_dof(self) -> float:
        """Final Pearson chi-square per degree of freedom."""
        return self.chi2 / max(self.dof, 1)


def _check_energy_match(response: ResponseOperator, data: Any) -> None:
    """Refuse folded counts whose energy band does not hold the response's energy.

    A response is computed at one energy (the slats' attenuation there); applying it to
    counts from another band fits the wrong instrument without any warning otherwise.
    """
    band = getattr(data, "energy_band", None)
    e = getattr(response, "energy", None)
    if e is None or band is None:
        return
    lo, hi = band.e_min, band.e_max
    # Energies are stored as float32 in event files: 1e-6 relative is their precision.
    if not lo * (1 - 1e-6) <= e <= hi * (1 + 1e-6):
        raise ParameterError(
            f"response: made for {e:g} keV, but the folded counts are from the band "
            f"{lo:g}-{hi:g} keV; compute the response at an energy in the band (or fold "
            "the events with an energy window around the response's energy)"
        )


def _check_bins_match(response: ResponseOperator, data: Any) -> None:
    """Refuse folded counts whose mask-angle bins are not the response's time bins.

    Both are :class:`~rotmod.binning.TimeBinning`, so the bins either are the same or not:
    no tolerance on edges (folded files are checked to hold equal bins when read).
    """
    got = getattr(data, "time_bins", None)
    want = getattr(response, "time_bins", None)
    if got is None or want is None:
        return
    # The response's mode and n_sub say how it averages a bin, not which bins it has.
    if not want.same_bins(got):
        raise ParameterError(
            f"data: the folded bins ({got.n_bins} equal bins over a turn) are not the "
            f"response's time bins ({want.n_bins} equal bins over a turn); fold the events "
            "with the response's binning"
        )


#: The reconstruction algorithms by name (the ``method`` of :func:`reconstruct`).  Filled by
#: :func:`register_algorithm` where each solver class is defined; the package imports those
#: modules (and exports their classes) explicitly.
ALGORITHMS: Registry[type[Reconstructor]] = Registry("method")


def register_algorithm(name: str) -> Callable[[type[Reconstructor]], type[Reconstructor]]:
    """Class decorator registering a :class:`Reconstructor` under ``name`` in
    :data:`ALGORITHMS` (and naming the class ``name``).

    Raises
    ------
    ParameterError
        ``name`` is empty or registered already.
    """

    def deco(cls: type[Reconstructor]) -> type[Reconstructor]:
        ALGORITHMS.register(name, cls)
        cls.name = name
        return cls

    return deco


def get_algorithm(method: str | type[Reconstructor]) -> type[Reconstructor]:
    """The solver class registered as ``method`` (a solver class passes through).

    Raises
    ------
    ParameterError
        Unknown name (the message lists the registered ones and suggests the closest).
    """
    if isinstance(method, type) and issubclass(method, Reconstructor):
        return method
    return ALGORITHMS.get(method)


def _image_shape(response: Any, grid: Any, n_sky: int) -> tuple[tuple[int, ...], Any]:
    g = grid if grid is not None else getattr(response, "grid", None)
    if g is not None:
        shape = tuple(g.shape)
        if int(np.prod(shape)) != n_sky:
            raise ParameterError(
                f"grid shape {shape} does not match the response's {n_sky} sky pixels"
            )
        return shape, g
    return (1, n_sky), None


class Reconstructor(ABC):
    """Base class: setup / step / run with callbacks and a fit-based stopping rule.

    Parameters
    ----------
    response : ResponseOperator
        Anything with ``n_det``, ``n_time``, ``n_sky``, ``forward``, ``adjoint`` and
        ``sensitivity``.
    data : PoissonData, FoldedProfiles or ndarray
        Folded counts ``(n_det, n_time)`` with exposure (and background).
    max_iter, chi2_dof, rel_tol, min_iter
        The :class:`StoppingRule` (or pass ``stopping=``); class defaults per algorithm.
    callbacks : sequence of callables, optional
        Called as ``cb(solver, iteration)`` after every step; a truthy return stops the run.
    grid : SkyGrid, optional
        Image grid; default ``response.grid`` when the response has one.
    exposure, background, fit_background
        Override or complete ``data`` (see :class:`PoissonData`).
    **params
        Algorithm parameters (see each class's ``defaults``); unknown names raise.
    """

    name: ClassVar[str] = ""
    #: Whether the method iterates (and so obeys a :class:`StoppingRule`); a direct method
    #: (back-projection) computes its image in one go.
    iterative: ClassVar[bool] = True
    #: Algorithm parameters and their defaults.
    defaults: ClassVar[dict[str, Any]] = {}
    #: Default stopping rule.
    default_stopping: ClassVar[StoppingRule] = StoppingRule()

    def __init__(
        self,
        response: ResponseOperator,
        data: Any,
        *,
        stopping: StoppingRule | None = None,
        max_iter: int | None = None,
        chi2_dof: float | str | None = "default",
        rel_tol: float | str | None = "default",
        min_iter: int | None = None,
        callbacks: Sequence[Callback] | None = None,
        grid: Any = None,
        exposure: Any = None,
        background: Any = None,
        fit_background: bool | None = None,
        **params: Any,
    ) -> None:
        _check_bins_match(response, data)
        _check_energy_match(response, data)
        self.data: PoissonData = as_data(
            data, exposure=exposure, background=background, fit_background=fit_background
        )
        self.model = ForwardModel(response, self.data)
        self.response = response
        self.image_shape, self.grid = _image_shape(response, grid, self.model.n_sky)
        base = stopping if stopping is not None else self.default_stopping
        if stopping is not None and not isinstance(stopping, StoppingRule):
            raise ParameterError(f"stopping must be a StoppingRule, got {type(stopping)}")
        self.stopping = StoppingRule(
            max_iter=base.max_iter if max_iter is None else max_iter,
            chi2_dof=base.chi2_dof if chi2_dof == "default" else chi2_dof,  # type: ignore[arg-type]
            rel_tol=base.rel_tol if rel_tol == "default" else rel_tol,  # type: ignore[arg-type]
            min_iter=base.min_iter if min_iter is None else min_iter,
        )
        unknown = set(params) - set(self.defaults)
        if unknown:
            raise ParameterError(
                f"unknown parameter(s) {sorted(unknown)} for method {self.name!r}; "
                f"allowed: {sorted(self.defaults)}"
            )
        self.params: dict[str, Any] = {**self.defaults, **params}
        self._check_params()
        self.callbacks = list(callbacks or [])
        for cb in self.callbacks:
            if not callable(cb):
                raise ParameterError(f"callbacks must be callables, got {cb!r}")
        self.dof = max(self.data.n_valid - self.model.n_bkg, 1)
        self.z: np.ndarray = np.zeros(self.model.size)
        self.mu: np.ndarray = np.zeros(self.data.shape)
        self.iteration = 0
        self.history: dict[str, list[float]] = {"deviance": [], "chi2": [], "chi2_dof": []}
        self._is_setup = False
        self._warm: np.ndarray | None = None

    def warm_start(self, z: np.ndarray) -> None:
        """Start the next :meth:`setup` from ``z`` (augmented vector) instead of the default."""
        z = np.asarray(z, dtype=float)
        if z.shape != (self.model.size,):
            raise ParameterError(f"warm start must have shape ({self.model.size},), got {z.shape}")
        self._warm = z.copy()

    # -- hooks -------------------------------------------------------------------------
    def _check_params(self) -> None:
        """Validate ``self.params`` (raise ParameterError naming the parameter)."""
        return None

    @abstractmethod
    def _initial(self) -> np.ndarray:
        """Starting ``z``."""

    @abstractmethod
    def _update(self) -> None:
        """One iteration: update ``self.z`` (and ``self.mu`` = forward(z))."""

    # -- public --------------------------------------------------------------------------
    @property
    def y(self) -> np.ndarray:
        """Counts with bins without exposure zeroed."""
        return np.where(self.data.valid, self.data.counts, 0.0)

    def _record(self) -> None:
        v = self.data.valid
        dev = deviance(self.data.counts, self.mu, v)
        c2 = chi2(self.data.counts, self.mu, v)
        self.history["deviance"].append(dev)
        self.history["chi2"].append(c2)
        self.history["chi2_dof"].append(c2 / self.dof)

    def _convergence_series(self) -> list[float]:
        """What the relative-change rule watches: the deviance (penalised methods add
        their penalty, so that they stop when their own objective settles)."""
        return self.history["deviance"]

    def setup(self) -> None:
        """Initialise the estimate and the history."""
        self._t0 = time.perf_counter()
        z0 = self._initial()
        self.z = z0 if self._warm is None else self._warm.copy()
        self.mu = self.model.forward(self.z)
        self.iteration = 0
        self.history = {"deviance": [], "chi2": [], "chi2_dof": []}
        self._is_setup = True

    def step(self) -> None:
        """One iteration (calls :meth:`setup` first if needed) and records the fit."""
        if not self._is_setup:
            self.setup()
        self._update()
        self.iteration += 1
        self._record()

    def run(self) -> ReconstructionResult:
        """Iterate until the stopping rule (or a callback) stops; return the result."""
        self.setup()
        return self.finalise(self.run_from_setup())

    def run_from_setup(self) -> str:
        """Iterate from the current state until a stop; return the stop reason."""
        reason = None
        while reason is None:
            self.step()
            for cb in self.callbacks:
                if cb(self, self.iteration):
                    reason = f"callback at iteration {self.iteration}"
            if reason is None:
                reason = self.stopping.check(
                    self.iteration, self.history["chi2_dof"], self._convergence_series()
                )
        log.debug("%s stopped after %d iterations: %s", self.name, self.iteration, reason)
        return reason

    @property
    def image(self) -> np.ndarray:
        """Current sky estimate, image-shaped."""
        return self.model.split(self.z)[0].reshape(self.image_shape).copy()

    def finalise(self, reason: str, extras: dict[str, Any] | None = None) -> ReconstructionResult:
        """Package the current state as a :class:`ReconstructionResult`."""
        v = self.data.valid
        params = {
            **self.params,
            "max_iter": self.stopping.max_iter,
            "chi2_dof_target": self.stopping.chi2_dof,
            "rel_tol": self.stopping.rel_tol,
            "min_iter": self.stopping.min_iter,
            "fit_background": self.data.fit_background,
        }
        return ReconstructionResult(
            image=self.image,
            uncertainty=None,
            history={k: np.asarray(h) for k, h in self.history.items()},
            params=params,
            n_iter=self.iteration,
            stop_reason=reason,
            run_time=time.perf_counter() - self._t0,
            method=self.name,
            background=self.model.background_rate(self.z),
            model_counts=self.mu.copy(),
            deviance=deviance(self.data.counts, self.mu, v),
            chi2=chi2(self.data.counts, self.mu, v),
            dof=self.dof,
            grid=self.grid,
            extras=dict(extras or {}),
        )

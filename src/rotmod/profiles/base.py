"""The profile-model interface, the projected geometry every model shares, and the registry.

A characteristic profile ``P[d, t, n]`` is the unattenuated fraction of the photons of source
``n`` that reach detector ``d`` at mask angle ``xi[t]`` (see :mod:`rotmod.conventions`).

Every model reduces the 3-D geometry the same way (derived in ``docs/physics.md``): for
detector ``d`` and source ``n`` let

* ``X = x0 + L tan(theta) cos(phi)`` and ``Y = y0 + L tan(theta) sin(phi)`` be the point
  where the ray to the detector centre crosses the mask bottom (the paper's ``r, xi0`` are
  its polar coordinates);
* ``uc = X cos(xi) - Y sin(xi)`` its mask-frame coordinate (the paper's ``x(t)``);
* ``s = Sx cos(xi) - Sy sin(xi) = h tan(theta) cos(xi + phi)`` with
  ``(Sx, Sy) = h tan(theta) (cos phi, sin phi)``, the growth of the ray's mask coordinate
  across the slab;
* ``tau = mu h / cos(theta)``, the optical depth of the full slat thickness.

Per-source and per-angle quantities are computed once, so the hot loops see only products
and sums.
"""

from __future__ import annotations

import functools
import warnings
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar, TypeVar

import numba
import numpy as np

from rotmod._validate import as_angle, as_distance, as_energy_scalar, as_float_dtype
from rotmod.errors import ModelValidityError, ParameterError
from rotmod.geometry import Instrument
from rotmod.limits import check_memory
from rotmod.registry import Registry

__all__ = [
    "DEFAULT_COMPARISON",
    "DEFAULT_MODEL",
    "MODELS",
    "ProfileModel",
    "ProjectedGeometry",
    "get_model",
    "project",
    "register_model",
]


@dataclass(frozen=True)
class ProjectedGeometry:
    """Source-, detector- and angle-independent pieces of the profile computation.

    Attributes
    ----------
    X, Y : ndarray, shape (n_det, n_src)
        Lab coordinates (cm) where the ray to each detector centre crosses the mask bottom.
    Sx, Sy : ndarray, shape (n_src,)
        ``h tan(theta) (cos phi, sin phi)`` (cm).
    tau : ndarray, shape (n_src,)
        Optical depth ``mu h / cos(theta)`` of a full slat (``inf`` for opaque slats).
    theta, phi : ndarray, shape (n_src,)
        Source zenith and azimuth (rad).
    mu : float
        Linear attenuation coefficient of the slats (1/cm).
    positions : ndarray, shape (n_det, 2)
        Detector centres (cm) of the detectors this geometry covers.
    distance : ndarray, shape (n_src,)
        Source distances from the origin (cm; ``inf``: at infinity, the only case the
        ``X ... tau`` above describe).
    mu_det : float
        Linear attenuation coefficient of thick detectors (1/cm; 0 for flat faces).
    """

    X: np.ndarray
    Y: np.ndarray
    Sx: np.ndarray
    Sy: np.ndarray
    tau: np.ndarray
    theta: np.ndarray
    phi: np.ndarray
    mu: float
    positions: np.ndarray | None = None
    distance: np.ndarray | None = None
    mu_det: float = 0.0

    @property
    def at_infinity(self) -> bool:
        """Whether every source is at infinity (parallel rays)."""
        return self.distance is None or not bool(np.isfinite(self.distance).any())

    def mask_coordinates(self, xi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``uc[d, t, n]`` and ``s[t, n]`` at mask angles ``xi`` (plain numpy; for checks)."""
        c, s_ = np.cos(xi)[:, None], np.sin(xi)[:, None]
        uc = self.X[:, None, :] * c[None] - self.Y[:, None, :] * s_[None]
        return uc, self.Sx[None, :] * c - self.Sy[None, :] * s_


def check_sources(theta: Any, phi: Any) -> tuple[np.ndarray, np.ndarray]:
    """Validate source directions (Quantities, or plain numbers in deg).

    Returns 1-D float arrays (rad) of equal length.
    """
    th = as_angle(theta, "theta", lo=0.0, hi=90.0, hi_open=True, ndim=1)
    ph = as_angle(phi, "phi", ndim=1)
    if th.shape != ph.shape:
        if ph.size == 1:
            ph = np.full(th.shape, ph[0])
        elif th.size == 1:
            th = np.full(ph.shape, th[0])
        else:
            raise ParameterError(
                f"theta and phi must have the same length, got {th.size} and {ph.size}"
            )
    return th, ph


def check_angles(xi: Any) -> np.ndarray:
    """Validate mask angles (Quantities, or plain numbers in deg); returns 1-D rad."""
    return as_angle(xi, "xi", ndim=1)


def project(
    instrument: Instrument, theta: Any, phi: Any, energy: Any = None, distance: Any = None
) -> ProjectedGeometry:
    """Compute the :class:`ProjectedGeometry` of ``instrument`` for sources ``(theta, phi)``.

    Parameters
    ----------
    instrument : Instrument
    theta, phi : array_like or Quantity
        Source zenith (0 <= theta < 90 deg) and azimuth; deg if plain numbers.
    energy : float or Quantity, optional
        Photon energy (keV); needed unless the mask has an explicit ``mu``.
    distance : float, array_like or Quantity, optional
        Source distances from the origin along their directions (cm; one for all or one
        per source); ``None`` or ``inf``: at infinity.

    Raises
    ------
    ParameterError
        Bad directions or distances (a finite source must lie above the mask's top face).
    """
    if not isinstance(instrument, Instrument):
        raise ParameterError(f"instrument must be an Instrument, got {type(instrument).__name__}")
    th, ph = check_sources(theta, phi)
    dist = as_distance(distance, th.size)
    if np.isfinite(dist).any():
        instrument.source_positions(th, ph, dist)  # validates: above the mask's top face
    mask, det = instrument.mask, instrument.detectors
    # One energy: the attenuation calls also take many, which a projection cannot use.
    energy = None if energy is None else as_energy_scalar(energy, "energy")
    mu = mask.linear_attenuation(energy)
    mu_det = 0.0 if det.is_flat else det.linear_attenuation(energy)
    t = np.tan(th)
    X = det.positions[:, 0:1] + mask.height * t * np.cos(ph)
    Y = det.positions[:, 1:2] + mask.height * t * np.sin(ph)
    h = mask.thickness
    Sx, Sy = h * t * np.cos(ph), h * t * np.sin(ph)
    if mu == 0.0:
        tau = np.zeros_like(th)
    elif np.isinf(mu):
        # Opaque slats, even in the thin-mask limit h = 0.
        tau = np.full_like(th, np.inf)
    else:
        tau = mu * h / np.cos(th)
    return ProjectedGeometry(X, Y, Sx, Sy, tau, th, ph, mu, det.positions, dist, mu_det)


#: Bytes of the float64 buffer through which :meth:`ProfileModel.evaluate_into` fills a
#: float32 output (a few angles at a time; in the last-level cache of this machine).
CAST_BYTES = 2 << 20
#: Rows (detector x angle) per numba thread in each such call, at least.
CAST_ROWS = 4


class ProfileModel(ABC):
    """A characteristic-profile model.

    Call instances as ``model.profile(...)``; the response layer calls :meth:`evaluate` on
    blocks of its own.

    Notes
    -----
    A new model is one subclass and its registration, nothing else::

        @register_model("my-model")
        class MyModel(ProfileModel):
            def evaluate(self, instrument, geom, cos_xi, sin_xi, out):
                out[...] = ...  # P[d, t, n], in place

    after which :func:`get_model`, :meth:`profile`, the responses
    (``build_response(..., model="my-model")``) and the command line take it by name (the
    paper's report compares its own selection, :mod:`rotmod.paper.selection`).  The
    subclass implements :meth:`evaluate`, the extension point:

    * ``geom`` is the :class:`ProjectedGeometry` of the sources, already validated: per
      detector and source the crossing point ``X, Y`` (shape ``(n_det, n_src)``), per
      source ``Sx, Sy, tau, theta, phi`` (shape ``(n_src,)``), the slats' ``mu``, the
      detector ``positions`` and the source ``distance`` (``inf``: at infinity).  It may
      describe a subset of the instrument's detectors and sources (the response layer
      evaluates blocks): size the loops by ``out``, not by ``instrument``.
    * ``cos_xi, sin_xi`` are 1-D arrays of the ``n_angle`` mask angles' cosines and sines.
    * ``out`` is a C-contiguous float64 array of shape ``(n_det, n_angle, n_src)``,
      allocated by the caller and filled *in place* (no return value); every element must
      be written (it is not zeroed first).  Callers that want float32 go through
      :meth:`evaluate_into`, so that each kernel is compiled for one type only.

    If the model has a limited domain it overrides :meth:`check_validity`; a model of the
    instrument as built sets :attr:`handles_as_built`; a model of an asymmetric mask sets
    :attr:`half_turn_symmetric` to False.
    """

    #: Registry name (set by :func:`register_model`; a class registered with parameters
    #: names its variants' instances itself).
    name: ClassVar[str] = ""
    #: ``P(xi + pi) = P(xi)``: a half turn maps the mask onto itself (the slat pattern is
    #: symmetric about the gap on the rotation axis, docs/conventions.md), so the response
    #: layer computes only half a turn of time bins.  A model of an asymmetric mask must set
    #: this to False.
    half_turn_symmetric: ClassVar[bool] = True
    #: Whether the model describes the instrument as built (``Instrument.is_ideal`` false,
    #: sources at a finite distance); the others refuse such instruments.
    handles_as_built: ClassVar[bool] = False

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        # Models written before the hook was public implement `_evaluate`: they keep working
        # (their kernel is the hook) and are told the new name.
        if "_evaluate" in cls.__dict__ and "evaluate" not in cls.__dict__:
            warnings.warn(f"{cls.__qualname__}._evaluate: the kernel hook is now the public "
                          "ProfileModel.evaluate; rename the method", DeprecationWarning,
                          stacklevel=2)
            cls.evaluate = cls.__dict__["_evaluate"]  # type: ignore[method-assign]

    def profile(
        self,
        instrument: Instrument,
        theta: Any,
        phi: Any,
        xi: Any,
        energy: Any = None,
        *,
        dtype: Any = np.float64,
        distance: Any = None,
    ) -> np.ndarray:
        """Characteristic profiles ``P[d, t, n]``.

        Parameters
        ----------
        instrument : Instrument
        theta, phi : array_like or Quantity, shape (n_src,)
            Source zenith (< 90 deg) and azimuth; deg if plain numbers.
        xi : array_like or Quantity, shape (n_angle,)
            Mask angles; deg if plain numbers.
        energy : float or Quantity, optional
            Photon energy (keV); needed unless the mask has an explicit ``mu``.
        dtype : numpy dtype
            float64 (default) or float32 output.
        distance : float, array_like or Quantity, optional
            Source distances from the origin (cm); ``None`` or ``inf``: at infinity.  Only
            models with :attr:`handles_as_built` take finite distances.

        Returns
        -------
        numpy.ndarray, shape (n_det, n_angle, n_src)
            Values in [0, 1] (thick detectors: counts per photon of an unobstructed face,
            up to the effective-area ratio; docs/physics.md).

        Raises
        ------
        ParameterError, MaterialError, ModelValidityError
        """
        geom = project(instrument, theta, phi, energy, distance)
        xi = check_angles(xi)
        self.validate(instrument, geom)
        dt = as_float_dtype(dtype)
        n_det = len(instrument.detectors)
        check_memory(float(n_det) * xi.size * geom.theta.size * dt.itemsize,
                     f"profiles of {n_det} detectors x {xi.size} angles x {geom.theta.size} "
                     "sources", hint="ask for fewer angles or sources at a time")
        out = np.empty((len(instrument.detectors), xi.size, geom.theta.size), dtype=dt)
        self.evaluate_into(instrument, geom, np.cos(xi), np.sin(xi), out)
        return out

    def validate(self, instrument: Instrument, geom: ProjectedGeometry) -> None:
        """Refuse an instrument as built unless the model describes it, then
        :meth:`check_validity`.

        Raises
        ------
        ModelValidityError
        """
        if not self.handles_as_built and not instrument.is_ideal:
            raise ModelValidityError(
                f"the {self.name!r} model describes the ideal instrument, but this one is "
                f"as built ({', '.join(instrument.as_built_features())}); use the 'exact' "
                "model"
            )
        if not self.handles_as_built and not geom.at_infinity:
            raise ModelValidityError(
                f"the {self.name!r} model describes sources at infinity, but some are at a "
                "finite distance; use the 'exact' model"
            )
        self.check_validity(instrument, geom)

    def check_validity(  # noqa: B027 - a deliberate no-op: models valid everywhere keep it
        self, instrument: Instrument, geom: ProjectedGeometry
    ) -> None:
        """Raise :class:`~rotmod.errors.ModelValidityError` outside the model's domain."""

    @abstractmethod
    def evaluate(
        self,
        instrument: Instrument,
        geom: ProjectedGeometry,
        cos_xi: np.ndarray,
        sin_xi: np.ndarray,
        out: np.ndarray,
    ) -> None:
        """Fill ``out[d, t, n]`` with the profiles, in place (the kernel; class Notes).

        Parameters
        ----------
        instrument : Instrument
        geom : ProjectedGeometry
            The sources' projected geometry (validated by :meth:`validate`).
        cos_xi, sin_xi : ndarray, shape (n_angle,)
            Cosines and sines of the mask angles.
        out : ndarray, shape (n_det, n_angle, n_src)
            C-contiguous float64 (the only type the kernels are compiled for; callers
            wanting float32 cast); every element is written.
        """

    def evaluate_into(
        self,
        instrument: Instrument,
        geom: ProjectedGeometry,
        cos_xi: np.ndarray,
        sin_xi: np.ndarray,
        out: np.ndarray,
    ) -> None:
        """:meth:`evaluate` into ``out`` of float64 or float32, a few angles per call.

        The kernels are compiled for float64 only: a float32 specialisation of each would
        double what a first run compiles (seconds of the README's first command).  A float32
        ``out`` is filled a few angles at a time through a float64 buffer of about
        :data:`CAST_BYTES` (it stays in cache, so the cast costs little beside the kernel,
        and the values are the kernel's, rounded once).  The buffer holds at least
        :data:`CAST_ROWS` rows per numba thread (the kernels run rows in parallel) and at
        least one angle, so it is larger where one angle's rows are.  A float64 ``out``
        larger than the buffer goes through it too: each kernel call is then short (about
        0.1 s on one core for the exact model), and compiled code never sees Ctrl-C, so a
        KeyboardInterrupt stops a long evaluation between calls (docs/reliability.md).
        """
        nd, nt, nn = out.shape
        step = max(CAST_BYTES // (8 * max(nd * nn, 1)),
                   -(-CAST_ROWS * numba.get_num_threads() // max(nd, 1)), 1)
        step = min(step, max(nt, 1))
        if out.dtype == np.float64 and step == nt:
            self.evaluate(instrument, geom, cos_xi, sin_xi, out)
            return
        flat = np.empty(nd * step * nn)
        for t0 in range(0, nt, step):
            t1 = min(nt, t0 + step)
            part = flat[: nd * (t1 - t0) * nn].reshape(nd, t1 - t0, nn)  # contiguous
            self.evaluate(instrument, geom, cos_xi[t0:t1], sin_xi[t0:t1], part)
            out[:, t0:t1] = part

    def describe(self) -> dict[str, Any]:
        """Parameters that identify this model (for metadata)."""
        return {"model": self.name}


#: The profile models by name: each entry makes an instance (a class, or a class with bound
#: parameters).  Filled by :func:`register_model` where each model is defined.
MODELS: Registry[Callable[..., ProfileModel]] = Registry("model")

#: The model every entry point uses when none is named (API, command line, report): the exact
#: model is valid for every geometry, and within the advanced model's domain it costs about
#: the same (docs/physics.md).
DEFAULT_MODEL = "exact"

#: The models compared when none are named (``rotmod profile``, the report's profile
#: figures): the paper's standard and advanced models and the exact one.
DEFAULT_COMPARISON: tuple[str, ...] = ("standard", "advanced", "exact")

_M = TypeVar("_M", bound=type[ProfileModel])


def register_model(name: str, **params: Any) -> Callable[[_M], _M]:
    """Class decorator registering a :class:`ProfileModel` under ``name`` in :data:`MODELS`.

    ``params`` are passed to the class on :func:`get_model`, so one class can be registered
    under several names (``@register_model("advanced-approx", g1="approx")``).  Without
    ``params`` the class takes ``name`` as its :attr:`ProfileModel.name`.

    Raises
    ------
    ParameterError
        ``name`` is empty or registered already.
    """

    def deco(cls: _M) -> _M:
        MODELS.register(name, functools.partial(cls, **params) if params else cls)
        if not params:
            # The name is written once, here: messages and metadata read it from the class.
            cls.name = name
        return cls

    return deco


def get_model(model: str | ProfileModel) -> ProfileModel:
    """Return a model instance by registry name (or pass an instance through).

    Raises
    ------
    ParameterError
        Unknown name; the message lists the registered ones and suggests the closest.
    """
    if isinstance(model, ProfileModel):
        return model
    return MODELS.get(model)()

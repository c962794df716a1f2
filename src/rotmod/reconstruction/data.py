"""Folded counts, exposure and background: the data every reconstruction algorithm sees.

The model of the data is Poisson with mean

    mu[d, t] = E[d, t] * ((P S)[d, t] + B[d, t]),

``E`` the exposure of each bin (s), ``P S`` the response applied to the sky (count rate,
1/s), ``B`` the background rate (1/s).  ``B`` is either known (a fixed term) or a template
whose amplitude is fitted as one scalar per detector, ``B[d, t] = beta[d] * T[d, t]``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from rotmod.errors import ParameterError
from rotmod.response.operator import ResponseOperator

__all__ = ["ForwardModel", "PoissonData", "as_data"]


def _finite(arr: np.ndarray, name: str) -> None:
    if not np.all(np.isfinite(arr)):
        raise ParameterError(f"{name} must be finite, got non-finite values")


def _per_bin(
    value: Any, name: str, unit: str, n_det: int, n_t: int, *, per_detector: bool
) -> np.ndarray:
    """``value`` (scalar, per time bin ``(n_t,)``, per detector ``(n_det,)`` if
    ``per_detector``, or ``(n_det, n_t)``) as a finite, non-negative ``(n_det, n_t)`` array."""
    v = np.array(value, dtype=float)
    shapes = [(n_t,), (n_det, n_t)]
    if v.ndim == 0:
        v = np.full((n_det, n_t), float(v))
    elif per_detector and v.shape == (n_det,) and v.shape != (n_t,):
        v = np.repeat(v[:, None], n_t, axis=1)
    elif v.shape == (n_t,):
        v = np.broadcast_to(v, (n_det, n_t)).copy()
    elif v.shape != (n_det, n_t):
        if per_detector:
            shapes.insert(0, (n_det,))
        allowed = ", ".join(str(s) for s in shapes[:-1]) + f" or {shapes[-1]}"
        raise ParameterError(f"{name} must be a scalar or have shape {allowed}, got {v.shape}")
    _finite(v, name)
    if np.any(v < 0):
        raise ParameterError(f"{name} must be >= 0 {unit}, got minimum {v.min():g} {unit}")
    return v


@dataclass(frozen=True, eq=False)
class PoissonData:
    """Folded counts with their exposure and background model.

    Parameters
    ----------
    counts : array_like, shape (n_det, n_time)
        Counts per detector and time (mask-angle) bin, >= 0.  Integers for real data;
        non-integer (noiseless expected) counts are accepted.
    exposure : float or array_like, shape (n_time,) or (n_det, n_time)
        Good time of each bin (s), >= 0.  Bins with zero exposure are ignored.
    background : float or array_like, shape (n_det,), (n_time,) or (n_det, n_time), optional
        Background count *rate* (1/s).  Known (fixed) unless ``fit_background`` is set, in
        which case it is the template whose amplitude is fitted per detector (default a
        flat template).
    fit_background : bool
        Fit the background as one scalar per detector (times the template).

    Raises
    ------
    ParameterError
        Shapes that do not match, negative or non-finite values.
    """

    counts: np.ndarray
    exposure: Any = 1.0
    background: Any = None
    fit_background: bool = False

    def __post_init__(self) -> None:
        c = np.array(self.counts, dtype=float)
        if c.ndim != 2:
            raise ParameterError(f"counts must have shape (n_det, n_time), got {c.shape}")
        _finite(c, "counts")
        if np.any(c < 0):
            raise ParameterError(f"counts must be >= 0, got minimum {c.min():g}")
        n_det, n_t = c.shape
        ex = _per_bin(self.exposure, "exposure", "s", n_det, n_t, per_detector=False)
        if not np.any(ex > 0):
            raise ParameterError("exposure must be > 0 s in at least one bin, got all zero")
        bkg = None
        if self.background is not None:
            bkg = _per_bin(self.background, "background", "1/s", n_det, n_t, per_detector=True)
        if self.fit_background and bkg is not None and np.any(bkg.sum(axis=1) <= 0):
            raise ParameterError(
                "background template must be > 0 somewhere on every detector when "
                "fit_background is set"
            )
        for name, val in (("counts", c), ("exposure", ex), ("background", bkg)):
            if val is not None:
                val.flags.writeable = False
            object.__setattr__(self, name, val)
        object.__setattr__(self, "fit_background", bool(self.fit_background))

    @property
    def shape(self) -> tuple[int, int]:
        """``(n_det, n_time)``."""
        return self.counts.shape  # type: ignore[return-value]

    @property
    def valid(self) -> np.ndarray:
        """Boolean mask of bins with exposure > 0."""
        return self.exposure > 0

    @property
    def n_valid(self) -> int:
        """Number of bins with exposure > 0."""
        return int(np.count_nonzero(self.valid))

    @property
    def total_counts(self) -> float:
        """Sum of the counts in bins with exposure."""
        return float(self.counts[self.valid].sum())

    def with_counts(self, counts: np.ndarray, exposure_scale: float = 1.0) -> PoissonData:
        """A copy with other counts (and the exposure scaled), e.g. a Poisson re-draw."""
        return PoissonData(
            counts, self.exposure * exposure_scale, self.background, self.fit_background
        )

    @classmethod
    def from_folded(
        cls, folded: Any, *, background: Any = None, fit_background: bool = False
    ) -> PoissonData:
        """From an object with ``counts`` (n_det, n_bins) and ``exposure`` attributes.

        Parameters
        ----------
        folded : rotmod.events.FoldedProfiles or similar
        background, fit_background
            See the class parameters.
        """
        try:
            counts, exposure = folded.counts, folded.exposure
        except AttributeError as exc:
            raise ParameterError(
                f"data must be PoissonData, an array or have counts and exposure, got "
                f"{type(folded).__name__}"
            ) from exc
        return cls(np.asarray(counts), np.asarray(exposure), background, fit_background)


def as_data(
    data: Any,
    *,
    exposure: Any = None,
    background: Any = None,
    fit_background: bool | None = None,
) -> PoissonData:
    """Coerce ``data`` (PoissonData, FoldedProfiles-like or a counts array) to PoissonData.

    Keyword values override those of a given :class:`PoissonData` when not ``None``.
    """
    if isinstance(data, PoissonData):
        if exposure is None and background is None and fit_background is None:
            return data
        return PoissonData(
            data.counts,
            data.exposure if exposure is None else exposure,
            data.background if background is None else background,
            data.fit_background if fit_background is None else fit_background,
        )
    fb = bool(fit_background) if fit_background is not None else False
    if isinstance(data, np.ndarray | list | tuple):
        return PoissonData(np.asarray(data), 1.0 if exposure is None else exposure, background, fb)
    d = PoissonData.from_folded(data, background=background, fit_background=fb)
    if exposure is not None:
        d = PoissonData(d.counts, exposure, d.background, d.fit_background)
    return d


class ForwardModel:
    """The augmented linear model ``z -> mu`` that the algorithms iterate on.

    ``z = [S (n_sky), beta (n_det if the background is fitted)]`` and
    ``mu = E * (P S) + E * B_fixed + beta[d] * E * T`` (counts).  Only the response's
    ``forward``, ``adjoint`` and ``sensitivity`` are used.

    Parameters
    ----------
    response : ResponseOperator
    data : PoissonData

    Notes
    -----
    ``adjoint(r) = [P^T (E r), sum_t E T r]`` and ``sensitivity = adjoint(1)`` restricted to
    bins with exposure; pixels of zero sensitivity are frozen at 0 by every algorithm.
    """

    def __init__(self, response: ResponseOperator, data: PoissonData) -> None:
        for attr in ("forward", "adjoint", "sensitivity"):
            if not callable(getattr(response, attr, None)):
                raise ParameterError(
                    f"response must provide forward, adjoint and sensitivity, missing {attr}"
                )
        n_det, n_t = data.shape
        if (response.n_det, response.n_time) != (n_det, n_t):
            raise ParameterError(
                f"data counts must have shape ({response.n_det}, {response.n_time}) to match "
                f"the response, got {data.shape}"
            )
        self.response = response
        self.data = data
        self.n_sky = int(response.n_sky)
        self.E = np.where(data.valid, data.exposure, 0.0)
        self.fixed = np.zeros((n_det, n_t))
        self.template: np.ndarray | None = None
        if data.fit_background:
            tmpl = np.ones((n_det, n_t)) if data.background is None else data.background
            self.template = self.E * tmpl
            if np.any(self.template.sum(axis=1) <= 0):
                raise ParameterError(
                    "background template times exposure must be > 0 on every detector"
                )
        elif data.background is not None:
            self.fixed = self.E * data.background
        self.n_bkg = n_det if self.template is not None else 0
        self._uniform = bool(np.all(self.E == self.E.flat[0]))
        self._sens: np.ndarray | None = None

    @property
    def size(self) -> int:
        """Length of the augmented unknown vector ``z``."""
        return self.n_sky + self.n_bkg

    def split(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(sky, beta)`` views of ``z``."""
        return z[: self.n_sky], z[self.n_sky :]

    def forward(self, z: np.ndarray) -> np.ndarray:
        """Expected counts ``mu[d, t]`` (bins without exposure are 0)."""
        sky, beta = self.split(z)
        mu = self.E * self.response.forward(sky) + self.fixed
        if self.template is not None:
            mu = mu + beta[:, None] * self.template
        return mu

    def adjoint(self, r: np.ndarray) -> np.ndarray:
        """``K^T r`` for count-space ``r[d, t]``."""
        out = np.empty(self.size)
        out[: self.n_sky] = self.response.adjoint(self.E * r)
        if self.template is not None:
            out[self.n_sky :] = np.sum(self.template * r, axis=1)
        return out

    def forward_detectors(self, z: np.ndarray, detectors: np.ndarray) -> np.ndarray:
        """Expected counts of some detectors only, ``(len(detectors), n_time)``."""
        sky, beta = self.split(z)
        E = self.E[detectors]
        mu = E * self.response.forward_detectors(sky, detectors) + self.fixed[detectors]
        if self.template is not None:
            mu = mu + beta[detectors, None] * self.template[detectors]
        return mu

    def adjoint_detectors(self, r: np.ndarray, detectors: np.ndarray) -> np.ndarray:
        """``K_D^T r`` for count-space ``r`` of some detectors ``D`` (the rest taken as 0)."""
        out = np.zeros(self.size)
        out[: self.n_sky] = self.response.adjoint_detectors(self.E[detectors] * r, detectors)
        if self.template is not None:
            out[self.n_sky :][detectors] = np.sum(self.template[detectors] * r, axis=1)
        return out

    def sensitivity(self) -> np.ndarray:
        """``K^T 1``: expected counts per unit of each unknown."""
        if self._sens is None:
            if self._uniform:
                sky = self.E.flat[0] * np.asarray(self.response.sensitivity(), dtype=float)
            else:
                sky = self.response.adjoint(self.E)
            s = np.empty(self.size)
            s[: self.n_sky] = sky
            if self.template is not None:
                s[self.n_sky :] = self.template.sum(axis=1)
            self._sens = s
        return self._sens

    def background_rate(self, z: np.ndarray) -> np.ndarray | None:
        """Background rate ``B[d, t]`` (1/s) of the model (``None`` without background)."""
        if self.template is not None:
            tmpl = (
                np.ones(self.data.shape) if self.data.background is None else self.data.background
            )
            return self.split(z)[1][:, None] * tmpl
        return self.data.background

    def initial(self, fraction_sky: float = 0.5) -> np.ndarray:
        """A flat positive start whose expected total equals the observed total.

        The excess over the fixed background is shared between the sky (``fraction_sky``)
        and the fitted background (the rest); without a fitted background the sky gets it
        all.
        """
        y = self.data.counts * self.data.valid
        sens = self.sensitivity()
        excess = max(float(y.sum() - self.fixed.sum()), 1e-3 * max(float(y.sum()), 1.0))
        z = np.zeros(self.size)
        sky_s = sens[: self.n_sky]
        live = sky_s > 0
        f = fraction_sky if self.template is not None else 1.0
        if np.any(live):
            z[: self.n_sky][live] = f * excess / float(sky_s[live].sum())
        if self.template is not None:
            per_det = np.maximum(y.sum(axis=1) - self.fixed.sum(axis=1), 1e-3)
            z[self.n_sky :] = (1 - f) * per_det / sens[self.n_sky :]
        return z

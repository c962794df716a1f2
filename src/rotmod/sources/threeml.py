"""A threeML plugin for the modulator's counts: rotmod's spectral likelihood in joint fits.

threeML fits one astromodels model to the data of several instruments at once, each through
a plugin that returns its log-likelihood for the model's current parameters.
:class:`RotmodLike` is rotmod's: the counts per detector, mask-angle bin and energy channel
of point sources at fixed positions (:class:`~rotmod.sources.spectra.SpectralColumns`), with
:func:`~rotmod.sources.spectra.fit_spectra`'s Poisson likelihood -- the same numbers,
forward-folded through the same response, the background's normalisations profiled out
exactly for each trial of the spectra.  A fit of the modulator alone in threeML therefore
gives ``fit_spectra``'s parameters and errors (tests/sources/test_threeml.py); with other
plugins (e.g. threeML's ``OGIPLike`` of another instrument) the model is fitted to both.

The plugin needs threeML and astromodels (``pip install "rotmod[threeml]"``); the rest of
rotmod does not import this module.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import astropy.units as u
import numpy as np

from rotmod.errors import ParameterError
from rotmod.sources.spectra import SpectralColumns, _SpectraLikelihood
from rotmod.spectral.models import Function, PowerLaw

try:
    from astromodels import Model
    from threeML.plugin_prototype import PluginPrototype
except ImportError as exc:  # pragma: no cover - the message is the point
    raise ImportError("rotmod.sources.threeml needs threeML and astromodels: "
                      'pip install "rotmod[threeml]"') from exc

__all__ = ["RotmodLike"]

#: astromodels' differential flux, as its point sources return it for energies in keV.
_DNDE = 1.0 / (u.keV * u.cm**2 * u.s)


class _NotFinite(Exception):
    """A model's spectrum is not finite at the node energies: outside what it can
    represent, which the fit must see as the edge of the parameters' domain."""


def _dnde(source: Any) -> Function:
    """The astromodels point source's ``dN/dE`` as a :class:`Function` of keV."""
    def dnde(e: np.ndarray) -> np.ndarray:
        value = source(e * u.keV).to_value(_DNDE)
        if not np.all(np.isfinite(value)):
            raise _NotFinite
        return value
    return Function(dnde)


class RotmodLike(PluginPrototype):
    """The modulator's counts of point sources as a threeML plugin.

    Parameters
    ----------
    name : str
        The plugin's name in threeML (a Python identifier, not ``"total"``).
    columns : SpectralColumns
        The sources' energy-resolved response (:func:`rotmod.sources.spectral_columns`):
        their positions are fixed there, so the model's point sources are used for their
        spectra only (their positions in the model are not read).
    counts : array_like
        As :func:`rotmod.sources.fit_spectra`.
    exposure : array_like
        As :func:`rotmod.sources.fit_spectra`.
    sources : str or sequence of str
        The names of the model's point sources, one per source of ``columns``, in its order.
    background : array_like or mapping of str to array_like, optional
        As :func:`rotmod.sources.fit_spectra`.
    background_free : {"level", "detector", "component"}
        As :func:`rotmod.sources.fit_spectra`.
    off_counts : array_like, optional
        As :func:`rotmod.sources.fit_spectra`.
    off_exposure : float or array_like, optional
        As :func:`rotmod.sources.fit_spectra`.

    Notes
    -----
    :meth:`get_log_like` is ``ln L`` of :func:`~rotmod.sources.fit_spectra` (less the
    data's constant, the same for every model), maximised over the background's
    normalisations: those are this plugin's own parameters, profiled rather than handed to
    threeML's minimiser, so threeML's errors are the profile likelihood's, as
    ``fit_spectra``'s.  The spectra are folded by quadrature of the astromodels functions
    (:class:`rotmod.spectral.Function`: within 1e-8 of a node's photons for smooth spectra
    and across Band's break; a line narrower than ~1 keV is not resolved).
    """

    def __init__(self, name: str, columns: SpectralColumns, counts: Any, exposure: Any,
                 sources: str | Sequence[str], *, background: Any = None,
                 background_free: str = "level", off_counts: Any = None,
                 off_exposure: Any = None) -> None:
        names = [sources] if isinstance(sources, str) else list(sources)
        if not isinstance(columns, SpectralColumns):
            raise ParameterError(f"columns must be SpectralColumns, got "
                                 f"{type(columns).__name__}")
        if len(names) != columns.n_sources or not all(isinstance(n, str) for n in names):
            raise ParameterError(f"sources must name the model's point sources, one per "
                                 f"source of columns ({columns.n_sources}), got {sources!r}")
        # Placeholder spectra for the checks: the model's replace them at every evaluation.
        # No warm start: threeML requires ln L to be a function of the parameters alone,
        # bit for bit (it recomputes its minimum and compares).
        self._likelihood = _SpectraLikelihood(
            columns, counts, exposure, [PowerLaw()] * len(names), background,
            background_free, off_counts, off_exposure, warm_start=False)
        self._sources = names
        self._model: Any = None
        super().__init__(name, {})

    def set_model(self, likelihood_model_instance: Any) -> None:
        """Use the astromodels model's point sources named by ``sources``."""
        if not isinstance(likelihood_model_instance, Model):
            raise ParameterError(f"likelihood_model_instance must be an astromodels Model, "
                                 f"got {type(likelihood_model_instance).__name__}")
        point = likelihood_model_instance.point_sources
        missing = [n for n in self._sources if n not in point]
        if missing:
            raise ParameterError(f"sources: the model has no point source {missing[0]!r} "
                                 f"(it has {sorted(point)})")
        self._model = likelihood_model_instance

    def get_log_like(self) -> float:
        """``ln L`` of the counts for the model's current spectra, the background's
        normalisations profiled out; ``-inf`` where a spectrum is not finite at the node
        energies (parameters outside what the model can represent)."""
        if self._model is None:
            raise ParameterError(f"plugin {self.name!r}: set_model first (threeML's "
                                 "JointLikelihood does)")
        spectra = [_dnde(self._model.point_sources[n]) for n in self._sources]
        try:
            return -0.5 * self._likelihood.statistic(spectra)
        except _NotFinite:
            return -np.inf

    def inner_fit(self) -> float:
        """:meth:`get_log_like`: its nuisance parameters are profiled there already."""
        return self.get_log_like()

    def get_number_of_data_points(self) -> int:
        """The bins with exposure (and the off-source bins, if given)."""
        return int(self._likelihood.bins.y.size)

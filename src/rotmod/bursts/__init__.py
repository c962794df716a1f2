"""Bursts: transients found in the event stream, localised and measured.

A burst lasts a few rotations of the mask or less, so its counts are not folded: the
likelihood is that of the time-tagged counts in short bins, with the burst's light curve in
the model (:class:`rotmod.response.UnfoldedResponse`), and the background fitted outside
the burst.

* :func:`search` -- candidates in the detector-summed rates over several timescales and
  energy bands, at a stated false-alarm rate;
* :func:`fit_background`, :func:`burst_light_curve`, :func:`durations` -- the background
  per detector, the Bayesian-block light curve, T90/T50, net counts and peak rate;
* :func:`fit_pulses` -- the burst's light curve as Norris pulses (the model's ``L(t)``);
* :func:`localise_burst` -- the position: a score map of the visible sky (two adjoint
  products), the exact likelihood at its peaks, continuous refits, and the region from the
  likelihood surfaces of every mode (:class:`Posterior`);
* :func:`analyse_burst` -- all of it from a candidate to a :class:`Burst` with a
  GCN-style summary;
* :func:`simulate_burst` -- injected bursts (exact model) for tests and calibration.

See ``docs/bursts.md``.
"""

from rotmod.bursts.analysis import Burst, analyse_burst
from rotmod.bursts.inject import simulate_burst
from rotmod.bursts.localisation import (
    BurstPosition,
    ScoreMap,
    burst_pulses,
    localise_burst,
    search_map,
)
from rotmod.bursts.measure import (
    Background,
    BurstLightCurve,
    Durations,
    burst_light_curve,
    durations,
    fit_background,
    norris_pulse,
    true_durations,
)
from rotmod.bursts.posterior import Posterior
from rotmod.bursts.pulses import PulseLightCurve, fit_pulses
from rotmod.bursts.search import Candidate, SearchResult, search

__all__ = ["Background", "Burst", "BurstLightCurve", "BurstPosition", "Candidate",
           "Durations", "Posterior", "PulseLightCurve", "ScoreMap", "SearchResult",
           "analyse_burst", "burst_light_curve", "burst_pulses", "durations",
           "fit_background", "fit_pulses", "localise_burst",
           "norris_pulse", "search", "search_map", "simulate_burst", "true_durations"]

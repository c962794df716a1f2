"""Analog 3-D photon transport through the rotating slat mask: the models' ground truth.

Each photon of a source at infinity ``(theta, phi)`` reaches a point sampled uniformly on a
detector face (the unobstructed flux); the ray is traced back toward the source through the
mask slab ``L <= z <= L + h`` in the mask frame at the photon's mask angle, its path in
slat material is the sum of its exact 3-D chords through every slat box it meets (slab
method on the two side planes and the top and bottom faces; the mask is infinite, so the
slats are unbounded along their length), and it survives with probability
``exp(-mu * path)``.  Only photopeak transport is simulated (no scattering, no detector
response).  The simulation shares the geometry objects and :mod:`rotmod.conventions` with
the profile models but none of their 1-D reduction.

Two entry points: :func:`simulate_profiles` (transmitted fraction per detector, mask
angle and source, with binomial errors) and :func:`simulate_observation` (a time-tagged
:class:`~rotmod.events.EventList` of a rotating mask); and :func:`simulate_channel_counts`,
the whole chain photon by photon (mask, crystal, resolution) into counts per detector, bin
and energy channel, with the detector transport of :mod:`rotmod.spectral.detector`.
"""

from rotmod._rng import seed_sequence
from rotmod.montecarlo.chain import ChannelCounts, simulate_channel_counts
from rotmod.montecarlo.simulate import (
    MCProfiles,
    chord_lengths,
    simulate_drift,
    simulate_observation,
    simulate_profiles,
)

# PointSources is sky truth (rotmod.sky.sources); it stays importable from here because
# rotmod.montecarlo has documented it (its __all__, the API reference) since the start.
from rotmod.sky.sources import PointSources

__all__ = [
    "ChannelCounts",
    "MCProfiles",
    "PointSources",
    "chord_lengths",
    "seed_sequence",
    "simulate_channel_counts",
    "simulate_drift",
    "simulate_observation",
    "simulate_profiles",
]

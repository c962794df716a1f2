"""Characteristic count-rate profile models.

``standard`` (the paper's Sec. 2), ``advanced`` in three variants (Sec. 3: G0 only, G0 plus
the exact G1, G0 plus the approximation G1~) and ``exact`` (first principles, any geometry,
and the instrument as built: offsets, tilts, slat patterns, finite masks, sources at a
finite distance, thick detectors).  Pick one by name with :func:`get_model` (the names:
``MODELS.names()``); :func:`effective_area` gives a detector's area against zenith and
energy.  A new model is a :class:`ProfileModel` subclass registered with
:func:`register_model` (see :class:`ProfileModel`).
"""

from rotmod.profiles.advanced import AdvancedModel
from rotmod.profiles.area import effective_area
from rotmod.profiles.base import (
    DEFAULT_COMPARISON,
    DEFAULT_MODEL,
    MODELS,
    ProfileModel,
    ProjectedGeometry,
    get_model,
    project,
    register_model,
)
from rotmod.profiles.exact import ExactModel
from rotmod.profiles.standard import StandardModel

__all__ = [
    "DEFAULT_COMPARISON",
    "DEFAULT_MODEL",
    "MODELS",
    "AdvancedModel",
    "ExactModel",
    "ProfileModel",
    "ProjectedGeometry",
    "StandardModel",
    "effective_area",
    "get_model",
    "project",
    "register_model",
]

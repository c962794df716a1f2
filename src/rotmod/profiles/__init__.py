"""Characteristic count-rate profile models.

``standard`` (the paper's Sec. 2), ``advanced`` in three variants (Sec. 3: G0 only, G0 plus
the exact G1, G0 plus the approximation G1~) and ``exact`` (first principles, any geometry).
Pick one by name with :func:`get_model`.
"""

from rotmod.profiles.advanced import AdvancedModel
from rotmod.profiles.base import (
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
    "DEFAULT_MODEL",
    "MODELS",
    "AdvancedModel",
    "ExactModel",
    "ProfileModel",
    "ProjectedGeometry",
    "StandardModel",
    "get_model",
    "project",
    "register_model",
]

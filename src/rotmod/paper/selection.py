"""Which registered models and methods the paper's experiments use, chosen once, by name.

The profile models and reconstruction methods are registries
(:data:`rotmod.profiles.MODELS`, :data:`rotmod.reconstruction.ALGORITHMS`); the report
compares deliberate subsets of them, in a deliberate order.  Those subsets are written here
and nowhere else, and :func:`check_registered` checks each against its registry when this
module is imported, so that a renamed or removed entry fails at once instead of silently
dropping out of a report.  (The figures' default trio is
:data:`rotmod.profiles.DEFAULT_COMPARISON`; each run size's own choices are
:data:`rotmod.paper.report.SIZES`, checked the same way.)
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from rotmod.paper.claims import MONTE_CARLO, PAPER_SPEED_S
from rotmod.profiles import DEFAULT_COMPARISON, MODELS
from rotmod.registry import Registry

__all__ = [
    "IMAGE_PAIR",
    "REFERENCE_MODEL",
    "SPEED_MODELS",
    "VALIDATION_MODELS",
    "check_registered",
]

#: Every model the profile validation compares, in the order of its tables (docs/validation.md)
#: and of the report's results: the exact model first (the reference), then the paper's
#: advanced model with the exact G1, with the approximation G1~ and with G0 alone, and its
#: standard model.
VALIDATION_MODELS: tuple[str, ...] = (
    "exact", "advanced", "advanced-approx", "advanced-g0", "standard",
)

#: The model the others are measured against: first principles, valid for every geometry.
REFERENCE_MODEL = "exact"

#: The responses the summary figure sets side by side: the paper's standard model against
#: the exact one.
IMAGE_PAIR: tuple[str, str] = ("standard", REFERENCE_MODEL)

#: The models the paper timed (Sec. 4.2), in its order: those of :data:`PAPER_SPEED_S`.
SPEED_MODELS: tuple[str, ...] = tuple(k for k in PAPER_SPEED_S if k != MONTE_CARLO)


def check_registered(registry: Registry[Any], names: Iterable[str], where: str) -> None:
    """Refuse a selection naming something ``registry`` does not hold.

    Parameters
    ----------
    registry : Registry
    names : iterable of str
    where : str
        The selection's name, for the message.

    Raises
    ------
    ParameterError
        A name that is not registered (the message lists the registered ones and suggests
        the closest).
    """
    for name in names:
        registry.get(name, parameter=f"{where}: {registry.kind}")


check_registered(MODELS, VALIDATION_MODELS, "VALIDATION_MODELS")
check_registered(MODELS, DEFAULT_COMPARISON, "DEFAULT_COMPARISON")
check_registered(MODELS, IMAGE_PAIR, "IMAGE_PAIR")
check_registered(MODELS, SPEED_MODELS, "SPEED_MODELS (the keys of PAPER_SPEED_S)")

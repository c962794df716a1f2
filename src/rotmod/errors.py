"""The exception family of rotmod.

Every error that a user's input can cause derives from :class:`RotmodError`, itself a
:class:`ValueError`, so callers may catch either.  Messages name the parameter, the value
received and the rule it broke.
"""

from __future__ import annotations

__all__ = [
    "InstrumentMismatchError",
    "MaterialError",
    "ModelValidityError",
    "ParameterError",
    "RotmodError",
    "UnknownNameError",
]


class RotmodError(ValueError):
    """Base class of all rotmod errors caused by input."""


class ParameterError(RotmodError):
    """A parameter is out of its allowed range, has the wrong unit, shape or is not finite."""


class UnknownNameError(ParameterError, KeyError):
    """A name no registry entry has (also a :class:`KeyError`: ``registry[name]`` is a lookup)."""

    # KeyError quotes its message; this one reads like every other rotmod error.
    __str__ = Exception.__str__


class MaterialError(RotmodError):
    """Unknown material, or an energy outside the attenuation database's range."""


class ModelValidityError(RotmodError):
    """A profile model was asked for a geometry or source outside its validity."""


class InstrumentMismatchError(RotmodError):
    """A stored product (e.g. a response) does not match the instrument it is used with."""

"""rotmod: rotating-modulator imaging of hard X-rays and gamma rays.

Its instrument, material and model names (``rotmod.Instrument``, ``rotmod.Material``,
``rotmod.get_model``, ...) load on first use (PEP 562: ``rotmod.Instrument`` imports
:mod:`rotmod.geometry` when first asked for), so that ``rotmod --help`` and a light import
such as ``rotmod.errors`` start without numba and astropy.
"""

from importlib.metadata import PackageNotFoundError, version
from typing import Any

try:
    __version__ = version("rotmod")
except PackageNotFoundError:  # pragma: no cover - running from a source tree
    __version__ = "0.0.0"

from rotmod.errors import (
    InstrumentMismatchError,
    MaterialError,
    ModelValidityError,
    ParameterError,
    RotmodError,
)

__all__ = [
    "DetectorArray",
    "Instrument",
    "InstrumentMismatchError",
    "Mask",
    "Material",
    "MaterialError",
    "ModelValidityError",
    "ParameterError",
    "RotmodError",
    "__version__",
    "get_model",
]


def __getattr__(name: str) -> Any:
    # Function-local on purpose (the structure test lists these): see the module docstring.
    if name in ("DetectorArray", "Instrument", "Mask"):
        from rotmod import geometry

        return getattr(geometry, name)
    if name == "Material":
        from rotmod import materials

        return materials.Material
    if name == "get_model":
        from rotmod import profiles

        return profiles.get_model
    raise AttributeError(f"module 'rotmod' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})

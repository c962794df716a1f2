"""rotmod: rotating-modulator imaging of hard X-rays and gamma rays."""

from importlib.metadata import PackageNotFoundError, version

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
from rotmod.geometry import DetectorArray, Instrument, Mask
from rotmod.materials import Material
from rotmod.profiles import get_model

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

"""rotmod: rotating-modulator imaging of hard X-rays and gamma rays.

Its instrument, material and model names (``rotmod.Instrument``, ``rotmod.Material``,
``rotmod.get_model``, ...) load on first use (PEP 562: ``rotmod.Instrument`` imports
:mod:`rotmod.geometry` when first asked for), so that ``rotmod --help`` and a light import
such as ``rotmod.errors`` start without numba and astropy.
"""

import os
from importlib.metadata import PackageNotFoundError, version
from typing import Any

# numba's OpenMP threads spin while they wait for work by default.  On a shared machine (two
# cores, other jobs) the spinning threads take the cores the working ones need: a source
# detection measured 24 s with passive waiting and 575 s without.  Passive waiting costs a
# few microseconds per parallel launch, nothing next to rotmod's kernels.  A user's own
# setting wins (setdefault); it must be set before OpenMP starts, hence here.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

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

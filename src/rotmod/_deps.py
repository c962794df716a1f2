"""Optional dependencies: imported on first use, with an error that says what to install.

rotmod's core install is what every command needs (numpy, scipy, numba, astropy, matplotlib,
zarr, dask, tqdm, jinja2, ...; all installed from wheels).  Features that only some users
want live in extras (``pip install "rotmod[yaml]"``, ``"rotmod[distributed]"``,
``"rotmod[all]"``).
"""

from __future__ import annotations

import importlib
from types import ModuleType

from rotmod.errors import RotmodError

__all__ = ["MissingDependencyError", "optional_import"]


class MissingDependencyError(RotmodError, ImportError):
    """An optional package a feature needs is not installed."""


def optional_import(module: str, extra: str, feature: str) -> ModuleType:
    """Import ``module`` or raise :class:`MissingDependencyError` naming the extra to install.

    Parameters
    ----------
    module : str
        Module to import, e.g. ``"yaml"``.
    extra : str
        rotmod extra that provides it, e.g. ``"yaml"``.
    feature : str
        What the user asked for, for the message (e.g. ``"YAML instrument files"``).
    """
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise MissingDependencyError(
            f"{feature} need the optional package {module!r}: "
            f'pip install "rotmod[{extra}]"'
        ) from exc

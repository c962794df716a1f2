"""Where a result came from: rotmod's version and commit, the libraries, the machine, the seed.

Recorded on the report page and in ``reproduce.json`` so that a figure can be traced to the
code and the environment that made it.
"""

from __future__ import annotations

import importlib.metadata
import os
import platform
import time
from typing import Any

import rotmod
from rotmod.io.provenance import git_commit
from rotmod.materials import database_provenance

__all__ = ["git_commit", "provenance"]

_LIBRARIES = ("numpy", "scipy", "numba", "astropy", "matplotlib", "zarr", "dask")


def _version(name: str) -> str | None:
    try:
        return importlib.metadata.version(name)
    except importlib.metadata.PackageNotFoundError:
        return None


def provenance(seed: int | None = None) -> dict[str, Any]:
    """A JSON-ready record of the code, libraries, machine and seed of a run."""
    return {
        "rotmod": rotmod.__version__,
        "git_commit": git_commit(),
        "seed": seed,
        "python": platform.python_version(),
        "libraries": {name: _version(name) for name in _LIBRARIES},
        # The attenuation tables ship with rotmod: where they were taken from.
        "attenuation_data": database_provenance(),
        "machine": {
            "platform": platform.platform(),
            "processor": platform.machine(),
            "cpus": os.cpu_count(),
            "hostname": platform.node(),
        },
        "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }

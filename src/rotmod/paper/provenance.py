"""Where a result came from: rotmod's version and commit, the libraries, the machine, the seed.

Recorded on the report page and in ``reproduce.json`` so that a figure can be traced to the
code and the environment that made it.
"""

from __future__ import annotations

import importlib.metadata
import os
import platform
import subprocess
import time
from pathlib import Path
from typing import Any

import rotmod

__all__ = ["git_commit", "provenance"]

_LIBRARIES = ("numpy", "scipy", "numba", "astropy", "matplotlib", "zarr", "dask", "fisx")


def git_commit(start: str | os.PathLike | None = None) -> str | None:
    """The commit (and ``+dirty`` when the work tree has changes) of the checkout holding
    ``start`` (default: this package), or None when it is not a git checkout."""
    where = Path(start) if start is not None else Path(__file__).resolve().parent
    try:
        sha = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=where, capture_output=True, text=True,
            timeout=10, check=True,
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"], cwd=where,
            capture_output=True, text=True, timeout=10, check=True,
        ).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None
    return f"{sha}+dirty" if dirty else sha or None


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
        "machine": {
            "platform": platform.platform(),
            "processor": platform.machine(),
            "cpus": os.cpu_count(),
            "hostname": platform.node(),
        },
        "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }

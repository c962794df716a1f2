"""Matplotlib figures as files, atomically, under the one overwrite policy."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from rotmod.io.atomic import atomic_path, check_overwrite

__all__ = ["save_figure"]


def save_figure(fig: Any, path: str | os.PathLike, *, dpi: int = 120,
                overwrite: bool = False) -> Path:
    """Save a matplotlib figure to ``path`` (its format from the extension, default PNG),
    cropped to its content, atomically.

    Raises
    ------
    ParameterError
        ``path`` exists and ``overwrite`` is false.
    """
    p = check_overwrite(path, overwrite)
    with atomic_path(p) as tmp:
        fig.savefig(tmp, dpi=dpi, bbox_inches="tight", format=p.suffix[1:] or "png")
    return p

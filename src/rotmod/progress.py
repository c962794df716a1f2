"""Progress of long work: one way for every long call to report how far it has got.

A long call takes ``progress``: ``None``/``False`` (silent), ``True`` (a tqdm bar, which also
writes plain lines when stderr is not a terminal) or a callable ``progress(done, total)``
(a GUI, a log, a test).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from rotmod.errors import ParameterError

__all__ = ["Progress", "progress_callbacks"]

#: What a ``progress`` argument may be.
Progress = Callable[[int, int], Any] | bool | None


def progress_callbacks(progress: Progress, total: int, desc: str,
                       unit: str = "it") -> tuple[Callable[[int, int], None], Callable[[], None]]:
    """An ``(update(done, total), close())`` pair for ``progress``.

    Raises
    ------
    ParameterError
        ``progress`` is none of the accepted kinds.
    """
    if progress is None or progress is False:
        return (lambda done, tot: None), (lambda: None)
    if progress is True:
        from tqdm.auto import tqdm  # only with a progress bar (~20 ms)

        bar = tqdm(total=total, desc=desc, unit=unit, unit_scale=True)

        def update(done: int, tot: int) -> None:
            bar.update(done - bar.n)

        return update, bar.close
    if callable(progress):
        return progress, (lambda: None)
    raise ParameterError(f"progress must be None, a bool or a callable, got {progress!r}")

"""Atomic file and folder writes whose modes follow the umask.

Every file rotmod writes goes through :func:`atomic_path` (or :func:`write_text`): the content
is written to a temporary name in the target's folder and renamed over the target only when
complete, so an interruption never leaves a half-written file under the final name.
``tempfile`` creates files 0600 and folders 0700 whatever the umask; the final object gets
the mode a plain ``open()``/``mkdir()`` would have given it (0666/0777 minus the umask), so
results are as readable as the user's other files.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

from rotmod.errors import ParameterError

__all__ = [
    "atomic_dir",
    "atomic_path",
    "check_overwrite",
    "current_umask",
    "remove_stale_dirs",
    "write_text",
]


def check_overwrite(path: str | os.PathLike, overwrite: bool, *, parameter: str = "path",
                    flag: str = "overwrite=True") -> Path:
    """The one overwrite policy: refuse an existing ``path`` unless ``overwrite`` is true.

    Every writer calls this before it starts work, so the refusal costs nothing and the
    message is the same everywhere.

    Parameters
    ----------
    path : str or path-like
    overwrite : bool
    parameter : str
        The caller's name of ``path`` in the message.
    flag : str
        How the caller's user asks to overwrite (the command line: ``"--overwrite"``).

    Raises
    ------
    ParameterError
        ``path`` exists and ``overwrite`` is false.
    """
    p = Path(path)
    if not overwrite and (p.exists() or p.is_symlink()):
        raise ParameterError(
            f"{parameter} {str(p)!r} already exists; pass {flag} to replace it"
        )
    return p


def current_umask() -> int:
    """The process umask (read without changing it for other threads for long)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _default_mode(directory: bool) -> int:
    return (0o777 if directory else 0o666) & ~current_umask()


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success rename it to ``path``.

    The caller writes the whole file to the yielded path (any library that takes a file
    name).  On an exception the temporary file is removed and ``path`` is left untouched.
    """
    p = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=p.parent or ".")
    os.close(fd)
    try:
        yield Path(tmp)
        os.chmod(tmp, _default_mode(False))
        os.replace(tmp, p)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


#: What marks the temporary folders of :func:`atomic_dir` (``.<name>.tmp-<random>``).
_DIR_TAG = ".tmp-"


@contextlib.contextmanager
def atomic_dir(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary folder beside ``path``; on success it replaces ``path``.

    An existing ``path`` is removed only once the new folder is complete.
    """
    p = Path(path)
    tmp = Path(tempfile.mkdtemp(prefix=f".{p.name}{_DIR_TAG}", dir=p.parent or "."))
    try:
        yield tmp
        os.chmod(tmp, _default_mode(True))
        if p.exists():
            shutil.rmtree(p)
        os.replace(tmp, p)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def remove_stale_dirs(folder: str | os.PathLike) -> None:
    """Remove the temporary folders of :func:`atomic_dir` left in ``folder`` by a process that
    was killed before it could clean up (an exception cleans up by itself)."""
    for stale in Path(folder).glob(f".*{_DIR_TAG}*"):
        shutil.rmtree(stale, ignore_errors=True)


def write_text(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)

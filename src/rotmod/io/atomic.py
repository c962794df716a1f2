"""Atomic file and folder writes whose modes follow the umask.

Every file rotmod writes goes through :func:`atomic_path` (or :func:`write_text`): the content
is written to a temporary name in the target's folder and renamed over the target only when
complete, so an interruption never leaves a half-written file under the final name.
``tempfile`` creates files 0600 and folders 0700 whatever the umask; the final object gets
the mode a plain ``open()``/``mkdir()`` would have given it (0666/0777 minus the umask), so
results are as readable as the user's other files.

Every name a writer makes beside its output fits the file system's 255-byte limit whatever
the output's name (:data:`NAME_MAX`): the temporary names keep a shortened start of the
name and a random part, and the fixed names (:func:`sibling`: a response store's
``.partial`` form, a ``.lock``) a shortened start and a hash of the whole name.  None of
them is a fixed name a user may own: a folder being replaced is moved to a fresh temporary
name (:func:`replace_dir`), never to ``<name>.old``.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import shutil
import signal
import tempfile
import threading
from collections.abc import Iterator
from pathlib import Path

from rotmod.errors import ParameterError

__all__ = [
    "NAME_MAX",
    "atomic_dir",
    "atomic_path",
    "check_file_target",
    "check_overwrite",
    "current_umask",
    "remove_stale_dirs",
    "replace_dir",
    "sibling",
    "write_text",
]

#: Longest file name, in bytes, of the file systems rotmod writes to (ext4, XFS, APFS, NTFS).
NAME_MAX = 255
#: Bytes that :func:`tempfile.mkstemp`/:func:`~tempfile.mkdtemp` add around the kept start
#: of a name here: ``.`` + name + ``.`` + 8 random characters + ``.tmp`` (or ``.tmp-`` ...).
_TEMP_EXTRA = 14


def _cut(name: str, nbytes: int) -> str:
    """The longest start of ``name`` that takes at most ``nbytes`` bytes on disk (never half
    a character)."""
    return os.fsencode(name)[:nbytes].decode("utf-8", errors="ignore")


def _temp_stem(p: Path) -> str:
    """The start of ``p``'s name that a temporary name beside it keeps (within NAME_MAX)."""
    return _cut(p.name, NAME_MAX - _TEMP_EXTRA)


def sibling(path: str | os.PathLike, suffix: str) -> Path:
    """``path`` with ``suffix`` added to its name: a fixed name a writer keeps beside its
    output (``.partial``, ``.lock``), the same at every run.

    A name that would pass :data:`NAME_MAX` bytes keeps the start of ``path``'s name and a
    hash of the whole (``<start>~<12 hex digits><suffix>``), so it still fits and still
    differs between outputs.
    """
    p = Path(path)
    if len(os.fsencode(p.name + suffix)) <= NAME_MAX:
        return p.with_name(p.name + suffix)
    tail = f"~{hashlib.sha256(os.fsencode(p.name)).hexdigest()[:12]}{suffix}"
    return p.with_name(_cut(p.name, NAME_MAX - len(os.fsencode(tail))) + tail)


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


def check_file_target(path: str | os.PathLike, *, parameter: str = "path") -> Path:
    """Refuse a file ``path`` that cannot be written: a folder, or in a folder that does not
    exist (said before any work, rather than as the operating system's error at the end).

    Raises
    ------
    ParameterError
        Naming ``parameter`` and the path.
    """
    p = Path(path)
    if p.is_dir():
        raise ParameterError(f"{parameter} {str(p)!r} is a folder; give a file name")
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise ParameterError(f"{parameter} {str(p)!r}: folder {str(parent)!r} does not exist")
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
    p = check_file_target(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{_temp_stem(p)}.", suffix=".tmp", dir=p.parent or ".")
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

    An existing ``path`` is removed only once the new folder is complete
    (:func:`replace_dir`).
    """
    p = Path(path)
    tmp = Path(tempfile.mkdtemp(prefix=f".{_temp_stem(p)}{_DIR_TAG}", dir=p.parent or "."))
    try:
        yield tmp
        os.chmod(tmp, _default_mode(True))
        replace_dir(tmp, p)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


@contextlib.contextmanager
def _interrupts_deferred() -> Iterator[None]:
    """Hold Ctrl-C (and SIGTERM) until the block is done: a pair of renames that must both
    happen, or neither, is never cut in the middle.  The signal is delivered on exit.

    Only the main thread receives Python's signals, and only POSIX can block them; elsewhere
    this does nothing.
    """
    held = {signal.SIGINT, signal.SIGTERM}
    if os.name != "posix" or threading.current_thread() is not threading.main_thread():
        yield
        return
    before = signal.pthread_sigmask(signal.SIG_BLOCK, held)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, before)


def replace_dir(src: str | os.PathLike, dst: str | os.PathLike) -> None:
    """Rename the folder ``src`` to ``dst``, replacing an existing ``dst``.

    An existing ``dst`` is first moved into a fresh temporary folder beside it (a name no
    one else holds: never a fixed one such as ``<dst>.old``, which could be the user's), and
    removed only once ``src`` is in its place.  The two renames run with interrupts held, so
    ``dst`` always holds either the old folder or the new one; if the new one cannot be
    renamed and the old one cannot be put back, the old one is left where it is and the error
    says where.
    """
    s, d = Path(src), Path(dst)
    if not (d.exists() or d.is_symlink()):
        os.replace(s, d)
        return
    trash = Path(tempfile.mkdtemp(prefix=f".{_temp_stem(d)}.old-", dir=d.parent or "."))
    old = trash / "old"
    kept = False  # the old folder must survive: the new one is not in place
    try:
        with _interrupts_deferred():
            os.replace(d, old)
            try:
                os.replace(s, d)
            except BaseException as exc:
                try:
                    os.replace(old, d)  # put the old one back
                except BaseException as again:
                    kept = True
                    if isinstance(again, OSError):
                        raise OSError(
                            f"{str(d)!r} could not be replaced ({exc}) nor restored; the "
                            f"previous folder is kept at {str(old)!r}") from exc
                    raise
                raise
    finally:
        # Reached with the new folder in place, or the old one back (an interrupt held
        # during the renames is raised only after them).
        if not kept:
            shutil.rmtree(trash, ignore_errors=True)


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

"""One writer at a time for an output path.

``PathLock(path)`` takes an exclusive lock on ``<path>.lock`` (a :class:`filelock.FileLock`:
``flock`` on POSIX, ``LockFileEx`` on Windows) for as long as the ``with`` block runs, and
writes the owner's pid, host and start time into it.  A second writer gets a
:class:`LockedError` naming the owner at once (no waiting, no hang).  The operating system
releases the lock when its process dies, however it dies, so a lock left behind by a killed run
is never stale: the next run takes it and resumes.

The lock file does not outlive a run that ends normally: the holder removes it *while it still
holds the lock*, then releases.  That is safe because filelock refuses a lock taken on a file
that was removed meanwhile (its link count is 0; ``filelock._native._unix``), so a peer that
opened the old file just before the removal never believes it holds the lock: it is refused
like any writer that came while the lock was held, and its next run creates a fresh file.
(On Windows a held file cannot be removed; filelock removes it after the release instead.)
Only a run that was killed leaves its ``.lock`` file behind, holding the killed owner's
details; the next run takes it over and removes it when done.
"""

from __future__ import annotations

import json
import os
import socket
import time
from contextlib import suppress
from pathlib import Path
from types import TracebackType

from filelock import FileLock, Timeout

from rotmod.errors import RotmodError
from rotmod.io.atomic import sibling

__all__ = ["LockedError", "PathLock", "lock_path"]


class LockedError(RotmodError):
    """Another live process is writing the same output."""


def _write_owner(fd: int) -> None:
    # Called by filelock with the locked descriptor: this process's details, for the message
    # a second writer gets.  Through the locked descriptor, so it works where a second handle
    # could not write (Windows locks are mandatory).
    info = {"pid": os.getpid(), "host": socket.gethostname(),
            "since": time.strftime("%Y-%m-%d %H:%M:%S")}
    os.ftruncate(fd, 0)
    os.lseek(fd, 0, os.SEEK_SET)
    os.write(fd, json.dumps(info).encode())


def lock_path(path: str | os.PathLike) -> Path:
    """The lock file of the output ``path``: ``<path>.lock`` (:func:`rotmod.io.atomic.sibling`)."""
    return sibling(path, ".lock")


class PathLock:
    """Exclusive, non-blocking lock on ``<path>.lock`` (see the module notes).

    Parameters
    ----------
    path : str or path-like
        The output to protect; the lock file is ``<path>.lock`` beside it (a shortened name
        with a hash when that would be too long: :func:`rotmod.io.atomic.sibling`).

    Raises
    ------
    LockedError
        On entry, when another process (or another ``PathLock`` of this one) holds the lock.
    """

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        self.lock_path = lock_path(self.path)
        self._lock = FileLock(self.lock_path, blocking=False, on_acquired=_write_owner)

    def _owner(self) -> str:
        try:
            owner = json.loads(self.lock_path.read_text() or "{}")
        except (OSError, ValueError, UnicodeDecodeError):  # gone, unreadable or half-written
            owner = {}
        if not isinstance(owner, dict) or not owner:
            return "another process"
        return f"pid {owner.get('pid')} on {owner.get('host')} since {owner.get('since')}"

    def __enter__(self) -> PathLock:
        try:
            self._lock.acquire()
        except Timeout:
            raise LockedError(
                f"{str(self.path)!r} is being written by {self._owner()}; wait for it to finish "
                "(an interrupted run's lock is released with its process: just run again)"
            ) from None
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if not self._lock.is_locked:
            return
        try:
            # Removed while still held (see the module notes); a held file cannot be removed on
            # Windows, where filelock removes it after the release.
            with suppress(OSError):
                self.lock_path.unlink()
        finally:
            self._lock.release()

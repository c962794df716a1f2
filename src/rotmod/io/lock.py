"""One writer at a time for an output path.

``PathLock(path)`` takes an exclusive ``flock`` on ``<path>.lock`` for as long as the ``with``
block runs and writes the owner's pid, host and start time into it.  A second writer gets a
:class:`LockedError` naming the owner at once (no waiting, no hang).  The kernel releases an
``flock`` when its process dies, however it dies, so a lock left behind by a killed run is
never stale: the next run takes it and resumes.
"""

from __future__ import annotations

import fcntl
import json
import os
import socket
import time
from pathlib import Path
from types import TracebackType

from rotmod.errors import RotmodError

__all__ = ["LockedError", "PathLock"]


class LockedError(RotmodError):
    """Another live process is writing the same output."""


class PathLock:
    """Exclusive, non-blocking lock on ``<path>.lock`` (see the module notes)."""

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        self.lock_path = self.path.with_name(self.path.name + ".lock")
        self._fd: int | None = None

    def __enter__(self) -> PathLock:
        fd = os.open(self.lock_path, os.O_RDWR | os.O_CREAT, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            try:
                owner = json.loads(os.pread(fd, 4096, 0).decode() or "{}")
            except (ValueError, UnicodeDecodeError):
                owner = {}
            os.close(fd)
            who = (f"pid {owner.get('pid')} on {owner.get('host')} since {owner.get('since')}"
                   if owner else "another process")
            raise LockedError(
                f"{str(self.path)!r} is being written by {who}; wait for it to finish (an "
                "interrupted run's lock is released with its process: just run again)"
            ) from None
        os.ftruncate(fd, 0)
        info = {"pid": os.getpid(), "host": socket.gethostname(),
                "since": time.strftime("%Y-%m-%d %H:%M:%S")}
        os.pwrite(fd, json.dumps(info).encode(), 0)
        self._fd = fd
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if self._fd is not None:
            os.ftruncate(self._fd, 0)
            fcntl.flock(self._fd, fcntl.LOCK_UN)
            os.close(self._fd)
            self._fd = None

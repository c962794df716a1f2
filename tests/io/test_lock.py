"""The writer's lock: one writer at a time, named; no stale lock after a kill; no litter."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from rotmod.io.lock import LockedError, PathLock

# A child that takes the lock, says so, and waits to be killed.
_HOLDER = """
import sys, time
from rotmod.io.lock import PathLock
with PathLock(sys.argv[1]):
    print("locked", flush=True)
    time.sleep(600)
"""


def _hold(path):
    child = subprocess.Popen([sys.executable, "-c", _HOLDER, str(path)],
                             stdout=subprocess.PIPE, text=True, env=os.environ.copy())
    assert child.stdout.readline().strip() == "locked"
    return child


def test_a_successful_run_leaves_no_lock_file(tmp_path):
    path = tmp_path / "r.zarr"
    with PathLock(path) as lock:
        assert lock.lock_path.exists()
        with pytest.raises(LockedError, match=rf"r\.zarr.* is being written by pid {os.getpid()}"):
            PathLock(path).__enter__()
    assert list(tmp_path.iterdir()) == []
    with PathLock(path):  # and the lock can be taken again
        pass
    assert list(tmp_path.iterdir()) == []


def test_another_process_is_named_and_its_kill_frees_the_lock(tmp_path):
    path = tmp_path / "r.zarr"
    child = _hold(path)
    try:
        with pytest.raises(LockedError, match=rf"pid {child.pid} on .* since "), PathLock(path):
            pass
    finally:
        child.kill()  # SIGKILL on POSIX: no cleanup runs
        child.wait()
        child.stdout.close()
    # The killed holder's lock file stays, but not its lock: the next run takes it over and
    # removes the file when it is done.
    assert (tmp_path / "r.zarr.lock").exists()
    with PathLock(path):
        pass
    assert list(tmp_path.iterdir()) == []

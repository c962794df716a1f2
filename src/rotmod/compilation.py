"""A first run on a new machine: numba compiles rotmod's kernels once, said and shortened.

rotmod's kernels are compiled by numba on their first use and kept in numba's cache (next to
the sources, or ``NUMBA_CACHE_DIR``), so only a machine's first run of each pays for it
(the README's first command: 21 s cold against 11 s warm on 2 cores;
``benchmarks/bench_coldstart.py``, ``docs/response.md``).  Two things make that wait
shorter and not silent:

* :func:`rotmod.progress.compile_notice` says when compilation starts and how long it took
  (the command line wraps every command in it);
* :func:`compile_in_background` starts a second process, at the first compilation only
  (a warm cache never starts it), that compiles the kernels a command will need later
  (:func:`warm_kernels`) while the first process compiles the ones it needs now; the
  first then loads the second's from the cache.

``python -m rotmod.compilation NAME ...`` is the second process.
"""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
from collections.abc import Iterator, Sequence

import numpy as np
from numba.core import event

from rotmod.geometry import DetectorArray, Instrument, Mask
from rotmod.montecarlo import PointSources, simulate_observation, simulate_profiles
from rotmod.profiles import get_model
from rotmod.progress import compiles_rotmod

__all__ = ["MC_OBSERVATION", "MC_PROFILES", "BackgroundCompilation", "compile_in_background",
           "warm_kernels"]

#: Seconds a background compilation gets to stop when the block ends, before it is killed.
STOP_TIMEOUT = 5.0


#: Names of the Monte Carlo's kernels among the models of :func:`warm_kernels`: its
#: profiles (:func:`~rotmod.montecarlo.simulate_profiles`) and its event lists
#: (:func:`~rotmod.montecarlo.simulate_observation`).
MC_PROFILES, MC_OBSERVATION = "monte-carlo-profiles", "monte-carlo-observation"


def warm_kernels(names: Sequence[str]) -> None:
    """Compile (or load from numba's cache) the kernels of ``names``: profile models on the
    ideal instrument, and the Monte Carlo's (:data:`MC_PROFILES`, :data:`MC_OBSERVATION`).
    Each is evaluated once on a tiny case, in the order given, with the argument types of a
    real run (so the cache entries are the ones a real run looks up).

    Raises
    ------
    rotmod.errors.RotmodError
        An unknown model.
    """
    # a = b = c (the standard model's domain), two detectors (a single detector's positions
    # would pass as a contiguous read-only column: another specialisation than a run's).
    inst = Instrument(Mask(1.0, 1.0, 1.0, 10.0),
                      DetectorArray(np.array([[0.0, 0.0], [2.0, 0.0]]), 1.0),
                      rotation_period=10.0)
    for name in names:
        if name == MC_OBSERVATION:
            simulate_observation(inst, PointSources([1.0], [0.0], rate=1.0, energy=300.0),
                                 t_stop=1.0, background=1.0, seed=0)
        elif name == MC_PROFILES:
            simulate_profiles(inst, [1.0], [0.0], xi=[0.0, 1.0], n_photons=1, seed=0,
                              energy=300.0)
        else:
            get_model(name).profile(inst, [1.0], [0.0], [0.0, 1.0], energy=300.0)


class BackgroundCompilation:
    """The second process of :func:`compile_in_background` (if it started)."""

    def __init__(self, cmd: list[str]) -> None:
        self._cmd = cmd
        self._proc: subprocess.Popen[bytes] | None = None
        self._tried = False

    def start(self) -> None:
        """Start the process (once; later calls do nothing)."""
        if self._tried:
            return
        self._tried = True
        # Called inside numba's compiler: a process that cannot start (no executable, no
        # resources) only loses the help, never the run.
        with contextlib.suppress(OSError, ValueError):
            self._proc = subprocess.Popen(self._cmd, stdin=subprocess.DEVNULL,
                                          stdout=subprocess.DEVNULL,
                                          stderr=subprocess.DEVNULL)

    @property
    def running(self) -> bool:
        """Whether the process started and has not ended."""
        return self._proc is not None and self._proc.poll() is None

    def finish(self) -> None:
        """Wait for the process to end, and start none after: before work that must have
        the cores to itself (timings)."""
        self._tried = True
        if self._proc is not None:
            self._proc.wait()

    def stop(self) -> None:
        """End the process: terminated, killed after :data:`STOP_TIMEOUT` s."""
        if self._proc is None:
            return
        self._proc.terminate()
        try:
            self._proc.wait(STOP_TIMEOUT)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()


def _cores() -> int:
    """The cores this process may run on (its affinity, not the machine's count)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # no affinity on this platform
        return os.cpu_count() or 1


@contextlib.contextmanager
def compile_in_background(names: Sequence[str]) -> Iterator[BackgroundCompilation]:
    """While the block runs, compile the kernels of ``names`` (as :func:`warm_kernels`) in
    a second process, started at the block's first compilation of a rotmod kernel.

    With a warm cache nothing compiles and nothing starts.  On a cold one the second
    process runs :func:`warm_kernels` of ``names`` in their order while the block compiles
    what it needs first; the block then loads from numba's cache whatever the second has
    finished.  So give ``names`` as the kernels the block needs *after* its first long
    compilation, in the order it needs them (a kernel both compile at once is compiled
    twice).  The block gets a :class:`BackgroundCompilation`: ``finish()`` before work
    that is timed.  The process is stopped when the block ends (killed after
    :data:`STOP_TIMEOUT`); what it had not finished, the block did not need.  Nothing starts
    with one core.
    """
    bg = BackgroundCompilation(_command(list(names)))

    class _Listener(event.Listener):
        def on_start(self, ev: event.Event) -> None:
            if compiles_rotmod(ev):
                bg.start()

        def on_end(self, ev: event.Event) -> None:
            pass

    if _cores() < 2:
        yield bg
        return
    try:
        with event.install_listener("numba:compile", _Listener()):
            yield bg
    finally:
        bg.stop()


def _command(names: list[str]) -> list[str]:
    """The second process of :func:`compile_in_background`."""
    return [sys.executable, "-m", "rotmod.compilation", *names]


def _main(argv: Sequence[str]) -> int:
    """``python -m rotmod.compilation NAME ...``: :func:`warm_kernels` of the names."""
    warm_kernels(list(argv))
    return 0


if __name__ == "__main__":  # pragma: no cover - the background process
    sys.exit(_main(sys.argv[1:]))

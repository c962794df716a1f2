"""Progress of long work: one way for every long call to report how far it has got.

A long call takes ``progress``: ``None``/``False`` (silent), ``True`` (a :class:`Progress`:
a tqdm bar on a terminal or in Jupyter, log lines every few seconds everywhere else, so a
batch job is never silent) or a callable ``progress(done, total)`` (a GUI, a log, a test).
"""

from __future__ import annotations

import contextlib
import logging
import sys
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

from rotmod.errors import ParameterError

__all__ = ["Progress", "ProgressArg", "compile_notice", "compiles_rotmod", "progress_callbacks"]

log = logging.getLogger(__name__)

#: What a ``progress`` argument may be.
ProgressArg = Callable[[int, int], Any] | bool | None

#: Seconds between progress lines when stderr is not a terminal (logs, batch jobs, CI).
PROGRESS_INTERVAL = 5.0


def _interactive() -> bool:
    """Whether a progress bar is seen: stderr is a terminal, or a Jupyter kernel (whose
    stderr is no TTY but shows tqdm's widget) imported this process's code."""
    return sys.stderr.isatty() or "ipykernel" in sys.modules


class Progress:
    """Progress of ``total`` steps: a tqdm bar on a terminal, log lines everywhere else.

    On a terminal (stderr is a TTY) or in a Jupyter kernel it draws a tqdm bar.  Off a
    terminal (a log file, a batch job) a bar would be a wall of carriage returns, so it logs
    ``desc: done/total (pct), elapsed`` on the ``rotmod.progress`` logger at INFO
    every ``interval`` seconds instead (configure :mod:`logging` to see them; the command
    line does), from a daemon thread:
    the line comes even while no step completes (numba compiling the first kernel can take
    minutes), so a long job is never silent.  The first line comes after ``interval``
    seconds, so short work logs nothing.

    Use as a context manager; :meth:`update` adds steps and :meth:`update_to` has the
    ``progress(done, total)`` signature of the library's callbacks
    (:func:`rotmod.montecarlo.simulate_observation`, ...).

    Parameters
    ----------
    total : int or None
        Number of steps (``None``: unknown, e.g. solver iterations).
    desc : str
        What is progressing (the start of each line).
    unit : str
        Name of a step.
    interval : float
        Seconds between log lines off a terminal.
    tty : bool, optional
        Force the bar (``True``) or the log lines (``False``); default a bar when stderr is
        a TTY or the code runs in a Jupyter kernel.
    """

    def __init__(self, total: int | None, desc: str, unit: str = "it", *,
                 interval: float = PROGRESS_INTERVAL, tty: bool | None = None) -> None:
        self.total, self.desc, self.unit, self.done = total, desc, unit, 0
        self.interval = float(interval)
        self._t0 = time.monotonic()
        self._stop = threading.Event()
        self._bar: Any = None
        self._thread: threading.Thread | None = None
        if _interactive() if tty is None else tty:
            from tqdm.auto import tqdm  # only with a progress bar (~20 ms)

            self._bar = tqdm(total=total, desc=desc, unit=unit, file=sys.stderr)
        else:
            self._thread = threading.Thread(target=self._beat, name="rotmod-progress",
                                            daemon=True)
            self._thread.start()

    def line(self) -> str:
        """The progress line: ``desc: done/total unit (pct), elapsed s``."""
        elapsed = time.monotonic() - self._t0
        if self.total:
            return (f"{self.desc}: {self.done}/{self.total} {self.unit} "
                    f"({100.0 * self.done / self.total:.0f}%), {elapsed:.0f} s")
        return f"{self.desc}: {self.done} {self.unit}, {elapsed:.0f} s"

    def _beat(self) -> None:
        while not self._stop.wait(self.interval):
            log.info("%s", self.line())

    def update(self, n: int = 1) -> None:
        """``n`` more steps done."""
        self.done += int(n)
        if self._bar is not None:
            self._bar.update(int(n))

    def update_to(self, done: int, total: int | None = None) -> None:
        """``done`` steps of ``total`` (a ``progress(done, total)`` callback)."""
        if total is not None and total != self.total:
            self.total = int(total)
            if self._bar is not None:
                self._bar.total = self.total
        self.update(int(done) - self.done)

    def close(self) -> None:
        """Stop the bar or the log lines (logging a last line if any was logged)."""
        self._stop.set()
        if self._bar is not None:
            self._bar.close()
        elif time.monotonic() - self._t0 >= self.interval:
            log.info("%s (done)", self.line())

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def progress_callbacks(progress: ProgressArg, total: int, desc: str,
                       unit: str = "it") -> tuple[Callable[[int, int], None], Callable[[], None]]:
    """An ``(update(done, total), close())`` pair for a ``progress`` argument.

    Raises
    ------
    ParameterError
        ``progress`` is none of the accepted kinds.
    """
    if progress is None or progress is False:
        return (lambda done, tot: None), (lambda: None)
    if progress is True:
        bar = Progress(total, desc, unit)
        return bar.update_to, bar.close
    if callable(progress):
        return progress, (lambda: None)
    raise ParameterError(f"progress must be None, a bool or a callable, got {progress!r}")


def compiles_rotmod(ev: Any) -> bool:
    """Whether a numba ``numba:compile`` event is one of rotmod's kernels."""
    module = getattr(ev.data["dispatcher"].py_func, "__module__", None) or ""
    return module.startswith("rotmod")


@contextlib.contextmanager
def compile_notice(say: Callable[[str], Any]) -> Iterator[None]:
    """Say when rotmod's numba kernels compile (their first use on a machine), and for how
    long: otherwise a first run sits silent while it compiles.

    ``say`` gets one line when the first of rotmod's kernels starts compiling and one with
    the count and the time when the block ends.  Kernels loaded from numba's cache do not
    compile and say nothing.  (numba is imported here, not by this module: the command
    line's ``--help`` loads none.)
    """
    from numba.core import event

    state = {"depth": 0, "count": 0, "seconds": 0.0, "t0": 0.0}

    class _Listener(event.Listener):
        # These run inside numba's compiler: nothing here may raise into it.
        def on_start(self, ev: event.Event) -> None:
            if not compiles_rotmod(ev):
                return
            state["depth"] += 1
            if state["depth"] == 1:
                state["t0"] = time.perf_counter()
                if state["count"] == 0:
                    with contextlib.suppress(Exception):
                        say("rotmod: compiling numba kernels for their first use on this "
                            "machine (cached for later runs) ...")

        def on_end(self, ev: event.Event) -> None:
            if not compiles_rotmod(ev):
                return
            state["depth"] -= 1
            state["count"] += 1
            if state["depth"] == 0:
                state["seconds"] += time.perf_counter() - state["t0"]

    try:
        with event.install_listener("numba:compile", _Listener()):
            yield
    finally:
        n = state["count"]
        if n:
            say(f"rotmod: compiled {n} numba kernel{'s' if n > 1 else ''} in "
                f"{state['seconds']:.0f} s (once per machine)")

"""The ``rotmod`` command line: thin subcommands over the library that chain through files.

::

    rotmod profile     profiles of chosen sources and models (table + plot)
    rotmod simulate    Monte Carlo observation -> FITS event list
    rotmod fold        event list -> folded profiles (FITS)
    rotmod response    build and store a response (zarr), on Dask when given a scheduler
    rotmod reconstruct folded profiles + response -> FITS image + plot
    rotmod detect      the sources in the data -> catalogue, TS map, regions
    rotmod lightcurve  fluxes of catalogued sources per time interval -> table + plot
    rotmod burst       bursts in an event list -> positions, regions, durations, summaries
    rotmod design      mask design trade-off (Pareto front)
    rotmod reproduce   regenerate the seed paper's results with an HTML report

The top-level parser imports no science: each subcommand's module (which imports what its
options need) is imported only when that subcommand runs or shows its help, so ``rotmod
--help`` stays fast.  Logging goes to stderr with timestamps (``-v`` debug, ``-q`` warnings
only); long work reports progress there (a bar on a terminal, a line every few seconds
elsewhere).

Exit codes: 0 success; 2 a usage error or a user error (bad option, bad or missing file,
invalid parameter: one ``rotmod: error: ...`` line on stderr); 1 an unexpected failure
(a traceback, which is a bug to report); 130 interrupted.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import logging
import os
import signal
import sys
import threading
import traceback
from collections.abc import Iterator, Sequence

from rotmod import __version__
from rotmod.errors import RotmodError
from rotmod.progress import compile_notice

__all__ = ["build_parser", "main"]

EXIT_OK = 0
EXIT_UNEXPECTED = 1
EXIT_USER = 2
EXIT_INTERRUPTED = 130

#: Subcommand -> (module in this package, one-line help).  The modules are imported lazily
#: (importlib, same package): the science stack loads only for the command that runs.
SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "profile": ("_profile", "profiles of chosen sources and models (table + plot)"),
    "simulate": ("_simulate", "Monte Carlo observation -> FITS event list"),
    "fold": ("_fold", "event list -> folded profiles (FITS)"),
    "response": ("_response", "build and store a response (zarr); on Dask with --scheduler"),
    "reconstruct": ("_reconstruct", "folded profiles + response -> FITS image + plot"),
    "detect": ("_detect", "find the sources in the data -> catalogue, TS map, regions"),
    "lightcurve": ("_lightcurve",
                   "fluxes of catalogued sources per time interval -> table + plot"),
    "burst": ("_burst", "find, localise and measure bursts -> summaries, regions, maps"),
    "design": ("_design", "mask design trade-off (Pareto front)"),
    "reproduce": ("_reproduce", "regenerate the seed paper's results with an HTML report"),
}

#: Why detectors on the rotation axis image a source and its mirror alike (docs/cli.md).
MIRROR_NOTE = (
    "Mirror sources: the mask looks the same after a half turn about the rotation axis, "
    "which takes a source at (theta, phi) to its mirror at (theta, phi + 180 deg) and a "
    "detector at r to -r. A detector on the axis goes to itself and records the same "
    "profile for both, so an instrument whose detectors all sit on the axis (the 'paper' "
    "preset) cannot tell them apart, and the commands warn. An array with detectors off the "
    "axis (the 'prototype' preset) can, even a point-symmetric one: the mirror seen by the "
    "detector at r is the source seen by the detector at -r, and the folded data keep the "
    "detectors apart."
)

_EPILOG = (
    "Run 'rotmod COMMAND --help' for the options of a command; instruments are TOML files or "
    "presets (listed there). A chain: rotmod simulate -i prototype ... -o events.fits; rotmod "
    "fold events.fits -o folded.fits; rotmod response -i prototype ... -o response.zarr; "
    f"rotmod reconstruct folded.fits response.zarr -o image.fits. {MIRROR_NOTE}"
)


def _module(name: str) -> object:
    return importlib.import_module(f"{__name__}.{SUBCOMMANDS[name][0]}")


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The ``rotmod`` argument parser.

    Parameters
    ----------
    command : str, optional
        Load only this subcommand's options (the others are listed with their help but not
        imported); default: every subcommand's.
    """
    parser = argparse.ArgumentParser(
        prog="rotmod",
        description="Rotating-modulator (RM) gamma-ray imaging: profiles, Monte Carlo, "
        "responses, reconstruction, mask design and the seed paper's results.",
        epilog=_EPILOG,
    )
    parser.add_argument("--version", action="version", version=f"rotmod {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0,
                        help="log more (-v debug)")
    parser.add_argument("-q", "--quiet", action="store_true",
                        help="log warnings and errors only (no progress)")
    parser.add_argument("--debug", action="store_true",
                        help="show the full traceback of any error")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (_, help_) in SUBCOMMANDS.items():
        if command is None or name == command:
            _module(name).register(sub)  # type: ignore[attr-defined]
            sub.choices[name].add_argument(
                "--time-budget", default=None, metavar="DURATION",
                help="run work estimated to take up to DURATION ('3h', '90m', '2d', seconds "
                "or 'inf'; default ROTMOD_TIME_BUDGET, else 1h): longer requests are "
                "refused before they start, with the estimate")
        else:
            sub.add_parser(name, help=help_, add_help=False)
    return parser


def _command_of(argv: Sequence[str]) -> str:
    """The subcommand in ``argv``: its first word that is not an option ("" if none)."""
    return next((a for a in argv if not a.startswith("-")), "")


@contextlib.contextmanager
def cli_logging(verbose: int = 0, quiet: bool = False) -> Iterator[None]:
    """Log ``rotmod`` messages to stderr with a timestamp while a command runs: info by
    default (progress lines, notes, warnings), debug with ``-v``, warnings only with
    ``--quiet``.  The handler and level are undone on exit, so that calling :func:`main` in
    a process (tests, notebooks) leaves its logging as it was."""
    level = logging.WARNING if quiet else (logging.DEBUG if verbose else logging.INFO)
    logger = logging.getLogger("rotmod")
    handler = logging.StreamHandler(sys.stderr)  # the current stderr (a test may replace it)
    handler.setFormatter(logging.Formatter("%(asctime)s rotmod: %(levelname)s: %(message)s",
                                           datefmt="%Y-%m-%dT%H:%M:%S"))
    old_level, old_propagate = logger.level, logger.propagate
    logger.addHandler(handler)
    logger.setLevel(level)
    logger.propagate = False  # one line per message, not another from a root handler
    try:
        yield
    finally:
        logger.removeHandler(handler)
        logger.setLevel(old_level)
        logger.propagate = old_propagate


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``rotmod`` command line.

    Parameters
    ----------
    argv : sequence of str, optional
        Arguments without the program name (default ``sys.argv[1:]``).

    Returns
    -------
    int
        The exit code (0 ok, 2 usage or user error, 1 unexpected error, 130 interrupted).
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    with _sigint() as interrupted:
        try:
            return _run(argv, interrupted)
        except KeyboardInterrupt:  # also while the command's modules load
            print("rotmod: interrupted", file=sys.stderr)
            return EXIT_INTERRUPTED


@contextlib.contextmanager
def _sigint() -> Iterator[list[bool]]:
    """While a command runs, Ctrl-C (SIGINT) raises KeyboardInterrupt as usual and is also
    recorded (the yielded list holds ``True``), so that an interrupt that a library turned
    into an error of its own still exits :data:`EXIT_INTERRUPTED`.  Only Python's default
    handler is replaced (a SIGINT that the parent ignores stays ignored), and only in the
    main thread; the old handler comes back on exit."""
    seen = [False]
    if (threading.current_thread() is not threading.main_thread()
            or signal.getsignal(signal.SIGINT) is not signal.default_int_handler):
        yield seen
        return

    def handler(signum: int, frame: object) -> None:
        seen[0] = True
        raise KeyboardInterrupt

    signal.signal(signal.SIGINT, handler)
    try:
        yield seen
    finally:
        signal.signal(signal.SIGINT, signal.default_int_handler)


def _run(argv: list[str], interrupted: list[bool]) -> int:
    parser = build_parser(_command_of(argv))
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, --version or a usage error
        code = exc.code
        return code if isinstance(code, int) else (EXIT_OK if code is None else EXIT_USER)
    if not getattr(args, "func", None):
        parser.print_help(sys.stderr)
        return EXIT_USER
    # The command as given, for the provenance cards of the files a command writes.
    args.command_line = ["rotmod", *argv]
    try:
        with (cli_logging(args.verbose, args.quiet), _compile_notice(args.quiet),
              _time_budget(getattr(args, "time_budget", None))):
            return int(args.func(args) or EXIT_OK)
    except (RotmodError, OSError) as exc:  # a UserError is a RotmodError
        if interrupted[0] and not args.debug:
            raise KeyboardInterrupt from None  # an interrupt a library reported as its error
        if args.debug:
            raise
        print(f"rotmod: error: {_describe(exc)}", file=sys.stderr)
        return EXIT_USER
    except Exception as exc:  # a bug: show it
        if interrupted[0] and not args.debug:
            raise KeyboardInterrupt from None
        if args.debug:
            raise

        traceback.print_exc()
        print(f"rotmod: unexpected error ({type(exc).__name__}); this is a bug, please "
              "report it with the traceback above", file=sys.stderr)
        return EXIT_UNEXPECTED


@contextlib.contextmanager
def _time_budget(text: str | None) -> Iterator[None]:
    """``--time-budget``: ``ROTMOD_TIME_BUDGET`` for the command's duration, checked before
    any work by the one place that reads it, :func:`rotmod.limits.time_budget` (loaded like
    the subcommands, on use: ``rotmod --help`` imports no Dask)."""
    if text is None:
        yield
        return
    old = os.environ.get("ROTMOD_TIME_BUDGET")
    os.environ["ROTMOD_TIME_BUDGET"] = text
    try:
        importlib.import_module("rotmod.limits").time_budget()
        yield
    finally:
        if old is None:
            del os.environ["ROTMOD_TIME_BUDGET"]
        else:
            os.environ["ROTMOD_TIME_BUDGET"] = old


def _compile_notice(quiet: bool) -> contextlib.AbstractContextManager[None]:
    """Say on stderr when numba compiles rotmod's kernels (not with ``-q``)."""
    if quiet:
        return contextlib.nullcontext()
    return compile_notice(lambda msg: print(msg, file=sys.stderr, flush=True))


def _describe(exc: BaseException) -> str:
    if isinstance(exc, OSError) and exc.filename and exc.strerror:
        return f"{exc.filename}: {exc.strerror}"
    return str(exc) or type(exc).__name__


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

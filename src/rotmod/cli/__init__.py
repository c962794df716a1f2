"""The ``rotmod`` command line: thin subcommands over the library that chain through files.

::

    rotmod profile     profiles of chosen sources and models (table + plot)
    rotmod simulate    Monte Carlo observation -> FITS event list
    rotmod fold        event list -> folded profiles (FITS)
    rotmod response    build and store a response (zarr), on Dask when given a scheduler
    rotmod reconstruct folded profiles + response -> FITS image + plot
    rotmod design      mask design trade-off (Pareto front)
    rotmod reproduce   regenerate the seed paper's results with an HTML report

Exit codes: 0 success; 2 a usage error or a user error (bad option, bad or missing file,
invalid parameter: one ``rotmod: error: ...`` line on stderr); 1 an unexpected failure
(a traceback, which is a bug to report); 130 interrupted.
"""

from __future__ import annotations

import argparse
import logging
import sys
import traceback
from collections.abc import Sequence

from rotmod import __version__
from rotmod.cli import (
    _design,
    _fold,
    _profile,
    _reconstruct,
    _reproduce,
    _response,
    _simulate,
)
from rotmod.cli._common import UserError
from rotmod.errors import RotmodError

__all__ = ["build_parser", "main"]

EXIT_OK = 0
EXIT_UNEXPECTED = 1
EXIT_USER = 2
EXIT_INTERRUPTED = 130

_SUBCOMMANDS = (_profile, _simulate, _fold, _response, _reconstruct, _design, _reproduce)


def build_parser() -> argparse.ArgumentParser:
    """The ``rotmod`` argument parser with every subcommand."""
    parser = argparse.ArgumentParser(
        prog="rotmod",
        description="Rotating-modulator (RM) gamma-ray imaging: profiles, Monte Carlo, "
        "responses, reconstruction, mask design and the seed paper's results.",
        epilog="Run 'rotmod COMMAND --help' for the options of a command. Instruments are "
        "TOML files or the presets 'paper' and 'prototype'.",
    )
    parser.add_argument("--version", action="version", version=f"rotmod {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0,
                        help="log more (-v info, -vv debug)")
    parser.add_argument("--debug", action="store_true",
                        help="show the full traceback of any error")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for mod in _SUBCOMMANDS:
        mod.register(sub)
    return parser


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
    parser = build_parser()
    try:
        args = parser.parse_args(list(argv) if argv is not None else None)
    except SystemExit as exc:  # --help, --version or a usage error
        code = exc.code
        return code if isinstance(code, int) else (EXIT_OK if code is None else EXIT_USER)
    if not getattr(args, "func", None):
        parser.print_help(sys.stderr)
        return EXIT_USER
    level = {0: logging.WARNING, 1: logging.INFO}.get(args.verbose, logging.DEBUG)
    logging.basicConfig(level=level, format="rotmod: %(levelname)s: %(message)s")
    logging.getLogger("rotmod").setLevel(level)
    try:
        return int(args.func(args) or EXIT_OK)
    except KeyboardInterrupt:
        print("rotmod: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except (RotmodError, UserError, OSError) as exc:
        if args.debug:
            raise
        print(f"rotmod: error: {_describe(exc)}", file=sys.stderr)
        return EXIT_USER
    except Exception as exc:  # a bug: show it
        if args.debug:
            raise

        traceback.print_exc()
        print(f"rotmod: unexpected error ({type(exc).__name__}); this is a bug, please "
              "report it with the traceback above", file=sys.stderr)
        return EXIT_UNEXPECTED


def _describe(exc: BaseException) -> str:
    if isinstance(exc, OSError) and exc.filename and exc.strerror:
        return f"{exc.filename}: {exc.strerror}"
    return str(exc) or type(exc).__name__


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
